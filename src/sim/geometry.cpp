// Primitives of the simulator: exact ray casts (with normals) and exact signed distances in each
// primitive's own frame, and the primitives that make up objects, furniture and the room.
#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "planesdf/sim.hpp"
#include "world.hpp"

namespace planesdf::sim {
namespace {
using detail::Hit;
using detail::kInf;
using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr double kTMin = 1e-9;  ///< hits closer than this along the ray are ignored

// ---- local ray casts (frame of the primitive; direction not necessarily unit) -----------------

Hit rayBox(const Vector3d& o, const Vector3d& d, const Vector3d& half) {
  double t0 = -kInf, t1 = kInf;
  int axis0 = 0, axis1 = 0;
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) {
      if (std::abs(o[i]) > half[i]) return {};
      continue;
    }
    double a = (-half[i] - o[i]) / d[i];
    double b = (half[i] - o[i]) / d[i];
    if (a > b) std::swap(a, b);
    if (a > t0) {
      t0 = a;
      axis0 = i;
    }
    if (b < t1) {
      t1 = b;
      axis1 = i;
    }
  }
  if (t0 > t1 || t1 <= kTMin) return {};
  Hit hit;
  const bool entering = t0 > kTMin;
  hit.t = entering ? t0 : t1;
  const int axis = entering ? axis0 : axis1;
  hit.normal = Vector3d::Zero();
  const double coord = o[axis] + hit.t * d[axis];
  hit.normal[axis] = coord >= 0.0 ? 1.0 : -1.0;
  return hit;
}

/// Real roots of a t^2 + b t + c (numerically stable); returns how many (0, 1 or 2).
int solveQuadratic(double a, double b, double c, double& r0, double& r1) {
  const double scale = std::max({std::abs(a), std::abs(b), std::abs(c)});
  if (scale == 0.0) return 0;
  if (std::abs(a) <= 1e-14 * scale) {
    if (b == 0.0) return 0;
    r0 = r1 = -c / b;
    return 1;
  }
  const double disc = b * b - 4.0 * a * c;
  if (disc < 0.0) return 0;
  const double q = -0.5 * (b + std::copysign(std::sqrt(disc), b));
  r0 = q / a;
  r1 = q != 0.0 ? c / q : r0;
  if (r0 > r1) std::swap(r0, r1);
  return 2;
}

/// Capped cone (frustum) about z, z in [-h, h], radius r_bottom at -h and r_top at +h; a cylinder
/// when both radii are equal.
Hit rayCone(const Vector3d& o, const Vector3d& d, double r_bottom, double r_top, double h) {
  Hit best;
  const double k = (r_top - r_bottom) / (2.0 * h);  // radius grows by k per unit z
  const double m = 0.5 * (r_bottom + r_top);        // radius at z = 0
  const double w = m + k * o.z();
  const double a = d.x() * d.x() + d.y() * d.y() - k * k * d.z() * d.z();
  const double b = 2.0 * (o.x() * d.x() + o.y() * d.y() - k * d.z() * w);
  const double c = o.x() * o.x() + o.y() * o.y() - w * w;
  double r0 = 0.0, r1 = 0.0;
  const int n = solveQuadratic(a, b, c, r0, r1);
  for (int i = 0; i < n; ++i) {
    const double t = i == 0 ? r0 : r1;
    if (t <= kTMin || t >= best.t) continue;
    const Vector3d p = o + t * d;
    if (std::abs(p.z()) > h) continue;
    const double rho = std::hypot(p.x(), p.y());
    best.t = t;
    best.normal = rho > 0.0 ? Vector3d(p.x() / rho, p.y() / rho, -k).normalized()
                            : Vector3d(0.0, 0.0, p.z() >= 0.0 ? 1.0 : -1.0);
  }
  if (d.z() != 0.0) {
    for (const double zc : {-h, h}) {
      const double r = zc < 0.0 ? r_bottom : r_top;
      if (r <= 0.0) continue;
      const double t = (zc - o.z()) / d.z();
      if (t <= kTMin || t >= best.t) continue;
      const Vector3d p = o + t * d;
      if (p.x() * p.x() + p.y() * p.y() > r * r) continue;
      best.t = t;
      best.normal = Vector3d(0.0, 0.0, zc < 0.0 ? -1.0 : 1.0);
    }
  }
  return best;
}

