// `planesdf simulate --scene tabletop|room|FILE.json [--seed N] --out DIR`: a synthetic session
// pair with ground truth (design.md, "Formats"), progress on stderr, a summary on stdout.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>

#include "commands.hpp"
#include "planesdf/error.hpp"
#include "planesdf/sim.hpp"

namespace planesdf::cli {

int runSimulate(const SimulateArgs& args) {
  const auto t0 = std::chrono::steady_clock::now();
  sim::Scene scene;
  if (args.scene == "tabletop" || args.scene == "room") {
    scene = sim::makePreset(args.scene, args.seed);
  } else {
    std::error_code ec;
    if (!std::filesystem::exists(args.scene, ec))
      throw Error("--scene", "'" + args.scene +
                                 "' is neither a preset (tabletop, room) nor an existing scene "
                                 "file");
    scene = sim::loadSceneJson(args.scene);
    if (args.seed_given) scene.seed = args.seed;  // new sensor noise for the same scene
  }
  std::cerr << "simulate: scene '" << scene.name << "' seed " << scene.seed << ", "
            << scene.reference.objects.size() << " objects in the reference, "
            << scene.current.objects.size() << " in the current session\n";

  sim::SimulateOptions options;
  options.progress = [](const std::string& msg) { std::cerr << "simulate: " << msg << "\n"; };
  const sim::Simulation result = sim::simulate(scene, options);
  std::cerr << "simulate: writing " << args.out << "\n";
  sim::writeSimulation(args.out, scene, result);

  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const sim::ChangedIds changed = sim::changedObjects(scene);
  const sim::SessionData& ref = result.reference;
  const sim::SessionData& cur = result.current;
  std::printf(
      "%s: %zu + %zu frames, clouds %zu + %zu points, ground truth %zu + %zu points "
      "(%zu removed-side, %zu added-side objects), reconstructions %zu + %zu points "
      "(ground truth %zu + %zu), meshes %zu + %zu triangles, %.1f s\n",
      args.out.c_str(), ref.frames.size(), cur.frames.size(), ref.cloud.size(), cur.cloud.size(),
      ref.gt.size(), cur.gt.size(), changed.reference.size(), changed.current.size(),
      ref.reconstruction.size(), cur.reconstruction.size(), ref.reconstruction_gt.size(),
      cur.reconstruction_gt.size(), ref.mesh_triangles.size(), cur.mesh_triangles.size(), seconds);
  for (const sim::Change& c : scene.changes) {
    std::printf("  change %-10s reference", sim::toString(c.kind));
    for (const int id : c.reference_ids) std::printf(" %d", id);
    std::printf("  current");
    for (const int id : c.current_ids) std::printf(" %d", id);
    std::printf("\n");
  }
  return kExitOk;
}

}  // namespace planesdf::cli
