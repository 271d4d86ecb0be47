// A thin panel's plane on its front face (design.md, "A panel's front face").

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "plane_internal.hpp"

namespace planesdf::detail {
namespace {

constexpr std::size_t kMinCellPoints = 8;  // a cell needs this many points to show its faces
constexpr double kMinFaceShare = 0.1;      // each face holds this share of its cell's points
constexpr std::size_t kMinFacePoints = 3;
constexpr double kMinSlabShare = 0.1;  // of the counted cells show two faces

/// The points over one in-plane cell: (signed distance, point index), and where its front face
/// starts once sorted (0: one face).
struct Cell {
  std::vector<std::pair<double, std::uint32_t>> s;
  std::size_t front_start = 0;
  bool counted = false;  ///< it has kMinCellPoints or more
};
using Cells = std::unordered_map<std::uint64_t, Cell>;

/// In one cell's sorted signed distances, the index where the front face starts: the widest gap
/// of at least `min_gap` with enough points on both sides; 0 when the cell shows one face.
std::size_t frontStart(const std::vector<std::pair<double, std::uint32_t>>& s, double min_gap) {
  const std::size_t m = s.size();
  const std::size_t min_side = std::max(
      kMinFacePoints, static_cast<std::size_t>(std::ceil(kMinFaceShare * static_cast<double>(m))));
  std::size_t best = 0;
  double widest = min_gap;
  for (std::size_t k = min_side; k + min_side <= m; ++k)
    if (s[k].first - s[k - 1].first >= widest) {
      widest = s[k].first - s[k - 1].first;
      best = k;
    }
  return best;
}

/// One cell's mean in-plane position and the level of its front face (and of its back face when
/// it shows two), as signed distances from the plane being refitted.
struct CellLevels {
  double u = 0.0, v = 0.0;
  double front = 0.0, back = 0.0;
  bool two = false;
};

/// The front face as a + b u + c v (u, v relative to their means) over the cells: two-faced
/// cells give both faces (the back one lifted by `separation`), one-faced cells the face the
/// current model puts them on, within `tolerance`. Least squares, three rounds.
Eigen::Vector3d fitFrontLevels(const std::vector<CellLevels>& cells, double separation,
                               double start, double tolerance, double u0, double v0) {
  Eigen::Vector3d model(start, 0.0, 0.0);
  for (int round = 0; round < 3; ++round) {
    Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
    Eigen::Vector3d atb = Eigen::Vector3d::Zero();
    const auto add = [&](const CellLevels& c, double level) {
      const Eigen::Vector3d row(1.0, c.u - u0, c.v - v0);
      ata += row * row.transpose();
      atb += row * level;
    };
    for (const CellLevels& c : cells) {
      const double at = model(0) + model(1) * (c.u - u0) + model(2) * (c.v - v0);
      if (c.two) {
        add(c, c.front);
        add(c, c.back + separation);
      } else if (std::abs(c.front - at) <= tolerance) {
        add(c, c.front);
      } else if (std::abs(c.front + separation - at) <= tolerance) {
        add(c, c.front + separation);
      }
    }
    const Eigen::Vector3d next = ata.ldlt().solve(atb);
    if (!next.allFinite()) break;
    model = next;
  }
  return model;
}

/// The sums of a sorted cell's signed distances below and from index `k`.
void faceSums(const Cell& c, std::size_t k, double& back_sum, double& front_sum) {
  back_sum = front_sum = 0.0;
  for (std::size_t j = 0; j < c.s.size(); ++j) (j < k ? back_sum : front_sum) += c.s[j].first;
}

/// The signed distances (to `normal`, `offset`) of the part's points and of the unclaimed ones
/// within `reach` over its cells, normals agreeing, per in-plane cell: the other face of a panel
/// lies beyond the inlier distance of a plane on one face.
Cells gatherCells(const SlabSearch& in, const std::vector<std::uint32_t>& part,
                  const Eigen::Matrix3d& axes, const Eigen::Vector3d& normal, double offset) {
  const auto cellKey = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector3d q = axes.transpose() * p;
    const auto cu = static_cast<std::int64_t>(std::floor(q.x() / in.cell));
    const auto cv = static_cast<std::int64_t>(std::floor(q.y() / in.cell));
    return (static_cast<std::uint64_t>(cu) << 32) ^
           (static_cast<std::uint64_t>(cv) & 0xffffffffULL);
  };
  Cells cells;
  for (const std::uint32_t i : part) {
    const Eigen::Vector3d p = in.points[i].cast<double>();
    cells[cellKey(p)].s.emplace_back(normal.dot(p) + offset, i);
  }
  const float* nrm = xyzData(in.normals);
  for (const std::uint32_t i : in.valid) {
    if (in.claimed[i]) continue;
    const Eigen::Vector3d p = in.points[i].cast<double>();
    const double s = normal.dot(p) + offset;
    if (std::abs(s) > in.reach) continue;
    const float* q = nrm + 3 * i;
    if (finite3(q) &&
        std::abs(normal.x() * q[0] + normal.y() * q[1] + normal.z() * q[2]) < in.min_cos)
      continue;
    const auto c = cells.find(cellKey(p));
    if (c != cells.end()) c->second.s.emplace_back(s, i);
  }
  return cells;
}

/// Sorts each cell with kMinCellPoints or more, marks it counted and finds where it splits into
/// two faces; returns how many were counted and the median distance between the faces' means of
/// the split ones in `thickness` (NaN: none split).
std::size_t splitCells(Cells& cells, double min_gap, double& thickness) {
  std::vector<double> separations;
  std::size_t counted = 0;
  for (auto& [key, c] : cells) {
    if (c.s.size() < kMinCellPoints) continue;
    ++counted;
    c.counted = true;
    std::sort(c.s.begin(), c.s.end());
    const std::size_t k = frontStart(c.s, min_gap);
    c.front_start = k;
    if (k == 0) continue;
    double back_sum = 0.0, front_sum = 0.0;
    faceSums(c, k, back_sum, front_sum);
    separations.push_back(front_sum / static_cast<double>(c.s.size() - k) -
                          back_sum / static_cast<double>(k));
  }
  thickness = std::numeric_limits<double>::quiet_NaN();
  if (separations.empty()) return counted;
  std::nth_element(separations.begin(), separations.begin() + separations.size() / 2,
                   separations.end());
  thickness = separations[separations.size() / 2];
  return counted;
}

/// Each counted cell's mean position and face levels; a split whose faces lie not within
/// `tolerance` of `thickness` apart (an object's top over the front face) counts as one face.
std::vector<CellLevels> cellLevels(const Cells& cells, const std::vector<Eigen::Vector3f>& points,
                                   const Eigen::Matrix3d& axes, double thickness,
                                   double tolerance) {
  std::vector<CellLevels> levels;
  for (const auto& [key, c] : cells) {
    if (!c.counted) continue;
    CellLevels l;
    for (const auto& [s, i] : c.s) {
      const Eigen::Vector3d q = axes.transpose() * points[i].cast<double>();
      l.u += q.x();
      l.v += q.y();
    }
    const auto m = static_cast<double>(c.s.size());
    l.u /= m;
    l.v /= m;
    std::size_t k = c.front_start;
    double back_sum = 0.0, sum = 0.0;
    faceSums(c, k, back_sum, sum);
    if (k > 0 && std::abs(sum / (m - static_cast<double>(k)) - back_sum / static_cast<double>(k) -
                          thickness) > tolerance) {
      k = 0;
      faceSums(c, k, back_sum, sum);
    }
    l.front = sum / (m - static_cast<double>(k));
    if (k > 0) {
      l.two = true;
      l.back = back_sum / static_cast<double>(k);
    }
    levels.push_back(l);
  }
  return levels;
}

}  // namespace

