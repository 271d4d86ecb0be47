// Per-frame plane detection by sequential RANSAC on a subsample.

#include "ransac.hpp"

#include <algorithm>
#include <cmath>

#include "clustering.hpp"
#include "plane_internal.hpp"

namespace planesdf {
namespace detail {
namespace {

constexpr double kConfidence = 0.995;
constexpr std::uint64_t kSeed = 0x9a5e5eedULL;

// Structure-of-arrays copy of the sample so that inlier counting vectorises.
struct SampleArrays {
  std::vector<float> x, y, z;
  std::vector<std::uint32_t> index;
  std::size_t size() const { return index.size(); }
  void push(const Eigen::Vector3f& p, std::uint32_t i) {
    x.push_back(p.x());
    y.push_back(p.y());
    z.push_back(p.z());
    index.push_back(i);
  }
};

SampleArrays makeArrays(const std::vector<Eigen::Vector3f>& points,
                        const std::vector<std::uint32_t>& sample) {
  SampleArrays s;
  for (std::uint32_t i : sample) s.push(points[i], i);
  return s;
}

std::size_t countInliers(const SampleArrays& s, const Eigen::Vector3d& n, double d, double t) {
  const float nx = static_cast<float>(n.x());
  const float ny = static_cast<float>(n.y());
  const float nz = static_cast<float>(n.z());
  const float fd = static_cast<float>(d);
  const float ft = static_cast<float>(t);
  const std::size_t m = s.size();
  const float* x = s.x.data();
  const float* y = s.y.data();
  const float* z = s.z.data();
  std::size_t count = 0;
  for (std::size_t i = 0; i < m; ++i) {
    count += std::abs(nx * x[i] + ny * y[i] + nz * z[i] + fd) <= ft ? 1 : 0;
  }
  return count;
}

std::vector<std::uint32_t> inlierIndices(const SampleArrays& s, const Eigen::Vector3d& n, double d,
                                         double t) {
  std::vector<std::uint32_t> out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    const double dist = n.x() * s.x[i] + n.y() * s.y[i] + n.z() * s.z[i] + d;
    if (std::abs(dist) <= t) out.push_back(s.index[i]);
  }
  return out;
}

// Iterations needed to draw an all-inlier triple with probability kConfidence.
double neededIterations(std::size_t inliers, std::size_t total) {
  const double w = static_cast<double>(inliers) / static_cast<double>(total);
  const double w3 = w * w * w;
  if (w3 >= 1.0) return 1.0;
  if (w3 <= 1e-12) return 1e18;
  return std::log(1.0 - kConfidence) / std::log(1.0 - w3);
}

std::optional<RansacPlane> bestPlane(const std::vector<Eigen::Vector3f>& points,
                                     const SampleArrays& s, double t, int max_iterations,
                                     std::size_t min_inliers, SplitMix64& rng) {
  const std::size_t m = s.size();
  if (m < 3) return std::nullopt;
  RansacPlane best;
  double needed = max_iterations;
  for (int it = 0; it < max_iterations && it < needed; ++it) {
    const std::size_t i = rng.below(m);
    const std::size_t j = rng.below(m);
    const std::size_t k = rng.below(m);
    if (i == j || j == k || i == k) continue;
    const Eigen::Vector3d a(s.x[i], s.y[i], s.z[i]);
    const Eigen::Vector3d b(s.x[j], s.y[j], s.z[j]);
    const Eigen::Vector3d c(s.x[k], s.y[k], s.z[k]);
    Eigen::Vector3d n = (b - a).cross(c - a);
    const double len = n.norm();
    if (!(len > 1e-12)) continue;
    n /= len;
    const double d = -n.dot(a);
    const std::size_t count = countInliers(s, n, d, t);
    if (count > best.sample_inliers) {
      best = {n, d, count};
      needed = neededIterations(count, m);
    }
  }
  if (best.sample_inliers < std::max<std::size_t>(min_inliers, 3)) return std::nullopt;
  // Least-squares refit on the inliers (twice: the inlier set moves with the plane).
  for (int pass = 0; pass < 2; ++pass) {
    Eigen::Vector3d n;
    double d = 0.0;
    if (!fitPlanePca(points, inlierIndices(s, best.normal, best.offset, t), n, d)) break;
    if (n.dot(best.normal) < 0.0) {
      n = -n;
      d = -d;
    }
    best.normal = n;
    best.offset = d;
  }
  best.sample_inliers = countInliers(s, best.normal, best.offset, t);
  if (best.sample_inliers < std::max<std::size_t>(min_inliers, 3)) return std::nullopt;
  return best;
}

SampleArrays withoutInliers(const SampleArrays& s, const RansacPlane& p, double t) {
  SampleArrays out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    const double dist =
        p.normal.x() * s.x[i] + p.normal.y() * s.y[i] + p.normal.z() * s.z[i] + p.offset;
    if (std::abs(dist) > t) out.push(Eigen::Vector3f(s.x[i], s.y[i], s.z[i]), s.index[i]);
  }
  return out;
}

// About `count` valid points evenly strided over the whole array (the valid fraction is probed on
// every 16th point, so no pass over all points is needed). Falls back to an exact subsample of the
// valid points when the probe sees too few.
std::vector<std::uint32_t> strideSample(const std::vector<Eigen::Vector3f>& points,
                                        std::size_t count) {
  const float* xyz = xyzData(points);
  const std::size_t n = points.size();
  std::size_t probed = 0, ok = 0;
  for (std::size_t i = 0; i < n; i += 16, ++probed) ok += finite3(xyz + 3 * i) ? 1 : 0;
  std::vector<std::uint32_t> sample;
  if (ok >= 16) {
    const double valid_estimate =
        static_cast<double>(n) * static_cast<double>(ok) / static_cast<double>(probed);
    const double step = std::max(1.0, valid_estimate / static_cast<double>(count));
    for (double x = 0.0; x < static_cast<double>(n); x += step) {
      const auto i = static_cast<std::size_t>(x);
      if (finite3(xyz + 3 * i)) sample.push_back(static_cast<std::uint32_t>(i));
    }
  }
  if (sample.size() < 3) sample = evenSubsample(validIndices(points), count);
  return sample;
}

// One pass over all points: each valid point goes to the inliers of the first plane within t.
// Returns the number of valid points.
std::size_t assignInliers(const std::vector<Eigen::Vector3f>& points,
                          const std::vector<RansacPlane>& planes, double t,
                          std::vector<std::vector<std::uint32_t>>& inliers) {
  std::vector<float> coeffs;  // nx ny nz d per plane
  for (const RansacPlane& p : planes) {
    for (double v : {p.normal.x(), p.normal.y(), p.normal.z(), p.offset}) {
      coeffs.push_back(static_cast<float>(v));
    }
  }
  inliers.assign(planes.size(), {});
  const float* xyz = xyzData(points);
  const auto ft = static_cast<float>(t);
  const std::size_t n = points.size();
  const int np = static_cast<int>(planes.size());
  std::size_t valid = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const float* p = xyz + 3 * i;
    if (!finite3(p)) continue;
    ++valid;
    for (int k = 0; k < np; ++k) {
      const float* c = coeffs.data() + 4 * k;
      if (std::abs(c[0] * p[0] + c[1] * p[1] + c[2] * p[2] + c[3]) <= ft) {
        inliers[k].push_back(static_cast<std::uint32_t>(i));
        break;
      }
    }
  }
  return valid;
}

}  // namespace