Hit raySphere(const Vector3d& o, const Vector3d& d, double r) {
  double r0 = 0.0, r1 = 0.0;
  const int n = solveQuadratic(d.squaredNorm(), 2.0 * o.dot(d), o.squaredNorm() - r * r, r0, r1);
  Hit hit;
  if (n == 0) return hit;
  if (r0 > kTMin)
    hit.t = r0;
  else if (r1 > kTMin)
    hit.t = r1;
  else
    return hit;
  hit.normal = (o + hit.t * d).normalized();
  return hit;
}

double torusDistance(const Vector3d& p, double major, double minor) {
  return std::hypot(std::hypot(p.x(), p.y()) - major, p.z()) - minor;
}

/// Torus in the xy plane by sphere tracing its exact distance from the entry of its bounding box.
Hit rayTorus(const Vector3d& o, const Vector3d& d, double major, double minor) {
  const double len = d.norm();
  if (len == 0.0) return {};
  const Vector3d u = d / len;
  const Vector3d half(major + minor, major + minor, minor);
  // The slab interval of the bounding box along the unit ray.
  double t0 = 0.0, t1 = kInf;
  for (int i = 0; i < 3; ++i) {
    if (u[i] == 0.0) {
      if (std::abs(o[i]) > half[i]) return {};
      continue;
    }
    double a = (-half[i] - o[i]) / u[i];
    double b = (half[i] - o[i]) / u[i];
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  }
  if (t0 > t1) return {};
  double t = t0;
  for (int it = 0; it < 400 && t <= t1 + 1e-7; ++it) {
    const Vector3d p = o + t * u;
    const double dist = torusDistance(p, major, minor);
    if (dist < 1e-7) {
      if (t / len <= kTMin) return {};
      Hit hit;
      hit.t = t / len;
      const double rho = std::hypot(p.x(), p.y());
      const Vector3d ring = rho > 0.0 ? Vector3d(p.x() / rho * major, p.y() / rho * major, 0.0)
                                      : Vector3d(major, 0.0, 0.0);
      hit.normal = (p - ring).normalized();
      return hit;
    }
    t += dist;
  }
  return {};
}

Hit raycastLocal(const Primitive& p, const Vector3d& o, const Vector3d& d) {
  const Vector3d& s = p.size;
  switch (p.kind) {
    case PrimitiveKind::Box:
      return rayBox(o, d, s);
    case PrimitiveKind::Cylinder:
      return rayCone(o, d, s.x(), s.x(), s.z());
    case PrimitiveKind::Sphere:
      return raySphere(o, d, s.x());
    case PrimitiveKind::Cone:
      return rayCone(o, d, s.x(), s.y(), s.z());
    case PrimitiveKind::Torus:
      return rayTorus(o, d, s.x(), s.y());
  }
  return {};
}

// ---- local signed distances -------------------------------------------------------------------

double coneDistance(const Vector3d& p, double r_bottom, double r_top, double h) {
  // Exact distance to a capped cone (I. Quilez, "distance functions"), axis z.
  const Vector2d q(std::hypot(p.x(), p.y()), p.z());
  const Vector2d k1(r_top, h);
  const Vector2d k2(r_top - r_bottom, 2.0 * h);
  const Vector2d ca(q.x() - std::min(q.x(), q.y() < 0.0 ? r_bottom : r_top), std::abs(q.y()) - h);
  const double f = std::clamp((k1 - q).dot(k2) / k2.squaredNorm(), 0.0, 1.0);
  const Vector2d cb = q - k1 + k2 * f;
  const double s = (cb.x() < 0.0 && ca.y() < 0.0) ? -1.0 : 1.0;
  return s * std::sqrt(std::min(ca.squaredNorm(), cb.squaredNorm()));
}

