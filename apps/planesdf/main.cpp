// planesdf: the command-line tool. One executable with the subcommands of DESIGN §3.
//
// Exit codes: 0 success; 1 bad input or a failed run (one line on stderr naming the file and
// what is wrong); 2 usage error or a subcommand that is not implemented yet.

#include <CLI/CLI.hpp>

#include <cstdio>
#include <iostream>
#include <sstream>
#include <string>

#include "planesdf/config.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/io/tum.hpp"

namespace {

constexpr int kExitBadInput = 1;
constexpr int kExitNotImplemented = 2;

/// Options shared by every subcommand that builds maps: the parameters of DESIGN §2.
struct PipelineOptions {
  planesdf::Config cfg;
  std::string up = "0,0,1";
  std::string intrinsics;  ///< "fx,fy,cx,cy[,width,height]" for TUM folders without intrinsics.txt
};

void addPipelineOptions(CLI::App* app, PipelineOptions& o) {
  app->add_option("--up", o.up, "Up axis: auto or X,Y,Z")->capture_default_str();
  app->add_option("--voxel", o.cfg.voxel_size, "Voxel size (m)")->capture_default_str();
  app->add_option("--band", o.cfg.fuse_band, "Fusion band above each plane (m)")
      ->capture_default_str();
  app->add_option("--delta-h", o.cfg.delta_h, "Height change threshold δh (m)")
      ->capture_default_str();
  app->add_option("--delta-n", o.cfg.delta_n, "Registration normal cosine δn")
      ->capture_default_str();
  app->add_option("--delta-d", o.cfg.delta_d, "Registration offset gap δd (m)")
      ->capture_default_str();
  app->add_option("--alpha", o.cfg.alpha, "Similarity scale α")->capture_default_str();
  app->add_option("--delta-blob", o.cfg.delta_blob, "Blob similarity threshold δ_blob")
      ->capture_default_str();
  app->add_option("--h-obj", o.cfg.h_obj, "Object height threshold (m)")->capture_default_str();
  app->add_option("--threads", o.cfg.threads, "Fusion threads (0 = all cores)")
      ->capture_default_str();
  app->add_option("--intrinsics", o.intrinsics,
                  "fx,fy,cx,cy[,width,height] for TUM folders without intrinsics.txt");
}

int notImplemented(const std::string& command, const std::string& issue) {
  std::cerr << "planesdf " << command << ": not implemented yet (" << issue << ")\n";
  return kExitNotImplemented;
}

/// `planesdf info INPUT`: what a cloud file or TUM folder holds; checks that it loads.
int runInfo(const std::string& input) {
  if (planesdf::io::isTumFolder(input)) {
    const auto seq = planesdf::io::readTumSequence(input);
    const auto& k = seq.intrinsics;
    std::cout << "TUM RGB-D sequence " << input << "\n"
              << "  frames:      " << seq.frames.size() << " (" << seq.dropped_frames
              << " without a pose dropped)\n"
              << "  intrinsics:  fx=" << k.fx << " fy=" << k.fy << " cx=" << k.cx << " cy=" << k.cy
              << " " << k.width << "x" << k.height << "\n"
              << "  depth scale: " << seq.depth_scale << " per metre\n";
    return 0;
  }
  const planesdf::PointCloud cloud = planesdf::io::readSceneCloud(input);
  Eigen::AlignedBox3f box;
  for (const auto& p : cloud.points)
    if (planesdf::PointCloud::isValid(p)) box.extend(p);
  std::cout << "point cloud " << input << "\n"
            << "  points:    " << cloud.size() << " (" << cloud.countValid() << " valid)\n"
            << "  layout:    " << (cloud.isOrganized() ? "organised " : "unorganised ")
            << cloud.width << "x" << cloud.height << "\n"
            << "  normals:   " << (cloud.hasNormals() ? "yes" : "no") << "\n"
            << "  colours:   " << (cloud.hasColors() ? "yes" : "no") << "\n";
  std::cout << "  fields:   ";
  for (const auto& f : cloud.fields) std::cout << " " << f.name;
  std::cout << (cloud.fields.empty() ? " none\n" : "\n");
  if (!box.isEmpty()) {
    const Eigen::IOFormat fmt(4, Eigen::DontAlignCols, " ", " ", "", "", "(", ")");
    std::cout << "  bounds:    " << box.min().transpose().format(fmt) << " .. "
              << box.max().transpose().format(fmt) << "\n";
  }
  const Eigen::Vector3d t = cloud.sensor_pose.translation();
  std::cout << "  sensor at: (" << t.x() << " " << t.y() << " " << t.z() << ")\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "planesdf: PlaneSDF-based change detection between mapping sessions.\n"
      "INPUT, REFERENCE and CURRENT are .ply/.pcd scene clouds, TUM RGB-D folders or .psdf maps."};
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

  // fuse
  std::string fuse_input, fuse_out;
  PipelineOptions fuse_opts;
  auto* fuse = app.add_subcommand("fuse", "Build a PlaneSDF map of one session");
  fuse->add_option("INPUT", fuse_input, "Scene cloud, TUM folder or .psdf map")->required();
  fuse->add_option("--out", fuse_out, "Output map (.psdf)")->required();
  addPipelineOptions(fuse, fuse_opts);

  // detect
  std::string det_ref, det_cur, det_out, det_config;
  PipelineOptions det_opts;
  auto* detect = app.add_subcommand("detect", "Detect changes between two sessions");
  detect->add_option("REFERENCE", det_ref, "Reference session (old)")->required();
  detect->add_option("CURRENT", det_cur, "Current session (new)")->required();
  detect->add_option("--out", det_out, "Output folder")->required();
  detect->add_option("--config", det_config, "JSON file with Config parameters");
  addPipelineOptions(detect, det_opts);

  // eval
  std::string eval_dir, eval_gt_ref, eval_gt_cur;
  double eval_tol = 0.007;
  bool eval_json = false;
  auto* eval = app.add_subcommand("eval", "Score a detect output against ground truth");
  eval->add_option("DETECT_DIR", eval_dir, "Output folder of planesdf detect")->required();
  eval->add_option("--gt-reference", eval_gt_ref, "GT PLY of removed points")->required();
  eval->add_option("--gt-current", eval_gt_cur, "GT PLY of added points")->required();
  eval->add_option("--tol", eval_tol, "Match distance (m), default one voxel")
      ->capture_default_str();
  eval->add_flag("--json", eval_json, "Print the figures as one JSON object");

  // bench
  std::string bench_json;
  auto* bench = app.add_subcommand("bench", "End-to-end benchmark on a simulated sequence");
  bench->add_option("--json", bench_json, "Write the figures as JSON");

  // info (ours, beyond DESIGN §3): check that an input loads and show what it holds
  std::string info_input;
  auto* info = app.add_subcommand("info", "Show what a cloud file or TUM folder holds");
  info->add_option("INPUT", info_input, "Scene cloud or TUM folder")->required();

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : kExitNotImplemented;
  }

  try {
    if (*info) return runInfo(info_input);
    if (*demo) return notImplemented("demo", "the simulator is issue 5");
    if (*simulate) return notImplemented("simulate", "issue 5");
    if (*fuse) return notImplemented("fuse", "issue 3");
    if (*detect) return notImplemented("detect", "issue 4");
    if (*eval) return notImplemented("eval", "issue 4");
    if (*bench) return notImplemented("bench", "issue 7");
  } catch (const planesdf::Error& e) {
    std::cerr << "planesdf: error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "planesdf: error: " << e.what() << "\n";
    return kExitBadInput;
  }
  return kExitNotImplemented;
}
