#pragma once
/// \file registration.hpp
/// PlaneSDF registration (paper §III-B) and the in-plane (u, v, yaw)
/// refinement from static height-map structure (beyond the paper; design.md, "Registration").
///
/// Both sessions are assumed to share one world frame; registration only absorbs small drift.
/// A source plane i matches a target plane j when
///   * n_i·n_j >= cfg.delta_n (same free side),
///   * |offset gap| <= cfg.delta_d, where the gap is the signed distance of the source plane's
///     anchor point (the centre of its extent, or its frame origin when the extent is empty) to
///     the target plane — for parallel planes this is d_j - d_i with the paper's (n, d),
///   * their in-plane extents overlap: the source extent, carried into the target frame by the
///     correction below, intersects the target extent grown by kRegistrationExtentMargin.
///     Planes with an empty extent (nothing observed yet) skip this test.
/// Each source plane keeps its best target: the largest overlap area, ties (within 1e-9 m²)
/// broken by the smallest |gap|. Several source planes may take the same target.
///
/// The relative transform (see planeCorrection) is
///   T_target_source_local = frame_t^{-1} * C * frame_s,
/// where C is the world correction moving the source plane onto the target plane with minimal
/// motion. T maps source plane-local (u, v, h) to target plane-local (u', v', h') with h' == h:
/// it is a yaw about the plane normal plus an in-plane translation.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/map.hpp"
#include "planesdf/plane.hpp"
#include "planesdf/types.hpp"

