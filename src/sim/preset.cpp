// The `tabletop` and `room` presets: layout, objects, change scenarios, trajectories and the
// localisation error, all drawn from one explicitly seeded std::mt19937 in a fixed order.
#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/sim.hpp"
#include "world.hpp"

namespace planesdf::sim {
namespace {
using detail::kPi;
using Eigen::Vector2d;
using Eigen::Vector3d;

/// Uniform numbers from std::mt19937 by our own formulas (the standard distributions differ
/// between standard libraries; mt19937's output does not).
class Random {
 public:
  explicit Random(std::uint32_t seed) : gen_(seed) {}
  double uniform(double lo, double hi) {
    return lo + (hi - lo) * ((static_cast<double>(gen_()) + 0.5) / 4294967296.0);
  }
  /// Integer in [lo, hi].
  int integer(int lo, int hi) {
    return lo + static_cast<int>(gen_() % static_cast<std::uint32_t>(hi - lo + 1));
  }
  template <class T>
  void shuffle(std::vector<T>& v) {
    for (std::size_t i = v.size(); i > 1; --i)
      std::swap(v[i - 1], v[static_cast<std::size_t>(integer(0, static_cast<int>(i) - 1))]);
  }

 private:
  std::mt19937 gen_;
};

constexpr double kGap = 0.03;   ///< free space between two objects' footprints (m)
constexpr double kEdge = 0.03;  ///< free space between a footprint and its support's edge (m)

const std::vector<ObjectType> kStanding = {
    ObjectType::Box,       ObjectType::Cylinder, ObjectType::Sphere,
    ObjectType::Cone,      ObjectType::Torus,    ObjectType::Mug,
    ObjectType::BookStack, ObjectType::Bottle,   ObjectType::ToyCar};
const std::vector<ObjectType> kHung = {ObjectType::Box, ObjectType::Cylinder, ObjectType::Torus};

bool isWall(const std::string& support) {
  return support.rfind("wall", 0) == 0;
}

/// Smallest height a type is generated with.
double minHeight(ObjectType t) {
  switch (t) {
    case ObjectType::Cylinder:
    case ObjectType::Sphere:
      return 0.06;
    case ObjectType::Cone:
    case ObjectType::Mug:
      return 0.08;
    case ObjectType::Bottle:
      return 0.18;
    default:
      return 0.04;
  }
}

/// A size for a standing object of type `t` at most `max_h` tall (4 to 35 cm).
Vector3d standingSize(Random& r, ObjectType t, double max_h) {
  const auto h = [&](double lo, double hi) { return r.uniform(lo, std::min(hi, max_h)); };
  switch (t) {
    case ObjectType::Box:
      return {r.uniform(0.06, 0.25), r.uniform(0.06, 0.25), h(0.04, 0.30)};
    case ObjectType::Cylinder: {
      const double d = r.uniform(0.05, 0.15);
      return {d, d, h(0.06, 0.30)};
    }
    case ObjectType::Sphere: {
      const double d = h(0.06, 0.20);
      return {d, d, d};
    }
    case ObjectType::Cone: {
      const double d = r.uniform(0.08, 0.20);
      return {d, d, h(0.08, 0.30)};
    }
    case ObjectType::Torus: {
      const double d = r.uniform(0.12, 0.25);
      return {d, d, h(0.04, std::min(0.08, d / 2.5))};
    }
    case ObjectType::Mug: {
      const double d = r.uniform(0.07, 0.10);
      return {d + r.uniform(0.025, 0.04), d, h(0.08, 0.12)};
    }
    case ObjectType::BookStack:
      return {r.uniform(0.15, 0.28), r.uniform(0.11, 0.20), h(0.04, 0.15)};
    case ObjectType::Bottle: {
      const double d = r.uniform(0.06, 0.10);
      return {d, d, h(0.18, 0.35)};
    }
    case ObjectType::ToyCar: {
      const double length = r.uniform(0.10, 0.25);
      return {length, r.uniform(0.45, 0.6) * length, h(0.04, 0.10)};
    }
  }
  return {0.1, 0.1, 0.1};
}

/// A size for an object hung on a wall (z = how far it sticks out).
Vector3d hungSize(Random& r, ObjectType t) {
  switch (t) {
    case ObjectType::Cylinder: {
      const double d = r.uniform(0.20, 0.32);
      return {d, d, r.uniform(0.04, 0.07)};
    }
    case ObjectType::Torus: {
      const double d = r.uniform(0.25, 0.35);
      return {d, d, r.uniform(0.04, 0.07)};
    }
    default:
      return {r.uniform(0.20, 0.40), r.uniform(0.15, 0.35), r.uniform(0.04, 0.12)};
  }
}

double footprintRadius(const Vector3d& size) {
  return 0.5 * std::hypot(size.x(), size.y());
}

/// A rectangle of a support plane (its coordinates) that no footprint may touch: the floor under
/// a table or in front of a shelf.
struct KeepOut {
  Vector2d center = Vector2d::Zero();
  Vector2d half = Vector2d::Zero();
  double yaw_rad = 0.0;

