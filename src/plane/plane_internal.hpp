#pragma once
// Internal helpers shared by the plane-stage translation units (not installed).

#include <Eigen/Core>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "../parallel.hpp"
#include "planesdf/config.hpp"
#include "planesdf/plane.hpp"

namespace planesdf::detail {

/// Small deterministic PRNG (SplitMix64); identical streams on every platform.
struct SplitMix64 {
  std::uint64_t state;
  explicit SplitMix64(std::uint64_t seed) : state(seed) {}
  std::uint64_t next() {
    std::uint64_t z = (state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
  /// Uniform in [0, n); n > 0.
  std::uint64_t below(std::uint64_t n) { return next() % n; }
};

// Raw coordinate access for the hot loops (they stay fast in unoptimised Debug builds, where
// every small Eigen call is a real call). std::vector<Eigen::Vector3f> is a packed xyz array.
static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float), "Vector3f must be packed");

/// The points as one packed array x0 y0 z0 x1 ... (nullptr when empty).
inline const float* xyzData(const std::vector<Eigen::Vector3f>& v) {
  return v.empty() ? nullptr : v.front().data();
}
inline bool finite3(const float* p) {
  return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
}

/// Indices of the points with finite coordinates.
std::vector<std::uint32_t> validIndices(const std::vector<Eigen::Vector3f>& points);

/// At most `max_count` of `indices`, evenly strided (all of them when there are fewer).
std::vector<std::uint32_t> evenSubsample(const std::vector<std::uint32_t>& indices,
                                         std::size_t max_count);

/// Centroid of points[indices] (double precision). Zero when `indices` is empty.
Eigen::Vector3d centroidOf(const std::vector<Eigen::Vector3f>& points,
                           const std::vector<std::uint32_t>& indices);

/// PCA plane through points[indices]; false when fewer than 3 points or degenerate.
bool fitPlanePca(const std::vector<Eigen::Vector3f>& points,
                 const std::vector<std::uint32_t>& indices, Eigen::Vector3d& normal,
                 double& offset);

/// Flips (normal, offset) so that `target` is on the positive side (no-op when on the plane).
void orientToward(Eigen::Vector3d& normal, double& offset, const Eigen::Vector3d& target);

/// A plane with its frame anchored at the centroid of points[inliers], support = inliers.size()
/// and the extent of those inliers.
Plane planeFromInliers(const Eigen::Vector3d& normal, double offset,
                       const std::vector<Eigen::Vector3f>& points,
                       const std::vector<std::uint32_t>& inliers, const Eigen::Vector3d& up);

/// Bounds (u, v) of points[indices] in the plane's frame.
Eigen::AlignedBox2d extentOf(const Plane& plane, const std::vector<Eigen::Vector3f>& points,
                             const std::vector<std::uint32_t>& indices);

/// Where fitFrontFace looks for a plane's faces.
struct SlabSearch {
  const std::vector<Eigen::Vector3f>& points;
  const std::vector<Eigen::Vector3f>& normals;  ///< per point (non-finite: any)
  const std::vector<std::uint32_t>& valid;      ///< indices of the finite points
  const std::vector<char>& claimed;             ///< points other planes hold (or this part)
  double cell = 0.05;                           ///< in-plane cell, m
  double reach = 0.03;    ///< how far from the plane unclaimed points may lie, m
  double min_gap = 0.01;  ///< faces closer than this are one, m
  double min_cos = 0.9;   ///< a point's normal within this cosine of the plane's (sign ignored)
};

/// A thin panel's points form two parallel faces, and a plane fitted to both lies between them
/// or tilts from one to the other. When at least a tenth of the in-plane cells of `part` (with
/// the unclaimed points within `reach` over them) show two faces more than `min_gap` apart along
/// `normal`, refits (`normal`, `offset`) to the front face, the one `normal` points out of
/// (parallel to the back face), adds the points on it to `part` (sorted) and returns true
/// (design.md, "A panel's front face"). `axes` is the plane's frame.
bool fitFrontFace(const SlabSearch& in, std::vector<std::uint32_t>& part,
                  const Eigen::Matrix3d& axes, Eigen::Vector3d& normal, double& offset);

/// Copies points[indices] (evenly subsampled to at most `max_count`).
std::vector<Eigen::Vector3f> gatherPoints(const std::vector<Eigen::Vector3f>& points,
                                          const std::vector<std::uint32_t>& indices,
                                          std::size_t max_count);

/// estimateNormals without validation; organised clouds evaluate every `stride`-th pixel in
/// each direction and copy the normal over the block (stride 1 = every pixel). `spread`, when
/// given, receives per point of an unorganised cloud the RMS distance of the neighbours the
/// normal came from to their plane (empty for organised clouds); `noisy` as in estimateNormals.
std::vector<Eigen::Vector3f> estimateNormalsStrided(const PointCloud& cloud, const Config& cfg,
                                                    int stride, std::vector<float>* curvature,
                                                    std::vector<float>* spread = nullptr,
                                                    bool* noisy = nullptr);

}  // namespace planesdf::detail
