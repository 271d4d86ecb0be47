#pragma once
// Internal to the simulator: primitive ray casts with surface normals, primitive bounds, and a
// World (the primitives of one session grouped by owner, with world bounding boxes) that answers
// ray casts restricted to candidate groups and nearest-surface queries.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <limits>
#include <vector>

#include "../numeric.hpp"
#include "planesdf/sim.hpp"

namespace planesdf::sim::detail {

inline constexpr double kInf = std::numeric_limits<double>::infinity();
using planesdf::detail::kPi;

inline double deg2rad(double deg) {
  return deg * (kPi / 180.0);
}

/// A ray hit: the ray parameter and the unit surface normal (world), facing outward.
struct Hit {
  double t = kInf;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
};

/// Ray cast of one primitive with the surface normal at the hit (t = +inf when missed).
Hit raycastWithNormal(const Primitive& p, const Eigen::Vector3d& origin,
                      const Eigen::Vector3d& direction);

/// Half extents of the primitive's bounding box in its own frame.
Eigen::Vector3d localHalfExtent(const Primitive& p);

/// World axis-aligned bounding box of the primitive.
Eigen::AlignedBox3d worldBox(const Primitive& p);

/// The primitives of one session, grouped by owner (one group per object and per piece of
/// furniture), each group with its world bounding box.
class World {
 public:
  struct Group {
    int owner = 0;
    std::vector<int> members;  ///< indices into primitives()
    Eigen::AlignedBox3d box;
  };

  explicit World(std::vector<Primitive> primitives);

  const std::vector<Primitive>& primitives() const { return primitives_; }
  const std::vector<Group>& groups() const { return groups_; }

  /// Nearest hit with t in (0, t_max) among the primitives `candidates` (indices into
  /// primitives(), sorted by `near` ascending: a lower bound of t for any hit on that primitive).
  /// `primitive` is set to the hit primitive's index (or -1).
  Hit raycast(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double t_max,
              const std::vector<std::pair<float, int>>& candidates, int& primitive) const;

  /// Unsigned distance from `p` to the nearest surface and the owner of that surface.
  double nearest(const Eigen::Vector3d& p, int& owner) const;

 private:
  std::vector<Primitive> primitives_;
  std::vector<Group> groups_;
};

/// Renders one depth frame of `world` (see renderDepth); the noise generator is seeded with
/// `noise_seed` alone, so frames can be rendered in any order or in parallel.
DepthFrame renderFrame(const World& world, const SensorModel& sensor, const Pose& camera_to_world,
                       std::uint64_t noise_seed);

}  // namespace planesdf::sim::detail
