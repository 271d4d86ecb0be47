#pragma once
// Analytic scenes for tests: primitives with exact ray casting and exact signed distance, and a
// pinhole depth renderer. World frame: z up unless a test says otherwise.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <vector>

#include "planesdf/types.hpp"

namespace planesdf::test {

/// A primitive: an axis-aligned box, a cylinder with axis `axis` (unit), a sphere, or an
/// infinite plane {x : n·x = d} (solid on the side opposite to n).
struct Primitive {
  enum class Kind { Box, Cylinder, Sphere, HalfSpace } kind = Kind::Box;
  Eigen::Vector3d center = Eigen::Vector3d::Zero();  ///< box/cylinder centre, sphere centre
  Eigen::Vector3d half = Eigen::Vector3d::Zero();    ///< box half extents
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();   ///< cylinder axis, half-space normal
  double radius = 0.0;                               ///< cylinder / sphere radius
  double half_height = 0.0;                          ///< cylinder half height
  double offset = 0.0;                               ///< half-space: n·x = offset on its surface

  static Primitive box(const Eigen::Vector3d& min, const Eigen::Vector3d& max);
  static Primitive cylinder(const Eigen::Vector3d& base_center, double radius, double height,
                            const Eigen::Vector3d& axis = Eigen::Vector3d::UnitZ());
  static Primitive sphere(const Eigen::Vector3d& c, double r);
  static Primitive halfSpace(const Eigen::Vector3d& n, double offset);

  /// Smallest t > 0 with o + t·d on the surface, or +inf.
  double raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const;
  /// Signed distance (exact outside; inside: negative, exact for sphere/half-space, a lower bound
  /// in magnitude for box/cylinder corners).
  double sdf(const Eigen::Vector3d& p) const;
};

struct AnalyticScene {
  std::vector<Primitive> primitives;
  double raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const;
  /// Union SDF: min over primitives.
  double sdf(const Eigen::Vector3d& p) const;
};

/// Height of the top of tableWith()'s table (m).
inline constexpr double kTableTop = 0.75;

/// The tests' tabletop: a floor at z = 0 and a 1.2 x 0.8 m table top (3 cm thick, top at
/// kTableTop) centred on the origin, plus `objects`.
AnalyticScene tableWith(std::vector<Primitive> objects);

/// Camera-to-world pose (OpenCV optical axes) of a camera at `eye` looking at `target`, with
/// `up` the world up direction (image y points against it).
Pose lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
            const Eigen::Vector3d& up = Eigen::Vector3d::UnitZ());

/// `n` camera poses on a circle of `radius` around `center` at height `height` above it, all
/// looking at `center`.
std::vector<Pose> ringPoses(const Eigen::Vector3d& center, double radius, double height, int n,
                            const Eigen::Vector3d& up = Eigen::Vector3d::UnitZ());

/// A pinhole camera `width` x `height` pixels with focal length `f` (pixels), centred.
Intrinsics pinhole(int width, int height, double f);

/// Noise-free depth image (metres; 0 where nothing is hit within max_depth).
DepthFrame renderDepth(const AnalyticScene& scene, const Intrinsics& k, const Pose& camera_to_world,
                       double max_depth = 10.0);

}  // namespace planesdf::test
