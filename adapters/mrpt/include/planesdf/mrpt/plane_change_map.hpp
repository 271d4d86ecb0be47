#pragma once
/// \file plane_change_map.hpp
/// CPlaneChangeMap: planesdf change detection as an MRPT metric map. It fuses
/// CObservation3DRangeScan observations into a planesdf::Map (the current session) and, once it
/// has a reference map, runs a planesdf::ChangeDetector after every `detect_every` scans and
/// publishes each notification (new / updated / retracted change) to the map's
/// mrpt::system::CObserver observers as an mrptEventPlaneChange.
///
/// Registered with MRPT's map factory as "planeChangeMap" (and by its full class name), so a
/// CMultiMetricMap INI can create it:
///
///     [map]
///     planeChangeMap_count = 1
///     [map_planeChangeMap_00_creationOpts]
///     config_file   = planesdf.json   ; planesdf Config JSON, empty = defaults
///     reference_map = reference.psdf  ; saved reference map, empty = set it later
///     detect_every  = 1               ; run the detector every N scans (0 = only on demand)
///
/// The factory entry is made when libplanesdf_mrpt is loaded: a program that only names the map
/// in an INI must still link the library (and not drop it with --as-needed).
///
/// This header derives from mrpt::maps::CMetricMap and so includes MRPT headers (slow to
/// compile): include it only where the map is used; the other adapter headers do not.

#include <mrpt/maps/CMetricMap.h>
#include <mrpt/system/mrptEvent.h>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "planesdf/change.hpp"
#include "planesdf/config.hpp"
#include "planesdf/events.hpp"
#include "planesdf/map.hpp"

namespace mrpt::maps {
class CColouredPointsMap;
}

namespace planesdf::mrpt_adapter {

class CPlaneChangeMap;

/// One ChangeDetector notification, published by a CPlaneChangeMap to its observers
/// (`e.isOfType<mrptEventPlaneChange>()`, then `e.getAs<mrptEventPlaneChange>()->event`).
class mrptEventPlaneChange : public mrpt::system::mrptEvent {
 protected:
  void do_nothing() override {}

 public:
  mrptEventPlaneChange(const CPlaneChangeMap& source, const ChangeEvent& e)
      : source_map(source), event(e) {}
  const CPlaneChangeMap& source_map;
  ChangeEvent event;  ///< status New, Updated or Retracted; `frame` = scans fused when emitted
};

class CPlaneChangeMap : public mrpt::maps::CMetricMap {
  DEFINE_SERIALIZABLE(CPlaneChangeMap, planesdf::mrpt_adapter)

 public:
  /// An empty map. Throws planesdf::Error("config", ...) on invalid parameters.
  explicit CPlaneChangeMap(const Config& cfg = Config{});

  /// Starts change detection against `reference` (a copy is kept); forgets earlier changes.
  void setReference(const Map& reference);
  /// setReference(Map::load(path)).
  void loadReference(const std::string& path);
  bool hasReference() const { return detector_.has_value(); }

  /// Runs the detector on the scans fused so far and publishes its notifications; returns how
  /// many there were. Does nothing (returns 0) without a reference.
  std::size_t detectChanges();
  /// As detectChanges(), at the end of the session: every result settles now instead of after
  /// Config::event_settle_frames (ChangeDetector::finish).
  std::size_t finishChanges();

  /// The current session's map.
  const Map& map() const { return map_; }
  const Config& config() const { return cfg_; }
  /// Run the detector after every `n` fused scans (0: only when detectChanges() is called).
  void setDetectEvery(int n) { detect_every_ = n < 0 ? 0 : n; }
  int detectEvery() const { return detect_every_; }
  /// The active changes (latest state), ordered by id; empty without a reference.
  std::vector<ChangeEvent> changes() const;
  /// The points of the active changes, coloured by type (see toColouredPointsMap).
  void getChangedPoints(mrpt::maps::CColouredPointsMap& out) const;

  // --- mrpt::maps::CMetricMap ---
  bool isEmpty() const override;
  /// Writes `<prefix>.psdf` (the current map) and `<prefix>_changes.json` (the active changes).
  void saveMetricMapRepresentationToFile(const std::string& prefix) const override;
  /// The changed points, coloured by type.
  void getVisualizationInto(mrpt::opengl::CSetOfObjects& o) const override;
  std::string asString() const override;

  MAP_DEFINITION_START(CPlaneChangeMap)
  std::string config_file;    ///< planesdf Config JSON; empty = defaults
  std::string reference_map;  ///< .psdf reference map; empty = none (call setReference later)
  int detect_every = 1;
  MAP_DEFINITION_END(CPlaneChangeMap)

 private:
  void internal_clear() override;
  /// Fuses a CObservation3DRangeScan (camera pose = robotPose * sensorPose, see
  /// range_scan.hpp); other observations are not inserted (returns false).
  bool internal_insertObservation(
      const mrpt::obs::CObservation& obs,
      const std::optional<const mrpt::poses::CPose3D>& robotPose = std::nullopt) override;
  /// Not a localisation map: likelihoods are not computed.
  double internal_computeObservationLikelihood(
      const mrpt::obs::CObservation& obs, const mrpt::poses::CPose3D& takenFrom) const override;
  bool internal_canComputeObservationLikelihood(const mrpt::obs::CObservation&) const override {
    return false;
  }

  Config cfg_;
  std::size_t publish(const UpdateStats& stats);

  Map map_;
  std::optional<ChangeDetector> detector_;
  int detect_every_ = 1;
};

/// Appends the points of `events` to `out`, coloured with planesdf::changeColor: added red,
/// removed blue, moved yellow, replaced magenta. Both sides of an event are exported (the
/// reference side where the object was, the current side where it is now).
void toColouredPointsMap(const std::vector<ChangeEvent>& events,
                         mrpt::maps::CColouredPointsMap& out);

}  // namespace planesdf::mrpt_adapter
