#pragma once
// The subcommands of the planesdf CLI, one file each (cmd_<name>.cpp). main.cpp parses the
// arguments into these structs and maps planesdf::Error to exit code 1.

#include <functional>
#include <string>
#include <vector>

#include "planesdf/config.hpp"

namespace planesdf::cli {

constexpr int kExitOk = 0;
constexpr int kExitBadInput = 1;
constexpr int kExitUsage = 2;  ///< usage errors and subcommands that are not implemented yet

/// Parameters shared by every subcommand that builds maps (design.md, "Pipeline"), as given on the
/// line.
struct PipelineArgs {
  Config cfg;
  /// "auto", "X,Y,Z", or empty: +z, except for an organised cloud given in its own camera
  /// frame (identity VIEWPOINT), where gravity cannot be +z (the optical axis) and auto is used.
  std::string up;
  std::string intrinsics;   ///< "fx,fy,cx,cy[,width,height]" for TUM folders
  std::string config_file;  ///< --config FILE: JSON parameters under the explicit flags
  /// Copies the value of each flag given on the command line from one Config to another (so a
  /// --config file can sit underneath the explicit flags).
  std::vector<std::function<void(Config& dst, const Config& src)>> given;
};

/// The Config of a run: --config file (or the defaults), then the flags given explicitly, then
/// --up. Throws planesdf::Error("--up", ...) on a malformed up axis, and names the file or
/// "command line" on an invalid parameter.
Config resolveConfig(const PipelineArgs& args);
/// True when neither --up nor the --config file chooses the up axis (loadSession may then pick
/// --up auto for organised clouds in their own camera frame).
bool upDefaulted(const PipelineArgs& args);

struct EvalArgs {
  std::string detect_dir;
  std::string gt_reference;
  std::string gt_current;
  double tol = 0.007;
  bool json = false;
};
int runEval(const EvalArgs& args);

struct FuseArgs {
  std::string input;
  std::string out;
  std::string pictures;  ///< optional folder for height-map / object-map PNGs
  PipelineArgs pipeline;
};
int runFuse(const FuseArgs& args);

int runInfo(const std::string& input);

struct DemoArgs {
  std::string out = "planesdf_demo";
  std::string scene = "tabletop";
  unsigned seed = 1;
};
int runDemo(const DemoArgs& args);

struct SimulateArgs {
  std::string scene;  ///< "tabletop", "room" or a scene JSON file
  unsigned seed = 1;
  bool seed_given = false;  ///< --seed was on the line (re-seeds the noise of a scene file)
  std::string out;
};
int runSimulate(const SimulateArgs& args);

struct DetectArgs {
  std::string reference;
  std::string current;
  std::string out;
  bool verbose = false;  ///< per plane pair: blobs and their 3D validation on stderr
  PipelineArgs pipeline;
};
int runDetect(const DetectArgs& args);

/// Seed of the simulated tabletop sequence `planesdf bench` runs on (fixed, so runs compare).
constexpr unsigned kBenchSeed = 7;

struct BenchArgs {
  int frames = 0;       ///< frames per session (0: the whole sequence; suite: 12)
  std::string json;     ///< --json FILE
  std::string suite;    ///< --suite DIR: the comparison suite instead of the benchmark
  int sim_pairs = 35;   ///< suite: simulated pairs
  int mosd_pairs = 21;  ///< suite: mOSD pairs (the first n of pairs.tsv)
  int room_pairs = 21;  ///< suite: simulated room pairs
  /// suite: the input forms each room pair runs in (streams, raw, recon, mesh)
  std::vector<std::string> room_forms = {"streams", "raw", "recon", "mesh"};
  std::string mosd_dir;    ///< suite: folder with pairs.tsv
  int octomap_stride = 8;  ///< suite: pixel stride of simulated frames into OctoMap
  int reserve_mb = 128;    ///< block memory each tabletop map reserves before fusing (MiB)
  int threads = 0;         ///< Config::threads of the benchmark (0: every CPU)
  int load = 0;            ///< busy processes beside the benchmark (a host's other work)
  bool stream = false;     ///< --stream: the incremental detector on simulated streams
  /// stream: the presets and seeds to run, "PRESET:SEED"
  std::vector<std::string> stream_runs = {"tabletop:7", "room:11"};
  int update_every = 1;    ///< stream: frames between ChangeDetector::update() calls
  int settle_frames = -1;  ///< stream: Config::event_settle_frames (-1: the default)
};
int runBench(const BenchArgs& args);
/// `bench --suite DIR` (cmd_bench_suite.cpp).
int runSuite(const BenchArgs& args);
/// `bench --stream` (cmd_bench_stream.cpp).
int runStreamBench(const BenchArgs& args);

}  // namespace planesdf::cli
