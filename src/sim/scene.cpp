// Scene description helpers: names of types and change kinds, poses, support planes, validation
// and the changed-object ground truth.
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/sim.hpp"
#include "world.hpp"

namespace planesdf::sim {
namespace {
using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr std::array<std::pair<ObjectType, const char*>, 9> kObjectTypes = {{
    {ObjectType::Box, "box"},
    {ObjectType::Cylinder, "cylinder"},
    {ObjectType::Sphere, "sphere"},
    {ObjectType::Cone, "cone"},
    {ObjectType::Torus, "torus"},
    {ObjectType::Mug, "mug"},
    {ObjectType::BookStack, "book_stack"},
    {ObjectType::Bottle, "bottle"},
    {ObjectType::ToyCar, "toy_car"},
}};

constexpr std::array<std::pair<ChangeKind, const char*>, 7> kChangeKinds = {{
    {ChangeKind::None, "none"},
    {ChangeKind::Add, "add"},
    {ChangeKind::Remove, "remove"},
    {ChangeKind::Move, "move"},
    {ChangeKind::SmallMove, "small_move"},
    {ChangeKind::Swap, "swap"},
    {ChangeKind::Replace, "replace"},
}};

// Limits of validateScene.
constexpr double kMinObjectSize = 0.01, kMaxObjectSize = 2.0;
constexpr int kMaxId = 1000000;
constexpr int kMaxFurnitureId = 999;
constexpr int kMaxFrames = 5000;
constexpr double kMaxCoordinate = 1000.0;

Pose framePose(const Vector3d& origin, const Vector3d& x, const Vector3d& y, const Vector3d& z) {
  Pose pose = Pose::Identity();
  pose.linear().col(0) = x;
  pose.linear().col(1) = y;
  pose.linear().col(2) = z;
  pose.translation() = origin;
  return pose;
}

Pose yawFrame(const Vector2d& center, double yaw_deg, double z) {
  Pose pose = Pose::Identity();
  pose.linear() = Eigen::AngleAxisd(detail::deg2rad(yaw_deg), Vector3d::UnitZ()).toRotationMatrix();
  pose.translation() = Vector3d(center.x(), center.y(), z);
  return pose;
}

/// Collects the checks of validateScene with element names.
class Checker {
 public:
  explicit Checker(std::string what) : what_(std::move(what)) {}
  void require(bool ok, const std::string& element, const std::string& message) const {
    if (!ok) throw Error(what_, element + ": " + message);
  }
  void finite(const Eigen::MatrixXd& m, const std::string& element) const {
    require(m.allFinite(), element, "must be finite");
    require(m.cwiseAbs().maxCoeff() <= kMaxCoordinate, element,
            "absurd value (beyond " + std::to_string(static_cast<int>(kMaxCoordinate)) + " m)");
  }
  void range(double v, double lo, double hi, const std::string& element,
             const std::string& unit = "") const {
    require(std::isfinite(v) && v >= lo && v <= hi, element,
            "must be in [" + num(lo) + ", " + num(hi) + "]" + unit + ", got " + num(v));
  }
  static std::string num(double v) {
    std::string s = std::to_string(v);
    if (s.find('.') != std::string::npos) {
      while (!s.empty() && s.back() == '0') s.pop_back();
      if (!s.empty() && s.back() == '.') s.pop_back();
    }
    return s;
  }