std::vector<RansacPlane> sequentialRansac(const std::vector<Eigen::Vector3f>& points,
                                          const std::vector<std::uint32_t>& sample,
                                          double inlier_dist, int max_iterations,
                                          std::size_t min_inliers, int max_planes,
                                          std::uint64_t seed) {
  std::vector<RansacPlane> planes;
  SplitMix64 rng(seed);
  SampleArrays remaining = makeArrays(points, sample);
  for (int p = 0; p < max_planes; ++p) {
    if (remaining.size() < std::max<std::size_t>(min_inliers, 3)) break;
    const auto best = bestPlane(points, remaining, inlier_dist, max_iterations, min_inliers, rng);
    if (!best) break;
    planes.push_back(*best);
    remaining = withoutInliers(remaining, *best, inlier_dist);
  }
  return planes;
}

std::vector<PlaneObservation> ransacFramePlanes(const std::vector<Eigen::Vector3f>& points,
                                                const Eigen::Vector3d& sensor, const Config& cfg,
                                                const Eigen::Vector3d* up) {
  const std::vector<std::uint32_t> sample =
      strideSample(points, static_cast<std::size_t>(cfg.ransac_max_samples));
  if (sample.size() < 3) return {};
  const double frac = cfg.ransac_min_inlier_frac;
  const double lowest = up ? std::min(frac, cfg.ransac_min_horizontal_frac) : frac;
  const auto min_sample =
      static_cast<std::size_t>(std::ceil(lowest * static_cast<double>(sample.size())));
  const std::vector<RansacPlane> planes =
      sequentialRansac(points, sample, cfg.ransac_inlier_dist, cfg.ransac_iterations, min_sample,
                       cfg.ransac_max_planes_per_frame, kSeed);
  std::vector<std::vector<std::uint32_t>> inliers;
  const std::size_t valid = assignInliers(points, planes, cfg.ransac_inlier_dist, inliers);
  std::vector<PlaneObservation> out;
  for (std::size_t k = 0; k < planes.size(); ++k) {
    Eigen::Vector3d n = planes[k].normal;
    double d = planes[k].offset;
    const bool horizontal = up && classifyOrientation(n, *up, cfg.orientation_tolerance_deg) ==
                                      Plane::Orientation::Horizontal;
    const auto min_full = static_cast<std::size_t>(std::ceil(
        (horizontal ? cfg.ransac_min_horizontal_frac : frac) * static_cast<double>(valid)));
    if (inliers[k].size() < std::max<std::size_t>(min_full, 3)) continue;
    orientToward(n, d, sensor);
    // Coplanar but separate surfaces (a wall's strip at table height) become separate
    // observations; parts below the minimum are dropped.
    std::vector<std::vector<std::uint32_t>> parts;
    if (cfg.plane_connect_cell > 0.0) {
      parts = connectedParts(points, inliers[k], planeAxes(n, n), cfg.plane_connect_cell);
    } else {
      parts.push_back(std::move(inliers[k]));
    }
    for (auto& part : parts) {
      if (part.size() < std::max<std::size_t>(min_full, 3)) break;  // largest first
      PlaneObservation o;
      o.plane.normal = n;
      o.plane.offset = d;
      o.plane.support = part.size();
      o.inliers = std::move(part);
      out.push_back(std::move(o));
    }
  }
  std::stable_sort(out.begin(), out.end(), [](const auto& a, const auto& b) {
    return a.inliers.size() > b.inliers.size();
  });
  return out;
}

