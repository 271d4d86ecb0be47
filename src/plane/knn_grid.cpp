// k-nearest-neighbour search on a hashed voxel grid.

#include "knn_grid.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>

namespace planesdf::detail {
namespace {

constexpr std::uint64_t kCoordMask = (1ULL << 21) - 1;

// MurmurHash3 finaliser: every key bit affects the low bits used as the slot.
std::uint64_t hashKey(std::uint64_t key) {
  key ^= key >> 33;
  key *= 0xFF51AFD7ED558CCDULL;
  key ^= key >> 33;
  key *= 0xC4CEB9FE1A85EC53ULL;
  return key ^ (key >> 33);
}

std::uint64_t tableSizeFor(std::size_t n) {
  std::uint64_t size = 16;
  while (size < 2 * static_cast<std::uint64_t>(n)) size <<= 1;
  return size;
}

int clampedFloor(double v) {
  const double f = std::floor(v);
  return static_cast<int>(std::clamp(f, -1.0e9, 1.0e9));
}

Eigen::Vector3i cellCoord(const Eigen::Vector3f& p, double inv_cell) {
  return {clampedFloor(p.x() * inv_cell), clampedFloor(p.y() * inv_cell),
          clampedFloor(p.z() * inv_cell)};
}

std::uint64_t packKey(const Eigen::Vector3i& c) {
  return ((static_cast<std::uint64_t>(c.x()) & kCoordMask) << 42) |
         ((static_cast<std::uint64_t>(c.y()) & kCoordMask) << 21) |
         (static_cast<std::uint64_t>(c.z()) & kCoordMask);
}

// Number of distinct cell keys among points[indices] at cell size `cell`.
std::size_t countOccupiedCells(const std::vector<Eigen::Vector3f>& points,
                               const std::vector<std::uint32_t>& indices, double cell) {
  const std::uint64_t size = tableSizeFor(indices.size());
  const std::uint64_t mask = size - 1;
  const std::uint64_t empty = std::numeric_limits<std::uint64_t>::max();
  std::vector<std::uint64_t> table(size, empty);
  std::size_t distinct = 0;
  const double inv = 1.0 / cell;
  for (std::uint32_t i : indices) {
    const std::uint64_t key = packKey(cellCoord(points[i], inv));
    for (std::uint64_t slot = hashKey(key) & mask;; slot = (slot + 1) & mask) {
      if (table[slot] == key) break;
      if (table[slot] == empty) {
        table[slot] = key;
        ++distinct;
        break;
      }
    }
  }
  return distinct;
}

// Per-axis extent of the bulk of points[indices]: four times the range between the 1st and 99th
// percentiles of up to 8192 evenly spaced points, capped by the bounding box. The box of a
// cloud without far points (any within 1.5 such ranges of the percentiles) is kept as it is; a
// few far outliers do not stretch the extent, so the cells stay sized to the bulk's density.
Eigen::Vector3d bulkExtent(const std::vector<Eigen::Vector3f>& points,
                           const std::vector<std::uint32_t>& indices,
                           const Eigen::AlignedBox3d& box) {
  constexpr std::size_t kSample = 8192;
  const std::size_t step = std::max<std::size_t>(1, indices.size() / kSample);
  std::vector<float> values;
  values.reserve(indices.size() / step + 1);
  Eigen::Vector3d extent = box.sizes();
  for (int axis = 0; axis < 3; ++axis) {
    values.clear();
    for (std::size_t i = 0; i < indices.size(); i += step)
      values.push_back(points[indices[i]][axis]);
    // The k-th smallest sample value.
    const auto kth = [&](std::size_t k) {
      const auto it = values.begin() + static_cast<std::ptrdiff_t>(k);
      std::nth_element(values.begin(), it, values.end());
      return static_cast<double>(*it);
    };
    // Rounded outward: samples of up to 101 points keep their minimum and maximum.
    const double last = static_cast<double>(values.size() - 1);
    const double lo = kth(static_cast<std::size_t>(std::floor(0.01 * last)));
    const double hi = kth(static_cast<std::size_t>(std::ceil(0.99 * last)));
    extent[axis] = std::min(extent[axis], 4.0 * (hi - lo));
  }
  return extent;
}

}  // namespace

KnnGrid::KnnGrid(const std::vector<Eigen::Vector3f>& points,
                 const std::vector<std::uint32_t>& indices, double cell)
    : points_(points), cell_(cell) {
  const double inv = 1.0 / cell_;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;
  keyed.reserve(indices.size());
  for (std::uint32_t i : indices) keyed.emplace_back(packKey(cellCoord(points[i], inv)), i);
  std::sort(keyed.begin(), keyed.end());
  order_.resize(keyed.size());
  for (std::size_t i = 0; i < keyed.size(); ++i) {
    order_[i] = keyed[i].second;
    if (i == 0 || keyed[i].first != keyed[i - 1].first) {
      cells_.push_back({keyed[i].first, static_cast<std::uint32_t>(i), 0,
                        cellCoord(points[keyed[i].second], inv)});
    }
    cells_.back().end = static_cast<std::uint32_t>(i + 1);
  }
  const std::uint64_t size = tableSizeFor(cells_.size());
  mask_ = size - 1;
  table_.assign(size, 0);
  for (std::size_t c = 0; c < cells_.size(); ++c) {
    std::uint64_t slot = hashKey(cells_[c].key) & mask_;
    while (table_[slot] != 0) slot = (slot + 1) & mask_;
    table_[slot] = static_cast<std::uint32_t>(c + 1);
  }
}

double KnnGrid::suggestCell(const std::vector<Eigen::Vector3f>& points,
                            const std::vector<std::uint32_t>& indices, int k) {
  if (indices.size() < 2) return 1.0;
  Eigen::AlignedBox3d box;
  for (std::uint32_t i : indices) box.extend(points[i].cast<double>());
  const Eigen::Vector3d size = bulkExtent(points, indices, box);
  const double diag = std::max(size.norm(), 1e-6);
  const Eigen::Vector3d clamped = size.cwiseMax(diag * 1e-3);
  const double n = static_cast<double>(indices.size());
  double cell = std::cbrt(clamped.prod() / n);
  const double target = std::max(4.0, 0.5 * k);
  for (int it = 0; it < 8; ++it) {
    const double occupied = static_cast<double>(countOccupiedCells(points, indices, cell));
    const double mean = n / occupied;
    const double factor = std::clamp(std::sqrt(target / mean), 0.3, 3.0);
    cell *= factor;
    if (std::abs(factor - 1.0) < 0.15) break;
  }
  cell = std::clamp(cell, diag * 1e-6, diag);
  // Calibrate on the k-th neighbour distance of a few points: the 3x3x3 block then holds the
  // k nearest neighbours of most points without holding many more.
  const KnnGrid grid(points, indices, cell);
  std::vector<float> kth;
  std::vector<std::uint32_t> scratch;
  std::vector<std::pair<float, std::uint32_t>> nb;
  const std::size_t step = std::max<std::size_t>(1, grid.order_.size() / 256);
  std::size_t c = 0;
  for (std::size_t i = 0; i < grid.order_.size(); i += step) {
    while (grid.cells_[c].end <= i) ++c;
    grid.knn(grid.order_[i], c, k, 4, nb, scratch);
    if (nb.size() == static_cast<std::size_t>(k)) kth.push_back(std::sqrt(nb.back().first));
  }
  if (kth.empty()) return cell;
  auto mid = kth.begin() + static_cast<std::ptrdiff_t>(kth.size() / 2);
  std::nth_element(kth.begin(), mid, kth.end());
  const double calibrated = 1.3 * static_cast<double>(*mid);
  return calibrated > diag * 1e-6 ? calibrated : cell;
}

Eigen::Vector3i KnnGrid::coordOf(const Eigen::Vector3f& p) const {
  return cellCoord(p, 1.0 / cell_);
}

std::uint64_t KnnGrid::keyOf(const Eigen::Vector3i& c) {
  return packKey(c);
}

long long KnnGrid::find(std::uint64_t key) const {
  for (std::uint64_t slot = hashKey(key) & mask_;; slot = (slot + 1) & mask_) {
    const std::uint32_t v = table_[slot];
    if (v == 0) return -1;
    if (cells_[v - 1].key == key) return static_cast<long long>(v - 1);
  }
}

void KnnGrid::gatherAround(std::size_t c, int radius, std::vector<std::uint32_t>& out) const {
  const Eigen::Vector3i base = cells_[c].coord;
  for (int dz = -radius; dz <= radius; ++dz) {
    for (int dy = -radius; dy <= radius; ++dy) {
      for (int dx = -radius; dx <= radius; ++dx) {
        const long long idx = find(keyOf(base + Eigen::Vector3i(dx, dy, dz)));
        if (idx < 0) continue;
        const CellRange& r = cells_[static_cast<std::size_t>(idx)];
        out.insert(out.end(), order_.begin() + r.begin, order_.begin() + r.end);
      }
    }
  }
}

float KnnGrid::selectNearest(std::uint32_t query, const std::vector<std::uint32_t>& candidates,
                             int k, float bound2,
                             std::vector<std::pair<float, std::uint32_t>>& out) const {
  const Eigen::Vector3f q = points_[query];
  out.clear();
  for (std::uint32_t j : candidates) {
    const float d2 = (points_[j] - q).squaredNorm();
    if (d2 <= bound2) out.emplace_back(d2, j);
  }
  const std::size_t kk = static_cast<std::size_t>(k);
  if (out.size() < kk) return std::numeric_limits<float>::infinity();
  std::nth_element(out.begin(), out.begin() + (kk - 1), out.end());
  const float kth = out[kk - 1].first;
  out.resize(kk);
  return kth;
}

void KnnGrid::knn(std::uint32_t query, std::size_t c, int k, int max_radius,
                  std::vector<std::pair<float, std::uint32_t>>& out,
                  std::vector<std::uint32_t>& scratch) const {
  for (int r = 1; r <= max_radius; ++r) {
    scratch.clear();
    gatherAround(c, r, scratch);
    // Within r cells every point closer than r * cell is a candidate; at the last radius take
    // whatever there is.
    const double reach = r * cell_;
    const float bound2 = r == max_radius ? std::numeric_limits<float>::infinity()
                                         : static_cast<float>(reach * reach);
    if (selectNearest(query, scratch, k, bound2, out) <= bound2) break;
  }
  std::sort(out.begin(), out.end());
}

}  // namespace planesdf::detail
