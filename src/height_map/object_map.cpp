// Object map (DESIGN §2 "object map"): 8-connected components of the cells above h_obj, with
// per-object statistics.

#include <algorithm>
#include <utility>
#include <vector>

#include "planesdf/height_map.hpp"

namespace planesdf {

ObjectMap computeObjectMap(const HeightMap& hm, const Config& cfg) {
  ObjectMap om;
  static_cast<GridGeometry&>(om) = hm.geometry();
  Components cc = connectedComponents(maskAbove(hm, static_cast<float>(cfg.h_obj)), 1, 8);
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
