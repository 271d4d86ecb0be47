// DP-vMF-means normal clustering, offset modes and connectivity split.

#include "clustering.hpp"
#include "../numeric.hpp"
#include "plane_internal.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>

namespace planesdf::detail {
namespace {

using detail::kPi;
static_assert(sizeof(Eigen::Vector3d) == 3 * sizeof(double), "Vector3d must be packed");

// Index of the axis with the largest |cos| to n, and that |cos|.
int nearestAxis(const std::vector<Eigen::Vector3d>& axes, const float* n, double& best) {
  int arg = -1;
  best = -1.0;
  const double nx = n[0], ny = n[1], nz = n[2];
  const double* a3 = axes.empty() ? nullptr : axes.front().data();  // packed like Vector3f
  for (std::size_t a = 0; a < axes.size(); ++a) {
    const double c = std::abs(a3[3 * a] * nx + a3[3 * a + 1] * ny + a3[3 * a + 2] * nz);
    if (c > best) {
      best = c;
      arg = static_cast<int>(a);
    }
  }
  return arg;
}

}  // namespace

std::vector<Eigen::Vector3d> dpvmfMeans(const std::vector<Eigen::Vector3f>& normals,
                                        const std::vector<std::uint32_t>& sample, double lambda_deg,
                                        int max_iterations, std::size_t min_cluster,
                                        const std::function<bool(const Eigen::Vector3d&)>& keep) {
  const double cos_lambda = std::cos(lambda_deg * kPi / 180.0);
  std::vector<Eigen::Vector3d> means;
  std::vector<int> label(sample.size(), -1);
  for (int it = 0; it < max_iterations; ++it) {
    // Assignment; only the first pass opens clusters (DP-means), later passes leave normals far
    // from every mean unassigned.
    bool changed = false;
    std::vector<Eigen::Vector3d> sums(means.size(), Eigen::Vector3d::Zero());
    std::vector<std::size_t> counts(means.size(), 0);
    const float* nrm = xyzData(normals);
    for (std::size_t s = 0; s < sample.size(); ++s) {
      const float* nf = nrm + 3 * sample[s];
      const Eigen::Vector3d n(nf[0], nf[1], nf[2]);
      double best = -1.0;
      int k = nearestAxis(means, nf, best);
      if (k < 0 || best < cos_lambda) {
        if (it == 0) {
          means.push_back(n);
          sums.emplace_back(Eigen::Vector3d::Zero());
          counts.push_back(0);
          k = static_cast<int>(means.size()) - 1;
        } else {
          k = -1;
        }
      }
      if (label[s] != k) changed = true;
      label[s] = k;
      if (k < 0) continue;
      const double* mk = means[k].data();
      const double sign = mk[0] * n[0] + mk[1] * n[1] + mk[2] * n[2] >= 0.0 ? 1.0 : -1.0;
      double* sk = sums[k].data();
      sk[0] += sign * n[0];
      sk[1] += sign * n[1];
      sk[2] += sign * n[2];
      ++counts[k];
    }
    // Means of the clusters, largest first; a cluster whose mean is within lambda of a larger
    // one merges into it (noise splits one direction into several Voronoi cells otherwise), and
    // clusters that stay below `min_cluster` are dropped.
    std::vector<std::size_t> order(means.size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t a, std::size_t b) { return counts[a] > counts[b]; });
    std::vector<Eigen::Vector3d> merged_sum;
    std::vector<std::size_t> merged_count;
    for (std::size_t k : order) {
      if (counts[k] == 0 || !(sums[k].norm() > 0.0)) continue;
      const Eigen::Vector3d m = sums[k].normalized();
      bool absorbed = false;
      for (std::size_t j = 0; j < merged_sum.size(); ++j) {
        const Eigen::Vector3d mj = merged_sum[j].normalized();
        if (std::abs(mj.dot(m)) >= cos_lambda) {
          merged_sum[j] += mj.dot(m) >= 0.0 ? sums[k] : Eigen::Vector3d(-sums[k]);
          merged_count[j] += counts[k];
          absorbed = true;
          changed = true;
          break;
        }
      }
      if (!absorbed) {
        merged_sum.push_back(sums[k]);
        merged_count.push_back(counts[k]);
      }
    }
    std::vector<Eigen::Vector3d> next;
    for (std::size_t j = 0; j < merged_sum.size(); ++j) {
      const Eigen::Vector3d m = merged_sum[j].normalized();
      if (merged_count[j] >= std::max<std::size_t>(min_cluster, 1) && (!keep || keep(m))) {
        next.push_back(m);
      } else {
        changed = true;
      }
    }
    // Labels are recomputed by the next pass; invalidate them so `changed` is meaningful.
    if (next.size() != means.size()) std::fill(label.begin(), label.end(), -2);
    means = std::move(next);
    if (!changed && it > 0) break;
  }
  return means;
}

