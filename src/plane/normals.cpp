// PCA normals: k nearest neighbours (hash grid) for unorganised clouds, integral-image windows
// for organised clouds.

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "knn_grid.hpp"
#include "plane_internal.hpp"
#include "planesdf/plane.hpp"

namespace planesdf {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
const Eigen::Vector3f kNaNNormal(kNaN, kNaN, kNaN);

// Normal (smallest eigenvector) and surface variation of a covariance matrix.
bool normalFromCovariance(const Eigen::Matrix3d& cov, Eigen::Vector3f& normal, float& curvature,
                          float* rms = nullptr) {
  const double trace = cov.trace();
  if (!(trace > 0.0) || !std::isfinite(trace)) return false;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
  es.computeDirect(cov);
  const Eigen::Vector3d n = es.eigenvectors().col(0);
  if (!n.allFinite() || n.norm() < 0.5) return false;
  normal = n.normalized().cast<float>();
  curvature = static_cast<float>(std::max(0.0, es.eigenvalues()(0)) / trace);
  if (rms) *rms = static_cast<float>(std::sqrt(std::max(0.0, es.eigenvalues()(0))));
  return true;
}

void orientNormals(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3d& sensor,
                   std::vector<Eigen::Vector3f>& normals) {
  const auto sx = static_cast<float>(sensor.x()), sy = static_cast<float>(sensor.y()),
             sz = static_cast<float>(sensor.z());
  const float* p = detail::xyzData(points);
  for (std::size_t i = 0; i < points.size(); ++i) {
    float* n = normals[i].data();
    // NaN normals compare false and stay NaN.
    if (n[0] * (sx - p[3 * i]) + n[1] * (sy - p[3 * i + 1]) + n[2] * (sz - p[3 * i + 2]) < 0.0f) {
      n[0] = -n[0];
      n[1] = -n[1];
      n[2] = -n[2];
    }
  }
}

// Covariance of points[neighbours]; their mean into `mean` when given.
Eigen::Matrix3d neighbourCovariance(const std::vector<Eigen::Vector3f>& points,
                                    const std::vector<std::pair<float, std::uint32_t>>& nb,
                                    Eigen::Vector3d* mean = nullptr) {
  const float* xyz = detail::xyzData(points);
  const double inv = 1.0 / static_cast<double>(nb.size());
  double mx = 0, my = 0, mz = 0;
  for (const auto& e : nb) {
    mx += xyz[3 * e.second];
    my += xyz[3 * e.second + 1];
    mz += xyz[3 * e.second + 2];
  }
  mx *= inv;
  my *= inv;
  mz *= inv;
  if (mean) *mean = Eigen::Vector3d(mx, my, mz);
  double xx = 0, xy = 0, xz = 0, yy = 0, yz = 0, zz = 0;
  for (const auto& e : nb) {
    const double x = xyz[3 * e.second] - mx;
    const double y = xyz[3 * e.second + 1] - my;
    const double z = xyz[3 * e.second + 2] - mz;
    xx += x * x;
    xy += x * y;
    xz += x * z;
    yy += y * y;
    yz += y * z;
    zz += z * z;
  }
  Eigen::Matrix3d cov;
  cov << xx, xy, xz, xy, yy, yz, xz, yz, zz;
  return cov * inv;
}

// Candidate neighbours of one grid cell, copied contiguously so distances vectorise.
struct Candidates {
  std::vector<std::uint32_t> index;
  std::vector<float> x, y, z, d2;

  void load(const std::vector<Eigen::Vector3f>& points) {
    const std::size_t n = index.size();
    x.resize(n);
    y.resize(n);
    z.resize(n);
    d2.resize(n);
    const float* xyz = detail::xyzData(points);
    for (std::size_t j = 0; j < n; ++j) {
      x[j] = xyz[3 * index[j]];
      y[j] = xyz[3 * index[j] + 1];
      z[j] = xyz[3 * index[j] + 2];
    }
  }

