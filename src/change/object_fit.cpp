// How a blob's source objects sit in the target map (see object_fit.hpp).

#include "object_fit.hpp"

#include <algorithm>
#include <cmath>
#include <set>
#include <utility>

namespace planesdf::detail {
namespace {

/// The cells of the source objects `labels` (`src`) and the target cells their centres map to
/// under T (`tgt`, unchecked), in the same order.
void mappedObjectCells(const HeightMap& hs, const ObjectMap& os, const std::vector<int>& labels,
                       const HeightMap& ht, const Pose& T, std::vector<Eigen::Vector2i>& src,
                       std::vector<Eigen::Vector2i>& tgt) {
  for (const int label : labels) {
    const ObjectInfo& o = os.object(label);
    for (int y = o.bbox_min.y(); y <= o.bbox_max.y(); ++y)
      for (int x = o.bbox_min.x(); x <= o.bbox_max.x(); ++x) {
        if (os.at(x, y) != label) continue;
        Eigen::Vector2i tc;
        targetHeight(ht, T, hs.cellCenter(x, y), std::max(0.0f, hs.at(x, y)), &tc);
        src.emplace_back(x, y);
        tgt.push_back(tc);
      }
  }
}

}  // namespace

float targetHeight(const HeightMap& tgt, const Pose& T, const Eigen::Vector2d& uv, double h,
                   Eigen::Vector2i* cell) {
  const Eigen::Vector3d p = T * Eigen::Vector3d(uv.x(), uv.y(), h);
  const Eigen::Vector2i c = tgt.cellOf(p.head<2>());
  if (cell != nullptr) *cell = c;
  if (!tgt.inBounds(c.x(), c.y())) return kUnobserved;
  return tgt.at(c.x(), c.y());
}

bool hasCore(const Blob& blob, int cells) {
  GridGeometry g;
  g.width = blob.bbox_max.x() - blob.bbox_min.x() + 1;
  g.height = blob.bbox_max.y() - blob.bbox_min.y() + 1;
  g.cell_size = 1.0;
  if (g.width <= 2 * cells || g.height <= 2 * cells) return false;
  Mask2D m = Mask2D::zeros(g);
  for (const Eigen::Vector2i& c : blob.cells)
    m.set(c.x() - blob.bbox_min.x(), c.y() - blob.bbox_min.y());
  return erode(m, cells).count() > 0;
}

std::vector<Eigen::Vector2i> objectCellsOutside(const ObjectMap& os, const std::vector<int>& labels,
                                                const std::vector<Eigen::Vector2i>& cells) {
  std::set<std::pair<int, int>> taken;
  for (const Eigen::Vector2i& c : cells) taken.emplace(c.x(), c.y());
  std::vector<Eigen::Vector2i> out;
  for (const int label : labels) {
    const ObjectInfo& o = os.object(label);
    for (int y = o.bbox_min.y(); y <= o.bbox_max.y(); ++y)
      for (int x = o.bbox_min.x(); x <= o.bbox_max.x(); ++x)
        if (os.at(x, y) == label && taken.count({x, y}) == 0) out.emplace_back(x, y);
  }
  return out;
}

ObjectFit fitObject(const HeightMap& hs, const ObjectMap& os, const std::vector<int>& labels,
                    const HeightMap& ht, const Pose& T, int large_cells, int max_shift,
                    double search_above) {
  ObjectFit fit;
  std::vector<Eigen::Vector2i> src, tgt;
  mappedObjectCells(hs, os, labels, ht, T, src, tgt);
  if (src.empty() || static_cast<int>(src.size()) >= large_cells) return fit;
  // Interior cells only: speckle and the outer ring of rim attached to an object do not move
  // with it.
  const auto onObjects = [&](int x, int y) {
    return hs.inBounds(x, y) &&
           std::find(labels.begin(), labels.end(), os.at(x, y)) != labels.end();
  };
  std::size_t n = 0;
  for (std::size_t i = 0; i < src.size(); ++i) {
    const int x = src[i].x(), y = src[i].y();
    if (!onObjects(x - 1, y) || !onObjects(x + 1, y) || !onObjects(x, y - 1) ||
        !onObjects(x, y + 1))
      continue;
    src[n] = src[i];
    tgt[n++] = tgt[i];
  }
  src.resize(n);
  tgt.resize(n);
  if (src.empty()) return fit;
  // A move by part of an object's size leaves most of its footprint on itself: the mismatch
  // that a tenth of the cells exceed.
  constexpr float kCap = 0.05f;
  std::vector<float> err;
  const auto misfit = [&](int dx, int dy) {
    err.clear();
    for (std::size_t i = 0; i < src.size(); ++i) {
      const int x = tgt[i].x() + dx, y = tgt[i].y() + dy;
      if (!ht.inBounds(x, y) || ht.at(x, y) == kUnobserved) continue;
      err.push_back(std::min(kCap, std::fabs(std::max(0.0f, hs.at(src[i].x(), src[i].y())) -
                                             std::max(0.0f, ht.at(x, y)))));
    }
    if (10 * err.size() < 8 * src.size()) return std::numeric_limits<double>::infinity();
    const auto q = err.begin() + static_cast<std::ptrdiff_t>(err.size() * 9 / 10);
    std::nth_element(err.begin(), q, err.end());
    return static_cast<double>(*q);
  };
  fit.in_place = fit.best = misfit(0, 0);
  if (!std::isfinite(fit.in_place) || fit.in_place <= search_above) return fit;
  for (int dy = -max_shift; dy <= max_shift; ++dy)
    for (int dx = -max_shift; dx <= max_shift; ++dx) {
      const double m = misfit(dx, dy);
      if (m < fit.best) {
        fit.best = m;
        fit.best_d2 = dx * dx + dy * dy;
      }
    }
  return fit;
}

bool isSmallMove(const ObjectFit& fit, int min_shift, double h_obj) {
  return std::isfinite(fit.in_place) && fit.in_place > h_obj &&
         fit.best_d2 >= min_shift * min_shift && fit.best <= 0.5 * fit.in_place;
}

std::map<int, int> objectsInFootprint(const HeightMap& hs, const ObjectMap& os,
                                      const std::vector<int>& labels, const HeightMap& ht,
                                      const ObjectMap& ot, const Pose& T, int large_cells,
                                      std::vector<std::size_t>* covered) {
  std::vector<Eigen::Vector2i> src, tgt;
  mappedObjectCells(hs, os, labels, ht, T, src, tgt);
  if (src.empty() || static_cast<int>(src.size()) >= large_cells) return {};
  std::map<int, int> landed;
  std::vector<std::size_t> cells;
  for (const Eigen::Vector2i& tc : tgt) {
    if (!ht.inBounds(tc.x(), tc.y())) continue;
    const int t = ot.at(tc.x(), tc.y());
    if (t == 0) continue;
    ++landed[t];
    cells.push_back(ht.index(tc.x(), tc.y()));
  }
  for (auto it = landed.begin(); it != landed.end();)
    it = 2 * it->second >= ot.object(it->first).area ? std::next(it) : landed.erase(it);
  if (covered != nullptr)
    for (const std::size_t c : cells)
      if (landed.count(ot.labels[c]) > 0) covered->push_back(c);
  return landed;
}

}  // namespace planesdf::detail