std::vector<std::vector<std::uint32_t>> assignToAxes(const std::vector<Eigen::Vector3f>& normals,
                                                     const std::vector<std::uint32_t>& indices,
                                                     const std::vector<Eigen::Vector3d>& axes,
                                                     double lambda_deg, int threads) {
  const double cos_lambda = std::cos(lambda_deg * kPi / 180.0);
  std::vector<int> label(indices.size(), -1);
  const long long n = static_cast<long long>(indices.size());
  parallelChunks(n, threads, kPointGrain, [&](int, long long begin, long long end) {
    for (long long i = begin; i < end; ++i) {
      double best = -1.0;
      const int k = nearestAxis(axes, xyzData(normals) + 3 * indices[i], best);
      if (k >= 0 && best >= cos_lambda) label[i] = k;
    }
  });
  std::vector<std::vector<std::uint32_t>> groups(axes.size());
  for (std::size_t i = 0; i < indices.size(); ++i) {
    if (label[i] >= 0) groups[label[i]].push_back(indices[i]);
  }
  return groups;
}

std::vector<std::vector<std::uint32_t>> offsetModes(const std::vector<Eigen::Vector3f>& points,
                                                    const std::vector<std::uint32_t>& members,
                                                    const Eigen::Vector3d& axis, double split,
                                                    std::size_t min_count) {
  std::vector<std::vector<std::uint32_t>> groups;
  if (members.size() < std::max<std::size_t>(min_count, 1)) return groups;
  std::vector<double> off(members.size());
  double lo = std::numeric_limits<double>::infinity();
  double hi = -lo;
  for (std::size_t i = 0; i < members.size(); ++i) {
    const float* p = xyzData(points) + 3 * members[i];
    off[i] = axis.x() * p[0] + axis.y() * p[1] + axis.z() * p[2];
    lo = std::min(lo, off[i]);
    hi = std::max(hi, off[i]);
  }
  constexpr double kMaxBins = 2.0e6;
  const double bin = std::max({split / 10.0, (hi - lo) / kMaxBins, 1e-9});
  const int half = std::max(1, static_cast<int>(std::lround(0.5 * split / bin)));
  const int bins = static_cast<int>((hi - lo) / bin) + 1;
  std::vector<int> bin_of(members.size());
  std::vector<double> count(static_cast<std::size_t>(bins), 0.0);
  for (std::size_t i = 0; i < members.size(); ++i) {
    bin_of[i] = std::min(bins - 1, static_cast<int>((off[i] - lo) / bin));
    count[bin_of[i]] += 1.0;
  }
  std::vector<char> taken(members.size(), 0);
  std::vector<double> prefix(static_cast<std::size_t>(bins) + 1);
  for (;;) {
    prefix[0] = 0.0;
    for (int b = 0; b < bins; ++b) prefix[b + 1] = prefix[b] + count[b];
    auto window = [&](int centre) {
      return prefix[std::min(bins, centre + half + 1)] - prefix[std::max(0, centre - half)];
    };
    int best = 0;
    for (int b = 1; b < bins; ++b) {
      if (window(b) > window(best)) best = b;
    }
    if (window(best) < static_cast<double>(std::max<std::size_t>(min_count, 1))) break;
    // Re-centre on the mean bin of the window.
    double wsum = 0.0;
    double bsum = 0.0;
    for (int b = std::max(0, best - half); b <= std::min(bins - 1, best + half); ++b) {
      wsum += count[b];
      bsum += count[b] * b;
    }
    const int centre = static_cast<int>(std::lround(bsum / wsum));
    const int b0 = std::max(0, centre - half);
    const int b1 = std::min(bins - 1, centre + half);
    std::vector<std::uint32_t> group;
    for (std::size_t i = 0; i < members.size(); ++i) {
      if (!taken[i] && bin_of[i] >= b0 && bin_of[i] <= b1) {
        taken[i] = 1;
        group.push_back(members[i]);
      }
    }
    for (int b = b0; b <= b1; ++b) count[b] = 0.0;
    if (!group.empty()) groups.push_back(std::move(group));
  }
  return groups;
}