  // The k nearest within squared distance `bound2` of q into `out`; false when fewer than k.
  bool nearest(const float* q, int k, float bound2,
               std::vector<std::pair<float, std::uint32_t>>& out) {
    const std::size_t n = index.size();
    const float qx = q[0], qy = q[1], qz = q[2];
    for (std::size_t j = 0; j < n; ++j) {
      const float dx = x[j] - qx;
      const float dy = y[j] - qy;
      const float dz = z[j] - qz;
      d2[j] = dx * dx + dy * dy + dz * dz;
    }
    out.clear();
    for (std::size_t j = 0; j < n; ++j) {
      if (d2[j] <= bound2) out.emplace_back(d2[j], index[j]);
    }
    const auto kk = static_cast<std::size_t>(k);
    if (out.size() < kk) return false;
    std::nth_element(out.begin(), out.begin() + (kk - 1), out.end());
    out.resize(kk);
    return true;
  }
};

using Neighbours = std::vector<std::pair<float, std::uint32_t>>;  // (squared distance, index)

// Calls fn(i, neighbours) for every valid point i for which want(i) holds, with its k nearest
// valid points among those for which member(i) holds (itself included when a member; fewer only
// when there are fewer within four grid cells), in parallel over cells.
template <typename Want, typename Member, typename Fn>
void forEachKnnAmong(const std::vector<Eigen::Vector3f>& points, int knn, int threads, Want want,
                     Member member, Fn fn) {
  const std::vector<std::uint32_t> valid = detail::validIndices(points);
  std::vector<std::uint32_t> members, indexed;
  for (const std::uint32_t i : valid) {
    if (member(i)) members.push_back(i);
    if (member(i) || want(i)) indexed.push_back(i);
  }
  if (members.size() < 3) return;
  const int k =
      static_cast<int>(std::min<std::size_t>(static_cast<std::size_t>(knn), members.size()));
  const detail::KnnGrid grid(points, indexed, detail::KnnGrid::suggestCell(points, members, k));
  const auto cells = static_cast<long long>(grid.cellCount());
  const float* xyz = detail::xyzData(points);
  const bool all = members.size() == indexed.size();
  struct Scratch {
    Candidates cand;
    std::vector<std::uint32_t> index;
    std::vector<std::pair<float, std::uint32_t>> nb;
  };
  std::vector<Scratch> per_worker(static_cast<std::size_t>(std::max(threads, 1)));
  // The members within `radius` cells of `cell`, loaded into `cand`; any point within radius *
  // cell of a point of `cell` is among them.
  const auto gather = [&](Candidates& cand, std::size_t cell, int radius) {
    cand.index.clear();
    grid.gatherAround(cell, radius, cand.index);
    if (!all)
      cand.index.erase(std::remove_if(cand.index.begin(), cand.index.end(),
                                      [&](std::uint32_t j) { return !member(j); }),
                       cand.index.end());
    cand.load(points);
  };
  const auto reach2 = [&](int r) { return static_cast<float>(r * r * grid.cell() * grid.cell()); };
  const auto visitCell = [&](Scratch& s, std::size_t cell) {
    bool any = false;
    for (const std::uint32_t* it = grid.cellBegin(cell); it != grid.cellEnd(cell) && !any; ++it)
      any = want(*it);
    if (!any) return;
    gather(s.cand, cell, 1);
    bool wide = false;  // cand holds a wider gather than the 3x3x3 block
    for (const std::uint32_t* it = grid.cellBegin(cell); it != grid.cellEnd(cell); ++it) {
      if (!want(*it)) continue;
      const float* q = xyz + 3 * *it;
      const bool found = s.cand.nearest(q, k, reach2(wide ? 4 : 1), s.nb);
      if (!found && !wide && all) {
        grid.knn(*it, cell, k, 4, s.nb, s.index);
      } else if (!found && !wide) {
        gather(s.cand, cell, 4);
        wide = true;
        s.cand.nearest(q, k, reach2(4), s.nb);
      }
      if (s.nb.size() >= 3) fn(*it, s.nb);
    }
  };
  detail::parallelChunks(cells, threads, 32, [&](int worker, long long begin, long long end) {
    for (long long c = begin; c < end; ++c)
      visitCell(per_worker[static_cast<std::size_t>(worker)], static_cast<std::size_t>(c));
  });
}

template <typename Want, typename Fn>
void forEachKnnWhere(const std::vector<Eigen::Vector3f>& points, int knn, int threads, Want want,
                     Fn fn) {
  forEachKnnAmong(
      points, knn, threads, want, [](std::uint32_t) { return true; }, fn);
}

template <typename Fn>
void forEachKnn(const std::vector<Eigen::Vector3f>& points, int knn, int threads, Fn fn) {
  forEachKnnWhere(
      points, knn, threads, [](std::uint32_t) { return true; }, fn);
}

// True for about one in `rate` indices, spread without pattern (a multiplicative hash), so a
// cloud stored in scan or voxel order is thinned evenly.
bool inSubsample(std::uint32_t i, std::uint32_t rate) {
  return rate <= 1 || ((i * 2654435761u) >> 16) % rate == 0;
}

// PCA normals at the flattest of the scales k, 4k, 16k, ... up to k_max in a noisy cloud
// (returned; isNoisyCloud at scale k). A larger neighbourhood is tried only where the smaller
// one is not flat, and kept only where at least cfg.normal_rough_share of its points are not
// flat at the smallest scale either: noise is a property of a region, an edge or a step is a
// line through smooth surfaces (design.md, "Noisy clouds"). `spread` receives the neighbours'
// RMS distance from their plane.
bool knnNormals(const std::vector<Eigen::Vector3f>& points, const Config& cfg, int threads,
                std::vector<Eigen::Vector3f>& normals, std::vector<float>& curvature,
                std::vector<float>& spread) {
  forEachKnn(points, cfg.normal_knn, threads, [&](std::uint32_t i, const Neighbours& nb) {
    normalFromCovariance(neighbourCovariance(points, nb), normals[i], curvature[i], &spread[i]);
  });
  const bool noisy = isNoisyCloud(spread, cfg);
  if (!noisy || cfg.normal_knn_max <= cfg.normal_knn) return noisy;
  const auto notFlat = [&](std::uint32_t i) {
    return !(static_cast<double>(curvature[i]) <= cfg.normal_max_curvature);  // NaN: no normal
  };
  std::vector<std::uint8_t> rough(points.size());  // at the smallest scale
  for (std::uint32_t i = 0; i < points.size(); ++i) rough[i] = notFlat(i);
  for (int k = 4 * cfg.normal_knn; k / 4 < cfg.normal_knn_max; k *= 4) {
    // A scale of more than normal_fit_points neighbours reads a subsample that holds that many
    // in the same extent. Points a smaller scale made flat keep it.
    const int scale = std::min(k, cfg.normal_knn_max);
    const auto rate = static_cast<std::uint32_t>(std::max(1, scale / cfg.normal_fit_points));
    forEachKnnAmong(
        points, scale / static_cast<int>(rate), threads, notFlat,
        [rate](std::uint32_t i) { return inSubsample(i, rate); },
        [&](std::uint32_t i, const Neighbours& nb) {
          std::size_t rough_nb = 0;
          for (const auto& e : nb) rough_nb += rough[e.second];
          if (static_cast<double>(rough_nb) <
              cfg.normal_rough_share * static_cast<double>(nb.size()))
            return;
          Eigen::Vector3f n;
          float c = 0.0f, rms = 0.0f;
          if (!normalFromCovariance(neighbourCovariance(points, nb), n, c, &rms)) return;
          if (c >= curvature[i]) return;  // NaN: no normal yet, any will do
          normals[i] = n;
          curvature[i] = c;
          spread[i] = rms;
        });
  }
  return noisy;
}

// --- organised clouds ----------------------------------------------------------------------------

constexpr int kChannels = 10;  // n, x, y, z, xx, xy, xz, yy, yz, zz

// Summed-area table of the moments of the valid points (centred on `centre`), (H+1) x (W+1).
std::vector<double> momentIntegral(const PointCloud& cloud, const Eigen::Vector3d& centre,
                                   int threads) {
  const int w = static_cast<int>(cloud.width);
  const int h = static_cast<int>(cloud.height);
  const std::size_t stride = static_cast<std::size_t>(w + 1) * kChannels;
  std::vector<double> s(stride * static_cast<std::size_t>(h + 1), 0.0);
  detail::parallelChunks(h, threads, 8, [&](int, long long r0, long long r1) {
    for (long long r = r0; r < r1; ++r) {
      double acc[kChannels] = {0};
      double* row = s.data() + stride * static_cast<std::size_t>(r + 1);
      for (int c = 0; c < w; ++c) {
        const float* pf = detail::xyzData(cloud.points) + 3 * (static_cast<std::size_t>(r) * w + c);
        if (detail::finite3(pf)) {
          const double x = pf[0] - centre.x();
          const double y = pf[1] - centre.y();
          const double z = pf[2] - centre.z();
          const double v[kChannels] = {1.0, x, y, z, x * x, x * y, x * z, y * y, y * z, z * z};
          for (int k = 0; k < kChannels; ++k) acc[k] += v[k];
        }
        double* cell = row + static_cast<std::size_t>(c + 1) * kChannels;
        for (int k = 0; k < kChannels; ++k) cell[k] = acc[k];
      }
    }
  });
  // Column pass, row after row so the inner loop is contiguous; threads split the columns.
  constexpr std::size_t kChunk = 1024;
  const auto chunks = static_cast<long long>((stride + kChunk - 1) / kChunk);
  detail::parallelChunks(chunks, threads, 1, [&](int, long long k, long long) {
    const std::size_t j0 = static_cast<std::size_t>(k) * kChunk;
    const std::size_t j1 = std::min(stride, j0 + kChunk);
    for (int r = 1; r <= h; ++r) {
      double* row = s.data() + stride * static_cast<std::size_t>(r);
      const double* above = row - stride;
      for (std::size_t j = j0; j < j1; ++j) row[j] += above[j];
    }
  });
  return s;
}

// Median angular spacing between horizontally adjacent pixels (range-relative), so that a window
// of `m` metres at range ρ spans about m / (ρ * pitch) pixels.
double angularPitch(const PointCloud& cloud, const Eigen::Vector3d& sensor) {
  const int w = static_cast<int>(cloud.width);
  const int h = static_cast<int>(cloud.height);
  std::vector<double> ratios;
  for (int r = 0; r < h; r += 7) {
    for (int c = 0; c + 1 < w; c += 3) {
      const Eigen::Vector3f& a = cloud.points[static_cast<std::size_t>(r) * w + c];
      const Eigen::Vector3f& b = cloud.points[static_cast<std::size_t>(r) * w + c + 1];
      if (!a.allFinite() || !b.allFinite()) continue;
      const double ra = (a.cast<double>() - sensor).norm();
      const double rb = (b.cast<double>() - sensor).norm();
      if (!(ra > 1e-6) || std::abs(ra - rb) > 0.02 * ra) continue;
      ratios.push_back((a - b).cast<double>().norm() / ra);
    }
  }
  if (ratios.empty()) return 1.0 / 525.0;
  auto mid = ratios.begin() + static_cast<std::ptrdiff_t>(ratios.size() / 2);
  std::nth_element(ratios.begin(), mid, ratios.end());
  return std::max(*mid, 1e-5);
}

// Normals of the pixels on a grid of `stride`; each is copied to the valid pixels of its
// stride x stride block (the window is several pixels wide, so this changes little).
void windowNormals(const PointCloud& cloud, const Config& cfg, int threads, int stride,
                   std::vector<Eigen::Vector3f>& normals, std::vector<float>& curvature) {
  const int w = static_cast<int>(cloud.width);
  const int h = static_cast<int>(cloud.height);
  const std::vector<std::uint32_t> valid = detail::validIndices(cloud.points);
  if (valid.size() < 3) return;
  const Eigen::Vector3d centre = detail::centroidOf(cloud.points, valid);
  const Eigen::Vector3d sensor = cloud.sensor_pose.translation();
  const std::vector<double> s = momentIntegral(cloud, centre, threads);
  const double pitch = angularPitch(cloud, sensor);
  const int r_min = std::max(1, static_cast<int>(std::ceil((std::sqrt(cfg.normal_knn) - 1.0) / 2)));
  const int r_max = std::max(r_min, 25);
  const double min_count = std::max(3.0, 0.5 * cfg.normal_knn);
  const std::size_t row_len = static_cast<std::size_t>(w + 1) * kChannels;
  auto at = [&](int r, int c) {
    return s.data() + row_len * r + static_cast<std::size_t>(c) * kChannels;
  };
  const float* xyz = detail::xyzData(cloud.points);
  const int rows = (h + stride - 1) / stride;
  const auto rowNormals = [&](int rs) {
    const int r = rs * stride;
    for (int c = 0; c < w; c += stride) {
      const std::size_t i = static_cast<std::size_t>(r) * w + c;
      const float* p = xyz + 3 * i;
      if (!detail::finite3(p)) continue;
      const double rx = p[0] - sensor.x(), ry = p[1] - sensor.y(), rz = p[2] - sensor.z();
      const double range = std::sqrt(rx * rx + ry * ry + rz * rz);
      const double want = cfg.normal_window / (2.0 * std::max(range, 1e-6) * pitch);
      const int rad = std::clamp(static_cast<int>(std::lround(want)), r_min, r_max);
      const int r0 = std::max(0, r - rad);
      const int r1 = std::min(h, r + rad + 1);
      const int c0 = std::max(0, c - rad);
      const int c1 = std::min(w, c + rad + 1);
      const double* a = at(r1, c1);
      const double* b = at(r0, c1);
      const double* d = at(r1, c0);
      const double* e = at(r0, c0);
      double m[kChannels];
      for (int k = 0; k < kChannels; ++k) m[k] = a[k] - b[k] - d[k] + e[k];
      const double n = m[0];
      const double area = static_cast<double>(r1 - r0) * (c1 - c0);  // clipped at the border
      if (n < std::max(3.0, std::min(min_count, 0.5 * area))) continue;
      const double mx = m[1] / n, my = m[2] / n, mz = m[3] / n;
      const double xx = m[4] / n - mx * mx, xy = m[5] / n - mx * my, xz = m[6] / n - mx * mz;
      const double yy = m[7] / n - my * my, yz = m[8] / n - my * mz, zz = m[9] / n - mz * mz;
      Eigen::Matrix3d cov;
      cov << xx, xy, xz, xy, yy, yz, xz, yz, zz;
      if (!normalFromCovariance(cov, normals[i], curvature[i]) || stride == 1) continue;
      for (int rr = r; rr < std::min(h, r + stride); ++rr) {
        for (int cc = c; cc < std::min(w, c + stride); ++cc) {
          const std::size_t j = static_cast<std::size_t>(rr) * w + cc;
          if (j == i || !detail::finite3(xyz + 3 * j)) continue;
          normals[j] = normals[i];
          curvature[j] = curvature[i];
        }
      }
    }
  };
  detail::parallelChunks(rows, threads, 4, [&](int, long long begin, long long end) {
    for (long long rs = begin; rs < end; ++rs) rowNormals(static_cast<int>(rs));
  });
}

}  // namespace

