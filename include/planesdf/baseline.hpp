#pragma once
/// \file baseline.hpp
/// Baselines for the paper-style comparison (issue 5, Table I): change detection without planes or
/// SDFs, with outputs in the `planesdf detect` point format (design.md, "Formats":
/// `removed_points.ply` and `added_points.ply`, a vertex property `int change_id` per point) so
/// `planesdf eval` and evaluateChanges score them exactly as they score PlaneSDF.
///
/// Point-distance differencing: both scene clouds are voxel-downsampled (one centroid per cell of
/// `voxel`); a reference centroid with no current centroid within `distance` is removed, a current
/// centroid with no reference centroid within `distance` is added. The flagged centroids of each
/// side are grouped by Euclidean clustering (single linkage at `cluster_distance`); clusters with
/// fewer than `min_cluster_cells` cells are dropped; each kept cluster is one change id. The
/// outputs are the original input points of the flagged cells (as PlaneSDF reports input points,
/// so the two are scored on the same points), labelled with their cluster's id: removed clusters
/// are numbered 1, 2, ..., added ones continue after them.
///
/// The OctoMap occupancy-differencing baseline lives in the OctoMap adapter
/// (planesdf/octomap/octomap_baseline.hpp) and shares clusterChanges and writeBaselineOutputs.

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "planesdf/types.hpp"

namespace planesdf {

struct BaselineParams {
  double voxel = 0.007;  ///< downsampling cell (m): the PlaneSDF voxel size
  /// A point is changed when the other session has no point within this distance (m). 2 cm: the
  /// paper's height threshold δh, about three voxels, above the mOSD sensor noise at 1 m.
  double distance = 0.02;
  double cluster_distance = 0.02;  ///< Euclidean clustering link distance (m)
  int min_cluster_cells = 10;      ///< smaller clusters (in downsampled cells) are dropped
};

/// The outputs of a baseline: removed / added points with the field `change_id` (Int32) and the
/// colours of `planesdf detect` (removed blue, added red).
struct BaselineResult {
  PointCloud removed;
  PointCloud added;
  int removed_clusters = 0;
  int added_clusters = 0;
  double milliseconds = 0.0;  ///< wall time of the baseline (without file output)
};

/// One cell of a voxel-downsampled cloud: the centroid and the input points it came from.
struct DownsampledCloud {
  std::vector<Eigen::Vector3f> centroids;
  std::vector<std::vector<std::uint32_t>> members;  ///< indices into the input, per centroid
};

/// Voxel downsampling of the valid points of `points` (cells of edge `voxel` from the origin),
/// cells in a deterministic order. Throws planesdf::Error("baseline", ...) unless voxel > 0.
DownsampledCloud voxelDownsample(const std::vector<Eigen::Vector3f>& points, double voxel);

/// For each of `query`, whether some point of `other` lies within `distance` (inclusive).
std::vector<bool> hasNeighbourWithin(const std::vector<Eigen::Vector3f>& query,
                                     const std::vector<Eigen::Vector3f>& other, double distance);

/// Euclidean clustering of `points` (single linkage at `distance`): a label per point, 0-based
/// cluster numbers in order of each cluster's first point, -1 for points of clusters with fewer
/// than `min_points` points.
std::vector<int> euclideanClusters(const std::vector<Eigen::Vector3f>& points, double distance,
                                   int min_points);

/// The output cloud of one side: the input points (`source`) of the flagged cells of `cloud`,
/// labelled per cell with change id first_id + label (cells labelled -1 are left out), coloured
/// `color`. Returns the number of distinct ids used in `clusters`.
int clusterChanges(const std::vector<Eigen::Vector3f>& source, const DownsampledCloud& cloud,
                   const std::vector<bool>& flagged, const BaselineParams& params, int first_id,
                   const std::array<std::uint8_t, 3>& color, PointCloud& out);

/// Point-distance differencing (see the file comment) between two scene clouds in one world
/// frame. Throws planesdf::Error("baseline", ...) on invalid parameters.
BaselineResult pointDistanceBaseline(const PointCloud& reference, const PointCloud& current,
                                     const BaselineParams& params = {});

/// Writes dir/removed_points.ply and dir/added_points.ply (atomically; the folder is created),
/// in the format of writeChangeOutputs. Throws planesdf::Error naming the folder or file.
void writeBaselineOutputs(const std::string& dir, const BaselineResult& result);

}  // namespace planesdf