namespace {

struct Bounds2 {
  float u_lo, u_hi, v_lo, v_hi;
};

/// Bounds of (us, vs) (non-empty), with 8 independent lanes: element-wise min/max vectorise, one
/// running min does not.
Bounds2 boundsOf(const std::vector<float>& us, const std::vector<float>& vs) {
  const std::size_t m = us.size();
  constexpr std::size_t kLanes = 8;
  std::array<float, kLanes> ulo, uhi, vlo, vhi;
  ulo.fill(us[0]);
  uhi.fill(us[0]);
  vlo.fill(vs[0]);
  vhi.fill(vs[0]);
  std::size_t i = 0;
  for (; i + kLanes <= m; i += kLanes) {
    for (std::size_t l = 0; l < kLanes; ++l) {
      ulo[l] = us[i + l] < ulo[l] ? us[i + l] : ulo[l];
      uhi[l] = us[i + l] > uhi[l] ? us[i + l] : uhi[l];
      vlo[l] = vs[i + l] < vlo[l] ? vs[i + l] : vlo[l];
      vhi[l] = vs[i + l] > vhi[l] ? vs[i + l] : vhi[l];
    }
  }
  for (; i < m; ++i) {
    ulo[0] = std::min(ulo[0], us[i]);
    uhi[0] = std::max(uhi[0], us[i]);
    vlo[0] = std::min(vlo[0], vs[i]);
    vhi[0] = std::max(vhi[0], vs[i]);
  }
  return {*std::min_element(ulo.begin(), ulo.end()), *std::max_element(uhi.begin(), uhi.end()),
          *std::min_element(vlo.begin(), vlo.end()), *std::max_element(vhi.begin(), vhi.end())};
}

/// Labels the 8-connected components of the occupied cells (-2) of an nu x nv grid 0, 1, ... in
/// scan order; returns their number.
int labelComponents(std::vector<int>& grid, int nu, int nv) {
  int labels = 0;
  std::vector<int> stack;
  for (std::size_t start = 0; start < grid.size(); ++start) {
    if (grid[start] != -2) continue;
    grid[start] = labels;
    stack.assign(1, static_cast<int>(start));
    while (!stack.empty()) {
      const int c = stack.back();
      stack.pop_back();
      const int cu = c % nu;
      const int cv = c / nu;
      for (int dv = -1; dv <= 1; ++dv) {
        for (int du = -1; du <= 1; ++du) {
          const int u = cu + du;
          const int v = cv + dv;
          if (u < 0 || v < 0 || u >= nu || v >= nv) continue;
          const int q = v * nu + u;
          if (grid[q] == -2) {
            grid[q] = labels;
            stack.push_back(q);
          }
        }
      }
    }
    ++labels;
  }
  return labels;
}

}  // namespace

std::vector<std::vector<std::uint32_t>> connectedParts(const std::vector<Eigen::Vector3f>& points,
                                                       const std::vector<std::uint32_t>& members,
                                                       const Eigen::Matrix3d& axes, double cell) {
  if (members.empty()) return {};
  // Single precision is plenty for cells of centimetres and keeps this pass cheap.
  const auto ux = static_cast<float>(axes(0, 0)), uy = static_cast<float>(axes(1, 0)),
             uz = static_cast<float>(axes(2, 0));
  const auto vx = static_cast<float>(axes(0, 1)), vy = static_cast<float>(axes(1, 1)),
             vz = static_cast<float>(axes(2, 1));
  // Project once into flat arrays (the min/max and cell passes then vectorise).
  const float* xyz = xyzData(points);
  const std::size_t m = members.size();
  // Per-thread scratch reused across calls (a frame's inliers are hundreds of thousands of
  // points: fresh arrays every frame cost page faults). Every entry used is rewritten.
  thread_local std::vector<float> us_scratch, vs_scratch;
  thread_local std::vector<int> cell_scratch, grid_scratch;
  std::vector<float>& us = us_scratch;
  std::vector<float>& vs = vs_scratch;
  us.resize(m);
  vs.resize(m);
  for (std::size_t i = 0; i < m; ++i) {
    const float* p = xyz + 3 * members[i];
    us[i] = ux * p[0] + uy * p[1] + uz * p[2];
    vs[i] = vx * p[0] + vy * p[1] + vz * p[2];
  }
  const auto [u_lo, u_hi, v_lo, v_hi] = boundsOf(us, vs);
  constexpr double kMaxCells = 16.0e6;
  const double area_cells = ((u_hi - u_lo) / cell + 1.0) * ((v_hi - v_lo) / cell + 1.0);
  if (area_cells > kMaxCells) cell *= std::sqrt(area_cells / kMaxCells);
  const int nu = static_cast<int>((u_hi - u_lo) / cell) + 1;
  const int nv = static_cast<int>((v_hi - v_lo) / cell) + 1;
  const auto inv = static_cast<float>(1.0 / cell);
  std::vector<int>& cell_of = cell_scratch;
  cell_of.resize(m);
  for (std::size_t i = 0; i < m; ++i) {
    const int cu = std::min(nu - 1, static_cast<int>((us[i] - u_lo) * inv));
    const int cv = std::min(nv - 1, static_cast<int>((vs[i] - v_lo) * inv));
    cell_of[i] = cv * nu + cu;
  }
  std::vector<int>& grid = grid_scratch;  // -1 empty, -2 occupied, else label
  grid.assign(static_cast<std::size_t>(nu) * nv, -1);
  for (int c : cell_of) grid[c] = -2;
  const int labels = labelComponents(grid, nu, nv);
  if (labels == 1) return {members};
  std::vector<std::size_t> count(static_cast<std::size_t>(labels), 0);
  for (int c : cell_of) ++count[grid[c]];
  std::vector<std::vector<std::uint32_t>> parts(static_cast<std::size_t>(labels));
  for (std::size_t l = 0; l < parts.size(); ++l) parts[l].reserve(count[l]);
  for (std::size_t i = 0; i < members.size(); ++i) parts[grid[cell_of[i]]].push_back(members[i]);
  std::stable_sort(parts.begin(), parts.end(),
                   [](const auto& a, const auto& b) { return a.size() > b.size(); });
  return parts;
}

}  // namespace planesdf::detail