double distanceLocal(const Primitive& p, const Vector3d& x) {
  const Vector3d& s = p.size;
  switch (p.kind) {
    case PrimitiveKind::Box: {
      const Vector3d q = x.cwiseAbs() - s;
      return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
    }
    case PrimitiveKind::Cylinder: {
      const Vector2d q(std::hypot(x.x(), x.y()) - s.x(), std::abs(x.z()) - s.z());
      return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
    }
    case PrimitiveKind::Sphere:
      return x.norm() - s.x();
    case PrimitiveKind::Cone:
      return coneDistance(x, s.x(), s.y(), s.z());
    case PrimitiveKind::Torus:
      return torusDistance(x, s.x(), s.y());
  }
  return kInf;
}

// ---- building blocks --------------------------------------------------------------------------

Pose translation(const Vector3d& t) {
  Pose pose = Pose::Identity();
  pose.translation() = t;
  return pose;
}

Pose yawPose(const Vector2d& center, double yaw_deg, double z = 0.0) {
  Pose pose = Pose::Identity();
  pose.linear() = Eigen::AngleAxisd(detail::deg2rad(yaw_deg), Vector3d::UnitZ()).toRotationMatrix();
  pose.translation() = Vector3d(center.x(), center.y(), z);
  return pose;
}

Primitive make(PrimitiveKind kind, const Pose& pose, const Vector3d& size, int owner) {
  Primitive p;
  p.kind = kind;
  p.pose = pose;
  p.size = size;
  p.owner = owner;
  return p;
}

/// A box given by its local min and max corners, placed by `frame`.
Primitive boxPart(const Pose& frame, const Vector3d& lo, const Vector3d& hi, int owner) {
  return make(PrimitiveKind::Box, frame * translation(0.5 * (lo + hi)), 0.5 * (hi - lo), owner);
}

/// Parts of an object in its local frame (base centre at the origin, z up), owner set later.
std::vector<Primitive> localParts(const Object& obj) {
  const double sx = obj.size.x(), sy = obj.size.y(), sz = obj.size.z();
  const Pose I = Pose::Identity();
  std::vector<Primitive> parts;
  switch (obj.type) {
    case ObjectType::Box:
      parts.push_back(make(PrimitiveKind::Box, translation({0, 0, sz / 2}),
                           Vector3d(sx / 2, sy / 2, sz / 2), 0));
      break;
    case ObjectType::Cylinder: {
      const double r = std::min(sx, sy) / 2;
      parts.push_back(
          make(PrimitiveKind::Cylinder, translation({0, 0, sz / 2}), Vector3d(r, r, sz / 2), 0));
      break;
    }
    case ObjectType::Sphere: {
      const double r = std::min({sx, sy, sz}) / 2;
      parts.push_back(make(PrimitiveKind::Sphere, translation({0, 0, r}), Vector3d(r, r, r), 0));
      break;
    }
    case ObjectType::Cone: {
      const double r = std::min(sx, sy) / 2;
      parts.push_back(
          make(PrimitiveKind::Cone, translation({0, 0, sz / 2}), Vector3d(r, 0.0, sz / 2), 0));
      break;
    }
    case ObjectType::Torus: {
      const double minor = sz / 2;
      const double major = std::min(sx, sy) / 2 - minor;
      parts.push_back(
          make(PrimitiveKind::Torus, translation({0, 0, minor}), Vector3d(major, minor, 0.0), 0));
      break;
    }
    case ObjectType::Mug: {
      const double rb = sy / 2;
      const double xb = -sx / 2 + rb;
      parts.push_back(
          make(PrimitiveKind::Cylinder, translation({xb, 0, sz / 2}), Vector3d(rb, rb, sz / 2), 0));
      const double reach = sx - sy;  // how far the handle sticks out of the body
      const double tube = std::min({0.25 * reach, 0.1 * sz, 0.008});
      const double major = std::min(reach - tube, 0.45 * sz - tube);
      Pose handle = translation({xb + rb, 0, sz / 2});
      handle.linear() = Eigen::AngleAxisd(detail::kPi / 2, Vector3d::UnitX()).toRotationMatrix();
      parts.push_back(make(PrimitiveKind::Torus, handle, Vector3d(major, tube, 0.0), 0));
      break;
    }
    case ObjectType::BookStack: {
      const int n = std::clamp(static_cast<int>(std::lround(sz / 0.035)), 1, 5);
      const double t = sz / n;
      for (int i = 0; i < n; ++i) {
        const double f = 1.0 - 0.06 * (i % 3);
        const double yaw = i == 0 ? 0.0 : ((i % 2) ? 5.0 : -3.0);
        const double shift = i == 0 ? 0.0 : 0.03 * sx * ((i % 3) - 1);
        const Pose frame = yawPose(Vector2d(shift, 0.0), yaw, (i + 0.5) * t);
        parts.push_back(
            make(PrimitiveKind::Box, frame, Vector3d(f * sx / 2, f * sy / 2, t / 2), 0));
      }
      break;
    }
    case ObjectType::Bottle: {
      const double r = std::min(sx, sy) / 2;
      const double body = 0.6 * sz, shoulder = 0.15 * sz, neck = sz - body - shoulder;
      parts.push_back(make(PrimitiveKind::Cylinder, translation({0, 0, body / 2}),
                           Vector3d(r, r, body / 2), 0));
      parts.push_back(make(PrimitiveKind::Cone, translation({0, 0, body + shoulder / 2}),
                           Vector3d(r, 0.35 * r, shoulder / 2), 0));
      parts.push_back(make(PrimitiveKind::Cylinder, translation({0, 0, sz - neck / 2}),
                           Vector3d(0.35 * r, 0.35 * r, neck / 2), 0));
      break;
    }
    case ObjectType::ToyCar: {
      const double rw = 0.22 * sz, ww = 0.2 * sy;
      const double body_y = sy / 2 - ww;
      parts.push_back(boxPart(I, {-sx / 2, -body_y, 0.6 * rw}, {sx / 2, body_y, 0.6 * sz}, 0));
      parts.push_back(
          boxPart(I, {-0.3 * sx, -0.85 * body_y, 0.6 * sz}, {0.2 * sx, 0.85 * body_y, sz}, 0));
      for (const double x : {-0.3 * sx, 0.3 * sx})
        for (const double y : {-(sy / 2 - ww / 2), sy / 2 - ww / 2}) {
          Pose wheel = translation({x, y, rw});
          wheel.linear() = Eigen::AngleAxisd(detail::kPi / 2, Vector3d::UnitX()).toRotationMatrix();
          parts.push_back(make(PrimitiveKind::Cylinder, wheel, Vector3d(rw, rw, ww / 2), 0));
        }
      break;
    }
  }
  return parts;
}

