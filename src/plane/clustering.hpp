#pragma once
// Clustering steps of whole-cloud plane detection (internal): DP-vMF-means on normals, offset
// modes within a normal cluster, spatial connectivity within a plane.

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <vector>

namespace planesdf::detail {

/// Axial DP-vMF-means (Straub et al. 2015, small-variance limit of the DP-vMF mixture): in the
/// first pass a normal opens a new cluster when its angle to every mean (sign ignored) exceeds
/// `lambda_deg`; then assignments and means alternate (normals beyond lambda of every mean stay
/// unassigned) until nothing changes or `max_iterations`. After each pass clusters whose means
/// are within lambda merge; clusters with fewer than `min_cluster` normals, or whose mean fails
/// `keep` (when given), are dropped.
/// Runs on normals[sample] in the given order (deterministic). Returns the unit cluster axes.
std::vector<Eigen::Vector3d> dpvmfMeans(const std::vector<Eigen::Vector3f>& normals,
                                        const std::vector<std::uint32_t>& sample, double lambda_deg,
                                        int max_iterations, std::size_t min_cluster,
                                        const std::function<bool(const Eigen::Vector3d&)>& keep);

/// For each of `indices`, the nearest axis (|cos| largest) when within `lambda_deg`, grouped:
/// result[a] holds the indices assigned to axes[a], in increasing order.
std::vector<std::vector<std::uint32_t>> assignToAxes(const std::vector<Eigen::Vector3f>& normals,
                                                     const std::vector<std::uint32_t>& indices,
                                                     const std::vector<Eigen::Vector3d>& axes,
                                                     double lambda_deg, int threads);

/// Greedy modes of the offsets axis·p over points[members]: the densest window of width
/// `split` (re-centred on its mean) becomes a group, its offsets are removed, repeat while a
/// window holds at least `min_count` points. Groups are at least about `split` apart.
std::vector<std::vector<std::uint32_t>> offsetModes(const std::vector<Eigen::Vector3f>& points,
                                                    const std::vector<std::uint32_t>& members,
                                                    const Eigen::Vector3d& axis, double split,
                                                    std::size_t min_count);

/// 8-connected parts of points[members] projected on the plane spanned by axes.col(0/1), on a
/// grid of `cell` metres (coarsened when the grid would be huge). Largest part first.
std::vector<std::vector<std::uint32_t>> connectedParts(const std::vector<Eigen::Vector3f>& points,
                                                       const std::vector<std::uint32_t>& members,
                                                       const Eigen::Matrix3d& axes, double cell);

/// The footprint of points[members] on the plane spanned by axes.col(0/1): a grid of `cell`
/// metres (coarsened as connectedParts does) with `margin` empty cells around it, and the number
/// of members in each cell.
struct PlaneCells {
  Eigen::Vector3d u = Eigen::Vector3d::UnitX(), v = Eigen::Vector3d::UnitY();
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();  ///< (u, v) of the grid's corner
  double cell = 1.0;
  int nu = 0, nv = 0;
  std::vector<std::uint32_t> count;  ///< members per cell, nu * nv

  /// The cell holding p's projection, -1 outside the grid.
  int cellOf(const Eigen::Vector3f& p) const;
};
PlaneCells planeCells(const std::vector<Eigen::Vector3f>& points,
                      const std::vector<std::uint32_t>& members, const Eigen::Matrix3d& axes,
                      double cell, int margin);

/// Members in the core of a footprint (planeCells with a margin of at least `radius`): the
/// occupied cells whose (2 radius + 1)^2 neighbourhood is occupied too. A strip narrower than
/// about 2 radius + 1 cells (a table leg, a top's edge) has none.
std::size_t coreSupport(const PlaneCells& cells, int radius);

}  // namespace planesdf::detail