  /// Distance from `xy` to the rectangle (negative inside).
  double distance(const Vector2d& xy) const {
    const Vector2d d = (Eigen::Rotation2Dd(-yaw_rad) * (xy - center)).cwiseAbs() - half;
    return d.cwiseMax(0.0).norm() + std::min(d.maxCoeff(), 0.0);
  }
};

/// Where objects may go on a support plane (in its frame), and how.
struct Spot {
  SupportPlane plane;
  Eigen::AlignedBox2d region;  ///< allowed base centres before the footprint margins
  bool hung = false;           ///< wall: upright objects, no yaw
  std::vector<KeepOut> keep_out;
};

class Builder {
 public:
  Builder(Scene& scene, Random& random, std::string label)
      : scene_(scene), r_(random), label_(std::move(label)) {}

  void addSpot(const std::string& support, std::optional<Eigen::AlignedBox2d> region = {},
               std::vector<KeepOut> keep_out = {}) {
    for (const SupportPlane& p : supportPlanes(scene_))
      if (p.name == support) {
        Spot s;
        s.plane = p;
        s.region = region ? *region : Eigen::AlignedBox2d(-p.half_extent, p.half_extent);
        s.hung = isWall(support);
        s.keep_out = std::move(keep_out);
        spots_.push_back(s);
        return;
      }
    throw Error("--scene", label_ + ": internal error: no support plane '" + support + "'");
  }

  const Spot* spot(const std::string& support) const {
    for (const Spot& s : spots_)
      if (s.plane.name == support) return &s;
    return nullptr;
  }

  /// Support-plane coordinates of an object's base centre.
  static Vector2d planeXY(const Spot& s, const Object& o) {
    return (s.plane.frame.inverse(Eigen::Isometry) * o.position).head<2>();
  }

  /// True when a footprint of `radius` at `xy` on `s` is inside its region and clear of the
  /// objects of `objects` on the same support (except `skip`).
  static bool isFree(const Spot& s, const Vector2d& xy, double radius,
                     const std::vector<Object>& objects, const std::set<int>& skip) {
    const Vector2d lo = s.region.min().array() + radius + kEdge;
    const Vector2d hi = s.region.max().array() - radius - kEdge;
    if ((xy.array() < lo.array()).any() || (xy.array() > hi.array()).any()) return false;
    for (const KeepOut& k : s.keep_out)
      if (k.distance(xy) < radius + kGap) return false;
    for (const Object& o : objects) {
      if (o.support != s.plane.name || skip.count(o.id)) continue;
      if ((planeXY(s, o) - xy).norm() < radius + footprintRadius(o.size) + kGap) return false;
    }
    return true;
  }

  /// A random free base centre for a footprint of `radius`, also satisfying `accept`.
  std::optional<Vector2d> findPlace(const Spot& s, double radius,
                                    const std::vector<Object>& objects, const std::set<int>& skip,
                                    const std::function<bool(const Vector2d&)>& accept = {}) {
    const Vector2d lo = s.region.min().array() + radius + kEdge;
    const Vector2d hi = s.region.max().array() - radius - kEdge;
    if ((lo.array() > hi.array()).any()) return std::nullopt;
    for (int attempt = 0; attempt < 400; ++attempt) {
      const Vector2d xy(r_.uniform(lo.x(), hi.x()), r_.uniform(lo.y(), hi.y()));
      if ((!accept || accept(xy)) && isFree(s, xy, radius, objects, skip)) return xy;
    }
    return std::nullopt;
  }

  static void placeAt(Object& o, const Spot& s, const Vector2d& xy, double yaw_deg) {
    o.support = s.plane.name;
    o.position = s.plane.frame * Vector3d(xy.x(), xy.y(), 0.0);
    const Eigen::Matrix3d R =
        s.plane.frame.linear() *
        Eigen::AngleAxisd(detail::deg2rad(yaw_deg), Vector3d::UnitZ()).toRotationMatrix();
    o.orientation = Eigen::Quaterniond(R).normalized();
  }