// Owners of the structure (objects have ids >= 1).
constexpr int kFloorOwner = -1;
constexpr int kWallOwner = -2;  // -2 .. -5
int tableOwner(int id) {
  return -(100 + id);
}
int shelfOwner(int id) {
  return -(2000 + id);
}

}  // namespace

// ---- public -------------------------------------------------------------------------------------

double raycast(const Primitive& primitive, const Vector3d& origin, const Vector3d& direction) {
  return detail::raycastWithNormal(primitive, origin, direction).t;
}

double signedDistance(const Primitive& primitive, const Vector3d& p) {
  return distanceLocal(primitive, primitive.pose.inverse(Eigen::Isometry) * p);
}

std::vector<Primitive> objectPrimitives(const Object& object) {
  const Pose pose = objectPose(object);
  std::vector<Primitive> parts = localParts(object);
  for (Primitive& p : parts) {
    p.pose = pose * p.pose;
    p.owner = object.id;
  }
  return parts;
}

std::vector<Primitive> structurePrimitives(const Scene& scene) {
  std::vector<Primitive> out;
  const double X = scene.room.size.x(), Y = scene.room.size.y(), H = scene.room.wall_height;
  constexpr double kWall = 0.1, kFloor = 0.05;
  const Pose I = Pose::Identity();
  out.push_back(boxPart(I, {-X / 2 - kWall, -Y / 2 - kWall, -kFloor},
                        {X / 2 + kWall, Y / 2 + kWall, 0.0}, kFloorOwner));
  if (scene.room.walls) {
    out.push_back(
        boxPart(I, {X / 2, -Y / 2 - kWall, 0.0}, {X / 2 + kWall, Y / 2 + kWall, H}, kWallOwner));
    out.push_back(boxPart(I, {-X / 2 - kWall, -Y / 2 - kWall, 0.0}, {-X / 2, Y / 2 + kWall, H},
                          kWallOwner - 1));
    out.push_back(boxPart(I, {-X / 2, Y / 2, 0.0}, {X / 2, Y / 2 + kWall, H}, kWallOwner - 2));
    out.push_back(boxPart(I, {-X / 2, -Y / 2 - kWall, 0.0}, {X / 2, -Y / 2, H}, kWallOwner - 3));
  }
  for (const Table& t : scene.tables) {
    const Pose frame = yawPose(t.center, t.yaw_deg);
    const double L = t.size.x(), W = t.size.y(), h = t.size.z();
    const int owner = tableOwner(t.id);
    out.push_back(boxPart(frame, {-L / 2, -W / 2, h - 0.03}, {L / 2, W / 2, h}, owner));
    for (const double sx : {-1.0, 1.0})
      for (const double sy : {-1.0, 1.0}) {
        const Vector3d c(sx * (L / 2 - 0.07), sy * (W / 2 - 0.07), 0.0);
        out.push_back(boxPart(frame, c + Vector3d(-0.025, -0.025, 0.0),
                              c + Vector3d(0.025, 0.025, h - 0.03), owner));
      }
  }
  for (const Shelf& s : scene.shelves) {
    const Pose frame = yawPose(s.center, s.yaw_deg);
    const double w = s.size.x(), d = s.size.y(), h = s.size.z();
    constexpr double kSide = 0.02, kBack = 0.01, kBoard = 0.02;
    const int owner = shelfOwner(s.id);
    out.push_back(boxPart(frame, {-w / 2, -d / 2, 0.0}, {-w / 2 + kSide, d / 2, h}, owner));
    out.push_back(boxPart(frame, {w / 2 - kSide, -d / 2, 0.0}, {w / 2, d / 2, h}, owner));
    out.push_back(
        boxPart(frame, {-w / 2 + kSide, d / 2 - kBack, 0.0}, {w / 2 - kSide, d / 2, h}, owner));
    for (int k = 0; k < s.boards; ++k) {
      const double z = 0.10 + k * (h - 0.10) / (s.boards - 1);
      out.push_back(boxPart(frame, {-w / 2 + kSide, -d / 2, z - kBoard},
                            {w / 2 - kSide, d / 2 - kBack, z}, owner));
    }
  }
  return out;
}

