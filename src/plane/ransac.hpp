#pragma once
// RANSAC plane fitting on point subsamples (internal).

#include <Eigen/Core>

#include <cstdint>
#include <optional>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/plane.hpp"

namespace planesdf::detail {

/// A plane found by RANSAC on a subsample: parameters (LS-refitted on its sample inliers) and
/// its sample inlier count.
struct RansacPlane {
  Eigen::Vector3d normal;
  double offset = 0.0;
  std::size_t sample_inliers = 0;
};

/// Sequential RANSAC on points[sample]: up to `max_planes` planes, each with at least
/// `min_inliers` of the (remaining) sample within `inlier_dist`; largest first. Deterministic
/// for a given `seed`.
std::vector<RansacPlane> sequentialRansac(const std::vector<Eigen::Vector3f>& points,
                                          const std::vector<std::uint32_t>& sample,
                                          double inlier_dist, int max_iterations,
                                          std::size_t min_inliers, int max_planes,
                                          std::uint64_t seed);

/// Frame planes of `points` with normals toward `sensor`, inliers over all points (each point to
/// the first plane within cfg.ransac_inlier_dist), not yet classified and without a frame
/// (frame_* default, extent empty). Largest first. Planes need cfg.ransac_min_inlier_frac of the
/// valid points, horizontal ones (against `up`, when given) cfg.ransac_min_horizontal_frac.
std::vector<PlaneObservation> ransacFramePlanes(const std::vector<Eigen::Vector3f>& points,
                                                const Eigen::Vector3d& sensor, const Config& cfg,
                                                const Eigen::Vector3d* up);

/// Builds frames (from `up`) and extents, classifies against `up` and keeps only horizontal and
/// vertical observations.
std::vector<PlaneObservation> finishObservations(std::vector<PlaneObservation> observations,
                                                 const std::vector<Eigen::Vector3f>& points,
                                                 const Eigen::Vector3d& up, const Config& cfg);

}  // namespace planesdf::detail