namespace planesdf {

/// Margin (m) by which the target extent is grown before the overlap test of registerPlanes.
constexpr double kRegistrationExtentMargin = 0.05;

/// One registered pair of planes.
struct PlaneMatch {
  int source_id = -1;  ///< Plane::id in the source map (or index when ids are -1)
  int target_id = -1;  ///< Plane::id in the target map (or index when ids are -1)
  /// Maps source plane-local (u, v, h) to target plane-local (u, v, h):
  /// frame_t^{-1} * planeCorrection(source, target) * frame_s.
  Pose T_target_source_local = Pose::Identity();
  double cos_normal = 0.0;  ///< n_s·n_t
  double offset_gap = 0.0;  ///< signed distance (m) of the source anchor to the target plane
  double overlap = 0.0;     ///< overlap area (m²) of the extents; 0 when an extent is empty
};

/// The world correction C taking the source plane onto the target plane with minimal motion:
/// the smallest rotation R taking n_s onto n_t, about the source anchor p (centre of the source
/// extent on the plane, or its frame origin), followed by a shift along n_t by minus the target
/// signed distance of p: C(x) = R (x - p) + p - n_t (n_t·p + d_t). Points of the source plane land
/// on the target plane; heights above the plane are preserved.
Pose planeCorrection(const Plane& source, const Plane& target);

/// frame_t^{-1} * planeCorrection(source, target) * frame_s (see the file comment).
Pose relativePlaneTransform(const Plane& source, const Plane& target);

/// The world point of the source plane used as anchor: its extent centre (u, v, 0) when the
/// extent is non-empty, else its frame origin.
Eigen::Vector3d planeAnchor(const Plane& plane);

/// Matches every source plane to its best target plane (see the file comment). Result ordered
/// by source plane. Ids are Plane::id, or the vector index when the id is negative. Throws
/// planesdf::Error("config", ...) when delta_n is not in [-1, 1] or delta_d is negative/NaN.
std::vector<PlaneMatch> registerPlanes(const std::vector<Plane>& source,
                                       const std::vector<Plane>& target, const Config& cfg);

/// True when `b` is a second fit of `a`'s surface (docs/design.md, "Duplicate planes"): the same
/// orientation, normals within cfg.plane_merge_angle_deg, the centre of b's extent within
/// 2 cfg.ransac_inlier_dist of `a` (closer than two supports with objects between them can be),
/// half or more of b's extent inside a's, and `a` the larger (more support; the lower id on a
/// tie). A frame stream fits a long wall seen in separate patches this way.
bool duplicateOf(const Plane& b, const Plane& a, const Config& cfg);

/// registerPlanes on the planes of two maps, leaving out each map's duplicate planes
/// (duplicateOf another plane of the same map): a duplicate would take the match of the plane it
/// duplicates, and a slightly tilted copy of a wall reads the wall's own surface as objects.
std::vector<PlaneMatch> registerPlanes(const Map& source, const Map& target, const Config& cfg);

/// Options of one refineInPlane call; the search window and the acceptance thresholds are
/// Config's (inplane_*).
struct InPlaneSearch {
  /// The session's drift (design.md): changed objects absorb their rings and a best candidate
  /// may pass the paired test. A pair refined after the drift looks for a residual: plain
  /// shares and the count tests only.
  bool session_drift = false;
};

/// What refineInPlane found. The correction is a yaw `dyaw` about `pivot` followed by a shift
/// (du, dv), both in the target plane frame, applied after the initial T.
struct InPlaneRefinement {
  bool applied = false;                             ///< T was changed
  double du = 0.0;                                  ///< m
  double dv = 0.0;                                  ///< m
  double dyaw = 0.0;                                ///< rad
  Eigen::Vector2d pivot = Eigen::Vector2d::Zero();  ///< target-local (u, v)
  int compared_before = 0;    ///< source cells observed in both maps, initial T
  int compared_after = 0;     ///< same with the refined T
  int mismatches_before = 0;  ///< of those, cells with |H - H'| > delta_h (nearest target cell)
  int mismatches_after = 0;
  double mean_abs_before = 0.0;  ///< mean |H - H'| (m, each term capped at 4 delta_h)
  double mean_abs_after = 0.0;
  int fixed = 0;   ///< cells the best candidate makes agree that mismatched (set when searched)
  int broken = 0;  ///< cells the best candidate makes mismatch that agreed
};

/// Refines the in-plane part of `T_target_source_local` so that cells observed in both height maps
/// agree best. The samples are the source cells (evenly subsampled) whose nearest target cell under
/// the initial T is observed; search over a yaw (about the centre of the samples) and a shift (du,
/// dv) within the window (cfg.inplane_max_shift, cfg.inplane_max_yaw_deg), coarse to fine:
/// 2-step and 1-degree steps over the whole window on at most 6000 samples (a sample agrees there
/// when a target cell within one cell agrees), then steps of cfg.inplane_shift_step (0: one
/// target cell) and cfg.inplane_yaw_step_deg around the coarse best and around the initial T on all
/// samples. A sample mismatches when its nearest target cell differs by more than cfg.delta_h; one
/// that mismatched under the initial T and is moved off the observed target still does, so
/// differences cannot hide in unobserved areas. The cost of a candidate counts the mismatches with
/// each object's share capped at half its samples (a sample belongs to the source object it lies
/// on, else to the target object it falls on under the initial T, else to the uncapped background):
/// a moved object mismatches wholly at the right T, and a candidate that drags the map onto its new
/// place must not win against the static objects. With search.session_drift, background samples
/// within cfg.inplane_max_shift of an object that mismatches in more than half its samples under
/// the initial T count in that object's share (the crescents any shift sweeps onto a changed object
/// are no evidence against the shift). Ties are broken by the mean capped absolute difference, then
/// by the smaller motion. Model selection: T becomes Δ * T only when the best candidate lies inside
/// the window (a best on its border is a moved object pulling, not drift) and removes at least
/// cfg.inplane_min_gain_cells cells and either cfg.inplane_min_gain_fraction of the initial
/// mismatches, or cfg.inplane_min_gain_sigmas of their count, or (search.session_drift) as many
/// sigmas of the paired test on the cells it flips ((fixed - broken) / sqrt(fixed + broken),
/// counting a run of s cells as one event when the candidate moves the map s cells). Empty or
/// non-overlapping maps: nothing is done. Does not read cfg.refine_inplane (the caller decides
/// whether to refine).
InPlaneRefinement refineInPlane(const HeightMap& src, const HeightMap& tgt,
                                Pose& T_target_source_local, const Config& cfg,
                                const InPlaneSearch& search = InPlaneSearch{});
/// refineInPlane with the maps' object maps already computed (computeObjectMap(src, cfg) and
/// computeObjectMap(tgt, cfg), as the change detection has them).
InPlaneRefinement refineInPlane(const HeightMap& src, const ObjectMap& src_objects,
                                const HeightMap& tgt, const ObjectMap& tgt_objects,
                                Pose& T_target_source_local, const Config& cfg,
                                const InPlaneSearch& search = InPlaneSearch{});

}  // namespace planesdf
