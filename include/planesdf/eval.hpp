#pragma once
/// \file eval.hpp
/// Scoring a change detection against ground truth (`planesdf eval`): the point-level
/// precision / recall / F1 and the object-level M (missed) and W (wrong) counts of the paper's
/// Table I, per side (removed, added) and pooled.
///
/// Inputs are point clouds as `planesdf detect` writes them (`removed_points.ply`,
/// `added_points.ply`, a vertex property `int change_id` per point) and as the ground truth is
/// stored (`--gt-reference`, `--gt-current`, a vertex property `int object_id` per point).
///
/// Matching: a predicted point matches when a ground-truth point of the same side lies within
/// `tol` of it (Euclidean distance, inclusive); a ground-truth point matches when a predicted point
/// of the same side lies within `tol` of it. Points with a non-finite coordinate are ignored
/// everywhere (they count in no total and form no object or cluster).
///
/// Objects and clusters: a ground-truth object is the set of valid points sharing one `object_id`
/// value, a predicted cluster the set of valid points sharing one `change_id` value. A cloud
/// without that field is taken as one single object / cluster (when it has any valid point).

#include <cstddef>
#include <string>

#include "planesdf/types.hpp"

namespace planesdf {

/// Name of the per-point property holding the change event id in `detect` outputs.
inline constexpr const char* kChangeIdField = "change_id";
/// Name of the per-point property holding the object number in ground-truth files.
inline constexpr const char* kObjectIdField = "object_id";

/// The figures of one side (removed or added), or of both pooled.
struct SideScore {
  double precision = 1.0;  ///< matched_predicted / predicted_points (see the empty-side rule)
  double recall = 1.0;     ///< matched_gt / gt_points (see the empty-side rule)
  double f1 = 1.0;         ///< harmonic mean of precision and recall; 0 when both are 0
  int missed = 0;          ///< M: ground-truth objects with no matched point
  int wrong = 0;           ///< W: predicted clusters with no matched point
  std::size_t predicted_points = 0;   ///< valid predicted points
  std::size_t gt_points = 0;          ///< valid ground-truth points
  std::size_t matched_predicted = 0;  ///< predicted points with a GT point within tol
  std::size_t matched_gt = 0;         ///< GT points with a predicted point within tol
  int gt_objects = 0;                 ///< distinct object ids among the valid GT points
  int predicted_clusters = 0;         ///< distinct change ids among the valid predicted points
};

/// The result of one evaluation: both sides and the pooled figures.
struct EvalResult {
  SideScore pooled;   ///< counts of both sides summed, rates recomputed from the sums
  SideScore removed;  ///< removed_points vs the reference-scene ground truth
  SideScore added;    ///< added_points vs the current-scene ground truth
  double tol = 0.0;   ///< the match distance used (m)
};

/// Fills precision, recall and f1 of `s` from its point counts. Empty-side rule: no
/// ground truth and no prediction scores 1 on all three; otherwise an empty denominator scores 0
/// (so a prediction with no ground truth has precision 0 and F1 0).
void computeRates(SideScore& s);

/// Scores one side: `predicted` (field `change_id`) against `gt` (field `object_id`) with match
/// distance `tol` (m). Throws planesdf::Error when `tol` is not positive and finite or when a
/// cloud's per-point arrays disagree in length. Parallel over query cells (every CPU).
SideScore scoreSide(const PointCloud& predicted, const PointCloud& gt, double tol);

/// Pools two sides: point counts, objects, clusters, M and W summed; rates from the sums.
SideScore poolScores(const SideScore& a, const SideScore& b);

/// Scores a `detect` output (design.md, "Formats") against ground truth: `removed_pred` against
/// `gt_reference`, `added_pred` against `gt_current`, and both pooled. Same errors as scoreSide.
EvalResult evaluateChanges(const PointCloud& removed_pred, const PointCloud& added_pred,
                           const PointCloud& gt_reference, const PointCloud& gt_current,
                           double tol);

/// The `eval --json` object (design.md, "Formats"): top-level pooled "precision", "recall", "f1",
/// "missed", "wrong", then "removed" and "added" objects with the same five keys. Every level also
/// carries the point, object and cluster counts ("predicted_points", "gt_points",
/// "matched_predicted", "matched_gt", "gt_objects", "predicted_clusters"); the top level carries
/// "tol". Indented by `indent` spaces (a negative value gives one line).
std::string evalToJson(const EvalResult& result, int indent = 2);

}  // namespace planesdf