std::vector<PlaneObservation> finishObservations(std::vector<PlaneObservation> observations,
                                                 const std::vector<Eigen::Vector3f>& points,
                                                 const Eigen::Vector3d& up, const Config& cfg) {
  std::vector<PlaneObservation> out;
  for (PlaneObservation& o : observations) {
    const auto cls = classifyOrientation(o.plane.normal, up, cfg.orientation_tolerance_deg);
    if (!cls) continue;
    Plane plane = planeFromInliers(o.plane.normal, o.plane.offset, points, o.inliers, up);
    plane.orientation = *cls;
    o.plane = plane;
    out.push_back(std::move(o));
  }
  return out;
}

}  // namespace detail

std::vector<PlaneObservation> detectPlanesRansac(const std::vector<Eigen::Vector3f>& points_world,
                                                 const Eigen::Vector3d& sensor_origin,
                                                 const Config& cfg, const Eigen::Vector3d& up) {
  validatePlaneConfig(cfg);
  const Eigen::Vector3d u = up.normalized();
  return detail::finishObservations(detail::ransacFramePlanes(points_world, sensor_origin, cfg, &u),
                                    points_world, u, cfg);
}

std::vector<PlaneObservation> detectPlanesRansac(const std::vector<Eigen::Vector3f>& points_world,
                                                 const Eigen::Vector3d& sensor_origin,
                                                 const Config& cfg) {
  validatePlaneConfig(cfg);
  Eigen::Vector3d up = cfg.up.normalized();
  std::vector<PlaneObservation> all =
      detail::ransacFramePlanes(points_world, sensor_origin, cfg, cfg.up_auto ? nullptr : &up);
  if (cfg.up_auto && !all.empty()) up = all.front().plane.normal;
  return detail::finishObservations(std::move(all), points_world, up, cfg);
}

}  // namespace planesdf
