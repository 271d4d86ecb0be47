// Whole-cloud plane detection: normals -> DP-vMF-means -> offset modes -> inliers ->
// connectivity -> refinement -> horizontal / vertical filter.

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>

#include "../numeric.hpp"
#include "clustering.hpp"
#include "plane_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/plane.hpp"
#include "ransac.hpp"

namespace planesdf {
namespace {

using detail::kPi;
constexpr std::size_t kClusterSample = 30000;  // normals DP-vMF-means runs on
constexpr int kVmfIterations = 10;
constexpr int kNormalStride = 2;         // organised clouds
constexpr std::size_t kUpSample = 5000;  // points estimateUp's RANSAC runs on
constexpr std::uint64_t kUpSeed = 0x00c0ffeeULL;

double cosDeg(double deg) {
  return std::cos(deg * kPi / 180.0);
}

// A plane hypothesis from one offset mode of one normal cluster.
struct Candidate {
  Eigen::Vector3d normal;
  double offset = 0.0;
  std::size_t seed_inliers = 0;
};

// PCA fit of the seed, then two trimmed refits on the seed points within `dist`.
std::optional<Candidate> fitCandidate(const std::vector<Eigen::Vector3f>& points,
                                      const std::vector<std::uint32_t>& seed, double dist) {
  Candidate c;
  if (!detail::fitPlanePca(points, seed, c.normal, c.offset)) return std::nullopt;
  std::vector<std::uint32_t> inliers;
  const float* xyz = detail::xyzData(points);
  for (int pass = 0; pass < 2; ++pass) {
    inliers.clear();
    const double nx = c.normal.x(), ny = c.normal.y(), nz = c.normal.z();
    for (std::uint32_t i : seed) {
      const float* p = xyz + 3 * i;
      if (std::abs(nx * p[0] + ny * p[1] + nz * p[2] + c.offset) <= dist) inliers.push_back(i);
    }
    Eigen::Vector3d n;
    double d = 0.0;
    if (!detail::fitPlanePca(points, inliers, n, d)) break;
    c.normal = n;
    c.offset = d;
  }
  c.seed_inliers = inliers.size();
  return c;
}

// Unclaimed valid points within `dist` of the plane whose normal (when finite) is within the
// angle of cos `min_cos` of it (sign ignored). Sequential: one pass costs well under a
// millisecond per 100k points.
std::vector<std::uint32_t> claimInliers(const std::vector<Eigen::Vector3f>& points,
                                        const std::vector<Eigen::Vector3f>& normals,
                                        const std::vector<std::uint32_t>& valid,
                                        const std::vector<char>& claimed, const Candidate& c,
                                        double dist, double min_cos) {
  const auto nx = static_cast<float>(c.normal.x()), ny = static_cast<float>(c.normal.y()),
             nz = static_cast<float>(c.normal.z());
  const auto d = static_cast<float>(c.offset);
  const auto t = static_cast<float>(dist);
  const auto mc = static_cast<float>(min_cos);
  const float* xyz = detail::xyzData(points);
  const float* nrm = detail::xyzData(normals);
  std::vector<std::uint32_t> out;
  for (std::uint32_t i : valid) {
    const float* p = xyz + 3 * i;
    if (claimed[i] || std::abs(nx * p[0] + ny * p[1] + nz * p[2] + d) > t) continue;
    const float* q = nrm + 3 * i;
    if (!detail::finite3(q) || std::abs(nx * q[0] + ny * q[1] + nz * q[2]) >= mc) {
      out.push_back(i);
    }
  }
  return out;
}

// A noisy cloud's accepted plane also claims the rest of its noise layer: unclaimed points over
// its footprint within `reach` times their local noise of it, normals agreeing. Left over, the
// shell just beyond ransac_inlier_dist seeds planes a few degrees off a far wall (design.md,
// "Noisy clouds").
void claimNoiseLayer(const std::vector<Eigen::Vector3f>& points,
                     const std::vector<Eigen::Vector3f>& normals, const std::vector<float>& noise,
                     const std::vector<std::uint32_t>& valid, const detail::PlaneCells& footprint,
                     const Candidate& c, double reach, double min_cos, std::vector<char>& claimed) {
  const auto nx = static_cast<float>(c.normal.x()), ny = static_cast<float>(c.normal.y()),
             nz = static_cast<float>(c.normal.z());
  const auto d = static_cast<float>(c.offset);
  const auto r = static_cast<float>(reach);
  const auto mc = static_cast<float>(min_cos);
  for (std::uint32_t i : valid) {
    if (claimed[i] || !(noise[i] > 0.0f)) continue;
    const Eigen::Vector3f& p = points[i];
    if (std::abs(nx * p.x() + ny * p.y() + nz * p.z() + d) > r * noise[i]) continue;
    const Eigen::Vector3f& q = normals[i];
    if (detail::finite3(q.data()) && std::abs(nx * q.x() + ny * q.y() + nz * q.z()) < mc) continue;
    const int cell_index = footprint.cellOf(p);
    if (cell_index >= 0 && footprint.count[static_cast<std::size_t>(cell_index)] > 0)
      claimed[i] = 1;
  }
}

// Plane hypotheses from every normal cluster that could be horizontal or vertical.
std::vector<Candidate> planeCandidates(const std::vector<Eigen::Vector3f>& points,
                                       const std::vector<Eigen::Vector3f>& normals,
                                       const Eigen::Vector3d& up, const Config& cfg, int threads) {
  std::vector<std::uint32_t> with_normal;
  const float* xyz = detail::xyzData(points);
  const float* nrm = detail::xyzData(normals);
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (detail::finite3(xyz + 3 * i) && detail::finite3(nrm + 3 * i)) {
      with_normal.push_back(static_cast<std::uint32_t>(i));
    }
  }
  const auto min_seed = static_cast<std::size_t>(cfg.min_plane_support) / 2;
  const std::vector<std::uint32_t> sample = detail::evenSubsample(with_normal, kClusterSample);
  // A cluster smaller than this (in sample units) cannot hold a plane candidate.
  const std::size_t min_cluster =
      with_normal.empty() ? 1 : min_seed * sample.size() / with_normal.size() / 2;
  // Cluster axes are rough normals: allow lambda of slack before the exact orientation filter.
  const double slack_tol = cfg.orientation_tolerance_deg + cfg.vmf_lambda_deg;
  const auto could_be_hv = [&](const Eigen::Vector3d& axis) {
    return classifyOrientation(axis, up, slack_tol).has_value();
  };
  const std::vector<Eigen::Vector3d> axes = detail::dpvmfMeans(
      normals, sample, cfg.vmf_lambda_deg, kVmfIterations, min_cluster, could_be_hv);
  const auto groups = detail::assignToAxes(normals, with_normal, axes, cfg.vmf_lambda_deg, threads);
  std::vector<Candidate> candidates;
  for (std::size_t a = 0; a < axes.size(); ++a) {
    if (groups[a].size() < min_seed) continue;
    for (const auto& seed :
         detail::offsetModes(points, groups[a], axes[a], cfg.offset_split, min_seed)) {
      if (auto c = fitCandidate(points, seed, cfg.ransac_inlier_dist)) candidates.push_back(*c);
    }
  }
  std::stable_sort(
      candidates.begin(), candidates.end(),
      [](const Candidate& a, const Candidate& b) { return a.seed_inliers > b.seed_inliers; });
  return candidates;
}

struct Found {
  Plane plane;
  std::vector<std::uint32_t> inliers;
  bool fitted = false;  ///< a thin panel's front face (PlaneObservation::fitted)
};

// Least squares + robust refinement of one connected part; the plane is kept when it is still
// horizontal / vertical. Normal toward the free side.
std::optional<Found> finishPart(const std::vector<Eigen::Vector3f>& points,
                                std::vector<std::uint32_t> part, const Candidate& c,
                                const Eigen::Vector3d& up,
                                const std::optional<Eigen::Vector3d>& sensor,
                                const Eigen::Vector3d& centroid, const detail::SlabSearch* slabs,
                                const Config& cfg) {
  Eigen::Vector3d n = c.normal;
  double d = c.offset;
  if (detail::fitPlanePca(points, part, n, d) && n.dot(c.normal) < 0.0) {
    n = -n;
    d = -d;
  }
  Plane plane = makePlane(n, d, detail::centroidOf(points, part), up);
  refinePlane(detail::gatherPoints(points, part, static_cast<std::size_t>(cfg.refine_max_points)),
              plane, cfg);
  const auto cls = classifyOrientation(plane.normal, up, cfg.orientation_tolerance_deg);
  if (!cls) return std::nullopt;
  n = plane.normal;
  d = plane.offset;
  if (sensor) {
    detail::orientToward(n, d, *sensor);
  } else if (*cls == Plane::Orientation::Horizontal) {
    if (n.dot(up) < 0.0) {
      n = -n;
      d = -d;
    }
  } else {
    detail::orientToward(n, d, centroid);
  }
  Found f;
  if (slabs) {
    f.fitted = detail::fitFrontFace(*slabs, part, planeAxes(n, up), n, d);
    if (f.fitted && classifyOrientation(n, up, cfg.orientation_tolerance_deg) != cls)
      return std::nullopt;
  }
  f.plane = detail::planeFromInliers(n, d, points, part, up);
  f.plane.orientation = *cls;
  f.inliers = std::move(part);
  return f;
}

}  // namespace