bool fitFrontFace(const SlabSearch& in, std::vector<std::uint32_t>& part,
                  const Eigen::Matrix3d& axes, Eigen::Vector3d& normal, double& offset) {
  if (!(in.cell > 0.0) || !(in.min_gap > 0.0) || part.size() < kMinCellPoints) return false;
  Cells cells = gatherCells(in, part, axes, normal, offset);
  double thickness = 0.0;
  const std::size_t counted = splitCells(cells, in.min_gap, thickness);
  if (!std::isfinite(thickness)) return false;
  const std::vector<CellLevels> levels =
      cellLevels(cells, in.points, axes, thickness, 0.5 * in.min_gap);
  std::size_t two_faced = 0;
  double u0 = 0.0, v0 = 0.0, front_sum = 0.0;
  for (const CellLevels& l : levels) {
    u0 += l.u;
    v0 += l.v;
    if (!l.two) continue;
    ++two_faced;
    front_sum += l.front;
  }
  if (static_cast<double>(two_faced) < kMinSlabShare * static_cast<double>(counted)) return false;
  u0 /= static_cast<double>(levels.size());
  v0 /= static_cast<double>(levels.size());
  // The front face over all cells: the two-faced cells fix which face the others show, and the
  // whole plane's cells, not only the strips where both faces were seen, fix its tilt.
  const Eigen::Vector3d m = fitFrontLevels(
      levels, thickness, front_sum / static_cast<double>(two_faced), 0.5 * in.min_gap, u0, v0);
  Eigen::Vector3d n = normal - m(1) * axes.col(0) - m(2) * axes.col(1);
  double d = offset - m(0) + m(1) * u0 + m(2) * v0;
  const double scale = n.norm();
  if (!(scale > 0.0) || !std::isfinite(d)) return false;
  normal = n / scale;
  offset = d / scale;
  // The slab's points all extend the plane (a board seen mostly from below), with the front
  // face's unclaimed ones.
  std::vector<std::uint32_t> all = part;
  for (const auto& [key, c] : cells)
    for (const auto& [s, i] : c.s)
      if (std::abs(normal.dot(in.points[i].cast<double>()) + offset) <= 0.5 * in.min_gap)
        all.push_back(i);
  std::sort(all.begin(), all.end());
  all.erase(std::unique(all.begin(), all.end()), all.end());
  part = std::move(all);
  return true;
}

}  // namespace planesdf::detail