  /// A random type and size that fits on `s` (clearance), optionally not `avoid`.
  std::pair<ObjectType, Vector3d> randomShape(const Spot& s, std::optional<ObjectType> avoid = {}) {
    std::vector<ObjectType> types;
    const double max_h = std::min(0.35, s.plane.clearance - 0.03);
    for (const ObjectType t : s.hung ? kHung : kStanding)
      if (t != avoid && (s.hung || minHeight(t) <= max_h)) types.push_back(t);
    if (types.empty())
      throw Error("--scene", label_ + ": no object fits on '" + s.plane.name + "'");
    const ObjectType t =
        types[static_cast<std::size_t>(r_.integer(0, static_cast<int>(types.size()) - 1))];
    return {t, s.hung ? hungSize(r_, t) : standingSize(r_, t, max_h)};
  }

  /// Adds a new random object on `support` to `objects`; false when there is no room.
  bool addObject(std::vector<Object>& objects, const std::string& support, int id) {
    const Spot& s = *spot(support);
    for (int attempt = 0; attempt < 20; ++attempt) {
      Object o;
      o.id = id;
      std::tie(o.type, o.size) = randomShape(s);
      const auto xy = findPlace(s, footprintRadius(o.size), objects, {});
      if (!xy) continue;
      placeAt(o, s, *xy, s.hung ? 0.0 : r_.uniform(0.0, 360.0));
      objects.push_back(o);
      return true;
    }
    return false;
  }

  std::vector<Spot>& spots() { return spots_; }

 private:
  Scene& scene_;
  Random& r_;
  std::string label_;
  std::vector<Spot> spots_;
};

int nextId(const Scene& s) {
  int id = 0;
  for (const Session* session : {&s.reference, &s.current})
    for (const Object& o : session->objects) id = std::max(id, o.id);
  return id + 1;
}

std::vector<ChangeKind> defaultChanges(const std::string& name) {
  if (name == "room")
    return {ChangeKind::Add, ChangeKind::Remove, ChangeKind::Move, ChangeKind::Replace};
  return {ChangeKind::Add, ChangeKind::Remove, ChangeKind::Move};
}

/// Makes one change at a time on the current objects, each on objects no earlier change touched.
/// Every method returns false when it found no object or no free place.
class ChangeMaker {
 public:
  ChangeMaker(Scene& scene, Builder& b, Random& r, const std::vector<std::string>& add_supports)
      : scene_(scene), cur_(scene.current.objects), b_(b), r_(r), add_supports_(add_supports) {}

  bool make(ChangeKind kind, Change& change) {
    switch (kind) {
      case ChangeKind::None:
        return true;
      case ChangeKind::Add:
        return add(change);
      case ChangeKind::Remove:
        return remove(change);
      case ChangeKind::Move:
      case ChangeKind::SmallMove:
        return move(kind == ChangeKind::SmallMove, change);
      case ChangeKind::Swap:
        return swap(change);
      case ChangeKind::Replace:
        return replace(change);
    }
    return false;
  }

 private:
  /// Objects of both sessions: new places must be free in both, so that no change lands where
  /// another one left (a moved object on the spot of a removed one would be a replacement).
  std::vector<Object> occupied() const {
    std::vector<Object> all = cur_;
    all.insert(all.end(), scene_.reference.objects.begin(), scene_.reference.objects.end());
    return all;
  }

  /// Indices of the untouched current objects (not on walls if `horizontal_only`), shuffled.
  std::vector<int> untouched(bool horizontal_only) {
    std::vector<int> idx;
    for (std::size_t i = 0; i < cur_.size(); ++i)
      if (!touched_.count(cur_[i].id) && (!horizontal_only || !isWall(cur_[i].support)))
        idx.push_back(static_cast<int>(i));
    r_.shuffle(idx);
    return idx;
  }

  bool add(Change& change) {
    std::vector<std::string> supports = add_supports_;
    r_.shuffle(supports);
    const int id = nextId(scene_);
    for (const std::string& sp : supports) {
      std::vector<Object> all = occupied();
      if (b_.addObject(all, sp, id)) {
        cur_.push_back(all.back());
        touched_.insert(id);
        change.current_ids = {id};
        return true;
      }
    }
    return false;
  }

  bool remove(Change& change) {
    const std::vector<int> idx = untouched(false);
    if (idx.empty()) return false;
    const Object o = cur_[static_cast<std::size_t>(idx.front())];
    cur_.erase(cur_.begin() + idx.front());
    touched_.insert(o.id);
    change.reference_ids = {o.id};
    return true;
  }