Eigen::Vector3d estimateUp(const PointCloud& cloud, const Config& cfg) {
  validatePlaneConfig(cfg);
  cloud.validate("point cloud");
  const Eigen::Vector3d fallback = cfg.up.normalized();
  const std::vector<std::uint32_t> valid = detail::validIndices(cloud.points);
  const std::vector<std::uint32_t> sample = detail::evenSubsample(valid, kUpSample);
  const auto min_inliers = static_cast<std::size_t>(
      std::ceil(cfg.ransac_min_inlier_frac * static_cast<double>(sample.size())));
  const std::vector<detail::RansacPlane> planes =
      detail::sequentialRansac(cloud.points, sample, cfg.ransac_inlier_dist,
                               std::max(cfg.ransac_iterations, 500), min_inliers, 1, kUpSeed);
  if (planes.empty()) return fallback;
  Eigen::Vector3d n = planes.front().normal;
  double d = planes.front().offset;
  if (const auto sensor = sensorOrigin(cloud)) {
    detail::orientToward(n, d, *sensor);
  } else if (n.dot(fallback) < 0.0) {
    n = -n;
  }
  return n;
}

namespace {

PlaneSegmentation segmentWithNormals(const PointCloud& world, const Config& cfg,
                                     const std::vector<Eigen::Vector3f>& normals,
                                     const std::vector<float>& noise) {
  PlaneSegmentation out;
  out.labels.assign(world.size(), -1);
  out.up = cfg.up.normalized();
  const std::vector<std::uint32_t> valid = detail::validIndices(world.points);
  if (valid.size() < 3) return out;
  if (cfg.up_auto) out.up = estimateUp(world, cfg);
  const int threads = detail::resolveThreads(cfg.threads);
  const std::vector<Candidate> candidates =
      planeCandidates(world.points, normals, out.up, cfg, threads);
  const std::optional<Eigen::Vector3d> sensor = sensorOrigin(world);
  const Eigen::Vector3d centroid = detail::centroidOf(world.points, valid);
  const double min_cos = cosDeg(2.0 * cfg.vmf_lambda_deg);
  const auto min_support = static_cast<std::size_t>(cfg.min_plane_support);
  // Unorganised clouds: a part needs a core 2 r + 1 cells wide, about plane_min_width (a single
  // view keeps object faces; design.md, "Shelf boards are planes, object faces are not").
  const int core_radius =
      !world.isOrganized() && cfg.plane_connect_cell > 0.0 && cfg.plane_min_width > 0.0
          ? std::max(1, static_cast<int>(std::lround(
                            0.5 * (cfg.plane_min_width / cfg.plane_connect_cell - 1.0))))
          : 0;
  // A noisy cloud's planes claim their noise layer over their footprint (needs the cell grid).
  const bool claim_layer =
      !noise.empty() && cfg.splat_noise_reach > 0.0 && cfg.plane_connect_cell > 0.0;
  // Claim inliers candidate by candidate (largest seed first), split them into connected parts.
  std::vector<char> claimed(world.size(), 0);
  std::vector<std::vector<std::uint32_t>> parts;
  std::vector<const Candidate*> part_candidate;
  for (const Candidate& c : candidates) {
    if (!classifyOrientation(c.normal, out.up, cfg.orientation_tolerance_deg)) continue;
    const Eigen::Matrix3d axes = planeAxes(c.normal, out.up);
    std::vector<std::uint32_t> inliers =
        claimInliers(world.points, normals, valid, claimed, c, cfg.ransac_inlier_dist, min_cos);
    if (inliers.size() < min_support) continue;
    std::vector<std::vector<std::uint32_t>> split;
    if (cfg.plane_connect_cell > 0.0) {
      split = detail::connectedParts(world.points, inliers, axes, cfg.plane_connect_cell);
    } else {
      split.push_back(std::move(inliers));
    }
    for (auto& part : split) {
      if (part.size() < min_support) break;  // largest first
      // Its footprint (with the core's margin), for the core rule and the noise layer's claim.
      detail::PlaneCells cells;
      if (core_radius > 0 || claim_layer)
        cells = detail::planeCells(world.points, part, axes, cfg.plane_connect_cell, core_radius);
      // A plane is a surface at least plane_min_width wide: half of min_plane_support lies in
      // its core (a 0.9 x 0.3 m board's core holds 57 % of its points); the face a table's legs
      // and top edge make has none (design.md, "Shelf boards are planes, object faces are not").
      if (core_radius > 0 && 2 * detail::coreSupport(cells, core_radius) < min_support) continue;
      for (std::uint32_t i : part) claimed[i] = 1;
      if (claim_layer)
        claimNoiseLayer(world.points, normals, noise, valid, cells, c, cfg.splat_noise_reach,
                        min_cos, claimed);
      parts.push_back(std::move(part));
      part_candidate.push_back(&c);
    }
  }
  // Whole-scene clouds see panels from both sides (a single view sees one face).
  detail::SlabSearch slabs{world.points, normals, valid, claimed};
  slabs.cell = cfg.plane_connect_cell;
  slabs.reach = 2.0 * cfg.ransac_inlier_dist;
  slabs.min_gap = cfg.h_obj;
  slabs.min_cos = min_cos;
  // Refit and refine the parts (independent of each other).
  std::vector<std::optional<Found>> finished(parts.size());
  const auto n_parts = static_cast<long long>(parts.size());
  detail::parallelChunks(n_parts, threads, 1, [&](int, long long begin, long long end) {
    for (long long k = begin; k < end; ++k)
      finished[k] = finishPart(world.points, std::move(parts[k]), *part_candidate[k], out.up,
                               sensor, centroid, world.isOrganized() ? nullptr : &slabs, cfg);
  });
  std::vector<Found> found;
  for (auto& f : finished) {
    if (f) found.push_back(std::move(*f));
  }
  std::stable_sort(found.begin(), found.end(), [](const Found& a, const Found& b) {
    return a.plane.support > b.plane.support;
  });
  for (std::size_t k = 0; k < found.size(); ++k) {
    found[k].plane.id = static_cast<int>(k);
    for (std::uint32_t i : found[k].inliers) out.labels[i] = static_cast<int>(k);
    out.planes.push_back(std::move(found[k].plane));
    out.fitted.push_back(found[k].fitted ? 1 : 0);
  }
  return out;
}

}  // namespace

PlaneSegmentation segmentPlanes(const PointCloud& world, const Config& cfg) {
  validatePlaneConfig(cfg);
  world.validate("point cloud");
  // Organised: normals on every other pixel (the window spans >= 5 pixels).
  return segmentWithNormals(world, cfg,
                            detail::estimateNormalsStrided(world, cfg, kNormalStride, nullptr), {});
}

PlaneSegmentation segmentPlanes(const PointCloud& world, const Config& cfg,
                                const std::vector<Eigen::Vector3f>& normals,
                                const std::vector<float>& noise) {
  validatePlaneConfig(cfg);
  world.validate("point cloud");
  if (normals.size() != world.size())
    throw Error("point cloud", "segmentPlanes: " + std::to_string(normals.size()) +
                                   " normals for " + std::to_string(world.size()) + " points");
  if (!noise.empty() && noise.size() != world.size())
    throw Error("point cloud", "segmentPlanes: " + std::to_string(noise.size()) +
                                   " noise values for " + std::to_string(world.size()) + " points");
  return segmentWithNormals(world, cfg, normals, noise);
}

std::vector<Plane> detectPlanes(const PointCloud& world, const Config& cfg) {
  return segmentPlanes(world, cfg).planes;
}

}  // namespace planesdf
