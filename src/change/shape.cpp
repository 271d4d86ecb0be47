// Shape signatures of height-map cells, their distance, and the in-place comparison of a blob
// with the target objects it lands on (see change.hpp, shapeDistance; change_internal.hpp,
// sameInPlace).

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "change_internal.hpp"
#include "object_fit.hpp"
#include "planesdf/comparison.hpp"

namespace planesdf {

namespace {

using detail::targetHeight;

double relDiff(double a, double b, double floor_value) {
  const double m = std::max({std::abs(a), std::abs(b), floor_value});
  return std::abs(a - b) / m;
}

}  // namespace

ShapeSignature signatureOf(const HeightMap& hm, const std::vector<Eigen::Vector2i>& cells) {
  ShapeSignature s;
  s.cells = static_cast<int>(cells.size());
  if (cells.empty()) return s;
  const double a = hm.cell_size * hm.cell_size;
  std::vector<double> heights;
  heights.reserve(cells.size());
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& c : cells) {
    const double h = std::max(0.0, static_cast<double>(hm.at(c.x(), c.y())));
    heights.push_back(h);
    s.volume += a * h;
    mean += hm.cellCenter(c.x(), c.y());
  }
  mean /= static_cast<double>(cells.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& c : cells) {
    const Eigen::Vector2d d = hm.cellCenter(c.x(), c.y()) - mean;
    cov += d * d.transpose();
  }
  cov /= static_cast<double>(cells.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
  s.minor = std::sqrt(std::max(0.0, es.eigenvalues()(0)));
  s.major = std::sqrt(std::max(0.0, es.eigenvalues()(1)));
  s.area = a * static_cast<double>(cells.size());
  std::sort(heights.begin(), heights.end());
  s.max_height = heights.back();
  for (int q = 1; q <= 10; ++q) {
    const auto i = std::min(heights.size() - 1,
                            static_cast<std::size_t>(std::ceil(q / 10.0 * heights.size())) - 1);
    s.deciles.push_back(heights[i]);
  }
  return s;
}

double shapeDistance(const ShapeSignature& a, const ShapeSignature& b) {
  if (a.cells == 0 || b.cells == 0) return std::numeric_limits<double>::infinity();
  const double cell = 0.007;  // floors keep tiny objects from dividing by ~0
  double d = relDiff(a.max_height, b.max_height, 0.02);
  d = std::max(d, relDiff(a.area, b.area, 4 * cell * cell));
  d = std::max(d, relDiff(a.volume, b.volume, 1e-6));
  d = std::max(d, relDiff(a.major, b.major, 2 * cell));
  d = std::max(d, relDiff(a.minor, b.minor, 2 * cell));
  const double hmax = std::max({a.max_height, b.max_height, 0.02});
  for (std::size_t i = 0; i < std::min(a.deciles.size(), b.deciles.size()); ++i)
    d = std::max(d, std::abs(a.deciles[i] - b.deciles[i]) / hmax);
  return d;
}

bool InPlaceMatch::same(const Config& cfg) const {
  return target_cells > 0 && overlap >= cfg.in_place_min_overlap &&
         shift <= cfg.in_place_shift_fraction * size && shape_distance < cfg.moved_shape_distance;
}

namespace {

/// The part of target object `label` that stands where a blob lands on a sliver of it (design.md,
/// "In place on structure"): its cells higher than delta_h above the structure (its median
/// height: most of a large object a blob covers a sliver of is the structure), 8-connected to
/// such cells under the footprint. Empty when the footprint holds none: it landed on structure.
std::vector<std::size_t> partStandingIn(const HeightMap& tgt, const ObjectMap& objects, int label,
                                        const std::vector<char>& mapped, double delta_h) {
  std::vector<float> heights;
  std::vector<std::size_t> seeds;
  for (std::size_t i = 0; i < objects.labels.size(); ++i) {
    if (objects.labels[i] != label) continue;
    heights.push_back(tgt.heights[i]);
    if (mapped[i] != 0) seeds.push_back(i);
  }
  if (heights.empty()) return {};
  const auto mid = heights.begin() + static_cast<std::ptrdiff_t>(heights.size() / 2);
  std::nth_element(heights.begin(), mid, heights.end());
  const float level = *mid + static_cast<float>(delta_h);
  Mask2D above = Mask2D::zeros(tgt);
  for (std::size_t i = 0; i < objects.labels.size(); ++i)
    above.cells[i] = objects.labels[i] == label && tgt.heights[i] > level ? 1 : 0;
  const Components cc = connectedComponents(above, 1, 8);
  std::vector<char> keep(cc.areas.size() + 1, 0);
  for (const std::size_t i : seeds) keep[static_cast<std::size_t>(cc.labels[i])] = 1;
  keep[0] = 0;  // seeds at or below the level
  std::vector<std::size_t> part;
  for (std::size_t i = 0; i < cc.labels.size(); ++i)
    if (keep[static_cast<std::size_t>(cc.labels[i])] != 0) part.push_back(i);
  return part;
}

}  // namespace

InPlaceMatch sameInPlace(const HeightMap& src, const std::vector<Eigen::Vector2i>& cells,
                         const HeightMap& tgt, const ObjectMap& tgt_objects, const Pose& T,
                         const Config& cfg) {
  InPlaceMatch m;
  if (cells.empty() || tgt.empty() || !tgt_objects.sameGeometry(tgt)) return m;
  // The blob's footprint in the target grid (distinct cells) and the objects it lands on, with
  // how many of their cells it lands on.
  std::vector<char> mapped(tgt.numCells(), 0);
  std::map<int, int> landed;
  for (const Eigen::Vector2i& c : cells) {
    const float h = src.at(c.x(), c.y());
    Eigen::Vector2i tc;
    targetHeight(tgt, T, src.cellCenter(c.x(), c.y()), std::max(0.0f, h), &tc);
    if (!tgt.inBounds(tc.x(), tc.y())) continue;
    const std::size_t i = tgt.index(tc.x(), tc.y());
    if (mapped[i] != 0) continue;
    mapped[i] = 1;
    const int label = tgt_objects.labels[i];
    if (label > 0) ++landed[label];
  }
  if (landed.empty()) return m;
  // Whole objects, but of a large one it lands on a sliver of, only the part standing there.
  std::vector<char> target(tgt.numCells(), 0);
  std::vector<char> is_label(static_cast<std::size_t>(tgt_objects.numObjects()) + 1, 0);
  const int large_cells = largeObjectCells(cfg, tgt.cell_size);
  for (const auto& [label, n] : landed) {
    if (!sliverOf(n, tgt_objects.object(label).area, cfg.blob_min_overlap, large_cells)) {
      is_label[static_cast<std::size_t>(label)] = 1;
      continue;
    }
    const std::vector<std::size_t> part =
        partStandingIn(tgt, tgt_objects, label, mapped, cfg.delta_h);
    if (part.empty()) is_label[static_cast<std::size_t>(label)] = 1;
    for (const std::size_t i : part) target[i] = 1;
  }
  std::vector<Eigen::Vector2i> obj_cells;
  Eigen::Vector2d c_obj = Eigen::Vector2d::Zero(), c_blob = Eigen::Vector2d::Zero();
  Eigen::AlignedBox2d box_obj, box_blob;
  int n_mapped = 0, common = 0;
  for (int y = 0; y < tgt.height; ++y)
    for (int x = 0; x < tgt.width; ++x) {
      const Eigen::Vector2d uv = tgt.cellCenter(x, y);
      const int label = tgt_objects.at(x, y);
      const bool in_obj = (label > 0 && is_label[static_cast<std::size_t>(label)] != 0) ||
                          target[tgt.index(x, y)] != 0;
      const bool in_blob = mapped[tgt.index(x, y)] != 0;
      if (in_obj) {
        obj_cells.emplace_back(x, y);
        c_obj += uv;
        box_obj.extend(uv);
      }
      if (in_blob) {
        ++n_mapped;
        c_blob += uv;
        box_blob.extend(uv);
      }
      if (in_obj && in_blob) ++common;
    }
  m.target_cells = static_cast<int>(obj_cells.size());
  const int n_union = n_mapped + m.target_cells - common;
  m.overlap = n_union > 0 ? static_cast<double>(common) / n_union : 0.0;
  m.shift = (c_blob / n_mapped - c_obj / m.target_cells).norm();
  // Box diagonals over cell centres, plus one cell (the cells' own extent).
  const Eigen::Vector2d one = Eigen::Vector2d::Constant(tgt.cell_size);
  m.size = std::min((box_blob.sizes() + one).norm(), (box_obj.sizes() + one).norm());
  m.shape_distance = shapeDistance(signatureOf(src, cells), signatureOf(tgt, obj_cells));
  return m;
}

}  // namespace planesdf