  /// A move to a free place at least 10 cm away, or (`small`) by 3 cm keeping the orientation.
  bool move(bool small, Change& change) {
    for (const int i : untouched(false)) {
      Object& o = cur_[static_cast<std::size_t>(i)];
      const Spot& s = *b_.spot(o.support);
      const Vector2d old = Builder::planeXY(s, o);
      const double radius = footprintRadius(o.size);
      std::optional<Vector2d> xy;
      if (!small) {
        xy = b_.findPlace(s, radius, occupied(), {o.id},
                          [&](const Vector2d& p) { return (p - old).norm() >= 0.10; });
      } else {
        const double a0 = r_.uniform(0.0, 2.0 * kPi);
        for (int k = 0; k < 16 && !xy; ++k) {
          const double a = a0 + k * (2.0 * kPi / 16);
          const Vector2d p = old + 0.03 * Vector2d(std::cos(a), std::sin(a));
          if (Builder::isFree(s, p, radius, occupied(), {o.id})) xy = p;
        }
      }
      if (!xy) continue;
      if (!small) {
        Builder::placeAt(o, s, *xy, s.hung ? 0.0 : r_.uniform(0.0, 360.0));
      } else {
        o.position = s.plane.frame * Vector3d(xy->x(), xy->y(), 0.0);  // same orientation
      }
      touched_.insert(o.id);
      change.reference_ids = change.current_ids = {o.id};
      return true;
    }
    return false;
  }

  /// Two objects of different shapes on horizontal supports trade places.
  bool swap(Change& change) {
    const std::vector<int> idx = untouched(true);
    for (std::size_t x = 0; x < idx.size(); ++x)
      for (std::size_t y = x + 1; y < idx.size(); ++y) {
        Object& a = cur_[static_cast<std::size_t>(idx[x])];
        Object& c = cur_[static_cast<std::size_t>(idx[y])];
        if (a.type == c.type && a.size == c.size) continue;
        const Spot& sa = *b_.spot(a.support);
        const Spot& sc = *b_.spot(c.support);
        const std::vector<Object> all = occupied();
        const bool fits = a.size.z() <= sc.plane.clearance - 0.03 &&
                          c.size.z() <= sa.plane.clearance - 0.03 &&
                          Builder::isFree(sc, Builder::planeXY(sc, c), footprintRadius(a.size), all,
                                          {a.id, c.id}) &&
                          Builder::isFree(sa, Builder::planeXY(sa, a), footprintRadius(c.size), all,
                                          {a.id, c.id});
        if (!fits) continue;
        std::swap(a.position, c.position);
        std::swap(a.support, c.support);
        touched_.insert(a.id);
        touched_.insert(c.id);
        change.reference_ids = change.current_ids = {a.id, c.id};
        return true;
      }
    return false;
  }

  /// An object replaced in place by a new one of another shape.
  bool replace(Change& change) {
    const int id = nextId(scene_);
    for (const int i : untouched(false)) {
      const Object old = cur_[static_cast<std::size_t>(i)];
      const Spot& s = *b_.spot(old.support);
      for (int attempt = 0; attempt < 30; ++attempt) {
        Object o = old;
        o.id = id;
        std::tie(o.type, o.size) = b_.randomShape(s, old.type);
        if (!Builder::isFree(s, Builder::planeXY(s, old), footprintRadius(o.size), occupied(),
                             {old.id}))
          continue;
        cur_[static_cast<std::size_t>(i)] = o;
        touched_.insert(old.id);
        touched_.insert(id);
        change.reference_ids = {old.id};
        change.current_ids = {id};
        return true;
      }
    }
    return false;
  }