std::vector<Eigen::Vector3f> estimateNormals(const PointCloud& cloud, const Config& cfg,
                                             std::vector<float>* curvature,
                                             std::vector<float>* spread, bool* noisy) {
  validatePlaneConfig(cfg);
  cloud.validate("point cloud");
  return detail::estimateNormalsStrided(cloud, cfg, 1, curvature, spread, noisy);
}

namespace detail {

std::vector<Eigen::Vector3f> estimateNormalsStrided(const PointCloud& cloud, const Config& cfg,
                                                    int stride, std::vector<float>* curvature,
                                                    std::vector<float>* spread, bool* noisy) {
  std::vector<Eigen::Vector3f> normals(cloud.size(), kNaNNormal);
  std::vector<float> curv(cloud.size(), kNaN);
  std::vector<float> rms(cloud.isOrganized() ? 0 : cloud.size(), kNaN);
  if (noisy) *noisy = false;
  const int threads = resolveThreads(cfg.threads);
  if (cloud.isOrganized()) {
    windowNormals(cloud, cfg, threads, std::max(1, stride), normals, curv);
  } else {
    const bool is_noisy = knnNormals(cloud.points, cfg, threads, normals, curv, rms);
    if (noisy) *noisy = is_noisy;
  }
  if (const auto sensor = sensorOrigin(cloud)) orientNormals(cloud.points, *sensor, normals);
  if (curvature) *curvature = std::move(curv);
  if (spread) *spread = std::move(rms);
  return normals;
}

}  // namespace detail

