// `planesdf demo [--out DIR] [--scene tabletop|room] [--seed N]`: the built-in default run
// (design.md, "Formats"). Simulates a session pair with ground truth, fuses both sessions frame by
// frame, detects the changes, scores them and writes report.json (the eval object plus timings) and
// report.md (figures, events and the pictures).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "commands.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"
#include "planesdf/eval.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/ply.hpp"
#include "planesdf/map.hpp"
#include "planesdf/sim.hpp"
#include "timing.hpp"

namespace planesdf::cli {
namespace {

namespace fs = std::filesystem;

struct Fused {
  Map map;
  std::vector<double> frame_ms;
};

// Integrates a simulated session frame by frame at its reported poses (what a SLAM system gives).
Fused fuseSession(const sim::SessionData& session, const Config& cfg, const char* label) {
  Fused f{Map(cfg), {}};
  const std::size_t n = session.frames.size();
  for (std::size_t i = 0; i < n; ++i) {
    const auto t0 = Clock::now();
    f.map.integrate(session.frames[i], session.reported_poses[i]);
    f.frame_ms.push_back(msSince(t0));
    if ((i + 1) % 10 == 0 || i + 1 == n)
      std::cerr << "demo: fused " << label << " frame " << i + 1 << "/" << n << "\n";
  }
  return f;
}

// One row of the markdown score table.
std::string scoreRow(const char* name, const SideScore& s) {
  char buf[200];
  std::snprintf(buf, sizeof(buf), "| %s | %.3f | %.3f | %.3f | %d | %d | %d | %d |\n", name,
                s.precision, s.recall, s.f1, s.missed, s.wrong, s.gt_objects, s.predicted_clusters);
  return buf;
}

void writeReportMarkdown(const std::string& path, const std::string& scene_name, unsigned seed,
                         const sim::Scene& scene, const EvalResult& e, const ChangeSet& set,
                         const nlohmann::json& timing, const std::vector<std::string>& pictures) {
  io::writeFileAtomic(path, [&](std::ostream& out) {
    out << "# planesdf demo\n\n";
    out << "Scene `" << scene_name << "`, seed " << seed << ": " << scene.reference.objects.size()
        << " objects in the reference session, " << scene.current.objects.size()
        << " in the current one. Changes made by the simulator:\n\n";
    for (const sim::Change& c : scene.changes) {
      out << "- " << sim::toString(c.kind) << ": reference objects";
      for (int id : c.reference_ids) out << " " << id;
      out << ", current objects";
      for (int id : c.current_ids) out << " " << id;
      out << "\n";
    }
    out << "\n## Scores (`planesdf eval`, tolerance one voxel)\n\n";
    out << "| side | Pr | Re | F1 | M | W | GT objects | predicted clusters |\n";
    out << "|---|---|---|---|---|---|---|---|\n";
    out << scoreRow("removed", e.removed) << scoreRow("added", e.added)
        << scoreRow("pooled", e.pooled);
    out << "\n## Events (`detect/changes.json`)\n\n";
    out << "| id | type | plane | centroid (m) | points | confidence "
           "|\n|---|---|---|---|---|---|\n";
    for (const ChangeEvent& ev : set.events) {
      const Eigen::Vector3d& c = ev.primary().centroid;
      char buf[200];
      std::snprintf(buf, sizeof(buf), "| %d | %s | %d | (%.3f, %.3f, %.3f) | %zu | %.2f |\n", ev.id,
                    toString(ev.type), ev.planeId(), c.x(), c.y(), c.z(), ev.numPoints(),
                    ev.confidence);
      out << buf;
    }
    out << "\n## Timings\n\n";
    for (const auto& [key, value] : timing.items()) out << "- " << key << ": " << value << "\n";
    out << "\n## Pictures\n\n";
    out << "Changed points: `detect/removed_points.ply`, `detect/added_points.ply` (coloured by "
           "type, `change_id` per point). Per plane pair (source to target), every stage of the "
           "comparison is in `detect/planes/`.\n\n";
    for (const std::string& p : pictures)
      out << "### " << p << "\n\n![" << p << "](" << p << ")\n\n";
  });
}

}  // namespace

int runDemo(const DemoArgs& args) {
  const auto t_start = Clock::now();
  const fs::path out(args.out);
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) throw Error(args.out, "cannot create the output folder: " + ec.message());

