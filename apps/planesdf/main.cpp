// planesdf: the command-line tool. One executable with the subcommands of docs/usage.md; each
// subcommand lives in cmd_<name>.cpp.
//
// Exit codes: 0 success; 1 bad input or a failed run (one line on stderr naming the file and
// what is wrong); 2 usage error.

#include <CLI/CLI.hpp>

#include <cstdlib>
#include <iostream>
#include <new>
#include <string>

#include "commands.hpp"
#include "planesdf/error.hpp"
#include "planesdf/memory.hpp"

namespace {
using namespace planesdf::cli;
using planesdf::Config;

/// A Config flag: bound to o.cfg.*member, and remembered so a --config file can sit under it.
template <class T>
void addParam(CLI::App* app, PipelineArgs& o, const std::string& flag, T Config::*member,
              const std::string& help) {
  CLI::Option* opt = app->add_option(flag, o.cfg.*member, help)->capture_default_str();
  o.given.push_back([opt, member](Config& dst, const Config& src) {
    if (opt->count() > 0) dst.*member = src.*member;
  });
}

void addPipelineOptions(CLI::App* app, PipelineArgs& o) {
  app->add_option("--up", o.up,
                  "Up axis: auto or X,Y,Z (default 0,0,1; auto for an organised cloud in its "
                  "camera frame)");
  addParam(app, o, "--voxel", &Config::voxel_size, "Voxel size (m)");
  addParam(app, o, "--band", &Config::fuse_band, "Fusion band above each plane (m)");
  addParam(app, o, "--delta-h", &Config::delta_h, "Height change threshold δh (m)");
  addParam(app, o, "--delta-n", &Config::delta_n, "Registration normal cosine δn");
  addParam(app, o, "--delta-d", &Config::delta_d, "Registration offset gap δd (m)");
  addParam(app, o, "--alpha", &Config::alpha, "Similarity scale α");
  addParam(app, o, "--delta-blob", &Config::delta_blob, "Blob similarity threshold δ_blob");
  addParam(app, o, "--h-obj", &Config::h_obj, "Object height threshold (m)");
  addParam(app, o, "--threads", &Config::threads, "Threads (0 = all cores)");
  addParam(app, o, "--memory-limit-mb", &Config::memory_limit_mb,
           "Memory budget of the large arrays in MB (0 = half the physical memory)");
  app->add_option("--intrinsics", o.intrinsics,
                  "fx,fy,cx,cy[,width,height] for TUM folders without intrinsics.txt");
}

CLI::App* addDemo(CLI::App& app, DemoArgs& a) {
  auto* cmd = app.add_subcommand("demo", "Simulate a scene pair, fuse, detect and evaluate");
  cmd->add_option("--out", a.out, "Output folder")->capture_default_str();
  cmd->add_option("--scene", a.scene, "tabletop or room")
      ->check(CLI::IsMember({"tabletop", "room"}))
      ->capture_default_str();
  cmd->add_option("--seed", a.seed, "Random seed")->capture_default_str();
  return cmd;
}

CLI::App* addSimulate(CLI::App& app, SimulateArgs& a) {
  auto* cmd = app.add_subcommand("simulate", "Render a synthetic session pair with ground truth");
  cmd->add_option("--scene", a.scene, "tabletop, room or a scene FILE.json")->required();
  cmd->add_option("--seed", a.seed, "Random seed")->capture_default_str();
  cmd->add_option("--out", a.out, "Output folder")->required();
  cmd->footer(
      "Writes into the --out folder: reference/ and current/ (TUM folders, reported poses),\n"
      "reference.ply and current.ply (whole-scene clouds), reference_recon.ply and\n"
      "current_recon.ply (TSDF reconstructions, 7 mm voxels), reference_mesh.ply and\n"
      "current_mesh.ply (their meshes), gt/reference.ply, gt/current.ply, gt/reference_recon.ply\n"
      "and gt/current_recon.ply (the points on changed objects, int object_id; the _recon ones\n"
      "also label the meshes' vertices), scene.json.");
  return cmd;
}

CLI::App* addFuse(CLI::App& app, FuseArgs& a) {
  auto* cmd = app.add_subcommand("fuse", "Build a PlaneSDF map of one session");
  cmd->add_option("INPUT", a.input, "Scene cloud, TUM folder, .psdf map or .rawlog")->required();
  cmd->add_option("--out", a.out, "Output map (.psdf)")->required();
  cmd->add_option("--pictures", a.pictures,
                  "Also write each plane's height map and object map as PNGs into this folder");
  cmd->add_option("--config", a.pipeline.config_file,
                  "JSON file with Config parameters (explicit flags override it)");
  addPipelineOptions(cmd, a.pipeline);
  return cmd;
}

CLI::App* addDetect(CLI::App& app, DetectArgs& a) {
  auto* cmd = app.add_subcommand("detect", "Detect changes between two sessions");
  cmd->add_option("REFERENCE", a.reference, "Reference session (old)")->required();
  cmd->add_option("CURRENT", a.current, "Current session (new)")->required();
  cmd->add_option("--out", a.out, "Output folder")->required();
  cmd->add_option("--config", a.pipeline.config_file,
                  "JSON file with Config parameters (explicit flags override it)");
  cmd->add_flag("-v,--verbose", a.verbose,
                "Per plane pair: registration, blobs and their 3D validation on stderr");
  addPipelineOptions(cmd, a.pipeline);
  return cmd;
}

CLI::App* addEval(CLI::App& app, EvalArgs& a) {
  auto* cmd = app.add_subcommand("eval", "Score a detect output against ground truth");
  cmd->add_option("DETECT_DIR", a.detect_dir, "Output folder of planesdf detect")->required();
  cmd->add_option("--gt-reference", a.gt_reference, "GT PLY of removed points")->required();
  cmd->add_option("--gt-current", a.gt_current, "GT PLY of added points")->required();
  cmd->add_option("--tol", a.tol, "Match distance (m), default one voxel")->capture_default_str();
  cmd->add_flag("--json", a.json, "Print the figures as one JSON object");
  return cmd;
}

/// The suite's and the stream run's options of `bench`.
void addBenchModes(CLI::App* cmd, BenchArgs& a) {
  cmd->add_option("--suite", a.suite,
                  "Run the comparison suite and write OUT_DIR/comparison.md and .json");
  cmd->add_option("--sim-pairs", a.sim_pairs, "Suite: simulated pairs")->capture_default_str();
  cmd->add_option("--room-pairs", a.room_pairs, "Suite: simulated room pairs")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--room-forms", a.room_forms,
                  "Suite: input forms of the room pairs (streams raw recon mesh)")
      ->delimiter(',');
  cmd->add_option("--mosd-pairs", a.mosd_pairs, "Suite: mOSD pairs (first n)")
      ->capture_default_str();
  cmd->add_option("--mosd", a.mosd_dir,
                  "Suite: the mOSD folder (holds pairs.tsv; default: env PLANESDF_MOSD_DIR)")
      ->capture_default_str();
  cmd->add_option("--octomap-stride", a.octomap_stride,
                  "Suite: pixel stride of simulated frames inserted into OctoMap")
      ->capture_default_str();
  cmd->add_flag("--stream", a.stream,
                "The incremental ChangeDetector on simulated streams: notifications, latency, "
                "update cost, final events against detect");
  cmd->add_option("--stream-runs", a.stream_runs, "Stream: PRESET:SEED runs (tabletop:7,room:11)")
      ->delimiter(',');
  cmd->add_option("--update-every", a.update_every, "Stream: frames between updates")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--settle-frames", a.settle_frames,
                  "Stream: Config::event_settle_frames (default: the Config's)")
      ->check(CLI::Range(0, 100000));
}

