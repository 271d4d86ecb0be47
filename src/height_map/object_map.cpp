// Object map (design.md, "Pipeline"): 8-connected components of the cells above h_obj, speckle
// components reduced to their opening (Config::object_min_solidity), with per-object statistics.

#include <algorithm>
#include <utility>
#include <vector>

#include "planesdf/height_map.hpp"

namespace planesdf {

ObjectMap computeObjectMap(const HeightMap& hm, const Config& cfg) {
  ObjectMap om;
  static_cast<GridGeometry&>(om) = hm.geometry();
  Mask2D mask = maskAbove(hm, static_cast<float>(cfg.h_obj));
  Components cc;
  bool labelled = false;  // cc holds the components of `mask`
  if (cfg.object_min_solidity > 0.0) {
    // Speckle: components with too few cells whose 3x3 neighbourhood is all object keep only
    // their opening (those cells' 3x3 squares, all inside the component).
    const Mask2D core = erode(mask, 1);
    Components all = connectedComponents(mask, 1, 8);
    std::vector<int> core_cells(all.areas.size() + 1, 0);
    for (std::size_t i = 0; i < mask.cells.size(); ++i)
      if (core.cells[i] != 0) ++core_cells[static_cast<std::size_t>(all.labels[i])];
    std::vector<char> speckle(all.areas.size() + 1, 0);
    bool any = false;
    for (std::size_t l = 1; l < speckle.size(); ++l) {
      speckle[l] = core_cells[l] < cfg.object_min_solidity * all.areas[l - 1];
      any = any || speckle[l] != 0;
    }
    if (any) {
      const Mask2D opened = dilate(core, 1);
      for (std::size_t i = 0; i < mask.cells.size(); ++i)
        if (speckle[static_cast<std::size_t>(all.labels[i])] != 0) mask.cells[i] = opened.cells[i];
    } else {
      cc = std::move(all);  // no speckle: the mask and its components stay
      labelled = true;
    }
  }
  if (!labelled) cc = connectedComponents(mask, 1, 8);
  om.labels = std::move(cc.labels);
  om.objects.resize(cc.areas.size());
  for (std::size_t l = 0; l < om.objects.size(); ++l) {
    ObjectInfo& o = om.objects[l];
    o.label = static_cast<int>(l) + 1;
    o.bbox_min = Eigen::Vector2i(om.width, om.height);
    o.bbox_max = Eigen::Vector2i(-1, -1);
  }
  for (int y = 0; y < om.height; ++y)
    for (int x = 0; x < om.width; ++x) {
      const int label = om.at(x, y);
      if (label == 0) continue;
      ObjectInfo& o = om.objects[static_cast<std::size_t>(label - 1)];
      ++o.area;
      o.bbox_min = o.bbox_min.cwiseMin(Eigen::Vector2i(x, y));
      o.bbox_max = o.bbox_max.cwiseMax(Eigen::Vector2i(x, y));
      o.max_height = std::max(o.max_height, hm.at(x, y));
      o.centroid += om.cellCenter(x, y);
    }
  for (ObjectInfo& o : om.objects) o.centroid /= static_cast<double>(o.area);
  return om;
}

}  // namespace planesdf
