#pragma once
/// \file change.hpp
/// Change detection between two session maps (paper §III-B to §III-D, DESIGN §2 and §3):
/// registration of the PlaneSDFs, eq. 2 height comparison in both directions, 3D validation of
/// every candidate blob, and typed change events.
///
/// Directions. reference→current finds objects of the reference that are gone (removed);
/// current→reference finds objects of the current scene that are new (added). Beyond the paper:
///  * moved: a removed and an added blob whose shape signatures match (see shapeDistance) are one
///    event;
///  * replaced: a removed blob whose footprint overlaps an object of the current map's object map
///    (something else stands there now) is one event with the added blobs overlapping it (or, when
///    the height test flagged none, the current object it overlaps).
///
/// Points and voxels of a blob. Per blob cell (x, y), the voxels of the column whose height
/// actually differs: from just above the other map's surface at that place (its height + δh/2,
/// or the plane when that height is 0 or unknown) to the top of the band; so an unchanged object
/// under a moved one stays unchanged. The input points of the session (Map::points()) that fall in
/// those columns and height ranges are the event's points.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "planesdf/comparison.hpp"
#include "planesdf/config.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/map.hpp"
#include "planesdf/registration.hpp"
#include "planesdf/types.hpp"
#include "planesdf/validation.hpp"

namespace planesdf {

enum class ChangeType { Added, Removed, Moved, Replaced };
/// "added", "removed", "moved", "replaced".
const char* toString(ChangeType t);

/// Life cycle of an event in the incremental ChangeDetector (detectChanges only makes New ones).
enum class ChangeStatus {
  New,       ///< first report of this change
  Updated,   ///< a later frame changed its type, extent or confidence
  Retracted  ///< a later frame showed there is no change after all
};
/// "new", "updated", "retracted".
const char* toString(ChangeStatus s);

/// Rotation-invariant 2.5D shape signature of a blob (used to pair removed and added blobs).
struct ShapeSignature {
  int cells = 0;                ///< footprint area (cells)
  double area = 0.0;            ///< m²
  double max_height = 0.0;      ///< m
  double volume = 0.0;          ///< m³, Σ cell area × height
  double major = 0.0;           ///< m, sqrt of the larger eigenvalue of the footprint covariance
  double minor = 0.0;           ///< m, sqrt of the smaller one
  std::vector<double> deciles;  ///< heights (m) at the 10 %, 20 %, ..., 100 % quantiles
};

/// A dimensionless distance between two signatures: the largest of the relative differences of
/// max height, area, volume, major and minor axis, and of the height deciles (relative to the
/// larger max height). Two views of one rigid object score < ~0.25; different objects more.
double shapeDistance(const ShapeSignature& a, const ShapeSignature& b);

/// One side of a change: the object as one session saw it.
struct ChangeRegion {
  int plane_id = -1;                     ///< plane of that session's map; -1 = no such side
  std::vector<Eigen::Vector2i> columns;  ///< global voxel columns (i, j) of its cells
  std::vector<Eigen::Vector3i> voxels;   ///< observed voxels in the differing height range
  std::vector<Eigen::Vector3f> points;   ///< that session's input points in them (world)
  Eigen::AlignedBox3d bbox;              ///< world box of the voxels' centres (empty if none)
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();  ///< world, mean voxel centre
  ShapeSignature shape;
  int key_voxels = 0;            ///< 3D validation: key voxels found
  int scored = 0;                ///< key voxels with an observed counterpart
  double mean_similarity = 0.0;  ///< of the scored key voxels (0 when none)
  BlobValidation::Verdict verdict = BlobValidation::Verdict::Unknown;
  bool empty() const { return plane_id < 0; }
};

/// One detected change.
struct ChangeEvent {
  int id = 0;  ///< 1-based, stable within a ChangeSet / a ChangeDetector
  ChangeType type = ChangeType::Added;
  ChangeStatus status = ChangeStatus::New;
  ChangeRegion reference;  ///< the object in the reference (empty for Added)
  ChangeRegion current;    ///< the object in the current map (empty for Removed)
  /// In [0.5, 1]: 0.5 + 0.5 (δ_blob - s) / δ_blob for a side the 3D validation found changed with
  /// mean similarity s (the largest over the sides); 0.5 when no key voxel could be scored and
  /// the height test alone decided.
  double confidence = 0.0;
  std::uint64_t frame = 0;  ///< ChangeDetector: current map's frames() when emitted

