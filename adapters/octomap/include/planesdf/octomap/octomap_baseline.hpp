#pragma once
/// \file octomap_baseline.hpp
/// The OctoMap occupancy-differencing baseline (the "Octomap" row of the paper's Table I) and the
/// OctoMap side of `planesdf bench`. This header does not include OctoMap: the tree lives behind
/// a pointer, so the CLI can link planesdf_octomap without OctoMap's headers.
///
/// One OccupancyMap (an octomap::OcTree) per session, built from the same input as the PlaneSDF
/// map: organised clouds inserted from their sensor origin, depth frames from their camera pose,
/// each with insertPointCloud (rays from the origin to every point: cells along a ray get a miss,
/// the end cell a hit; OctoMap's default sensor model, hit 0.7, miss 0.4). Then a reference point
/// whose cell is known and free (not occupied) in the current tree is removed, a current point
/// whose cell is free in the reference tree is added; unknown cells are never changed. Decisions
/// are taken per downsampled cell (BaselineParams::voxel) and the flagged cells are clustered and
/// written exactly like the point-distance baseline (planesdf/baseline.hpp).

#include <cstddef>
#include <memory>

#include "planesdf/baseline.hpp"
#include "planesdf/types.hpp"

namespace planesdf::octomap_adapter {

struct OccupancyOptions {
  double resolution = 0.007;  ///< OcTree leaf size (m): the PlaneSDF voxel size
  double max_range = 4.0;     ///< m; longer rays are cut here (no hit), as Config::max_depth
  /// OctoMap's `discretize`: rays are cast once per end cell instead of once per point (same map up
  /// to the order of updates, many times faster for dense 640x480 frames).
  bool discretize = true;
  int pixel_stride = 1;  ///< insertFrame: use every n-th pixel in each direction
};

/// An octomap::OcTree behind a pointer.
class OccupancyMap {
 public:
  enum class State { Unknown, Free, Occupied };

  explicit OccupancyMap(const OccupancyOptions& options = {});
  ~OccupancyMap();
  OccupancyMap(OccupancyMap&&) noexcept;
  OccupancyMap& operator=(OccupancyMap&&) noexcept;

  /// Inserts the valid points of `cloud` (in its own frame) placed by `cloud_to_world`, rays from
  /// cloud_to_world * cloud.sensor_pose's origin. Returns the wall time in milliseconds.
  double insertCloud(const PointCloud& cloud, const Pose& cloud_to_world = Pose::Identity());
  /// Back-projects a depth frame (camera-to-world pose) and inserts it from the camera centre.
  /// Returns the wall time in milliseconds (back-projection included).
  double insertFrame(const DepthFrame& frame, const Pose& camera_to_world);

  State query(const Eigen::Vector3f& world) const;
  std::size_t leafCount() const;
  std::size_t memoryBytes() const;
  const OccupancyOptions& options() const { return options_; }

 private:
  struct Impl;
  OccupancyOptions options_;
  std::unique_ptr<Impl> impl_;
};

/// Occupancy differencing (see the file comment): `reference_points` / `current_points` are the
/// sessions' scene points in the world frame (what the outputs report); `reference_map` /
/// `current_map` their trees. The tree building is not included in milliseconds.
BaselineResult octomapBaseline(const PointCloud& reference_points,
                               const OccupancyMap& reference_map, const PointCloud& current_points,
                               const OccupancyMap& current_map, const BaselineParams& params = {});

}  // namespace planesdf::octomap_adapter