 private:
  std::string what_;
};

void validateObjectShape(const Checker& c, const Object& o, const std::string& e) {
  for (int i = 0; i < 3; ++i)
    c.range(o.size[i], kMinObjectSize, kMaxObjectSize, e + ".size[" + std::to_string(i) + "]",
            " m");
  const double sx = o.size.x(), sy = o.size.y(), sz = o.size.z();
  if (o.type == ObjectType::Torus)
    c.require(std::min(sx, sy) >= 2.0 * sz, e + ".size",
              "a torus needs min(size x, size y) >= 2 * size z (its tube is size z thick)");
  if (o.type == ObjectType::Mug) {
    c.require(sx >= sy + 0.01 && sx <= 2.0 * sy, e + ".size",
              "a mug needs size y + 0.01 <= size x <= 2 * size y (body diameter y, handle to x)");
    const double reach = sx - sy;
    const double tube = std::min({0.25 * reach, 0.1 * sz, 0.008});
    const double major = std::min(reach - tube, 0.45 * sz - tube);
    c.require(major > tube, e + ".size", "a mug this flat has no room for its handle");
  }
}

}  // namespace

const char* toString(ObjectType type) {
  for (const auto& [t, name] : kObjectTypes)
    if (t == type) return name;
  return "?";
}

std::optional<ObjectType> objectTypeFromString(const std::string& name) {
  for (const auto& [t, n] : kObjectTypes)
    if (name == n) return t;
  return std::nullopt;
}

const char* toString(ChangeKind kind) {
  for (const auto& [k, name] : kChangeKinds)
    if (k == kind) return name;
  return "?";
}

std::optional<ChangeKind> changeKindFromString(const std::string& name) {
  for (const auto& [k, n] : kChangeKinds)
    if (name == n) return k;
  return std::nullopt;
}

Pose objectPose(const Object& object) {
  Pose pose = Pose::Identity();
  pose.linear() = object.orientation.normalized().toRotationMatrix();
  pose.translation() = object.position;
  return pose;
}

Pose localisationErrorPose(const LocalisationError& error) {
  const double angle = detail::deg2rad(error.rotation_deg.norm());
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  if (angle > 0.0) R = Eigen::AngleAxisd(angle, error.rotation_deg.normalized()).toRotationMatrix();
  Pose pose = Pose::Identity();
  pose.linear() = R;
  pose.translation() = error.pivot + error.translation - R * error.pivot;
  return pose;
}

std::vector<SupportPlane> supportPlanes(const Scene& scene) {
  std::vector<SupportPlane> out;
  const double X = scene.room.size.x(), Y = scene.room.size.y(), H = scene.room.wall_height;
  const Vector3d up = Vector3d::UnitZ();
  out.push_back({"floor", Pose::Identity(), Vector2d(X / 2, Y / 2), H});
  if (scene.room.walls) {
    const auto wall = [&](const char* name, const Vector3d& origin, const Vector3d& inward,
                          double half_length) {
      out.push_back({name, framePose(origin, up.cross(inward), up, inward),
                     Vector2d(half_length, H / 2), 1.0});
    };
    wall("wall+x", {X / 2, 0, H / 2}, -Vector3d::UnitX(), Y / 2);
    wall("wall-x", {-X / 2, 0, H / 2}, Vector3d::UnitX(), Y / 2);
    wall("wall+y", {0, Y / 2, H / 2}, -Vector3d::UnitY(), X / 2);
    wall("wall-y", {0, -Y / 2, H / 2}, Vector3d::UnitY(), X / 2);
  }
  for (const Table& t : scene.tables)
    out.push_back({"table" + std::to_string(t.id), yawFrame(t.center, t.yaw_deg, t.size.z()),
                   Vector2d(t.size.x() / 2, t.size.y() / 2), 1.0});
  for (const Shelf& s : scene.shelves) {
    const double w = s.size.x(), d = s.size.y(), h = s.size.z();
    const Pose frame = yawFrame(s.center, s.yaw_deg, 0.0);
    for (int k = 0; k < s.boards; ++k) {
      const double z = 0.10 + k * (h - 0.10) / (s.boards - 1);
      const double next = k + 1 < s.boards ? 0.10 + (k + 1) * (h - 0.10) / (s.boards - 1) : 0.0;
      const double clearance = k + 1 < s.boards ? next - 0.02 - z : 0.5;
      Pose board = frame;
      board.translation() = frame * Vector3d(0.0, -0.005, z);
      out.push_back({"shelf" + std::to_string(s.id) + ".board" + std::to_string(k + 1), board,
                     Vector2d(w / 2 - 0.02, (d - 0.01) / 2), clearance});
    }
  }
  return out;
}

namespace {

/// The sensor model's fields, in their ranges.
void validateSensor(const Checker& c, const SensorModel& s, const std::string& what) {
  try {
    s.intrinsics.validate("sensor");
  } catch (const Error& e) {
    throw Error(what, e.message().empty() ? "sensor: bad intrinsics" : "sensor: " + e.message());
  }
  c.range(s.min_depth, 0.01, 100.0, "sensor.min_depth", " m");
  c.range(s.max_depth, s.min_depth, 100.0, "sensor.max_depth", " m");
  c.range(s.axial_a, 0.0, 1.0, "sensor.axial_a");
  c.range(s.axial_b, 0.0, 1.0, "sensor.axial_b");
  c.range(s.axial_z0, 0.0, 100.0, "sensor.axial_z0");
  c.range(s.axial_incidence, 0.0, 1.0, "sensor.axial_incidence");
  c.range(s.lateral_sigma_px, 0.0, 10.0, "sensor.lateral_sigma_px");
  c.range(s.quantisation, 0.0, 0.1, "sensor.quantisation", " m");
  c.range(s.max_incidence_deg, 1.0, 90.0, "sensor.max_incidence_deg");
  c.range(s.edge_jump, 0.0, 10.0, "sensor.edge_jump");
  c.range(s.edge_dropout, 0.0, 1.0, "sensor.edge_dropout");
  c.range(s.flying_pixel, 0.0, 1.0 - s.edge_dropout, "sensor.flying_pixel");
  c.range(s.frame_rate, 0.001, 10000.0, "sensor.frame_rate", " Hz");
}

/// Tables and shelves: unique ids, finite places, sizes in range.
void validateFurniture(const Checker& c, const Scene& scene) {
  std::set<int> ids;
  for (std::size_t i = 0; i < scene.tables.size(); ++i) {
    const Table& t = scene.tables[i];
    const std::string e = "tables[" + std::to_string(i) + "]";
    c.range(t.id, 1, kMaxFurnitureId, e + ".id");
    c.require(ids.insert(t.id).second, e + ".id", "duplicate table id " + std::to_string(t.id));
    c.finite(t.center, e + ".center");
    c.range(t.yaw_deg, -3600.0, 3600.0, e + ".yaw_deg");
    c.range(t.size.x(), 0.3, 5.0, e + ".size[0]", " m");
    c.range(t.size.y(), 0.3, 5.0, e + ".size[1]", " m");
    c.range(t.size.z(), 0.2, 2.0, e + ".size[2]", " m");
  }
  ids.clear();
  for (std::size_t i = 0; i < scene.shelves.size(); ++i) {
    const Shelf& sh = scene.shelves[i];
    const std::string e = "shelves[" + std::to_string(i) + "]";
    c.range(sh.id, 1, kMaxFurnitureId, e + ".id");
    c.require(ids.insert(sh.id).second, e + ".id", "duplicate shelf id " + std::to_string(sh.id));
    c.finite(sh.center, e + ".center");
    c.range(sh.yaw_deg, -3600.0, 3600.0, e + ".yaw_deg");
    c.range(sh.size.x(), 0.2, 5.0, e + ".size[0]", " m");
    c.range(sh.size.y(), 0.1, 2.0, e + ".size[1]", " m");
    c.range(sh.size.z(), 0.3, 5.0, e + ".size[2]", " m");
    c.range(sh.boards, 2, 10, e + ".boards");
    c.require((sh.size.z() - 0.10) / (sh.boards - 1) >= 0.1, e + ".boards",
              "boards closer than 10 cm (too many boards for the height)");
  }
}

/// One session's objects (on known supports), orbits and localisation error.
void validateSession(const Checker& c, const Session& session, const std::string& label,
                     const std::set<std::string>& supports) {
  std::set<int> ids;
  int total_frames = 0;
  for (std::size_t i = 0; i < session.objects.size(); ++i) {
    const Object& o = session.objects[i];
    const std::string e = label + ".objects[" + std::to_string(i) + "]";
    c.range(o.id, 1, kMaxId, e + ".id");
    c.require(ids.insert(o.id).second, e + ".id", "duplicate object id " + std::to_string(o.id));
    validateObjectShape(c, o, e);
    c.finite(o.position, e + ".position");
    c.require(
        o.orientation.coeffs().allFinite() && std::abs(o.orientation.coeffs().norm() - 1.0) <= 0.01,
        e + ".orientation", "must be a unit quaternion [qx, qy, qz, qw]");
    c.require(supports.count(o.support) > 0, e + ".support",
              "unknown support plane '" + o.support +
                  "' (floor, wall+x/-x/+y/-y with walls, table<id>, shelf<id>.board<k>)");
  }
  const std::string e = label + ".trajectory";
  c.require(!session.trajectory.empty(), e, "no orbit (the session needs camera views)");
  for (std::size_t i = 0; i < session.trajectory.size(); ++i) {
    const Orbit& o = session.trajectory[i];
    const std::string oe = e + "[" + std::to_string(i) + "]";
    c.finite(o.target, oe + ".target");
    c.finite(o.center, oe + ".center");
    c.range(o.radius, 0.0, 100.0, oe + ".radius", " m");
    c.range(o.z_min, -kMaxCoordinate, kMaxCoordinate, oe + ".z_min", " m");
    c.range(o.z_max, o.z_min, kMaxCoordinate, oe + ".z_max", " m");
    c.range(o.height_waves, 0, 1000, oe + ".height_waves");
    c.range(o.start_deg, -3600.0, 3600.0, oe + ".start_deg");
    c.range(o.end_deg, -3600.0, 3600.0, oe + ".end_deg");
    c.range(o.frames, 1, kMaxFrames, oe + ".frames");
    c.range(o.target_follow, 0.0, 1.0, oe + ".target_follow");
    total_frames += o.frames;
    c.require(total_frames <= kMaxFrames, oe + ".frames",
              "more than " + std::to_string(kMaxFrames) + " frames in the session");
    const std::vector<Pose> poses = trajectoryPoses({o});
    for (std::size_t k = 0; k < poses.size(); ++k)
      c.require(poses[k].matrix().allFinite(), oe,
                "camera " + std::to_string(k) + " sits on its target (no viewing direction)");
  }
  const LocalisationError& le = session.localisation_error;
  c.finite(le.translation, label + ".localisation_error.translation");
  c.require(le.translation.norm() <= 10.0, label + ".localisation_error.translation",
            "absurd (more than 10 m)");
  c.finite(le.rotation_deg, label + ".localisation_error.rotation_deg");
  c.require(le.rotation_deg.norm() <= 180.0, label + ".localisation_error.rotation_deg",
            "absurd (more than 180 degrees)");
  c.finite(le.pivot, label + ".localisation_error.pivot");
}

/// Every change record names objects of the session it refers to.
void validateChangeRecords(const Checker& c, const Scene& scene) {
  const auto has = [](const Session& s, int id) {
    return std::any_of(s.objects.begin(), s.objects.end(),
                       [id](const Object& o) { return o.id == id; });
  };
  for (std::size_t i = 0; i < scene.changes.size(); ++i) {
    const Change& ch = scene.changes[i];
    const std::string e = "changes[" + std::to_string(i) + "]";
    for (const int id : ch.reference_ids)
      c.require(has(scene.reference, id), e + ".reference_ids",
                "object " + std::to_string(id) + " is not in the reference session");
    for (const int id : ch.current_ids)
      c.require(has(scene.current, id), e + ".current_ids",
                "object " + std::to_string(id) + " is not in the current session");
  }
}

}  // namespace

void validateScene(const Scene& scene, const std::string& what) {
  const Checker c(what);
  c.range(scene.room.size.x(), 1.0, 50.0, "room.size[0]", " m");
  c.range(scene.room.size.y(), 1.0, 50.0, "room.size[1]", " m");
  c.range(scene.room.wall_height, 0.5, 10.0, "room.wall_height", " m");

  validateSensor(c, scene.sensor, what);
  validateFurniture(c, scene);
  std::set<std::string> supports;
  for (const SupportPlane& p : supportPlanes(scene)) supports.insert(p.name);
  validateSession(c, scene.reference, "reference", supports);
  validateSession(c, scene.current, "current", supports);
  validateChangeRecords(c, scene);
}

ChangedIds changedObjects(const Scene& scene) {
  std::map<int, const Object*> cur;
  for (const Object& o : scene.current.objects) cur[o.id] = &o;
  std::set<int> ref_ids, cur_ids;
  for (const Object& r : scene.reference.objects) {
    const auto it = cur.find(r.id);
    if (it == cur.end()) {
      ref_ids.insert(r.id);
      continue;
    }
    const Object& c = *it->second;
    const double angle = r.orientation.normalized().angularDistance(c.orientation.normalized()) *
                         180.0 / detail::kPi;
    const bool same = r.type == c.type && r.size == c.size &&
                      (r.position - c.position).norm() <= 0.001 && angle <= 0.1;
    if (!same) {
      ref_ids.insert(r.id);
      cur_ids.insert(r.id);
    }
  }
  std::set<int> ref_all;
  for (const Object& r : scene.reference.objects) ref_all.insert(r.id);
  for (const Object& c : scene.current.objects)
    if (!ref_all.count(c.id)) cur_ids.insert(c.id);
  return {std::vector<int>(ref_ids.begin(), ref_ids.end()),
          std::vector<int>(cur_ids.begin(), cur_ids.end())};
}

}  // namespace planesdf::sim