  /// The side that says where the object is now: current for added / moved / replaced,
  /// reference for removed.
  const ChangeRegion& primary() const;
  int planeId() const { return primary().plane_id; }
  std::size_t numVoxels() const { return reference.voxels.size() + current.voxels.size(); }
  std::size_t numPoints() const { return reference.points.size() + current.points.size(); }
};

/// How a changed blob of the source map compares with the objects of the target map it lands on
/// (see sameInPlace).
struct InPlaceMatch {
  int target_cells = 0;  ///< cells of the target objects its mapped footprint lands on
  double overlap = 0.0;  ///< IoU of its mapped footprint and those objects' footprint
  double shift = 0.0;    ///< m, between the two footprints' centroids (target plane frame)
  double size = 0.0;     ///< m, the smaller of the two footprints' box diagonals
  double shape_distance = std::numeric_limits<double>::infinity();  ///< shapeDistance of the two
  /// The same object in the same place: overlap >= kInPlaceMinOverlap, shift <=
  /// kInPlaceShiftFraction * size and shape_distance < kMovedShapeDistance.
  bool same() const;
};

/// The comparison of one registered plane pair in one direction, with every stage kept (for
/// pictures and debugging).
struct PlanePairResult {
  bool reference_to_current = true;  ///< direction: source = reference (removed candidates)
  PlaneMatch match;                  ///< source_id / target_id in the source / target maps
  InPlaneRefinement refinement;      ///< what the in-plane refinement did (applied or not)
  HeightMap source_heights;
  HeightMap target_heights;
  ObjectMap source_objects;
  HeightChange change;                      ///< 2D stages (raw, cleaned, blobs ...)
  std::vector<BlobValidation> validations;  ///< per change.blobs entry
  /// Per change.blobs entry: how it compares with the target objects it lands on (sameInPlace).
  std::vector<InPlaceMatch> in_place;
  Mask2D validated;  ///< cells of the blobs the 3D check kept
};

/// Everything detectChanges found.
struct ChangeSet {
  std::vector<ChangeEvent> events;     ///< ordered by id
  std::vector<PlanePairResult> pairs;  ///< both directions (stages only with keep_stages)
  double milliseconds = 0.0;           ///< wall time of detectChanges
  /// Wall times of its phases, which run one after the other (each parallel over planes or
  /// pairs): the height, object and point maps of the matched planes; the session-wide in-plane
  /// correction; the reference -> current pairs; the current -> reference pairs. The rest
  /// (registration, assembling the events) is milliseconds minus their sum.
  double maps_ms = 0.0;
  double correction_ms = 0.0;
  double forward_ms = 0.0;
  double backward_ms = 0.0;
};

struct DetectOptions {
  /// Keep the height maps, object maps and masks of every plane pair in ChangeSet::pairs
  /// (otherwise pairs hold the match, refinement and validations only).
  bool keep_stages = false;
  ValidationParams validation{};
};

/// Offline change detection between a reference and a current map (see the file comment).
/// Deterministic. Throws planesdf::Error("config", ...) on invalid parameters and
/// planesdf::Error("map", ...) when the voxel sizes of the maps differ.
ChangeSet detectChanges(const Map& reference, const Map& current, const Config& cfg,
                        const DetectOptions& options = {});

// --- building blocks, shared with the incremental ChangeDetector -------------------------------

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
/// no event. Then moved pairs (shapeDistance below kMovedShapeDistance, greedy by distance), then
/// replaced (a removed candidate with the added candidates its mapped footprint overlaps; or, with
/// none, the current objects it lands on when they cover at least kReplacedMinOverlap of it, with
/// the added candidates on those objects), then the rest. Ids 1..N in order of (type, primary
/// plane id, centroid); confidences from cfg.delta_blob (see ChangeEvent::confidence).
std::vector<ChangeEvent> assembleEvents(std::vector<CandidateChange> removed,
                                        std::vector<CandidateChange> added, const Config& cfg);

/// One source per target: of the matches sharing a target, the one with the smallest |gap|
/// keeps it (a second source plane on the same target is another surface — a box top 7 cm above
/// a table, within δd of it — whose content lies in the band of the plane that kept the target;
/// comparing it would shift every height by the gap). Result ordered by source id.
std::vector<PlaneMatch> uniqueMatches(std::vector<PlaneMatch> matches);

/// Smallest fraction of a removed footprint lying on current objects for a replaced event that
/// has no added candidate.
constexpr double kReplacedMinOverlap = 0.5;

/// Largest shapeDistance of a moved pair (and of the same object in place).
constexpr double kMovedShapeDistance = 0.3;

/// The same object in place: largest footprint centroid shift, as a fraction of the (smaller)
/// footprint's box diagonal (sameInPlace; assembleEvents' removed + added Unknown pairs).
constexpr double kInPlaceShiftFraction = 0.15;
/// The same object in place: smallest footprint IoU (sameInPlace).
constexpr double kInPlaceMinOverlap = 0.5;

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

// --- outputs (DESIGN §3 "detect") ----------------------------------------------------------------

/// changes.json: an array with one object per event: id, type, status, plane_id, bbox_min,
/// bbox_max, centroid (world, of the primary side), num_voxels, num_points (both sides),
/// confidence, and "reference" / "current" objects (plane_id, bbox_min, bbox_max, centroid,
/// num_voxels, num_points, key_voxels, scored, mean_similarity, verdict) for the sides present.
std::string changesToJson(const std::vector<ChangeEvent>& events, int indent = 2);

/// The events of a changes.json text (`name` names it in errors): id, type, status, confidence
/// and, per side, plane id, box, centroid and 3D evidence. Columns, voxels, points and shape
/// signatures are not in changes.json: the regions have none. Throws planesdf::Error(name, ...)
/// naming the event and field on a text changesToJson could not have written.
std::vector<ChangeEvent> changesFromJson(const std::string& text, const std::string& name);

/// Reads back what writeChangeOutputs wrote into `dir`: changesFromJson of changes.json, with
/// each side's points from removed_points.ply / added_points.ply (by change_id). Throws
/// planesdf::Error naming the file when one is missing or does not match changes.json.
std::vector<ChangeEvent> readChangeOutputs(const std::string& dir);

/// The events whole (every field, both sides' columns, voxels and points) in a binary form, for
/// a host that saves a ChangeDetector's state (ChangeDetector::restore).
std::string serializeEvents(const std::vector<ChangeEvent>& events);
/// serializeEvents' inverse. Throws planesdf::Error(what, "corrupt change events: ...") on bytes
/// it did not write.
std::vector<ChangeEvent> deserializeEvents(const std::string& bytes, const std::string& what);

/// Colour of a change type in pictures and PLYs (RGB): added red, removed blue, moved yellow,
/// replaced magenta.
std::array<std::uint8_t, 3> changeColor(ChangeType t);

/// Writes DESIGN §3's detect outputs into `dir` (created if missing): changes.json,
/// removed_points.ply (reference points of removed, moved-away and replaced objects) and
/// added_points.ply (current points of added, moved-in and replacing objects), both binary PLY
/// with RGB colours (changeColor) and a vertex property `int change_id`; and, when the set kept
/// its stages, planes/<ref|cur>_<id>_to_<ref|cur>_<id>_<stage>.png per plane pair and direction
/// (stages: source_height, target_height, source_objects, raw, unknown, filtered, cleaned,
/// blobs, validated). The folder is replaced all or nothing (io::replaceFolderAtomic): the files
/// are written into a fresh sibling `DIR.tmpXXXXXX` that is then swapped in, so a reader sees
/// the old outputs or the new ones and no picture of an earlier pair stays. An existing `dir`
/// that holds anything but these outputs is refused. Throws planesdf::Error naming the path on
/// failure.
void writeChangeOutputs(const std::string& dir, const ChangeSet& set);

}  // namespace planesdf