CLI::App* addBench(CLI::App& app, BenchArgs& a) {
  if (const char* mosd = std::getenv("PLANESDF_MOSD_DIR")) a.mosd_dir = mosd;
  auto* cmd = app.add_subcommand(
      "bench",
      "End-to-end benchmark on a simulated tabletop sequence (PlaneSDF vs OctoMap), or with "
      "--suite the comparison with the baselines on simulated and mOSD pairs");
  cmd->add_option("--frames", a.frames,
                  "Frames per session (default: the whole sequence; --suite: 12)");
  cmd->add_option("--json", a.json, "Write the figures as JSON (atomically)");
  cmd->add_option("--reserve-mb", a.reserve_mb,
                  "Block memory each tabletop map faults in before its frames "
                  "(Map::reserveMemory; 0: none)")
      ->capture_default_str()
      ->check(CLI::Range(0, 65536));
  cmd->add_option("--threads", a.threads, "Threads of the pipeline (0: every CPU)")
      ->capture_default_str()
      ->check(CLI::Range(0, planesdf::kMaxThreads));
  cmd->add_option("--load", a.load,
                  "Busy processes that compete for the CPU while the benchmark runs")
      ->capture_default_str()
      ->check(CLI::Range(0, 64));
  addBenchModes(cmd, a);
  return cmd;
}

