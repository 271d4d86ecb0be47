#pragma once
// How a blob's source objects sit in the target map: where their cells land, whether they moved
// a little (design.md, "Small moves") and what stands inside their footprint (design.md,
// "Replaced inside the footprint"); see comparePlanePair.

#include <Eigen/Core>

#include <limits>
#include <map>
#include <vector>

#include "planesdf/comparison.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/types.hpp"

namespace planesdf::detail {

/// Target height at the source cell centre mapped by T (nearest target cell); kUnobserved when
/// outside or unobserved. `cell` receives the target cell.
float targetHeight(const HeightMap& tgt, const Pose& T, const Eigen::Vector2d& uv, double h,
                   Eigen::Vector2i* cell);

/// True when `blob`'s cells eroded by `cells` (square element) keep at least one cell.
bool hasCore(const Blob& blob, int cells);

/// The cells of the objects `labels` of `os` that are not in `cells`, raster order per object.
std::vector<Eigen::Vector2i> objectCellsOutside(const ObjectMap& os, const std::vector<int>& labels,
                                                const std::vector<Eigen::Vector2i>& cells);

/// How the source objects `labels` fit the target heights, in place and at the best shift up
/// to `max_shift` cells (design.md, "Small moves"). "Off" is the 90th percentile of the height
/// mismatch (capped at 5 cm) of the objects' interior cells (all four neighbours on them).
/// Cells the target did not observe at a shift are not compared; a shift comparing fewer than
/// 80 % of the cells is infinitely off. Empty (both infinite) for objects of `large_cells` or
/// more; the shifts are searched only when in place is more than `search_above` off.
struct ObjectFit {
  double in_place = std::numeric_limits<double>::infinity();
  double best = std::numeric_limits<double>::infinity();  ///< least off over the shifts
  int best_d2 = 0;                                        ///< squared shift of `best`, cells
};

ObjectFit fitObject(const HeightMap& hs, const ObjectMap& os, const std::vector<int>& labels,
                    const HeightMap& ht, const Pose& T, int large_cells, int max_shift,
                    double search_above);

/// True when `fit` is a small move: in place more than `h_obj` off (and comparable), best at a
/// shift of at least `min_shift` cells and there at most half as far off as in place.
bool isSmallMove(const ObjectFit& fit, int min_shift, double h_obj);

/// The target objects standing inside the footprint of the source objects `labels` (together
/// smaller than `large_cells`): per target label, its cells the footprint covers, for those
/// covered at least half (design.md, "Replaced inside the footprint"). `covered` receives the
/// footprint's cells landing on them.
std::map<int, int> objectsInFootprint(const HeightMap& hs, const ObjectMap& os,
                                      const std::vector<int>& labels, const HeightMap& ht,
                                      const ObjectMap& ot, const Pose& T, int large_cells,
                                      std::vector<std::size_t>* covered);

}  // namespace planesdf::detail
