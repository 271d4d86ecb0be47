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

  // demo
  std::string demo_out = "planesdf_demo", demo_scene = "tabletop";
  unsigned demo_seed = 1;
  auto* demo = app.add_subcommand("demo", "Simulate a scene pair, fuse, detect and evaluate");
  demo->add_option("--out", demo_out, "Output folder")->capture_default_str();
  demo->add_option("--scene", demo_scene, "tabletop or room")
      ->check(CLI::IsMember({"tabletop", "room"}))
      ->capture_default_str();
  demo->add_option("--seed", demo_seed, "Random seed")->capture_default_str();

  // simulate
  std::string sim_scene, sim_out;
  unsigned sim_seed = 1;
  auto* simulate =
      app.add_subcommand("simulate", "Render a synthetic session pair with ground truth");
  simulate->add_option("--scene", sim_scene, "tabletop, room or a scene FILE.json")->required();
  simulate->add_option("--seed", sim_seed, "Random seed")->capture_default_str();
  simulate->add_option("--out", sim_out, "Output folder")->required();
  simulate->footer(
      "Writes into the --out folder: reference/ and current/ (TUM folders, reported poses),\n"
      "reference.ply and current.ply (whole-scene clouds), reference_recon.ply and\n"
      "current_recon.ply (TSDF reconstructions, 7 mm voxels), reference_mesh.ply and\n"
      "current_mesh.ply (their meshes), gt/reference.ply, gt/current.ply, gt/reference_recon.ply\n"
      "and gt/current_recon.ply (the points on changed objects, int object_id; the _recon ones\n"
      "also label the meshes' vertices), scene.json.");

  // fuse
  FuseArgs fuse_args;
  auto* fuse = app.add_subcommand("fuse", "Build a PlaneSDF map of one session");
  fuse->add_option("INPUT", fuse_args.input, "Scene cloud, TUM folder, .psdf map or .rawlog")
      ->required();
  fuse->add_option("--out", fuse_args.out, "Output map (.psdf)")->required();
  fuse->add_option("--pictures", fuse_args.pictures,
                   "Also write each plane's height map and object map as PNGs into this folder");
  fuse->add_option("--config", fuse_args.pipeline.config_file,
                   "JSON file with Config parameters (explicit flags override it)");
  addPipelineOptions(fuse, fuse_args.pipeline);

  // detect
  DetectArgs det_args;
  auto* detect = app.add_subcommand("detect", "Detect changes between two sessions");
  detect->add_option("REFERENCE", det_args.reference, "Reference session (old)")->required();
  detect->add_option("CURRENT", det_args.current, "Current session (new)")->required();
  detect->add_option("--out", det_args.out, "Output folder")->required();
  detect->add_option("--config", det_args.pipeline.config_file,
                     "JSON file with Config parameters (explicit flags override it)");
  detect->add_flag("-v,--verbose", det_args.verbose,
                   "Per plane pair: registration, blobs and their 3D validation on stderr");
  addPipelineOptions(detect, det_args.pipeline);

  // eval
  EvalArgs eval_args;
  auto* eval = app.add_subcommand("eval", "Score a detect output against ground truth");
  eval->add_option("DETECT_DIR", eval_args.detect_dir, "Output folder of planesdf detect")
      ->required();
  eval->add_option("--gt-reference", eval_args.gt_reference, "GT PLY of removed points")
      ->required();
  eval->add_option("--gt-current", eval_args.gt_current, "GT PLY of added points")->required();
  eval->add_option("--tol", eval_args.tol, "Match distance (m), default one voxel")
      ->capture_default_str();
  eval->add_flag("--json", eval_args.json, "Print the figures as one JSON object");

  // bench
  BenchArgs bench_args;
  if (const char* mosd = std::getenv("PLANESDF_MOSD_DIR")) bench_args.mosd_dir = mosd;
  auto* bench = app.add_subcommand(
      "bench",
      "End-to-end benchmark on a simulated tabletop sequence (PlaneSDF vs OctoMap), or with "
      "--suite the comparison with the baselines on simulated and mOSD pairs");
  bench->add_option("--frames", bench_args.frames,
                    "Frames per session (default: the whole sequence; --suite: 12)");
  bench->add_option("--json", bench_args.json, "Write the figures as JSON (atomically)");
  bench
      ->add_option("--reserve-mb", bench_args.reserve_mb,
                   "Block memory each tabletop map faults in before its frames "
                   "(Map::reserveMemory; 0: none)")
      ->capture_default_str()
      ->check(CLI::Range(0, 65536));
  bench->add_option("--suite", bench_args.suite,
                    "Run the comparison suite and write OUT_DIR/comparison.md and .json");
  bench->add_option("--sim-pairs", bench_args.sim_pairs, "Suite: simulated pairs")
      ->capture_default_str();
  bench->add_option("--room-pairs", bench_args.room_pairs, "Suite: simulated room pairs")
      ->check(CLI::NonNegativeNumber);
  bench
      ->add_option("--room-forms", bench_args.room_forms,
                   "Suite: input forms of the room pairs (streams raw recon mesh)")
      ->delimiter(',');
  bench->add_option("--mosd-pairs", bench_args.mosd_pairs, "Suite: mOSD pairs (first n)")
      ->capture_default_str();
  bench
      ->add_option("--mosd", bench_args.mosd_dir,
                   "Suite: the mOSD folder (holds pairs.tsv; default: env PLANESDF_MOSD_DIR)")
      ->capture_default_str();
  bench
      ->add_option("--octomap-stride", bench_args.octomap_stride,
                   "Suite: pixel stride of simulated frames inserted into OctoMap")
      ->capture_default_str();

  bench->add_flag("--stream", bench_args.stream,
                  "The incremental ChangeDetector on simulated streams: notifications, latency, "
                  "update cost, final events against detect");
  bench
      ->add_option("--stream-runs", bench_args.stream_runs,
                   "Stream: PRESET:SEED runs (tabletop:7,room:11)")
      ->delimiter(',');
  bench->add_option("--update-every", bench_args.update_every, "Stream: frames between updates")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  bench
      ->add_option("--settle-frames", bench_args.settle_frames,
                   "Stream: Config::event_settle_frames (default: the Config's)")
      ->check(CLI::Range(0, 100000));

  // info: check that an input loads and show what it holds
  std::string info_input;
  auto* info = app.add_subcommand("info", "Show what a session input or map holds");
  info->add_option("INPUT", info_input, "Scene cloud, TUM folder, .psdf map or .rawlog")
      ->required();

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? kExitOk : kExitUsage;
  }

  // What a run that failed below the library's own checks was working on, for its error line.
  const auto subject = [&]() -> std::string {
    if (*info) return info_input;
    if (*fuse) return "fusing " + fuse_args.input;
    if (*eval) return "evaluating " + eval_args.detect_dir;
    if (*demo) return "demo into " + demo_out;
    if (*simulate) return "simulating " + sim_scene + " into " + sim_out;
    if (*detect) return "detecting " + det_args.reference + " against " + det_args.current;
    return "bench";
  };
  try {
    if (*info) return runInfo(info_input);
    if (*fuse) return runFuse(fuse_args);
    if (*eval) return runEval(eval_args);
    if (*demo) return runDemo({demo_out, demo_scene, demo_seed});
    if (*simulate)
      return runSimulate({sim_scene, sim_seed, simulate->count("--seed") > 0, sim_out});
    if (*detect) return runDetect(det_args);
    if (*bench) return runBench(bench_args);
  } catch (const planesdf::Error& e) {  // names the file and the problem: one line, exit 1
    std::cerr << "planesdf: error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    std::cerr << "planesdf: error: " << subject() << ": out of memory (lower the input's extent, "
              << "raise --voxel or set --memory-limit-mb)\n";
    return kExitBadInput;
  } catch (const std::exception& e) {  // from a library underneath (OpenCV, the C++ library)
    std::cerr << "planesdf: error: " << subject() << ": " << e.what() << "\n";
    return kExitBadInput;
  }
  return kExitUsage;
}