/// Every subcommand's arguments and its CLI11 node (set by parsing).
struct Commands {
  DemoArgs demo;
  SimulateArgs simulate;
  FuseArgs fuse;
  DetectArgs detect;
  EvalArgs eval;
  BenchArgs bench;
  std::string info_input;
  CLI::App *demo_cmd = nullptr, *simulate_cmd = nullptr, *fuse_cmd = nullptr, *detect_cmd = nullptr,
           *eval_cmd = nullptr, *bench_cmd = nullptr, *info_cmd = nullptr;
};

void addCommands(CLI::App& app, Commands& c) {
  c.demo_cmd = addDemo(app, c.demo);
  c.simulate_cmd = addSimulate(app, c.simulate);
  c.fuse_cmd = addFuse(app, c.fuse);
  c.detect_cmd = addDetect(app, c.detect);
  c.eval_cmd = addEval(app, c.eval);
  c.bench_cmd = addBench(app, c.bench);
  c.info_cmd = app.add_subcommand("info", "Show what a session input or map holds");
  c.info_cmd->add_option("INPUT", c.info_input, "Scene cloud, TUM folder, .psdf map or .rawlog")
      ->required();
}

/// What a run that failed below the library's own checks was working on, for its error line.
std::string subject(const Commands& c) {
  if (*c.info_cmd) return c.info_input;
  if (*c.fuse_cmd) return "fusing " + c.fuse.input;
  if (*c.eval_cmd) return "evaluating " + c.eval.detect_dir;
  if (*c.demo_cmd) return "demo into " + c.demo.out;
  if (*c.simulate_cmd) return "simulating " + c.simulate.scene + " into " + c.simulate.out;
  if (*c.detect_cmd) return "detecting " + c.detect.reference + " against " + c.detect.current;
  return "bench";
}

int dispatch(Commands& c) {
  if (*c.info_cmd) return runInfo(c.info_input);
  if (*c.fuse_cmd) return runFuse(c.fuse);
  if (*c.eval_cmd) return runEval(c.eval);
  if (*c.demo_cmd) return runDemo(c.demo);
  if (*c.simulate_cmd) {
    c.simulate.seed_given = c.simulate_cmd->count("--seed") > 0;
    return runSimulate(c.simulate);
  }
  if (*c.detect_cmd) return runDetect(c.detect);
  if (*c.bench_cmd) return runBench(c.bench);
  return kExitUsage;
}

}  // namespace

int main(int argc, char** argv) {
  // Freed grids stay in the process for the next frame or detection (see memory.hpp).
  planesdf::retainFreedMemory();
  CLI::App app{
      "planesdf: PlaneSDF-based change detection between mapping sessions.\n"
      "INPUT, REFERENCE and CURRENT are .ply/.pcd scene clouds, TUM RGB-D folders, .psdf maps or "
      ".rawlog files of 3D range scans (MRPT builds)."};
  app.require_subcommand(1);
  app.set_version_flag("--version", "planesdf 0.1.0");
  Commands commands;
  addCommands(app, commands);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? kExitOk : kExitUsage;
  }
  try {
    return dispatch(commands);
  } catch (const planesdf::Error& e) {  // names the file and the problem: one line, exit 1
    std::cerr << "planesdf: error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    std::cerr << "planesdf: error: " << subject(commands) << ": out of memory (lower the input's "
              << "extent, raise --voxel or set --memory-limit-mb)\n";
    return kExitBadInput;
  } catch (const std::exception& e) {  // from a library underneath (OpenCV, the C++ library)
    std::cerr << "planesdf: error: " << subject(commands) << ": " << e.what() << "\n";
    return kExitBadInput;
  }
}
