#include "analytic_scene.hpp"

#include <utility>

#include <algorithm>
#include <cmath>
#include <limits>

namespace planesdf::test {
namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();

double rayBox(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d& lo,
              const Eigen::Vector3d& hi) {
  double t0 = -kInf, t1 = kInf;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(d[i]) < 1e-15) {
      if (o[i] < lo[i] || o[i] > hi[i]) return kInf;
      continue;
    }
    double a = (lo[i] - o[i]) / d[i], b = (hi[i] - o[i]) / d[i];
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  }
  if (t0 > t1 || t1 <= 1e-9) return kInf;
  return t0 > 1e-9 ? t0 : t1;
}

// Cylinder in its own frame: axis z through the origin, z in [-h, h].
double rayCylinder(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double r, double h) {
  double best = kInf;
  const double a = d.x() * d.x() + d.y() * d.y();
  const double b = 2 * (o.x() * d.x() + o.y() * d.y());
  const double c = o.x() * o.x() + o.y() * o.y() - r * r;
  if (a > 1e-15) {
    const double disc = b * b - 4 * a * c;
    if (disc >= 0) {
      const double s = std::sqrt(disc);
      for (double t : {(-b - s) / (2 * a), (-b + s) / (2 * a)}) {
        const double z = o.z() + t * d.z();
        if (t > 1e-9 && std::abs(z) <= h) best = std::min(best, t);
      }
    }
  }
  if (std::abs(d.z()) > 1e-15)
    for (double zc : {-h, h}) {
      const double t = (zc - o.z()) / d.z();
      const Eigen::Vector3d p = o + t * d;
      if (t > 1e-9 && p.x() * p.x() + p.y() * p.y() <= r * r) best = std::min(best, t);
    }
  return best;
}

Eigen::Matrix3d frameOfAxis(const Eigen::Vector3d& axis) {
  return Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis).toRotationMatrix();
}
}  // namespace

Primitive Primitive::box(const Eigen::Vector3d& min, const Eigen::Vector3d& max) {
  Primitive p;
  p.kind = Kind::Box;
  p.center = (min + max) / 2;
  p.half = (max - min) / 2;
  return p;
}

Primitive Primitive::cylinder(const Eigen::Vector3d& base, double r, double height,
                              const Eigen::Vector3d& axis) {
  Primitive p;
  p.kind = Kind::Cylinder;
  p.axis = axis.normalized();
  p.center = base + p.axis * (height / 2);
  p.radius = r;
  p.half_height = height / 2;
  return p;
}

Primitive Primitive::sphere(const Eigen::Vector3d& c, double r) {
  Primitive p;
  p.kind = Kind::Sphere;
  p.center = c;
  p.radius = r;
  return p;
}

Primitive Primitive::halfSpace(const Eigen::Vector3d& n, double offset) {
  Primitive p;
  p.kind = Kind::HalfSpace;
  p.axis = n.normalized();
  p.offset = offset;
  return p;
}

double Primitive::raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  switch (kind) {
    case Kind::Box:
      return rayBox(o, d, center - half, center + half);
    case Kind::Cylinder: {
      const Eigen::Matrix3d R = frameOfAxis(axis);
      return rayCylinder(R.transpose() * (o - center), R.transpose() * d, radius, half_height);
    }
    case Kind::Sphere: {
      const Eigen::Vector3d oc = o - center;
      const double a = d.squaredNorm(), b = 2 * oc.dot(d), c = oc.squaredNorm() - radius * radius;
      const double disc = b * b - 4 * a * c;
      if (disc < 0) return kInf;
      const double s = std::sqrt(disc);
      const double t0 = (-b - s) / (2 * a), t1 = (-b + s) / (2 * a);
      return t0 > 1e-9 ? t0 : (t1 > 1e-9 ? t1 : kInf);
    }
    case Kind::HalfSpace: {
      const double dn = axis.dot(d);
      if (std::abs(dn) < 1e-15) return kInf;
      const double t = (offset - axis.dot(o)) / dn;
      return t > 1e-9 ? t : kInf;
    }
  }
  return kInf;
}

double Primitive::sdf(const Eigen::Vector3d& p) const {
  switch (kind) {
    case Kind::Box: {
      const Eigen::Vector3d q = (p - center).cwiseAbs() - half;
      return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
    }
    case Kind::Cylinder: {
      const Eigen::Vector3d l = frameOfAxis(axis).transpose() * (p - center);
      const Eigen::Vector2d q(std::hypot(l.x(), l.y()) - radius, std::abs(l.z()) - half_height);
      return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
    }
    case Kind::Sphere:
      return (p - center).norm() - radius;
    case Kind::HalfSpace:
      return axis.dot(p) - offset;
  }
  return kInf;
}

double AnalyticScene::raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  double best = kInf;
  for (const auto& p : primitives) best = std::min(best, p.raycast(o, d));
  return best;
}

double AnalyticScene::sdf(const Eigen::Vector3d& p) const {
  double best = kInf;
  for (const auto& q : primitives) best = std::min(best, q.sdf(p));
  return best;
}

AnalyticScene tableWith(std::vector<Primitive> objects) {
  AnalyticScene s;
  s.primitives.push_back(Primitive::halfSpace(Eigen::Vector3d::UnitZ(), 0.0));  // floor
  s.primitives.push_back(Primitive::box({-0.6, -0.4, kTableTop - 0.03}, {0.6, 0.4, kTableTop}));
  for (auto& o : objects) s.primitives.push_back(std::move(o));
  return s;
}

Intrinsics pinhole(int width, int height, double f) {
  Intrinsics k;
  k.width = width;
  k.height = height;
  k.fx = k.fy = f;
  k.cx = 0.5 * width - 0.5;
  k.cy = 0.5 * height - 0.5;
  return k;
}

Pose lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target, const Eigen::Vector3d& up) {
  const Eigen::Vector3d z = (target - eye).normalized();
  Eigen::Vector3d x = z.cross(up);
  if (x.norm() < 1e-9) x = z.unitOrthogonal();
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  Pose T = Pose::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = eye;
  return T;
}

std::vector<Pose> ringPoses(const Eigen::Vector3d& center, double radius, double height, int n,
                            const Eigen::Vector3d& up) {
  const Eigen::Vector3d u = up.normalized();
  const Eigen::Vector3d a = u.unitOrthogonal(), b = u.cross(a);
  std::vector<Pose> poses;
  for (int i = 0; i < n; ++i) {
    const double phi = 2 * M_PI * i / n;
    const Eigen::Vector3d eye =
        center + radius * (std::cos(phi) * a + std::sin(phi) * b) + height * u;
    poses.push_back(lookAt(eye, center, u));
  }
  return poses;
}

DepthFrame renderDepth(const AnalyticScene& scene, const Intrinsics& k, const Pose& T,
                       double max_depth) {
  DepthFrame f;
  f.intrinsics = k;
  f.depth.assign(static_cast<std::size_t>(k.width) * k.height, 0.0f);
  const Eigen::Matrix3d R = T.linear();
  const Eigen::Vector3d o = T.translation();
  for (int v = 0; v < k.height; ++v)
    for (int u = 0; u < k.width; ++u) {
      const Eigen::Vector3d ray((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
      const double t = scene.raycast(o, R * ray);  // t is the z-depth since ray.z = 1
      if (t < max_depth) f.depth[static_cast<std::size_t>(v) * k.width + u] = static_cast<float>(t);
    }
  return f;
}

}  // namespace planesdf::test
