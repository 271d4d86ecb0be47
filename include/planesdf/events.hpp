#pragma once
/// \file events.hpp
/// Incremental change detection (DESIGN §3): a ChangeDetector holds the reference map and, each
/// time update(current) is called while the current session is being mapped, re-checks only the
/// plane pairs whose current volume changed since the last call, and tells user callbacks about
/// each change once (status New), again when a later frame changes its type, extent or
/// confidence (Updated), and when later frames show there is no change after all (Retracted).
///
/// Identity of a change across updates: a new result is the same change as an active one when
/// one of their sides covers a common voxel column of the same plane (reference side with
/// reference side, current with current). Its id stays; ids are never reused.

#include <cstdint>
#include <functional>
#include <map>
#include <tuple>
#include <vector>

#include "planesdf/change.hpp"
#include "planesdf/config.hpp"
#include "planesdf/map.hpp"

namespace planesdf {

/// What one ChangeDetector::update() call did.
struct UpdateStats {
  int pairs_checked = 0;  ///< plane pairs (per direction) compared again
  int pairs_reused = 0;   ///< plane pairs whose volumes had not changed: previous result kept
  std::vector<ChangeEvent> notifications;  ///< what the callbacks received, in order
  double milliseconds = 0.0;
};

class ChangeDetector {
 public:
  using Callback = std::function<void(const ChangeEvent&)>;

  /// Keeps a copy of `reference` (or takes it). Throws planesdf::Error("config", ...) on
  /// invalid parameters and when `cfg` gives the maps another geometry than the reference was
  /// built with (voxel size, truncation, band): detection reads the maps at the Config's.
  ChangeDetector(const Map& reference, const Config& cfg);
  ChangeDetector(Map&& reference, const Config& cfg);

  /// Adds a callback; every notification goes to every callback, in the order they were added,
  /// on the thread calling update(). A callback must not call update().
  void onEvent(Callback callback);

  /// Compares `current` with the reference (see the file comment) and notifies. `current` must
  /// be the same session's map from call to call (plane ids are matched by id), built with the
  /// reference's geometry (else planesdf::Error("current map", ...)).
  UpdateStats update(const Map& current);

  /// The active changes (latest state, status of their last notification), ordered by id.
  std::vector<ChangeEvent> events() const;
  const Map& reference() const { return reference_; }
  const Config& config() const { return cfg_; }

 private:
  struct PairCache {
    std::uint64_t current_revision = 0;
    std::vector<CandidateChange> candidates;
    Pose T_target_source = Pose::Identity();  ///< the transform the comparison used
    SessionCorrection correction;             ///< the session correction it started from
  };
  struct CurrentMaps {
    PlaneMaps maps;
    std::size_t num_planes = 0;  ///< planes of the map when computed (exclusion uses them)
  };

  Map reference_;
  Config cfg_;
  DetectOptions options_;
  std::vector<Callback> callbacks_;
  std::vector<PlaneMaps> reference_maps_;
  std::map<int, CurrentMaps> current_maps_;
  /// (reference→current?, source id, target id) -> candidates
  std::map<std::tuple<bool, int, int>, PairCache> pairs_;
  std::map<int, ChangeEvent> active_;  ///< by id
  /// sessionCorrection, and the (current plane id, revision) of the forward pairs it was
  /// estimated from (recomputed when they change).
  SessionCorrection correction_;
  std::vector<std::pair<int, std::uint64_t>> correction_key_;
  int next_id_ = 1;
};

}  // namespace planesdf
