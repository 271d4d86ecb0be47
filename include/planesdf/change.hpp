#pragma once
/// \file change.hpp
/// Change detection between two session maps (paper §III-B to §III-D, design.md, "Pipeline"):
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
#include <limits>
#include <string>
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
  /// The same object in the same place: overlap >= cfg.in_place_min_overlap, shift <=
  /// cfg.in_place_shift_fraction * size and shape_distance < cfg.moved_shape_distance.
  bool same(const Config& cfg) const;
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
};

/// Offline change detection between a reference and a current map (see the file comment).
/// Deterministic. Throws planesdf::Error("config", ...) on invalid parameters and
/// planesdf::Error("map", ...) when the voxel sizes of the maps differ.
ChangeSet detectChanges(const Map& reference, const Map& current, const Config& cfg,
                        const DetectOptions& options = {});

// --- outputs (design.md, "Formats") -----------------------------------------------------------

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

/// Writes the detect outputs (design.md, "Formats") into `dir` (created if missing): changes.json,
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
