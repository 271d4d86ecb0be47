// mrpt_change_map: planesdf change detection as an MRPT metric map. A CMultiMetricMap is built
// from an INI with a "planeChangeMap"; 3D range scans of the current session are inserted like
// any other observation, and a CObserver receives each change as an mrptEventPlaneChange.
// Runs with no arguments on the simulated tabletop (its depth frames turned into
// CObservation3DRangeScan observations).
#include <mrpt/config/CConfigFileMemory.h>
#include <mrpt/maps/CColouredPointsMap.h>
#include <mrpt/maps/CMultiMetricMap.h>
#include <mrpt/obs/CObservation3DRangeScan.h>
#include <mrpt/system/CObserver.h>

#include <cstdio>

#include "planesdf/mrpt/plane_change_map.hpp"
#include "planesdf/mrpt/range_scan.hpp"
#include "planesdf/sim.hpp"

using planesdf::mrpt_adapter::CPlaneChangeMap;
using planesdf::mrpt_adapter::mrptEventPlaneChange;

/// Prints every change notification the map publishes.
class ChangePrinter : public mrpt::system::CObserver {
 public:
  int received = 0;

 protected:
  void OnEvent(const mrpt::system::mrptEvent& e) override {
    const auto* change = e.getAs<mrptEventPlaneChange>();
    if (change == nullptr) return;
    ++received;
    const planesdf::ChangeEvent& ev = change->event;
    const Eigen::Vector3d c = ev.primary().centroid;
    std::printf("  scan %3llu: change #%d %s (%s) at (%.2f, %.2f, %.2f)\n",
                static_cast<unsigned long long>(ev.frame), ev.id, planesdf::toString(ev.type),
                planesdf::toString(ev.status), c.x(), c.y(), c.z());
  }
};

/// The session's frames as MRPT observations (robot at the origin: sensorPose is the camera pose).
std::vector<mrpt::obs::CObservation3DRangeScan::Ptr> toScans(const planesdf::sim::SessionData& s) {
  std::vector<mrpt::obs::CObservation3DRangeScan::Ptr> scans;
  for (std::size_t i = 0; i < s.frames.size(); ++i) {
    auto scan = mrpt::obs::CObservation3DRangeScan::Create();
    planesdf::mrpt_adapter::toRangeScan(s.frames[i], s.reported_poses[i], *scan);
    scan->sensorLabel = "RGBD";
    scans.push_back(scan);
  }
  return scans;
}

int main() {
  const planesdf::sim::Scene scene = planesdf::sim::makePreset("tabletop", /*seed=*/7);
  std::printf("simulating the tabletop scene (seed 7)...\n");
  const planesdf::sim::Simulation data = planesdf::sim::simulate(scene);

  // A multi-map with one planeChangeMap, as a SLAM application would read it from its INI.
  const mrpt::config::CConfigFileMemory ini(
      "[map]\n"
      "planeChangeMap_count = 1\n"
      "[map_planeChangeMap_00_creationOpts]\n"
      "detect_every = 5\n");
  mrpt::maps::TSetOfMetricMapInitializers inits;
  inits.loadFromConfigFile(ini, "map");
  mrpt::maps::CMultiMetricMap maps;
  maps.setListOfMaps(inits);
  const CPlaneChangeMap::Ptr changes = maps.mapByClass<CPlaneChangeMap>();

  // The reference session, mapped earlier with its own planeChangeMap.
  CPlaneChangeMap reference_session;
  for (const auto& scan : toScans(data.reference)) reference_session.insertObservation(*scan);
  changes->setReference(reference_session.map());
  std::printf("reference: %llu scans, %zu planes\n",
              static_cast<unsigned long long>(reference_session.map().frames()),
              reference_session.map().planes().size());

  // The current session: scans go into the multi-map; changes arrive at the observer.
  ChangePrinter printer;
  printer.observeBegin(*changes);
  for (const auto& scan : toScans(data.current)) maps.insertObservation(*scan);
  changes->finishChanges();  // the session ended: the last scans, and every result settles

  mrpt::maps::CColouredPointsMap points;
  changes->getChangedPoints(points);
  std::printf("%s\n", changes->asString().c_str());
  std::printf(
      "%d notifications; %zu coloured change points (added red, removed blue, moved "
      "yellow, replaced magenta)\n",
      printer.received, points.size());
  std::printf("%zu change events\n", changes->changes().size());
  return 0;
}