bool isNoisyCloud(const std::vector<float>& spread, const Config& cfg) {
  std::size_t thick = 0, measured = 0;
  for (const float s : spread) {
    if (!std::isfinite(s)) continue;
    ++measured;
    thick += static_cast<double>(s) > cfg.voxel_size ? 1 : 0;
  }
  return measured > 0 &&
         static_cast<double>(thick) >= cfg.noisy_cloud_share * static_cast<double>(measured);
}

std::vector<Eigen::Vector3f> projectToLocalPlanes(const std::vector<Eigen::Vector3f>& points,
                                                  const Config& cfg) {
  std::vector<Eigen::Vector3f> out = points;
  if (cfg.cloud_smooth_knn < 3) return out;
  forEachKnn(
      points, cfg.cloud_smooth_knn, detail::resolveThreads(cfg.threads),
      [&](std::uint32_t i, const Neighbours& nb) {
        Eigen::Vector3d c;
        Eigen::Vector3f n;
        float curvature = 0.0f;
        const Eigen::Matrix3d cov = neighbourCovariance(points, nb, &c);
        if (!normalFromCovariance(cov, n, curvature)) return;
        const Eigen::Vector3f p = points[i];
        const float d = n.dot(p - c.cast<float>());
        // sqrt(λ0): the RMS distance of the neighbours from their plane.
        const double rms = std::sqrt(std::max(0.0, static_cast<double>(curvature) * cov.trace()));
        // (10 µm: float rounding of room-sized coordinates, so exact surfaces keep every point)
        if (cfg.cloud_outlier_sigma > 0.0 && std::abs(d) > cfg.cloud_outlier_sigma * rms + 1e-5) {
          out[i] = kNaNNormal;  // an outlier of its neighbourhood: dropped
          return;
        }
        out[i] = p - n * d;
      });
  return out;
}

}  // namespace planesdf