namespace planesdf::detail {

int PlaneCells::cellOf(const Eigen::Vector3f& p) const {
  const Eigen::Vector3d q = p.cast<double>();
  const double gu = (u.dot(q) - origin.x()) / cell, gv = (v.dot(q) - origin.y()) / cell;
  if (!(gu >= 0.0 && gv >= 0.0 && gu < nu && gv < nv)) return -1;
  return static_cast<int>(gv) * nu + static_cast<int>(gu);
}

PlaneCells planeCells(const std::vector<Eigen::Vector3f>& points,
                      const std::vector<std::uint32_t>& members, const Eigen::Matrix3d& axes,
                      double cell, int margin) {
  PlaneCells g;
  g.u = axes.col(0);
  g.v = axes.col(1);
  if (members.empty()) return g;
  std::vector<Eigen::Vector2d> uv(members.size());
  Eigen::AlignedBox2d box;
  for (std::size_t i = 0; i < members.size(); ++i) {
    const Eigen::Vector3d p = points[members[i]].cast<double>();
    uv[i] = {g.u.dot(p), g.v.dot(p)};
    box.extend(uv[i]);
  }
  constexpr double kMaxCells = 16.0e6;
  const Eigen::Vector2d size = box.sizes();
  const double area_cells = (size.x() / cell + 1.0) * (size.y() / cell + 1.0);
  if (area_cells > kMaxCells) cell *= std::sqrt(area_cells / kMaxCells);
  g.cell = cell;
  g.origin = box.min() - Eigen::Vector2d::Constant(margin * cell);
  g.nu = static_cast<int>(size.x() / cell) + 1 + 2 * margin;
  g.nv = static_cast<int>(size.y() / cell) + 1 + 2 * margin;
  g.count.assign(static_cast<std::size_t>(g.nu) * g.nv, 0);
  for (const Eigen::Vector2d& q : uv) {
    const Eigen::Vector2d c = (q - box.min()) / cell;
    const int cu = std::min(g.nu - 1 - 2 * margin, static_cast<int>(c.x())) + margin;
    const int cv = std::min(g.nv - 1 - 2 * margin, static_cast<int>(c.y())) + margin;
    ++g.count[static_cast<std::size_t>(cv) * g.nu + cu];
  }
  return g;
}

std::size_t coreSupport(const PlaneCells& g, int radius) {
  // The margin of at least `radius` empty cells around the footprint: border cells are never core.
  std::size_t core = 0;
  for (int cv = radius; cv < g.nv - radius; ++cv) {
    for (int cu = radius; cu < g.nu - radius; ++cu) {
      const std::uint32_t here = g.count[static_cast<std::size_t>(cv) * g.nu + cu];
      if (here == 0) continue;
      bool full = true;
      for (int dv = -radius; dv <= radius && full; ++dv)
        for (int du = -radius; du <= radius && full; ++du)
          full = g.count[static_cast<std::size_t>(cv + dv) * g.nu + cu + du] > 0;
      if (full) core += here;
    }
  }
  return core;
}

}  // namespace planesdf::detail
