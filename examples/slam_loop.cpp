// slam_loop: planesdf inside a host SLAM loop. The reference session is mapped first; then, frame
// by frame, the current session is integrated into its own planesdf::Map and the ChangeDetector
// re-checks only the planes that changed, calling back with each alert once its evidence has
// held over Config::event_settle_frames frames; finish() settles the rest when the session ends.
//
// Runs with no arguments on the simulator's tabletop scene (fixed seed): a table with objects,
// some added, removed or moved between the two sessions.
#include <chrono>
#include <cstdio>

#include "planesdf/events.hpp"
#include "planesdf/map.hpp"
#include "planesdf/sim.hpp"

int main() {
  using namespace planesdf;
  const sim::Scene scene = sim::makePreset("tabletop", /*seed=*/7);
  std::printf("simulating the tabletop scene (seed 7)...\n");
  const sim::Simulation data = sim::simulate(scene);  // depth frames + reported camera poses

  Config cfg;  // defaults: 7 mm voxels, z up

  // 1. The reference session, mapped earlier (a host would Map::load() it from disk).
  Map reference(cfg);
  for (std::size_t i = 0; i < data.reference.frames.size(); ++i)
    reference.integrate(data.reference.frames[i], data.reference.reported_poses[i]);
  std::printf("reference: %zu frames, %zu planes\n", data.reference.frames.size(),
              reference.planes().size());

  // 2. The current session: the host's SLAM loop hands over each frame with its pose.
  Map current(cfg);
  ChangeDetector detector(reference, cfg);
  std::size_t frame_index = 0;
  int alerts = 0;
  detector.onEvent([&](const ChangeEvent& e) {
    ++alerts;
    const Eigen::Vector3d c = e.primary().centroid;
    std::printf(
        "  frame %3zu: change #%d %s (%s) at (%.2f, %.2f, %.2f), %zu points, confidence %.2f\n",
        frame_index, e.id, toString(e.type), toString(e.status), c.x(), c.y(), c.z(), e.numPoints(),
        e.confidence);
  });
  for (frame_index = 0; frame_index < data.current.frames.size(); ++frame_index) {
    const auto t0 = std::chrono::steady_clock::now();
    current.integrate(data.current.frames[frame_index], data.current.reported_poses[frame_index]);
    const bool last = frame_index + 1 == data.current.frames.size();
    // Callbacks run inside update() and finish().
    const UpdateStats stats = last ? detector.finish(current) : detector.update(current);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::printf("frame %3zu: %6.1f ms (fusion + detection), %d plane pairs re-checked\n",
                frame_index, ms, stats.pairs_checked);
  }

  // 3. The changes standing at the end of the session.
  const std::vector<ChangeEvent> changes = detector.events();
  std::printf("%d alerts\n%zu change events\n", alerts, changes.size());
  for (const ChangeEvent& e : changes)
    std::printf("  change #%d %s, %zu points\n", e.id, toString(e.type), e.numPoints());
  return 0;
}