  // 1. Simulate (and keep the `planesdf simulate` folder, so every step can be re-run by hand).
  auto t0 = Clock::now();
  const sim::Scene scene = sim::makePreset(args.scene, args.seed);
  sim::SimulateOptions sim_options;
  sim_options.progress = [](const std::string& msg) { std::cerr << "demo: " << msg << "\n"; };
  const sim::Simulation simulation = sim::simulate(scene, sim_options);
  sim::writeSimulation((out / "sim").string(), scene, simulation);
  const double simulate_ms = msSince(t0);

  // 2. Fuse both sessions frame by frame (z up, as the simulator's world).
  const Config cfg;
  t0 = Clock::now();
  Fused reference = fuseSession(simulation.reference, cfg, "reference");
  Fused current = fuseSession(simulation.current, cfg, "current");
  const double fuse_ms = msSince(t0);
  reference.map.save((out / "reference.psdf").string());
  current.map.save((out / "current.psdf").string());

  // 3. Detect.
  DetectOptions detect_options;
  detect_options.keep_stages = true;
  const ChangeSet set = detectChanges(reference.map, current.map, cfg, detect_options);
  const std::string detect_dir = (out / "detect").string();
  writeChangeOutputs(detect_dir, set);

  // 4. Evaluate against the simulator's ground truth, as `planesdf eval` does.
  const EvalResult e =
      evaluateChanges(io::readPly(detect_dir + "/removed_points.ply"),
                      io::readPly(detect_dir + "/added_points.ply"), simulation.reference.gt,
                      simulation.current.gt, cfg.voxel_size);

  std::vector<double> all_ms = reference.frame_ms;
  all_ms.insert(all_ms.end(), current.frame_ms.begin(), current.frame_ms.end());
  nlohmann::ordered_json timing;
  timing["simulate_ms"] = simulate_ms;
  timing["fuse_ms"] = fuse_ms;
  timing["frames"] = all_ms.size();
  timing["integrate_ms_median"] = quantile(all_ms, 0.5);
  timing["detect_ms"] = set.milliseconds;
  timing["total_ms"] = msSince(t_start);

  nlohmann::ordered_json report = nlohmann::ordered_json::parse(evalToJson(e));
  report["scene"] = args.scene;
  report["seed"] = args.seed;
  report["events"] = set.events.size();
  report["timings"] = timing;
  io::writeFileAtomic((out / "report.json").string(),
                      [&](std::ostream& os) { os << report.dump(2) << "\n"; });

  // Pictures for the report: each pair's heights, the raw eq. 2 mask and the validated blobs.
  std::vector<std::string> pictures;
  for (const auto& entry : fs::directory_iterator(fs::path(detect_dir) / "planes")) {
    const std::string name = entry.path().filename().string();
    for (const char* stage : {"_source_height.png", "_raw.png", "_validated.png"})
      if (name.size() > std::string(stage).size() &&
          name.compare(name.size() - std::string(stage).size(), std::string::npos, stage) == 0)
        pictures.push_back("detect/planes/" + name);
  }
  std::sort(pictures.begin(), pictures.end());
  writeReportMarkdown((out / "report.md").string(), args.scene, args.seed, scene, e, set,
                      nlohmann::json(timing), pictures);

  std::printf("planesdf demo: scene %s, seed %u, %zu + %zu frames -> %s\n", args.scene.c_str(),
              args.seed, simulation.reference.frames.size(), simulation.current.frames.size(),
              args.out.c_str());
  std::printf("%-8s %6s %6s %6s %4s %4s\n", "side", "Pr", "Re", "F1", "M", "W");
  for (const auto& [name, s] : {std::pair<const char*, SideScore>{"removed", e.removed},
                                {"added", e.added},
                                {"pooled", e.pooled}})
    std::printf("%-8s %6.3f %6.3f %6.3f %4d %4d\n", name, s.precision, s.recall, s.f1, s.missed,
                s.wrong);
  std::printf("%zu events; integrate %.1f ms/frame (median of %zu), detect %.0f ms, total %.1f s\n",
              set.events.size(), quantile(all_ms, 0.5), all_ms.size(), set.milliseconds,
              msSince(t_start) / 1000.0);
  std::printf("report: %s, %s\n", (out / "report.md").string().c_str(),
              (out / "report.json").string().c_str());
  return kExitOk;
}

}  // namespace planesdf::cli
