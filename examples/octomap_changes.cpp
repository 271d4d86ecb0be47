// octomap_changes: keep a user's OctoMap up to date with planesdf's changes. Two sessions of the
// simulated tabletop are fused into planesdf maps and compared; the changes are then applied to
// an octomap::OcTree of the reference session (removed objects free, added ones occupied) and
// painted into a ColorOcTree written as changes.ot in the current folder (view it with octovis).
#include <octomap/ColorOcTree.h>
#include <octomap/OcTree.h>

#include <cstdio>

#include "planesdf/change.hpp"
#include "planesdf/map.hpp"
#include "planesdf/octomap/change_octree.hpp"
#include "planesdf/sim.hpp"

using namespace planesdf;

Map fuse(const sim::SessionData& session, const Config& cfg) {
  Map map(cfg);
  for (std::size_t i = 0; i < session.frames.size(); ++i)
    map.integrate(session.frames[i], session.reported_poses[i]);
  return map;
}

const char* state(const octomap::OcTree& tree, const Eigen::Vector3d& p) {
  const octomap::OcTreeNode* n = tree.search(p.x(), p.y(), p.z());
  return n == nullptr ? "unknown" : tree.isNodeOccupied(n) ? "occupied" : "free";
}

int main() {
  const sim::Scene scene = sim::makePreset("tabletop", /*seed=*/7);
  std::printf("simulating the tabletop scene (seed 7)...\n");
  const sim::Simulation data = sim::simulate(scene);
  const Config cfg;
  const ChangeSet changes = detectChanges(fuse(data.reference, cfg), fuse(data.current, cfg), cfg);

  // The user's map of the reference session: a 2 cm OcTree (here from the session's scene cloud).
  octomap::OcTree tree(0.02);
  for (const Eigen::Vector3f& p : data.reference.cloud.points)
    tree.updateNode(p.x(), p.y(), p.z(), true);
  const octomap::OcTree before = tree;

  const octomap_adapter::OctreeChangeStats stats = octomap_adapter::applyChanges(changes, tree);
  std::printf("OcTree (%.2f m): %zu voxels freed, %zu voxels occupied\n", tree.getResolution(),
              stats.freed_voxels, stats.occupied_voxels);
  for (const ChangeEvent& e : changes.events) {
    const Eigen::Vector3d c = e.primary().centroid;
    std::printf("  change #%d %-8s at (%.2f, %.2f, %.2f): %s -> %s\n", e.id, toString(e.type),
                c.x(), c.y(), c.z(), state(before, c), state(tree, c));
  }

  octomap::ColorOcTree painted(tree.getResolution());
  const std::size_t n = octomap_adapter::paintChanges(changes.events, painted);
  octomap_adapter::writeOcTree("changes.ot", painted);
  std::printf("changes.ot: %zu voxels painted (added red, removed blue, moved yellow)\n", n);
  std::printf("%zu change events\n", changes.events.size());
  return 0;
}
