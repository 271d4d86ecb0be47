#pragma once
// The session comparison behind both detectChanges and ChangeDetector (design.md, "Incremental
// detection"): plane pairs matched one-to-one, the session's drift corrected, both directions
// compared pair by pair, the candidates assembled into events.

#include <cstdint>
#include <map>
#include <memory>
#include <tuple>
#include <utility>
#include <vector>

#include "change_internal.hpp"
#include "planesdf/map.hpp"

namespace planesdf::detail {

/// Compares current maps with one reference map. A later run on the same session's grown map
/// reuses what its changes did not touch: the reference's plane maps, a current plane's maps
/// while its volume and the plane set are unchanged, the session correction while the forward
/// pairs' current volumes are, and a pair's candidates while its current volume and the
/// correction are. detectChanges runs one comparison once.
class SessionComparison {
 public:
  /// `reference` must outlive the comparison (and its copies) unchanged.
  SessionComparison(const Map& reference, const Config& cfg, const DetectOptions& options);

  struct Run {
    ChangeSet set;  ///< the events; the pairs compared in this run; phase times
    int pairs_checked = 0;
    int pairs_reused = 0;
  };
  /// Compares `current` (the same session's map from run to run: plane ids are matched by id).
  Run run(const Map& current);

 private:
  struct PairCache {
    std::uint64_t current_revision = 0;
    std::vector<CandidateChange> candidates;
    Pose T_target_source = Pose::Identity();  ///< the transform the comparison used
    SessionCorrection correction;             ///< the session correction it started from
    std::size_t num_planes = 0;               ///< current planes then (exclusion uses them)
  };
  struct CurrentMaps {
    PlaneMaps maps;
    std::size_t num_planes = 0;  ///< planes of the map when computed (exclusion uses them)
  };

  using PairCaches = std::map<std::tuple<bool, int, int>, PairCache>;
  /// What the two directions of one run build up: the candidates, the pair caches that replace
  /// pairs_ at the end, and the forward pairs' refined transforms (reused backwards).
  struct Direction {
    std::vector<CandidateChange> removed, added;
    PairCaches next;
    RefinedTransforms refined;
  };

  /// The maps of both directions' matched planes.
  void computeMatchedMaps(const Map& current, const std::vector<PlaneMatch>& forward_matches,
                          const std::vector<PlaneMatch>& backward_matches);
  /// The session correction, estimated again when a forward pair's current volume or the plane
  /// count changed.
  void updateCorrection(const Map& current, const std::vector<PlaneMatch>& forward_matches);
  /// Compares the pairs of one direction (reference -> current when `forward`): a pair whose
  /// current volume and correction are unchanged keeps its cached result.
  void compareDirection(const Map& current, bool forward, std::vector<PlaneMatch> matches,
                        Direction& d, Run& out);
  bool currentMapsValid(const Map& current, int id) const;
  /// The maps of the planes `needed` (reference?, id) that are not cached, in parallel.
  void computeMaps(const Map& current, std::vector<std::pair<bool, int>> needed);
  const PlaneMaps& maps(bool reference, int id) const;

  const Map* reference_;
  Config cfg_;
  DetectOptions options_;
  std::vector<PlaneMaps> reference_maps_;
  std::vector<bool> reference_done_;
  std::shared_ptr<PointChunks> reference_chunks_;
  std::map<int, CurrentMaps> current_maps_;
  /// (reference→current?, source id, target id) -> candidates
  PairCaches pairs_;
  /// The correction, and the (current plane id, revision) of the forward pairs it was
  /// estimated from and the plane count (re-estimated when they change; empty before the first).
  SessionCorrection correction_;
  std::vector<std::pair<int, std::uint64_t>> correction_key_;
};

}  // namespace planesdf::detail
