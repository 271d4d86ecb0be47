// 2D mask helpers: thresholding, connected components (flood fill), square dilation and
// erosion.

#include <algorithm>
#include <cstdint>
#include <vector>

#include "planesdf/height_map.hpp"

namespace planesdf {
namespace {

/// Labels the component containing the on-cell `seed` with `label` (8- or 4-connected flood
/// fill with an explicit stack); returns its area.
int floodFill(const Mask2D& mask, std::size_t seed, int label, bool eight, std::vector<int>& labels,
              std::vector<std::size_t>& stack) {
  const int w = mask.width, h = mask.height;
  int area = 0;
  stack.clear();
  stack.push_back(seed);
  labels[seed] = label;
  while (!stack.empty()) {
    const std::size_t c = stack.back();
    stack.pop_back();
    ++area;
    const int x = static_cast<int>(c % static_cast<std::size_t>(w));
    const int y = static_cast<int>(c / static_cast<std::size_t>(w));
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        if ((dx == 0 && dy == 0) || (!eight && dx != 0 && dy != 0)) continue;
        const int nx = x + dx, ny = y + dy;
        if (nx < 0 || ny < 0 || nx >= w || ny >= h) continue;
        const std::size_t n = mask.index(nx, ny);
        if (mask.cells[n] == 0 || labels[n] != 0) continue;
        labels[n] = label;
        stack.push_back(n);
      }
  }
  return area;
}

/// One pass of a 1D max (dilation) or min (erosion: `all`) filter of radius r along rows
/// (horizontal) or columns, on 0/1 cells, using a running count of on-cells in the window; cells
/// outside the line count as off.
std::vector<std::uint8_t> filter1d(const std::vector<std::uint8_t>& in, int w, int h, int r,
                                   bool horizontal, bool all) {
  std::vector<std::uint8_t> out(in.size(), 0);
  const int lines = horizontal ? h : w, len = horizontal ? w : h;
  const int need = all ? 2 * r + 1 : 1;
  const auto at = [&](int line, int i) {
    return horizontal ? static_cast<std::size_t>(line) * w + i
                      : static_cast<std::size_t>(i) * w + line;
  };
  for (int line = 0; line < lines; ++line) {
    int count = 0;  // on-cells in [i - r, i + r]
    for (int i = 0; i < std::min(r, len); ++i) count += in[at(line, i)] != 0;
    for (int i = 0; i < len; ++i) {
      if (i + r < len) count += in[at(line, i + r)] != 0;
      if (i - r - 1 >= 0) count -= in[at(line, i - r - 1)] != 0;
      out[at(line, i)] = count >= need ? 1 : 0;
    }
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
  Components cc;
  cc.labels.assign(mask.numCells(), 0);
  std::vector<std::size_t> stack;
  std::vector<int> raw_areas;
  for (std::size_t i = 0; i < mask.cells.size(); ++i) {
    if (mask.cells[i] == 0 || cc.labels[i] != 0) continue;
    const int label = static_cast<int>(raw_areas.size()) + 1;
    raw_areas.push_back(floodFill(mask, i, label, connectivity != 4, cc.labels, stack));
  }
  // Drop small components and renumber the rest 1..N in the same order.
  std::vector<int> remap(raw_areas.size() + 1, 0);
  for (std::size_t l = 0; l < raw_areas.size(); ++l) {
    if (raw_areas[l] < min_area) continue;
    cc.areas.push_back(raw_areas[l]);
    remap[l + 1] = cc.count();
  }
  for (int& l : cc.labels) l = remap[static_cast<std::size_t>(l)];
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
