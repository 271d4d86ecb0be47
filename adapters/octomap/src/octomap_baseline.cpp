#include "planesdf/octomap/octomap_baseline.hpp"

#include <octomap/OcTree.h>

#include <chrono>
#include <cmath>

#include "planesdf/error.hpp"
#include "planesdf/octomap/octomap_conversion.hpp"

namespace planesdf::octomap_adapter {
namespace {

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

/// Flags the downsampled cells of `points` that are free in `other`.
std::vector<bool> freeIn(const DownsampledCloud& points, const OccupancyMap& other) {
  std::vector<bool> flagged(points.centroids.size(), false);
  for (std::size_t i = 0; i < points.centroids.size(); ++i)
    flagged[i] = other.query(points.centroids[i]) == OccupancyMap::State::Free;
  return flagged;
}

}  // namespace

struct OccupancyMap::Impl {
  explicit Impl(double resolution) : tree(resolution) {}
  octomap::OcTree tree;
};

OccupancyMap::OccupancyMap(const OccupancyOptions& options) : options_(options) {
  if (!(std::isfinite(options.resolution) && options.resolution > 0.0))
    throw Error("octomap", "resolution must be positive and finite");
  if (!(options.max_range > 0.0)) throw Error("octomap", "max_range must be positive");
  if (options.pixel_stride < 1) throw Error("octomap", "pixel_stride must be at least 1");
  impl_ = std::make_unique<Impl>(options.resolution);
}
OccupancyMap::~OccupancyMap() = default;
OccupancyMap::OccupancyMap(OccupancyMap&&) noexcept = default;
OccupancyMap& OccupancyMap::operator=(OccupancyMap&&) noexcept = default;

double OccupancyMap::insertCloud(const PointCloud& cloud, const Pose& cloud_to_world) {
  const auto t0 = std::chrono::steady_clock::now();
  const octomap::Pointcloud pc = toOctomap(cloud, cloud_to_world);
  const Eigen::Vector3d o = (cloud_to_world * cloud.sensor_pose).translation();
  impl_->tree.insertPointCloud(pc, octomap::point3d(float(o.x()), float(o.y()), float(o.z())),
                               options_.max_range, false, options_.discretize);
  return msSince(t0);
}

double OccupancyMap::insertFrame(const DepthFrame& frame, const Pose& camera_to_world) {
  const auto t0 = std::chrono::steady_clock::now();
  const Intrinsics& k = frame.intrinsics;
  if (frame.depth.size() != static_cast<std::size_t>(k.width) * k.height)
    throw Error("octomap", "depth frame size does not match its intrinsics");
  const Eigen::Matrix3f R = camera_to_world.linear().cast<float>();
  const Eigen::Vector3f t = camera_to_world.translation().cast<float>();
  octomap::Pointcloud pc;
  const int s = options_.pixel_stride;
  pc.reserve(static_cast<std::size_t>(k.width / s + 1) * (k.height / s + 1));
  for (int v = 0; v < k.height; v += s)
    for (int u = 0; u < k.width; u += s) {
      const float z = frame.at(u, v);
      if (!DepthFrame::isValidDepth(z)) continue;
      const Eigen::Vector3f p(static_cast<float>((u - k.cx) / k.fx) * z,
                              static_cast<float>((v - k.cy) / k.fy) * z, z);
      const Eigen::Vector3f q = R * p + t;
      pc.push_back(q.x(), q.y(), q.z());
    }
  impl_->tree.insertPointCloud(pc, octomap::point3d(t.x(), t.y(), t.z()), options_.max_range, false,
                               options_.discretize);
  return msSince(t0);
}

OccupancyMap::State OccupancyMap::query(const Eigen::Vector3f& p) const {
  const octomap::OcTreeNode* n = impl_->tree.search(double(p.x()), double(p.y()), double(p.z()));
  if (n == nullptr) return State::Unknown;
  return impl_->tree.isNodeOccupied(n) ? State::Occupied : State::Free;
}

std::size_t OccupancyMap::leafCount() const {
  return impl_->tree.getNumLeafNodes();
}

std::size_t OccupancyMap::memoryBytes() const {
  return impl_->tree.memoryUsage();
}

BaselineResult octomapBaseline(const PointCloud& reference_points,
                               const OccupancyMap& reference_map, const PointCloud& current_points,
                               const OccupancyMap& current_map, const BaselineParams& params) {
  if (!(std::isfinite(params.voxel) && params.voxel > 0.0) || !(params.cluster_distance > 0.0) ||
      params.min_cluster_cells < 1)
    throw Error("baseline", "invalid parameters (voxel, cluster_distance, min_cluster_cells)");
  const auto t0 = std::chrono::steady_clock::now();
  const DownsampledCloud ref = voxelDownsample(reference_points.points, params.voxel);
  const DownsampledCloud cur = voxelDownsample(current_points.points, params.voxel);
  BaselineResult r;
  r.removed_clusters = clusterChanges(reference_points.points, ref, freeIn(ref, current_map),
                                      params, 1, {40, 90, 230}, r.removed);
  r.added_clusters = clusterChanges(current_points.points, cur, freeIn(cur, reference_map), params,
                                    1 + r.removed_clusters, {230, 40, 40}, r.added);
  r.milliseconds = msSince(t0);
  return r;
}

}  // namespace planesdf::octomap_adapter
