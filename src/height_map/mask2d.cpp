// 2D mask helpers: thresholding, connected components (runs and union-find), square dilation
// and erosion.

#include <algorithm>
#include <cstdint>
#include <vector>

#include "planesdf/height_map.hpp"

namespace planesdf {
namespace {

/// A run of on-cells [x0, x1] of row y, with its provisional label.
struct Run {
  int y, x0, x1, label;
};

/// Root of provisional label l (path halving). Each set's root is its smallest label.
int findRoot(std::vector<int>& parent, int l) {
  while (parent[static_cast<std::size_t>(l)] != l) {
    const auto i = static_cast<std::size_t>(l);
    parent[i] = parent[static_cast<std::size_t>(parent[i])];
    l = parent[i];
  }
  return l;
}

/// One pass of a 1D max (dilation) or min (erosion: `all`) filter of radius r along rows
/// (horizontal) or columns, on 0/1 cells, using a running count of on-cells in the window; cells
/// outside the line count as off. Columns are filtered row by row (a count per column), so both
/// passes read memory in order.
std::vector<std::uint8_t> filter1d(const std::vector<std::uint8_t>& in, int w, int h, int r,
                                   bool horizontal, bool all) {
  std::vector<std::uint8_t> out(in.size(), 0);
  const int need = all ? 2 * r + 1 : 1;
  if (horizontal) {
    for (int y = 0; y < h; ++y) {
      const std::uint8_t* row = in.data() + static_cast<std::size_t>(y) * w;
      std::uint8_t* dst = out.data() + static_cast<std::size_t>(y) * w;
      int count = 0;  // on-cells in [x - r, x + r]
      for (int x = 0; x < std::min(r, w); ++x) count += row[x] != 0;
      for (int x = 0; x < w; ++x) {
        if (x + r < w) count += row[x + r] != 0;
        if (x - r - 1 >= 0) count -= row[x - r - 1] != 0;
        dst[x] = count >= need ? 1 : 0;
      }
    }
    return out;
  }
  std::vector<int> count(static_cast<std::size_t>(w), 0);  // per column: on-cells in [y-r, y+r]
  const auto add = [&](int y, int sign) {
    const std::uint8_t* row = in.data() + static_cast<std::size_t>(y) * w;
    for (int x = 0; x < w; ++x) count[static_cast<std::size_t>(x)] += sign * (row[x] != 0);
  };
  for (int y = 0; y < std::min(r, h); ++y) add(y, 1);
  for (int y = 0; y < h; ++y) {
    if (y + r < h) add(y + r, 1);
    if (y - r - 1 >= 0) add(y - r - 1, -1);
    std::uint8_t* dst = out.data() + static_cast<std::size_t>(y) * w;
    for (int x = 0; x < w; ++x) dst[x] = count[static_cast<std::size_t>(x)] >= need ? 1 : 0;
  }
  return out;
}

}  // namespace

Mask2D Mask2D::zeros(const GridGeometry& g) {
  Mask2D m;
  static_cast<GridGeometry&>(m) = g;
  m.cells.assign(m.numCells(), 0);
  return m;
}

std::size_t Mask2D::count() const {
  return static_cast<std::size_t>(
      std::count_if(cells.begin(), cells.end(), [](std::uint8_t c) { return c != 0; }));
}

Mask2D maskAbove(const HeightMap& hm, float threshold) {
  Mask2D m = Mask2D::zeros(hm.geometry());
  for (std::size_t i = 0; i < m.cells.size(); ++i) m.cells[i] = hm.heights[i] > threshold ? 1 : 0;
  return m;
}

Components connectedComponents(const Mask2D& mask, int min_area, int connectivity) {
  // Two passes over runs of on-cells: each run joins the runs of the row above it touches
  // (8-connected: diagonally too) in a union-find whose roots are the smallest provisional
  // labels. Labels are created in raster order, so a component's root is the label of its
  // first run, and numbering the roots in order numbers the components in raster order of
  // their first cell.
  Components cc;
  cc.labels.assign(mask.numCells(), 0);
  const int w = mask.width, h = mask.height;
  const int reach = connectivity != 4 ? 1 : 0;
  std::vector<Run> runs;
  std::vector<int> parent;
  std::size_t above_begin = 0, above_end = 0;
  for (int y = 0; y < h; ++y) {
    const std::uint8_t* row = mask.cells.data() + static_cast<std::size_t>(y) * w;
    const std::size_t row_begin = runs.size();
    std::size_t a = above_begin;  // first run above that may touch the next run
    for (int x = 0; x < w;) {
      if (row[x] == 0) {
        ++x;
        continue;
      }
      const int x0 = x;
      while (x < w && row[x] != 0) ++x;
      const int x1 = x - 1;
      while (a < above_end && runs[a].x1 < x0 - reach) ++a;
      int label = -1;
      for (std::size_t q = a; q < above_end && runs[q].x0 <= x1 + reach; ++q) {
        const int r = findRoot(parent, runs[q].label);
        if (label < 0) {
          label = r;
        } else if (r != label) {
          parent[static_cast<std::size_t>(std::max(r, label))] = std::min(r, label);
          label = std::min(r, label);
        }
      }
      if (label < 0) {
        label = static_cast<int>(parent.size());
        parent.push_back(label);
      }
      runs.push_back({y, x0, x1, label});
    }
    above_begin = row_begin;
    above_end = runs.size();
  }
  // Components by root in label order, their areas; then drop small ones and renumber the rest
  // 1..N in the same order.
  std::vector<int> component(parent.size(), -1);
  std::vector<int> raw_areas;
  for (std::size_t l = 0; l < parent.size(); ++l) {
    const int r = findRoot(parent, static_cast<int>(l));
    if (static_cast<std::size_t>(r) == l) {
      component[l] = static_cast<int>(raw_areas.size());
      raw_areas.push_back(0);
    } else {
      component[l] = component[static_cast<std::size_t>(r)];
    }
  }
  for (Run& run : runs) {
    run.label = component[static_cast<std::size_t>(run.label)];
    raw_areas[static_cast<std::size_t>(run.label)] += run.x1 - run.x0 + 1;
  }
  std::vector<int> remap(raw_areas.size(), 0);
  for (std::size_t k = 0; k < raw_areas.size(); ++k) {
    if (raw_areas[k] < min_area) continue;
    cc.areas.push_back(raw_areas[k]);
    remap[k] = cc.count();
  }
  for (const Run& run : runs) {
    const int label = remap[static_cast<std::size_t>(run.label)];
    if (label == 0) continue;
    std::fill_n(cc.labels.begin() +
                    static_cast<std::ptrdiff_t>(static_cast<std::size_t>(run.y) * w + run.x0),
                run.x1 - run.x0 + 1, label);
  }
  return cc;
}

Mask2D removeSmallComponents(const Mask2D& mask, int min_area) {
  const Components cc = connectedComponents(mask, min_area);
  Mask2D out = Mask2D::zeros(mask.geometry());
  for (std::size_t i = 0; i < out.cells.size(); ++i) out.cells[i] = cc.labels[i] != 0 ? 1 : 0;
  return out;
}

Mask2D dilate(const Mask2D& mask, int cells) {
  if (cells <= 0 || mask.empty()) return mask;
  Mask2D out = Mask2D::zeros(mask.geometry());
  out.cells = filter1d(filter1d(mask.cells, mask.width, mask.height, cells, true, false),
                       mask.width, mask.height, cells, false, false);
  return out;
}

Mask2D erode(const Mask2D& mask, int cells) {
  if (cells <= 0 || mask.empty()) return mask;
  Mask2D out = Mask2D::zeros(mask.geometry());
  out.cells = filter1d(filter1d(mask.cells, mask.width, mask.height, cells, true, true), mask.width,
                       mask.height, cells, false, true);
  return out;
}

}  // namespace planesdf
