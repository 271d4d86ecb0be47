#pragma once
// The change stage's building blocks, shared by detectChanges and ChangeDetector and tested one by
// one: the plane maps of a session, one plane pair's comparison, the session drift, the events'
// assembly (design.md, "Pipeline"). Not installed: the public surface is change.hpp.

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

#include "planesdf/change.hpp"

namespace planesdf {

/// A map's points (Map::points()) that stand in a plane's band, bucketed by the cells of its
/// height map: those with height from h_obj / 2 to the highest cell + one voxel (1 mm of slack),
/// cell by cell, each cell's in input order. The change outputs' point loops read only the
/// cells they need instead of every point of the map.
struct CellPoints {
  std::vector<std::uint32_t> start;  ///< numCells() + 1 offsets into `index`; empty: not built
  std::vector<std::uint32_t> index;  ///< indices into the points
  std::size_t num_points = 0;        ///< size of the point array it was built from
  /// True when built from a point array of `n` points.
  bool builtFor(std::size_t n) const { return !start.empty() && num_points == n; }
};
/// The points of `points` (world) in `plane`'s band, bucketed by the cells of `heights`.
CellPoints bucketBandPoints(const Plane& plane, const HeightMap& heights,
                            const std::vector<Eigen::Vector3f>& points, const Config& cfg);

namespace detail {
/// Points per chunk of detail::PointChunks.
constexpr std::size_t kPointChunk = 4096;
/// The world boxes of a map's points in chunks of kPointChunk consecutive points, computed once
/// on first use: a change's points are gathered from the chunks its region's box meets.
struct PointChunks {
  const std::vector<Eigen::Vector3f>* source = nullptr;  ///< the map's points()
  std::once_flag once;
  std::vector<Eigen::AlignedBox3f> boxes;
  std::size_t num_points = 0;  ///< the points' count when built (points added since: not used)
};
/// The band points of one PlaneMaps, bucketed once on first use (see bandPoints), and the chunk
/// boxes of the map's points (shared by the PlaneMaps of one map in detectChanges).
struct LazyCellPoints {
  const std::vector<Eigen::Vector3f>* source = nullptr;  ///< the map's points()
  std::once_flag once;
  CellPoints cells;
  std::shared_ptr<PointChunks> chunks;
};
}  // namespace detail

/// The 2D maps of one plane (computed once per plane and volume revision).
struct PlaneMaps {
  HeightMap heights;
  ObjectMap objects;
  RoughnessMap roughness;      ///< computeRoughness(heights)
  int rim_cells = 0;           ///< lateral slack of the surfaces, cells (surfaceRimCells)
  std::uint64_t revision = 0;  ///< TsdfVolume::revision() they were computed at
  /// With computePlaneMaps given the map's points: the chunk boxes of those points (built on
  /// first use; comparePlanePair gathers a change's points from the chunks its region meets,
  /// else it scans them all) and their band points by cell (bucketed on first use by
  /// bandPoints()); shared by copies. Null without points.
  std::shared_ptr<detail::LazyCellPoints> points;
};
/// The height and object maps of `plane`, where cells whose surface lies on another,
/// non-parallel plane of the same map (`map_planes`: a wall rising through a table's band, a
/// table crossing a wall's band) are unknown: they are structure, which that plane's own PlaneSDF
/// compares. With `points` (the map's points(), which must outlive the maps), the maps carry
/// the points' chunk boxes and bandPoints() buckets them, each on first use, once.
PlaneMaps computePlaneMaps(const PlaneSdf& plane, const std::vector<PlaneSdf>& map_planes,
                           const Config& cfg, const std::vector<Eigen::Vector3f>* points = nullptr,
                           int rim_cells = 0);

/// How many cells to each side a surface of `map` may sit from where the height map shows it:
/// ceil(splat_radius_voxels) of the map's config for splatted maps (a splat writes its SDF over
/// that lateral radius, and a reconstruction cloud samples its surface about once per voxel),
/// 0 for maps fused from depth (zero crossings interpolated between rays).
int surfaceRimCells(const Map& map);

/// The band points of `maps` (of `plane`) by cell when computePlaneMaps was given `points`:
/// bucketBandPoints on the first call (thread-safe; later calls and copies of `maps` share the
/// result); nullptr when `maps` holds no points or other ones.
const CellPoints* bandPoints(const PlaneMaps& maps, const Plane& plane,
                             const std::vector<Eigen::Vector3f>& points, const Config& cfg);

/// A blob of one plane pair that the 3D validation did not reject, as one side of an event.
struct CandidateChange {
  ChangeRegion region;                          ///< in the source map
  int target_plane_id = -1;                     ///< plane of the other map it was compared with
  std::vector<Eigen::Vector2i> target_columns;  ///< its cells carried into the target grid
  /// Fraction of its (mapped) cells that land on an object of the target's object map, of
  /// which it is not a sliver (sliverOf: a large object it covers little of is structure).
  double target_object_overlap = 0.0;
  /// The target objects it overlaps, as a region of the target map (whole object columns above
  /// h_obj / 2); empty when it overlaps none.
  ChangeRegion target_object;
  /// sameInPlace(...).same(): the target has an object of its shape in its place.
  bool same_in_place = false;
  /// Its object moved by a few cm (design.md, "Small moves"): the region is the whole object and
  /// target_object the objects standing on its footprint now.
  bool small_move = false;
  /// A sliver with some 3D evidence: part of an event another candidate on its columns makes,
  /// never an event of its own (design.md, "Supporting slivers").
  bool supporting = false;
  /// Its columns' points under the height of the target objects it lands on: part of the change
  /// only when those objects changed too (design.md, "Changed objects whole").
  std::vector<Eigen::Vector3f> covered_points;
};

/// Compares source plane `src` with target plane `tgt` of a registered pair and returns the
/// blobs the 3D validation does not reject. The in-plane offset of match.T_target_source_local is
/// refined first when `refine_inplane`. Region points come from `source_points` and
/// `target_points` (world, the maps' points()). `result`, when given, receives the stages (the
/// maps only with options.keep_stages).
std::vector<CandidateChange> comparePlanePair(const PlaneSdf& src, const PlaneMaps& src_maps,
                                              const PlaneSdf& tgt, const PlaneMaps& tgt_maps,
                                              const PlaneMatch& match, bool refine_inplane,
                                              const std::vector<Eigen::Vector3f>& source_points,
                                              const std::vector<Eigen::Vector3f>& target_points,
                                              const Config& cfg, const DetectOptions& options,
                                              PlanePairResult* result);

/// In-plane transforms the reference→current comparisons settled on: (reference plane id,
/// current plane id) -> T_current_reference (plane-local).
using RefinedTransforms = std::map<std::pair<int, int>, Pose>;

/// comparePlanePair for one match of registerPlanes(reference, current) (`reference_to_current`)
/// or of registerPlanes(current, reference), with the source and target taken from the right map.
/// Forward pairs are refined in-plane (when cfg.refine_inplane) and record the transform in
/// `refined`; a reverse pair whose forward pair is there reuses its inverse instead of refining
/// again, so both directions use one alignment. `result`, when given, receives the stages and the
/// direction.
std::vector<CandidateChange> compareMatchedPair(
    const Map& reference, const Map& current, bool reference_to_current, PlaneMatch match,
    const PlaneMaps& source_maps, const PlaneMaps& target_maps, RefinedTransforms& refined,
    const Config& cfg, const DetectOptions& options, PlanePairResult* result);

/// The localisation error between the sessions as one world motion (rotation about the vertical,
/// horizontal shift); see sessionCorrection.
struct SessionCorrection {
  /// rigid: the motion taking reference-world points to current-world points. Otherwise the
  /// motion applied on the current side after each pair's plane alignment.
  Pose motion = Pose::Identity();
  /// True when walls fixed the rotation (design.md, "Session drift"): every pair's in-plane
  /// transform then comes from `motion` alone.
  bool rigid = false;
  bool operator==(const SessionCorrection& o) const {
    return rigid == o.rigid && motion.matrix() == o.motion.matrix();
  }
};

/// The localisation error between the sessions. The in-plane refinement of the horizontal forward
/// pair (reference to current) that removes the most height mismatches gives a motion in the
/// world. When matched vertical planes of at least kDriftMinWallArea agree on a rotation about
/// the vertical, that rotation (their weighted median) is the drift's, the walls' offsets give its
/// shift across them and the horizontal refinement the rest (a 1 degree error moves a wall 3 m
/// away by 5 cm, more than a table's refinement can tell); the result is rigid. Identity when
/// neither applies. `maps(is_reference, plane_id)` gives a plane's maps. Every forward pair then
/// starts from corrected(match, reference, current, correction) before its own refinement: the
/// floor or a side plane, with little in-plane structure of their own, get the drift's
/// alignment.
SessionCorrection sessionCorrection(const Map& reference, const Map& current,
                                    const std::vector<PlaneMatch>& forward_matches,
                                    const std::function<const PlaneMaps&(bool, int)>& maps,
                                    const Config& cfg);
/// Matched vertical planes smaller than this (m², the smaller extent) do not vote on the drift.
inline constexpr double kDriftMinWallArea = 0.5;

/// `match` (reference plane -> current plane) with the correction applied: a rigid correction's
/// motion carried into the two plane frames (its in-plane part), otherwise the motion applied on
/// the current side after the plane alignment.
PlaneMatch corrected(PlaneMatch match, const Map& reference, const Map& current,
                     const SessionCorrection& correction);

/// True when the two lists share a column.
bool columnsOverlap(const std::vector<Eigen::Vector2i>& a, const std::vector<Eigen::Vector2i>& b);

/// Turns removed and added candidates into events. One object in the bands of two planes first:
/// of candidates of one direction on different planes sharing half or more of the smaller one's
/// points (1 cm cells), the one with the stronger 3D evidence stays with the other's points.
/// Static next: Unknown candidates with same_in_place and no Changed candidate of the other
/// direction on their footprint, and removed + added Unknown pairs of one shape in one place, are
/// no event. Then moved pairs (shapeDistance below cfg.moved_shape_distance, greedy by distance),
/// then
/// replaced (a removed candidate with the added candidates its mapped footprint overlaps; or, with
/// none, the current objects it lands on when they cover at least cfg.replaced_min_overlap of it,
/// with
/// the added candidates on those objects), then the rest. Ids 1..N in order of (type, primary
/// plane id, centroid); confidences from cfg.delta_blob (see ChangeEvent::confidence).
std::vector<ChangeEvent> assembleEvents(std::vector<CandidateChange> removed,
                                        std::vector<CandidateChange> added, const Config& cfg);

/// One source per target: of the matches sharing a target, the one with the smallest |gap|
/// keeps it (a second source plane on the same target is another surface — a box top 7 cm above
/// a table, within δd of it — whose content lies in the band of the plane that kept the target;
/// comparing it would shift every height by the gap). Result ordered by source id.
std::vector<PlaneMatch> uniqueMatches(std::vector<PlaneMatch> matches);

/// Signature of a set of cells of a height map (heights > 0 count toward the volume).
ShapeSignature signatureOf(const HeightMap& hm, const std::vector<Eigen::Vector2i>& cells);

/// The blob `cells` of source height map `src`, carried into the target grid by T (plane-local
/// source -> target), against the objects of `tgt_objects` (on `tgt`) those cells land on: their
/// footprint overlap, centroid shift and shape distance (signatures over each map's own cells).
///
/// Used on candidates the 3D validation could not score (Unknown): one with same() is the object
/// the other map also has in that place, seen from other viewpoints (its outline differs by mixed
/// pixels and grazing rays at its silhouette, e.g. a table leg whose top is above the band and
/// whose sides carry no key voxel), so nothing shows a change and assembleEvents drops it, unless
/// the other direction has a candidate with 3D evidence (Changed) on its footprint. A candidate
/// with 3D evidence keeps its verdict; a different object in the same place (replaced, swapped)
/// differs in shape, a moved one in position. Of a large target object it lands on a sliver of
/// (structure: a shelf's back panel in a wall's band), only the part standing on its footprint
/// above that structure counts (cfg.delta_h, blob_large_area, blob_min_overlap; design.md, "In
/// place on structure").
InPlaceMatch sameInPlace(const HeightMap& src, const std::vector<Eigen::Vector2i>& cells,
                         const HeightMap& tgt, const ObjectMap& tgt_objects, const Pose& T,
                         const Config& cfg);

}  // namespace planesdf