std::vector<Primitive> sessionPrimitives(const Scene& scene, const Session& session) {
  std::vector<Primitive> out = structurePrimitives(scene);
  for (const Object& obj : session.objects) {
    std::vector<Primitive> parts = objectPrimitives(obj);
    out.insert(out.end(), parts.begin(), parts.end());
  }
  return out;
}

namespace detail {

Hit raycastWithNormal(const Primitive& p, const Vector3d& origin, const Vector3d& direction) {
  const Eigen::Matrix3d Rt = p.pose.linear().transpose();
  const Vector3d o = Rt * (origin - p.pose.translation());
  const Vector3d d = Rt * direction;
  Hit hit = raycastLocal(p, o, d);
  if (hit.t < kInf) hit.normal = p.pose.linear() * hit.normal;
  return hit;
}

Vector3d localHalfExtent(const Primitive& p) {
  const Vector3d& s = p.size;
  switch (p.kind) {
    case PrimitiveKind::Box:
      return s;
    case PrimitiveKind::Cylinder:
      return Vector3d(s.x(), s.x(), s.z());
    case PrimitiveKind::Sphere:
      return Vector3d::Constant(s.x());
    case PrimitiveKind::Cone: {
      const double r = std::max(s.x(), s.y());
      return Vector3d(r, r, s.z());
    }
    case PrimitiveKind::Torus:
      return Vector3d(s.x() + s.y(), s.x() + s.y(), s.y());
  }
  return s;
}

Eigen::AlignedBox3d worldBox(const Primitive& p) {
  const Vector3d half = localHalfExtent(p);
  const Vector3d extent = p.pose.linear().cwiseAbs() * half;
  return Eigen::AlignedBox3d(p.pose.translation() - extent, p.pose.translation() + extent);
}

}  // namespace detail
}  // namespace planesdf::sim