  Scene& scene_;
  std::vector<Object>& cur_;
  Builder& b_;
  Random& r_;
  const std::vector<std::string>& add_supports_;
  std::set<int> touched_;
};

/// Makes the changes: current = reference objects, then each change on untouched objects.
void applyChanges(Scene& scene, Builder& b, Random& r, const std::vector<ChangeKind>& kinds,
                  const std::vector<std::string>& add_supports, const std::string& label) {
  scene.current.objects = scene.reference.objects;
  ChangeMaker maker(scene, b, r, add_supports);
  for (const ChangeKind kind : kinds) {
    Change change;
    change.kind = kind;
    if (!maker.make(kind, change))
      throw Error("--scene", label + ": cannot make the '" + std::string(toString(kind)) +
                                 "' change (no untouched object or no free place left)");
    scene.changes.push_back(change);
  }
  std::vector<Object>& cur = scene.current.objects;
  std::sort(cur.begin(), cur.end(), [](const Object& a, const Object& c) { return a.id < c.id; });
}

/// Azimuth (deg) around `center` of the changed objects on `support`, if any.
std::optional<double> changeAzimuth(const Scene& scene, const std::string& support,
                                    const Vector2d& center) {
  const ChangedIds changed = changedObjects(scene);
  Vector2d sum = Vector2d::Zero();
  int n = 0;
  for (const auto& [session, ids] : {std::pair{&scene.reference, &changed.reference},
                                     std::pair{&scene.current, &changed.current}})
    for (const Object& o : session->objects)
      if (o.support == support && std::count(ids->begin(), ids->end(), o.id)) {
        sum += o.position.head<2>();
        ++n;
      }
  if (n == 0) return std::nullopt;
  const Vector2d d = sum / n - center;
  if (d.norm() < 0.01) return std::nullopt;
  return std::atan2(d.y(), d.x()) * 180.0 / kPi;
}

Orbit tableOrbit(Random& r, const Table& t, int frames, double coverage,
                 std::optional<double> focus_deg) {
  Orbit o;
  const double h = t.size.z();
  o.center = t.center;
  o.radius = 0.5 * std::hypot(t.size.x(), t.size.y()) + r.uniform(0.40, 0.55);
  o.z_min = h + r.uniform(0.30, 0.40);
  o.z_max = h + r.uniform(0.60, 0.80);
  o.height_waves = r.integer(1, 3);
  o.target = Vector3d(t.center.x() + r.uniform(-0.05, 0.05), t.center.y() + r.uniform(-0.05, 0.05),
                      h + 0.05);
  const double start = r.uniform(0.0, 360.0);
  if (coverage >= 1.0) {
    o.start_deg = start;
    o.end_deg = start + 360.0;
  } else {
    const double mid = focus_deg ? *focus_deg : start;
    o.start_deg = mid - 180.0 * coverage;
    o.end_deg = mid + 180.0 * coverage;
  }
  o.frames = frames;
  return o;
}

void checkOptions(const std::string& name, const PresetOptions& opt) {
  const auto bad = [&](const std::string& what) { throw Error("--scene", name + ": " + what); };
  if (opt.frames < 0 || opt.frames > 5000) bad("frames must be in [0, 5000]");
  for (const double c : {opt.reference_coverage, opt.current_coverage})
    if (!(c > 0.0 && c <= 1.0)) bad("coverage must be in (0, 1]");
  if (!(opt.localisation_translation >= 0.0 && opt.localisation_translation <= 1.0))
    bad("localisation_translation must be in [0, 1] m");
  if (!(opt.localisation_rotation_deg >= 0.0 && opt.localisation_rotation_deg <= 45.0))
    bad("localisation_rotation_deg must be in [0, 45] degrees");
}

Scene makeTabletop(std::uint32_t seed, const PresetOptions& opt) {
  Random r(seed);
  Scene s;
  s.name = "tabletop";
  s.seed = seed;
  s.room.size = Vector2d(5.0, 5.0);
  s.room.walls = false;
  Table t;
  t.id = 1;
  t.center = Vector2d(r.uniform(-0.1, 0.1), r.uniform(-0.1, 0.1));
  t.yaw_deg = r.uniform(-90.0, 90.0);
  t.size = Vector3d(r.uniform(1.0, 1.4), r.uniform(0.7, 0.9), r.uniform(0.70, 0.78));
  s.tables.push_back(t);

  const std::string label = "tabletop seed " + std::to_string(seed);
  Builder b(s, r, label);
  b.addSpot("table1");
  const int n = r.integer(5, 7);
  for (int i = 0; i < n; ++i)
    if (!b.addObject(s.reference.objects, "table1", i + 1))
      throw Error("--scene", label + ": no room for object " + std::to_string(i + 1));
  applyChanges(s, b, r, opt.changes.empty() ? defaultChanges("tabletop") : opt.changes, {"table1"},
               label);

  const int frames = opt.frames > 0 ? opt.frames : 30;
  const std::optional<double> focus = changeAzimuth(s, "table1", t.center);
  s.reference.trajectory = {tableOrbit(r, t, frames, opt.reference_coverage, focus)};
  s.current.trajectory = {tableOrbit(r, t, frames, opt.current_coverage, focus)};
  const double a = r.uniform(0.0, 2.0 * kPi);
  LocalisationError& e = s.current.localisation_error;
  e.translation = opt.localisation_translation * Vector3d(std::cos(a), std::sin(a), 0.0);
  e.rotation_deg =
      Vector3d(0.0, 0.0, (r.integer(0, 1) ? 1.0 : -1.0) * opt.localisation_rotation_deg);
  e.pivot = Vector3d(t.center.x(), t.center.y(), t.size.z());
  return s;
}

/// A table's or shelf's footprint on the floor, as a keep-out rectangle grown by `margin`.
KeepOut footprint(const Vector2d& center, double yaw_deg, const Vector2d& size, double margin) {
  return {center, 0.5 * size + Vector2d::Constant(margin), detail::deg2rad(yaw_deg)};
}

/// Table heights of a room: the first a desk; each further one, half the time, 3 to 6 cm from an
/// earlier one (two desks whose planes must stay apart), else anything from a coffee table to a
/// desk.
std::vector<double> tableHeights(Random& r, int n) {
  std::vector<double> h = {r.uniform(0.70, 0.78)};
  while (static_cast<int>(h.size()) < n) {
    if (r.integer(0, 1) == 0) {
      const double base = h[static_cast<std::size_t>(r.integer(0, static_cast<int>(h.size()) - 1))];
      const double step = r.uniform(0.03, 0.06);
      h.push_back(base + step > 0.82 ? base - step : base + step);
    } else {
      h.push_back(r.uniform(0.45, 0.80));
    }
  }
  return h;
}

/// A shelf against wall `wall` (0: +y, 1: -y, 2: -x), its open front toward the room.
Shelf roomShelf(Random& r, double X, double Y, int wall) {
  Shelf sh;
  sh.id = 1;
  sh.size = Vector3d(r.uniform(0.8, 1.1), r.uniform(0.30, 0.36), r.uniform(1.40, 1.85));
  sh.boards = r.integer(3, 5);
  const double w = sh.size.x(), d = sh.size.y();
  if (wall == 2) {
    sh.yaw_deg = 90.0;
    sh.center =
        Vector2d(-X / 2 + d / 2 + 0.005, r.uniform(-Y / 2 + w / 2 + 0.3, Y / 2 - w / 2 - 0.3));
  } else {
    sh.yaw_deg = wall == 0 ? 0.0 : 180.0;
    const double y = (Y / 2 - d / 2 - 0.005) * (wall == 0 ? 1.0 : -1.0);
    sh.center = Vector2d(r.uniform(-X / 2 + w / 2 + 0.3, X / 2 - w / 2 - 0.6), y);
  }
  return sh;
}

/// Places the tables at random in the room, apart from each other and from the shelf's front.
/// False when no place was found.
bool placeTables(Random& r, Scene& s, int n) {
  const double X = s.room.size.x(), Y = s.room.size.y();
  const Shelf& sh = s.shelves.front();
  const Vector2d shelf_front =
      sh.center + Eigen::Rotation2Dd(detail::deg2rad(sh.yaw_deg)) * Vector2d(0.0, -sh.size.y());
  const std::vector<double> heights = tableHeights(r, n);
  for (int k = 0; k < n; ++k) {
    Table t;
    t.id = k + 1;
    t.size =
        Vector3d(r.uniform(0.9, 1.4), r.uniform(0.6, 0.85), heights[static_cast<std::size_t>(k)]);
    t.yaw_deg = r.uniform(-30.0, 30.0) + (r.integer(0, 3) == 0 ? 90.0 : 0.0);
    const double hd = 0.5 * std::hypot(t.size.x(), t.size.y());
    const double reach = hd + 0.55 + 0.2;  // the table's orbit plus a margin to the walls
    bool placed = false;
    for (int attempt = 0; attempt < 200 && !placed; ++attempt) {
      t.center = Vector2d(r.uniform(-X / 2 + reach, X / 2 - reach),
                          r.uniform(-Y / 2 + reach, Y / 2 - reach));
      if (!(X / 2 - reach > -X / 2 + reach && Y / 2 - reach > -Y / 2 + reach)) return false;
      placed = (t.center - shelf_front).norm() >= hd + 1.2;
      for (const Table& o : s.tables) {
        const double gap = r.uniform(0.25, 0.8);
        if ((t.center - o.center).norm() < hd + 0.5 * std::hypot(o.size.x(), o.size.y()) + gap)
          placed = false;
      }
    }
    if (!placed) return false;
    s.tables.push_back(t);
  }
  return true;
}

/// True when every camera of both sessions is inside the room and at least 10 cm from every
/// surface (furniture and objects): a generated trajectory must not pass through a table top.
bool camerasClear(const Scene& s) {
  for (const Session* session : {&s.reference, &s.current}) {
    const std::vector<Primitive> prims = sessionPrimitives(s, *session);
    for (const Pose& pose : trajectoryPoses(session->trajectory)) {
      const Vector3d c = pose.translation();
      if (std::abs(c.x()) > s.room.size.x() / 2 - 0.15 ||
          std::abs(c.y()) > s.room.size.y() / 2 - 0.15 || c.z() > s.room.wall_height - 0.1)
        return false;
      for (const Primitive& p : prims)
        if (signedDistance(p, c) < 0.10) return false;
    }
  }
  return true;
}

/// An arc of `frames` views looking at `target` from `radius` away, centred on the direction
/// `toward_deg` (world azimuth from the target), spanning 2 * half_deg.
Orbit facingArc(Random& r, const Vector3d& target, double toward_deg, double radius, double z_lo,
                double z_hi, int frames) {
  Orbit o;
  o.center = target.head<2>();
  o.radius = radius;
  const double half = r.uniform(25.0, 40.0);
  o.start_deg = toward_deg - half;
  o.end_deg = toward_deg + half;
  o.z_min = z_lo;
  o.z_max = z_hi;
  o.height_waves = 1;
  o.target = target;
  o.frames = frames;
  return o;
}

/// The room's layout and reference objects; false when this draw does not fit (the caller draws
/// again).
bool roomLayout(Random& r, Scene& s, Builder& b, std::vector<std::string>& add_supports) {
  const int n_tables = r.integer(2, 3);
  const double X = r.uniform(4.5, 5.5) + (n_tables == 3 ? 1.2 : 0.0), Y = r.uniform(4.5, 5.5);
  s.room.size = Vector2d(X, Y);
  s.room.walls = true;
  s.room.wall_height = 2.5;
  const int shelf_wall = r.integer(0, 2);
  s.shelves = {roomShelf(r, X, Y, shelf_wall)};
  if (!placeTables(r, s, n_tables)) return false;
  const Shelf& sh = s.shelves.front();

  for (const Table& t : s.tables) {
    b.addSpot("table" + std::to_string(t.id));
    add_supports.push_back("table" + std::to_string(t.id));
  }
  for (int k = 2; k <= sh.boards; ++k) {
    const std::string name = "shelf1.board" + std::to_string(k);
    b.addSpot(name);
    add_supports.push_back(name);
  }
  std::vector<KeepOut> furniture;
  for (const Table& t : s.tables)
    furniture.push_back(footprint(t.center, t.yaw_deg, t.size.head<2>(), 0.15));
  // The shelf and the 1.2 m in front of it, where its scan stands.
  const Vector2d out = Eigen::Rotation2Dd(detail::deg2rad(sh.yaw_deg)) * Vector2d(0.0, -1.0);
  furniture.push_back(
      footprint(sh.center + 0.6 * out, sh.yaw_deg, sh.size.head<2>() + Vector2d(0.0, 1.2), 0.15));
  b.addSpot(
      "floor",
      Eigen::AlignedBox2d(Vector2d(-X / 2 + 0.5, -Y / 2 + 0.5), Vector2d(X / 2 - 0.5, Y / 2 - 0.5)),
      furniture);
  add_supports.push_back("floor");
  const double H = s.room.wall_height;
  std::vector<std::string> walls = {"wall+x"};
  const char* const other[] = {"wall-y", "wall+y", "wall+y"};  // a wall without the shelf
  if (r.integer(0, 1)) walls.push_back(other[shelf_wall]);
  for (const std::string& w : walls) {
    const double half = std::min(1.0, (w == "wall+x" ? Y : X) / 2 - 0.8);
    b.addSpot(w, Eigen::AlignedBox2d(Vector2d(-half, 1.2 - H / 2), Vector2d(half, 1.8 - H / 2)));
    add_supports.push_back(w);
  }

  int id = 1;
  bool fits = true;
  const auto add = [&](const std::string& support) {
    fits = fits && b.addObject(s.reference.objects, support, id++);
  };
  for (const Table& t : s.tables) {
    const int n = r.integer(3, 5);
    for (int i = 0; i < n; ++i) add("table" + std::to_string(t.id));
  }
  for (int k = 2; k <= sh.boards; ++k) add("shelf1.board" + std::to_string(k));
  for (const std::string& w : walls) add(w);
  const int n_floor = r.integer(1, 3);
  for (int i = 0; i < n_floor; ++i) add("floor");
  return fits;
}

/// Cameras: an orbit around each table, a scan of the shelf, an arc facing each object on a
/// wall or on the floor from the room's side.
void roomTrajectories(Random& r, Scene& s, const PresetOptions& opt) {
  const Shelf& sh = s.shelves.front();
  const std::vector<SupportPlane> supports = supportPlanes(s);
  std::vector<const Object*> spots;  // objects seen by an arc of their own (any session)
  for (const Session* session : {&s.reference, &s.current})
    for (const Object& o : session->objects)
      if ((isWall(o.support) || o.support == "floor") &&
          std::none_of(spots.begin(), spots.end(), [&](const Object* q) {
            return q->support == o.support && (q->position - o.position).norm() < 0.6;
          }))
        spots.push_back(&o);
  const double total = 14.0 * static_cast<double>(s.tables.size()) + 12.0 + 6.0 * spots.size();
  const auto frames = [&](int f) {
    return opt.frames > 0 ? std::max(1, static_cast<int>(std::lround(f * opt.frames / total))) : f;
  };
  for (Session* session : {&s.reference, &s.current}) {
    session->trajectory.clear();
    const double coverage = session == &s.reference ? opt.reference_coverage : opt.current_coverage;
    for (const Table& t : s.tables) {
      const std::string support = "table" + std::to_string(t.id);
      Orbit o = tableOrbit(r, t, frames(14), coverage, changeAzimuth(s, support, t.center));
      // Above every table the orbit passes over.
      for (const Table& q : s.tables)
        if ((q.center - t.center).norm() < o.radius + 0.5 * std::hypot(q.size.x(), q.size.y()))
          o.z_min = std::max(o.z_min, q.size.z() + 0.30);
      o.z_max = std::max(o.z_max, o.z_min + 0.2);
      session->trajectory.push_back(o);
    }
    const Vector2d out =
        Eigen::Rotation2Dd(detail::deg2rad(sh.yaw_deg)) * Vector2d(0.0, -1.0);  // front normal
    const Vector2d front = sh.center + 0.5 * sh.size.y() * out;
    Orbit shelf = facingArc(r, Vector3d(front.x(), front.y(), sh.size.z() / 2),
                            std::atan2(out.y(), out.x()) * 180.0 / detail::kPi, r.uniform(1.3, 1.5),
                            r.uniform(0.75, 0.9), r.uniform(1.45, 1.7), frames(12));
    shelf.height_waves = r.integer(1, 2);
    shelf.target = Vector3d(sh.center.x(), sh.center.y(), sh.size.z() / 2);
    shelf.target_follow = 0.6;
    session->trajectory.push_back(shelf);
    for (const Object* o : spots) {
      const Vector2d to_centre = -o->position.head<2>();
      const double toward = std::atan2(to_centre.y(), to_centre.x()) * 180.0 / detail::kPi;
      const bool wall = isWall(o->support);
      Vector3d target = o->position;
      if (!wall) target.z() += 0.5 * o->size.z();
      session->trajectory.push_back(
          facingArc(r, target, toward, r.uniform(1.0, 1.3), wall ? r.uniform(1.1, 1.3) : 1.0,
                    wall ? r.uniform(1.5, 1.7) : r.uniform(1.3, 1.5), frames(6)));
    }
  }
}

Scene makeRoom(std::uint32_t seed, const PresetOptions& opt) {
  Random r(seed);
  const std::string label = "room seed " + std::to_string(seed);
  for (int attempt = 0; attempt < 50; ++attempt) {
    Scene s;
    s.name = "room";
    s.seed = seed;
    Builder b(s, r, label);
    std::vector<std::string> add_supports;
    if (!roomLayout(r, s, b, add_supports)) continue;
    applyChanges(s, b, r, opt.changes.empty() ? defaultChanges("room") : opt.changes, add_supports,
                 label);
    roomTrajectories(r, s, opt);
    if (!camerasClear(s)) continue;
    const double a = r.uniform(0.0, 2.0 * kPi);
    LocalisationError& e = s.current.localisation_error;
    e.translation = opt.localisation_translation * Vector3d(std::cos(a), std::sin(a), 0.0);
    e.rotation_deg =
        Vector3d(0.0, 0.0, (r.integer(0, 1) ? 1.0 : -1.0) * opt.localisation_rotation_deg);
    e.pivot = Vector3d::Zero();
    return s;
  }
  throw Error("--scene", label + ": no layout found where every camera is clear of the furniture");
}

}  // namespace

Scene makePreset(const std::string& name, std::uint32_t seed, const PresetOptions& options) {
  checkOptions(name, options);
  Scene s;
  if (name == "tabletop")
    s = makeTabletop(seed, options);
  else if (name == "room")
    s = makeRoom(seed, options);
  else
    throw Error("--scene", "unknown preset '" + name + "' (expected tabletop or room)");
  validateScene(s, "--scene " + name + " seed " + std::to_string(seed));
  return s;
}

}  // namespace planesdf::sim
