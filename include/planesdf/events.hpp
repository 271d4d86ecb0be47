#pragma once
/// \file events.hpp
/// Incremental change detection (design.md, "Incremental detection"): a ChangeDetector shares the
/// reference map and, each time update(current) is called while the current session is being
/// mapped, re-checks only the plane pairs whose current volume changed since the last call, and
/// tells user callbacks about each change once (status New), again when a later frame changes its
/// type, extent or confidence (Updated), and when later frames show there is no change after all
/// (Retracted).
///
/// Stable events (design.md, "Stable events"): a result is announced only once the updates over
/// Config::event_settle_frames frames of the current session found it with the same type (over
/// Config::event_unscored_settle_frames when no side of it could be checked in 3D), and an
/// announced change is updated or retracted only once as many frames agree. finish() settles
/// everything at the end of a session: the events are then detectChanges' on the same maps.
///
/// Identity of a change across updates: a new result is the same change as an active one when
/// one of their sides covers a common voxel column of the same plane (reference side with
/// reference side, current with current). Its id stays; ids are never reused.
///
/// Threads: a ChangeDetector is used by one thread at a time; update() only reads `current`
/// and the reference, so other detectors may read the same maps meanwhile.

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <vector>

#include "planesdf/change.hpp"
#include "planesdf/config.hpp"
#include "planesdf/map.hpp"

namespace planesdf {

namespace detail {
class SessionComparison;
}

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

  /// Shares `reference` (not null; it must not change while the detector lives). Throws
  /// planesdf::Error("config", ...) on invalid parameters and when `cfg` gives the maps another
  /// geometry than the reference was built with (voxel size, truncation, band): detection reads
  /// the maps at the Config's.
  ChangeDetector(std::shared_ptr<const Map> reference, const Config& cfg);
  /// Keeps a copy of `reference` (or takes it), as above.
  ChangeDetector(const Map& reference, const Config& cfg);
  ChangeDetector(Map&& reference, const Config& cfg);
  ChangeDetector(const ChangeDetector& other);
  ChangeDetector(ChangeDetector&& other) noexcept;
  ChangeDetector& operator=(const ChangeDetector& other);
  ChangeDetector& operator=(ChangeDetector&& other) noexcept;
  ~ChangeDetector();

  /// Adds a callback; every notification goes to every callback, in the order they were added,
  /// on the thread calling update(). A callback must not call update().
  void onEvent(Callback callback);

  /// Compares `current` with the reference (see the file comment) and notifies. `current` must
  /// be the same session's map from call to call (plane ids are matched by id), built with the
  /// reference's geometry (else planesdf::Error("current map", ...)).
  UpdateStats update(const Map& current);

  /// As update(), at the end of the session: every result settles now (announced, updated or
  /// retracted without waiting for Config::event_settle_frames), so events() are then
  /// detectChanges(reference(), current, config()).events up to their ids and statuses.
  UpdateStats finish(const Map& current);

  /// The announced changes (their state as last notified), ordered by id.
  std::vector<ChangeEvent> events() const;
  /// The id the next announced change gets (ids are never reused).
  int nextId() const { return next_id_; }
  /// Continues a saved detector (same reference and config): `events` (as events() gave them)
  /// are the announced changes, `next_id` as nextId() gave it. Results of later updates that
  /// are the same changes keep their ids and are notified only when they differ. Throws
  /// planesdf::Error("events", ...) on duplicate ids or ids not below `next_id`.
  void restore(const std::vector<ChangeEvent>& events, int next_id);
  const Map& reference() const { return *reference_; }
  const Config& config() const { return cfg_; }

 private:
  /// A change found by recent updates: announced (in active_) or pending.
  struct Track {
    ChangeEvent shown;   ///< announced: as last notified
    ChangeEvent latest;  ///< the latest result found for it
    /// frames() from which the current disagreement has held: announced, `latest` materially
    /// different from `shown` or not found (`absent`); pending, `latest`'s type.
    std::uint64_t since = 0;
    bool differs = false;
    bool absent = false;
  };

  /// `finishing`: every result settles at once (finish()).
  UpdateStats run(const Map& current, bool finishing);
  void settle(std::vector<ChangeEvent> fresh, std::uint64_t now, bool finishing,
              UpdateStats& stats);

  std::shared_ptr<const Map> reference_;
  Config cfg_;
  std::vector<Callback> callbacks_;
  /// The session comparison (detectChanges'), with what it keeps from update to update.
  std::unique_ptr<detail::SessionComparison> comparison_;
  std::map<int, Track> active_;  ///< announced, by id
  std::vector<Track> pending_;   ///< found, not announced yet
  int next_id_ = 1;
};

}  // namespace planesdf
