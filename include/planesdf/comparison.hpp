#pragma once
/// \file comparison.hpp
/// Height-map comparison (paper §III-C, eq. 2), mask cleaning and changed blobs (design.md,
/// "Pipeline" and "Change").
///
/// Every mask here is on the SOURCE grid. A source cell is
///   * unknown when it is unobserved, or when any of the 2x2 target cells eq. 2 needs is
///     unobserved or outside the target grid (conservative: unknown is never changed);
///   * changed when all four target cells differ from its height by more than cfg.delta_h;
///   * unchanged otherwise.
/// Heights are floats, so "more than delta_h" means > delta_h + kHeightCompareTolerance: a
/// difference of exactly delta_h (as floats) is unchanged.

#include <Eigen/Core>

#include <limits>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/tsdf.hpp"
#include "planesdf/types.hpp"

namespace planesdf {

/// Slack (m) added to delta_h to absorb float rounding of the heights.
constexpr double kHeightCompareTolerance = 1e-6;

/// How far the two maps' surfaces can be trusted, for the height test: their roughness
/// (Config::roughness_factor; a null map counts as roughness 0, the plain delta_h test) and the
/// lateral slack, in cells, of surfaces placed only to within a cell or more (splatted clouds,
/// surfaceRimCells).
struct HeightTolerance {
  const RoughnessMap* source = nullptr;
  const RoughnessMap* target = nullptr;
  int slack_cells = 0;
  /// How far above its surfaces the target map observed free space (m): a splat writes free
  /// voxels only within the truncation in front of its point; depth fusion carves whole rays.
  /// A source cell whose top was never seen from above (HeightMap::unseen_above), below
  /// `band_top`, and more than this above the target is unknown: only the 2.5D premise, not an
  /// observation, would make the target free there.
  double free_reach = std::numeric_limits<double>::infinity();
  double band_top = std::numeric_limits<double>::infinity();  ///< the fused band (m)
  /// detectHeightChange: the sliver rule of changedBlobs holds for objects of any size, not
  /// only those over Config::blob_large_area. Set for splatted maps: a whole-cloud
  /// reconstruction places a static object's rim differently from other viewpoints, while a
  /// change covers most of an object's footprint.
  bool any_size_slivers = false;
};

/// Paper eq. 2. Each source cell centre (u, v, H(x, y)) is mapped by `T_target_source_local`
/// into the target plane frame; with (x', y') its continuous target cell coordinates (cell
/// centres at integer + 0.5), the four target cells around it are (x0 + i, y0 + j), i, j in
/// {0, 1}, x0 = floor(x' - 0.5), y0 = floor(y' - 0.5) (a point exactly on the centre of a last
/// column / row cell takes the in-grid pair: the tie is resolved inward). Output on the source grid
/// (1 = changed). A source cell is changed when its height lies more than
/// t = max(delta_h, roughness_factor * r) above or below the range of the four target heights
/// and of the observed target cells within tol.slack_cells of them (r the largest roughness of
/// the source cell and those target cells: `tol`). A height within the range lies on an edge
/// between them, or on a surface placed to within the slack. `unknown`, when
/// given, receives the unknown cells (same geometry). Throws planesdf::Error("config", ...) when
/// delta_h is not positive and finite, and planesdf::Error("height map", ...) when a map's cell
/// array does not match its size.
Mask2D compareHeightMaps(const HeightMap& src, const HeightMap& tgt,
                         const Pose& T_target_source_local, const Config& cfg,
                         Mask2D* unknown = nullptr, const HeightTolerance& tol = {});

/// The paper's cleaning: removeSmallComponents(mask, cfg.min_change_cells) (8-connected), then
/// dilate(…, cfg.dilation_cells). Throws planesdf::Error("config", ...) on negative values.
Mask2D cleanChangeMask(const Mask2D& mask, const Config& cfg);

/// A changed region grown to whole objects.
struct Blob {
  std::vector<Eigen::Vector2i> cells;  ///< its cells (source grid), raster order (y, then x)
  std::vector<int> object_labels;      ///< object-map labels it covers, ascending
  int area = 0;                        ///< cells
  Eigen::Vector2i bbox_min = Eigen::Vector2i::Zero();  ///< cell (x, y), inclusive
  Eigen::Vector2i bbox_max = Eigen::Vector2i::Zero();  ///< cell (x, y), inclusive
  /// True when it holds no whole object, only changed cells of objects it touches a sliver of
  /// (see changedBlobs), such as the edge of a shelf seen from another viewpoint.
  bool partial = false;
};

/// True when a change covering `changed_cells` of an object-map component of `object_cells`
/// touches only a sliver of it: the component has at least `large_cells` cells (larger than one
/// movable object: furniture, a noisy stretch of wall) and the change covers less than
/// `min_overlap` of them.
bool sliverOf(int changed_cells, int object_cells, double min_overlap, int large_cells);

/// Config::blob_large_area in cells of a grid of `cell_size` (m), rounded up.
int largeObjectCells(const Config& cfg, double cell_size);

/// The connected components (8-connected) of (cleaned ∩ object cells of `src_objects`), grown
/// to the object-map component they lie on (one each: distinct objects are never 8-adjacent);
/// the components on one object make one blob. An object that every component on it touches
/// only a sliver of (sliverOf with `min_overlap` and `large_cells`) is not grown into: each such
/// component is a blob of its own cells (Blob::partial), except that the slivers of an object
/// smaller than `join_below` cells make one blob (the rims of a small object's sides). The paper
/// selects the objects the change clusters overlap highly, and a box swapped on a shelf changes a
/// sliver of the shelf, which is one object of the wall's plane. min_overlap = 0 always grows
/// (the brief's blobs). Changed cells off any object are not blobs (in the source→target direction
/// they are places where something appeared: the reverse run reports them). Blobs of whole objects
/// come first, by object label, then the slivers, by component (raster order of their first cell).
/// Throws planesdf::Error("change", ...) when the two grids differ.
std::vector<Blob> changedBlobs(const Mask2D& cleaned, const ObjectMap& src_objects,
                               double min_overlap = 0.0, int large_cells = 0, int join_below = 0);

/// Every stage of the 2D change detection of one registered plane pair, so callers can save a
/// picture per stage.
struct HeightChange {
  Mask2D raw;               ///< compareHeightMaps, plus `vacated` when a target volume is given
  Mask2D unknown;           ///< cells eq. 2 could not compare
  Mask2D vacated;           ///< freeSpaceEvidence (empty without a target volume)
  Mask2D filtered;          ///< raw without components smaller than cfg.min_change_cells
  Mask2D cleaned;           ///< filtered, dilated by cfg.dilation_cells (= cleanChangeMask(raw))
  Mask2D blob_mask;         ///< union of the blobs' cells
  std::vector<Blob> blobs;  ///< changedBlobs(cleaned, src_objects)
};

/// compareHeightMaps, cleanChangeMask and changedBlobs in a row. With `target_volume`, the
/// cells of freeSpaceEvidence join the raw mask before cleaning.
HeightChange detectHeightChange(const HeightMap& src, const HeightMap& tgt,
                                const ObjectMap& src_objects, const Pose& T_target_source_local,
                                const Config& cfg, const TsdfVolume* target_volume = nullptr,
                                const HeightTolerance& tol = {});

/// Free-space evidence, beyond eq. 2 (which needs the target's height map, and a single view
/// leaves the places behind objects unobserved there): an `unknown` source cell higher than
/// h_obj is changed ("vacated") when the target TSDF saw free space where the source object was.
/// The three points 1, 2 and 3 voxels below the source surface of the cell (inside the source
/// object) are mapped by T into the target volume; the cell is vacated when at least two of
/// them fall in observed target voxels (weight >= w_min) with sdf >= min(δh, truncation) / 2 and
/// none in an observed voxel with sdf <= 0. Unobserved target voxels give no evidence.
Mask2D freeSpaceEvidence(const HeightMap& src, const Mask2D& unknown,
                         const TsdfVolume& target_volume, const Pose& T_target_source_local,
                         const Config& cfg);

}  // namespace planesdf
