// `planesdf bench --suite DIR`: the comparison of issue 5 (paper Table I). PlaneSDF detection,
// point-distance differencing and OctoMap occupancy differencing on simulated tabletop pairs
// (every change kind, localisation drift 0 to 3 cm) and on the real mOSD pairs, all scored by
// evaluateChanges from their detect-format outputs; DIR/comparison.md and DIR/comparison.json.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>

#include "commands.hpp"
#include "planesdf/baseline.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"
#include "planesdf/eval.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/io/ply.hpp"
#include "planesdf/map.hpp"
#include "planesdf/sim.hpp"
#include "timing.hpp"
#ifdef PLANESDF_HAVE_OCTOMAP
#include "planesdf/octomap/octomap_baseline.hpp"
#endif

namespace planesdf::cli {
namespace {

using nlohmann::json;

const char* const kPlaneSdf = "PlaneSDF";
const char* const kPointDistance = "Point distance";
const char* const kOctomap = "OctoMap";

/// One method on one pair: its figures (from the files it wrote) and its wall time.
struct MethodRun {
  EvalResult eval;
  double ms = 0.0;
};

struct PairRecord {
  std::string name;
  std::string kind;    ///< simulated: the change kind
  double drift = 0.0;  ///< simulated: localisation error (m)
  std::map<std::string, MethodRun> runs;
};

/// One session as every method needs it: the scene points (world frame) for PlaneSDF and the
/// point-distance baseline, and a way to feed the same input into an OctoMap tree.
struct SessionInput {
  PointCloud cloud;  ///< world frame
  bool camera_frame_organised = false;
  const sim::SessionData* frames = nullptr;  ///< simulated: frames + reported poses
  /// False for a whole-scene cloud without a viewpoint: OctoMap has no rays to carve free space
  /// with (and a ray per point from an invented origin would take hours on a room).
  bool has_rays = true;
};

MethodRun score(const std::string& dir, const PointCloud& gt_ref, const PointCloud& gt_cur,
                double ms, double tol) {
  MethodRun r;
  r.eval = evaluateChanges(io::readPly(dir + "/removed_points.ply"),
                           io::readPly(dir + "/added_points.ply"), gt_ref, gt_cur, tol);
  r.ms = ms;
  return r;
}

Map buildMap(const SessionInput& s, const Config& cfg) {
  if (s.frames != nullptr) {  // as `planesdf detect` does for the simulated TUM folders
    Map map(cfg);
    for (std::size_t i = 0; i < s.frames->frames.size(); ++i)
      map.integrate(s.frames->frames[i], s.frames->reported_poses[i]);
    return map;
  }
  if (s.camera_frame_organised) {  // as `planesdf detect` does for an organised camera-frame cloud
    Config auto_cfg = cfg;
    auto_cfg.up_auto = true;
    return Map::fromCloud(s.cloud, auto_cfg);
  }
  return Map::fromCloud(s.cloud, cfg);
}

#ifdef PLANESDF_HAVE_OCTOMAP
octomap_adapter::OccupancyMap buildTree(const SessionInput& s, const Config& cfg, int stride) {
  octomap_adapter::OccupancyOptions oo;
  oo.resolution = cfg.voxel_size;
  oo.max_range = cfg.max_depth;
  oo.pixel_stride = stride;
  octomap_adapter::OccupancyMap tree(oo);
  if (s.frames != nullptr)
    for (std::size_t i = 0; i < s.frames->frames.size(); ++i)
      tree.insertFrame(s.frames->frames[i], s.frames->reported_poses[i]);
  else
    tree.insertCloud(s.cloud);
  return tree;
}
#endif

/// Runs the three methods on one pair, writing DIR/<method>/{removed,added}_points.ply.
PairRecord runPair(const std::string& dir, const SessionInput& ref, const SessionInput& cur,
                   const PointCloud& gt_ref, const PointCloud& gt_cur, const BenchArgs& args) {
  const Config cfg;
  const double tol = cfg.voxel_size;
  PairRecord rec;
  {
    const auto t0 = Clock::now();
    const Map a = buildMap(ref, cfg);
    const Map b = buildMap(cur, cfg);
    const ChangeSet set = detectChanges(a, b, cfg);
    const double ms = msSince(t0);
    writeChangeOutputs(dir + "/planesdf", set);
    rec.runs[kPlaneSdf] = score(dir + "/planesdf", gt_ref, gt_cur, ms, tol);
  }
  BaselineParams bp;
  bp.voxel = cfg.voxel_size;
  {
    const BaselineResult r = pointDistanceBaseline(ref.cloud, cur.cloud, bp);
    writeBaselineOutputs(dir + "/point_distance", r);
    rec.runs[kPointDistance] = score(dir + "/point_distance", gt_ref, gt_cur, r.milliseconds, tol);
  }
#ifdef PLANESDF_HAVE_OCTOMAP
  if (ref.has_rays && cur.has_rays) {
    const auto t0 = Clock::now();
    const auto ta = buildTree(ref, cfg, args.octomap_stride);
    const auto tb = buildTree(cur, cfg, args.octomap_stride);
    const BaselineResult r = octomap_adapter::octomapBaseline(ref.cloud, ta, cur.cloud, tb, bp);
    const double ms = msSince(t0);
    writeBaselineOutputs(dir + "/octomap", r);
    rec.runs[kOctomap] = score(dir + "/octomap", gt_ref, gt_cur, ms, tol);
  }
#else
  (void)args;
#endif
  return rec;
}

void logPair(const std::string& label, const PairRecord& rec) {
  std::cerr << "suite: " << label;
  for (const auto& [method, run] : rec.runs) {
    char buf[160];
    std::snprintf(buf, sizeof buf, " | %s F1 %.2f M %d W %d %.1f s", method.c_str(),
                  run.eval.pooled.f1, run.eval.pooled.missed, run.eval.pooled.wrong,
                  run.ms / 1000.0);
    std::cerr << buf;
  }
  std::cerr << "\n";
}

// ---- simulated pairs ----------------------------------------------------------------------------

const sim::ChangeKind kKinds[] = {sim::ChangeKind::None,      sim::ChangeKind::Add,
                                  sim::ChangeKind::Remove,    sim::ChangeKind::Move,
                                  sim::ChangeKind::SmallMove, sim::ChangeKind::Swap,
                                  sim::ChangeKind::Replace};
constexpr int kNumKinds = 7;
constexpr int kDriftSteps = 5;        // 0, 0.75, 1.5, 2.25, 3 cm
constexpr double kMaxDrift = 0.03;    // m
constexpr double kMaxDriftDeg = 1.0;  // rotation about the vertical at the largest drift
constexpr std::uint32_t kSeed0 = 1000;
constexpr int kSuiteFrames = 12;  // frames per session (a full orbit, one view every 30 degrees)

/// Writes the pair's scene as ROOT/scenes/NAME.json (ROOT: the suite's sim/ or room/ folder), which
/// `planesdf simulate --scene` renders again.
void saveScene(const std::string& root, const std::string& name, const sim::Scene& scene) {
  std::filesystem::create_directories(root + "/scenes");
  sim::saveSceneJson(root + "/scenes/" + name + ".json", scene);
}

/// The preset's scene for `seed`, or for seed + 100, + 200, ... (updated) when the change does not
/// fit that layout.
sim::Scene suiteScene(const std::string& preset, const sim::PresetOptions& opt,
                      std::uint32_t& seed) {
  for (int attempt = 0;; ++attempt, seed += 100) {
    try {
      return sim::makePreset(preset, seed, opt);
    } catch (const Error&) {
      if (attempt == 9) throw;
    }
  }
}

std::vector<PairRecord> runSimulated(const std::string& root, const BenchArgs& args) {
  std::vector<PairRecord> out;
  for (int k = 0; k < args.sim_pairs; ++k) {
    const sim::ChangeKind kind = kKinds[k % kNumKinds];
    const double f = static_cast<double>((k / kNumKinds) % kDriftSteps) / (kDriftSteps - 1);
    sim::PresetOptions opt;
    opt.changes = {kind};
    opt.localisation_translation = f * kMaxDrift;
    opt.localisation_rotation_deg = f * kMaxDriftDeg;
    opt.frames = args.frames > 0 ? args.frames : kSuiteFrames;
    std::uint32_t seed = kSeed0 + static_cast<std::uint32_t>(k);
    const sim::Scene scene = suiteScene("tabletop", opt, seed);
    const auto t0 = Clock::now();
    const sim::Simulation s = sim::simulate(scene);
    const double sim_ms = msSince(t0);
    char name[64];
    std::snprintf(name, sizeof name, "sim%02d_%s_%.1fcm", k, sim::toString(kind),
                  f * kMaxDrift * 100.0);
    saveScene(root, name, scene);
    SessionInput ref{s.reference.cloud, false, &s.reference};
    SessionInput cur{s.current.cloud, false, &s.current};
    PairRecord rec = runPair(root + "/" + name, ref, cur, s.reference.gt, s.current.gt, args);
    rec.name = name;
    rec.kind = sim::toString(kind);
    rec.drift = f * kMaxDrift;
    char label[160];
    std::snprintf(label, sizeof label, "sim %d/%d %s (seed %u, simulated in %.1f s)", k + 1,
                  args.sim_pairs, name, seed, sim_ms / 1000.0);
    logPair(label, rec);
    out.push_back(std::move(rec));
  }
  return out;
}

// ---- simulated room pairs -----------------------------------------------------------------------

constexpr std::uint32_t kRoomSeed0 = 2000;
constexpr int kRoomDriftSteps = 3;        // 0, 1.5, 3 cm
constexpr double kRoomMaxDriftDeg = 2.0;  // rotation about the vertical at the largest drift

/// The input forms of a room pair: the TUM streams, and the whole-scene clouds a mapper exports.
const char* const kRoomForms[] = {"streams", "raw", "recon", "mesh"};

/// One session of a room pair in `form`. The mesh is written to `dir` and read back as a user's
/// file would be (its vertices; the faces are skipped).
SessionInput roomInput(const std::string& form, const sim::SessionData& s, const std::string& dir,
                       const std::string& label) {
  if (form == "streams") return {s.cloud, false, &s, true};
  if (form == "raw") return {s.cloud, false, nullptr, false};
  if (form == "recon") return {s.reconstruction, false, nullptr, false};
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/" + label + "_mesh.ply";
  io::writePlyMesh(path, s.reconstruction, s.mesh_triangles);
  return {io::readSceneCloud(path), false, nullptr, false};
}

/// Room pairs (varied layouts of the room preset, every change kind, drift 0 to 3 cm and 0 to 2
/// degrees), each run in every form of args.room_forms: form -> pairs.
std::map<std::string, std::vector<PairRecord>> runRooms(const std::string& root,
                                                        const BenchArgs& args) {
  std::map<std::string, std::vector<PairRecord>> out;
  for (int k = 0; k < args.room_pairs; ++k) {
    const sim::ChangeKind kind = kKinds[k % kNumKinds];
    const double f = static_cast<double>((k / kNumKinds) % kRoomDriftSteps) / (kRoomDriftSteps - 1);
    sim::PresetOptions opt;
    opt.changes = {kind};
    opt.localisation_translation = f * kMaxDrift;
    opt.localisation_rotation_deg = f * kRoomMaxDriftDeg;
    opt.frames = args.frames;
    std::uint32_t seed = kRoomSeed0 + static_cast<std::uint32_t>(k);
    const sim::Scene scene = suiteScene("room", opt, seed);
    const auto t0 = Clock::now();
    const sim::Simulation s = sim::simulate(scene);
    const double sim_ms = msSince(t0);
    char name[64];
    std::snprintf(name, sizeof name, "room%02d_%s_%.1fcm", k, sim::toString(kind),
                  f * kMaxDrift * 100.0);
    saveScene(root, name, scene);
    for (const std::string& form : args.room_forms) {
      const std::string dir = root + "/" + form + "/" + name;
      const bool recon = form == "recon" || form == "mesh";
      const SessionInput ref = roomInput(form, s.reference, dir, "reference");
      const SessionInput cur = roomInput(form, s.current, dir, "current");
      PairRecord rec =
          runPair(dir, ref, cur, recon ? s.reference.reconstruction_gt : s.reference.gt,
                  recon ? s.current.reconstruction_gt : s.current.gt, args);
      rec.name = name;
      rec.kind = sim::toString(kind);
      rec.drift = f * kMaxDrift;
      char label[200];
      std::snprintf(label, sizeof label, "room %d/%d %s %s (seed %u, simulated in %.1f s)", k + 1,
                    args.room_pairs, form.c_str(), name, seed, sim_ms / 1000.0);
      logPair(label, rec);
      out[form].push_back(std::move(rec));
    }
  }
  return out;
}

// ---- mOSD pairs ---------------------------------------------------------------------------------

std::vector<PairRecord> runMosd(const std::string& root, const BenchArgs& args) {
  const std::string tsv = args.mosd_dir + "/pairs.tsv";
  std::ifstream in(tsv);
  if (!in) throw Error(tsv, "cannot open the mOSD pair list (give the folder with --mosd)");
  std::string line;
  std::getline(in, line);  // header
  std::vector<PairRecord> out;
  int line_no = 1;
  while (static_cast<int>(out.size()) < args.mosd_pairs && std::getline(in, line)) {
    ++line_no;
    if (line.empty()) continue;
    std::istringstream ss(line);
    std::string group, r, c, gr, gc;
    std::getline(ss, group, '\t');
    std::getline(ss, r, '\t');
    std::getline(ss, c, '\t');
    std::getline(ss, gr, '\t');
    std::getline(ss, gc, '\t');
    if (gc.empty())
      throw Error(tsv, "line " + std::to_string(line_no) + ": expected at least 5 columns");
    const std::string base = args.mosd_dir + "/";
    SessionInput ref{io::readSceneCloud(base + r), true, nullptr};
    SessionInput cur{io::readSceneCloud(base + c), true, nullptr};
    const std::string name =
        std::filesystem::path(r).stem().string() + "__" + std::filesystem::path(c).stem().string();
    PairRecord rec =
        runPair(root + "/" + name, ref, cur, io::readPly(base + gr), io::readPly(base + gc), args);
    rec.name = name;
    logPair("mosd " + std::to_string(out.size() + 1) + "/" + std::to_string(args.mosd_pairs) + " " +
                name,
            rec);
    out.push_back(std::move(rec));
  }
  return out;
}

// ---- tables -------------------------------------------------------------------------------------

struct Summary {
  double pr = 0, pr_sd = 0, re = 0, re_sd = 0, f1 = 0, f1_sd = 0, m = 0, w = 0, seconds = 0;
  int m_total = 0, w_total = 0, pairs = 0;
};

void meanSd(const std::vector<double>& v, double& mean, double& sd) {
  mean = sd = 0.0;
  if (v.empty()) return;
  for (double x : v) mean += x;
  mean /= static_cast<double>(v.size());
  for (double x : v) sd += (x - mean) * (x - mean);
  sd = std::sqrt(sd / static_cast<double>(v.size()));
}

Summary summarise(const std::vector<PairRecord>& pairs, const std::string& method) {
  std::vector<double> pr, re, f1;
  Summary s;
  for (const PairRecord& p : pairs) {
    const auto it = p.runs.find(method);
    if (it == p.runs.end()) continue;
    const SideScore& e = it->second.eval.pooled;
    pr.push_back(e.precision);
    re.push_back(e.recall);
    f1.push_back(e.f1);
    s.m_total += e.missed;
    s.w_total += e.wrong;
    s.seconds += it->second.ms / 1000.0;
    ++s.pairs;
  }
  meanSd(pr, s.pr, s.pr_sd);
  meanSd(re, s.re, s.re_sd);
  meanSd(f1, s.f1, s.f1_sd);
  if (s.pairs > 0) {
    s.m = static_cast<double>(s.m_total) / s.pairs;
    s.w = static_cast<double>(s.w_total) / s.pairs;
    s.seconds /= s.pairs;
  }
  return s;
}

std::vector<std::string> methods() {
#ifdef PLANESDF_HAVE_OCTOMAP
  return {kPlaneSdf, kPointDistance, kOctomap};
#else
  return {kPlaneSdf, kPointDistance};
#endif
}

std::string table(const std::vector<PairRecord>& pairs) {
  if (pairs.empty()) return "(no pairs run)\n";
  std::ostringstream md;
  md << "| Method | Pr | Re | F1 | M | W | runtime / pair (s) |\n"
     << "|---|---|---|---|---|---|---|\n";
  for (const std::string& m : methods()) {
    const Summary s = summarise(pairs, m);
    if (s.pairs == 0) continue;  // not run on this input (OctoMap on clouds without viewpoints)
    char row[256];
    std::snprintf(row, sizeof row,
                  "| %s | %.2f±%.2f | %.2f±%.2f | %.2f±%.2f | %.2f (%d) | %.2f (%d) | %.2f |\n",
                  m.c_str(), s.pr, s.pr_sd, s.re, s.re_sd, s.f1, s.f1_sd, s.m, s.m_total, s.w,
                  s.w_total, s.seconds);
    md << row;
  }
  return md.str();
}

/// Simulated pairs: mean pooled F1 and W per pair of each method, by change kind and by drift.
std::string breakdown(const std::vector<PairRecord>& pairs) {
  if (pairs.empty()) return "";
  std::ostringstream md;
  md << "| group | pairs |";
  for (const std::string& m : methods()) md << " " << m << " F1 (W) |";
  md << "\n|---|---|";
  for (std::size_t i = 0; i < methods().size(); ++i) md << "---|";
  md << "\n";
  const auto rows = [&](const std::string& label, const auto& key) {
    std::map<std::string, std::vector<const PairRecord*>> groups;
    std::vector<std::string> order;
    for (const PairRecord& p : pairs) {
      const std::string k = key(p);
      if (groups.find(k) == groups.end()) order.push_back(k);
      groups[k].push_back(&p);
    }
    for (const std::string& k : order) {
      std::vector<PairRecord> sub;
      for (const PairRecord* p : groups[k]) sub.push_back(*p);
      md << "| " << label << " " << k << " | " << sub.size() << " |";
      for (const std::string& m : methods()) {
        const Summary s = summarise(sub, m);
        char cell[64];
        std::snprintf(cell, sizeof cell, " %.2f (%.1f) |", s.f1, s.w);
        md << cell;
      }
      md << "\n";
    }
  };
  rows("kind", [](const PairRecord& p) { return p.kind; });
  rows("drift", [](const PairRecord& p) {
    char b[32];
    std::snprintf(b, sizeof b, "%.2f cm", p.drift * 100.0);
    return std::string(b);
  });
  return md.str();
}

json sideJson(const SideScore& s) {
  return {{"precision", s.precision},
          {"recall", s.recall},
          {"f1", s.f1},
          {"missed", s.missed},
          {"wrong", s.wrong}};
}

json datasetJson(const std::vector<PairRecord>& pairs) {
  json j;
  j["pairs"] = pairs.size();
  json summary = json::object();
  for (const std::string& m : methods()) {
    const Summary s = summarise(pairs, m);
    summary[m] = {{"precision", s.pr},
                  {"precision_sd", s.pr_sd},
                  {"recall", s.re},
                  {"recall_sd", s.re_sd},
                  {"f1", s.f1},
                  {"f1_sd", s.f1_sd},
                  {"missed_per_pair", s.m},
                  {"wrong_per_pair", s.w},
                  {"missed_total", s.m_total},
                  {"wrong_total", s.w_total},
                  {"seconds_per_pair", s.seconds}};
  }
  j["summary"] = summary;
  json per = json::array();
  for (const PairRecord& p : pairs) {
    json pj;
    pj["name"] = p.name;
    if (!p.kind.empty()) {
      pj["kind"] = p.kind;
      pj["drift_m"] = p.drift;
    }
    for (const auto& [m, run] : p.runs) {
      json r = sideJson(run.eval.pooled);
      r["removed"] = sideJson(run.eval.removed);
      r["added"] = sideJson(run.eval.added);
      r["ms"] = run.ms;
      pj["methods"][m] = r;
    }
    per.push_back(pj);
  }
  j["per_pair"] = per;
  return j;
}

/// The room pairs' section of comparison.md: per input form, the table and the breakdown.
std::string roomSection(const std::map<std::string, std::vector<PairRecord>>& rooms,
                        const BenchArgs& args) {
  if (rooms.empty()) return "";
  std::ostringstream md;
  md << "\n## Simulated room pairs (" << args.room_pairs << " per input form)\n\n"
     << "`planesdf simulate --scene room` layouts (2 or 3 tables, some 3 to 6 cm apart in "
        "height; a shelf of 3 to 5 boards against a wall; objects on tables, boards, the floor "
        "and walls), seeds "
     << kRoomSeed0
     << " + pair index; kinds in turn as above; drift 0, 1.5, 3 cm with 0, 1, 2 degrees of yaw "
        "about the room centre. Forms: `streams` the TUM frames; `raw` the accumulated frame "
        "points (`reference.ply`); `recon` the frames fused into a whole-scene TSDF and exported "
        "as surface points, no normals or viewpoints (`reference_recon.ply`); `mesh` the "
        "vertices of its marching-cubes mesh read from a PLY with faces "
        "(`reference_mesh.ply`). The baselines take the same cloud (OctoMap: the frames for "
        "`streams`; none for the clouds, which have no viewpoint to cast rays from).\n";
  for (const std::string& form : args.room_forms) {
    const auto it = rooms.find(form);
    if (it == rooms.end()) continue;
    md << "\n### " << form << "\n\n" << table(it->second) << "\n" << breakdown(it->second);
  }
  return md.str();
}

}  // namespace

int runSuite(const BenchArgs& args) {
  if (args.sim_pairs < 0 || args.mosd_pairs < 0 || args.room_pairs < 0)
    throw Error("--sim-pairs", "pair counts must not be negative");
  for (const std::string& form : args.room_forms)
    if (std::find(std::begin(kRoomForms), std::end(kRoomForms), form) == std::end(kRoomForms))
      throw Error("--room-forms", "unknown form '" + form + "' (streams, raw, recon, mesh)");
  if (args.octomap_stride < 1) throw Error("--octomap-stride", "must be at least 1");
  if (args.mosd_pairs > 0 && args.mosd_dir.empty())
    throw Error("--mosd",
                "no mOSD folder: give it with --mosd DIR or PLANESDF_MOSD_DIR, or skip "
                "it with --mosd-pairs 0");
  std::error_code ec;
  std::filesystem::create_directories(args.suite, ec);
  if (ec) throw Error(args.suite, "cannot create the output folder: " + ec.message());
  const auto t0 = Clock::now();
  const std::vector<PairRecord> simulated = runSimulated(args.suite + "/sim", args);
  const std::vector<PairRecord> mosd =
      args.mosd_pairs > 0 ? runMosd(args.suite + "/mosd", args) : std::vector<PairRecord>{};
  const std::map<std::string, std::vector<PairRecord>> rooms = runRooms(args.suite + "/room", args);

  std::ostringstream md;
  md << "# Change detection comparison (planesdf bench --suite)\n\n"
     << "Means per pair (± standard deviation) of the pooled point-level precision, recall and F1 "
        "of `planesdf eval` (match distance 7 mm); M and W are means per pair (totals in "
        "brackets); runtime is wall time per pair (PlaneSDF: both maps and detectChanges; point "
        "distance: downsampling, tests and clustering; OctoMap: both trees "
        "and the differencing), on whatever machine ran it.\n\n"
     << "## Simulated tabletop pairs (" << simulated.size() << ")\n\n"
     << "Kinds none, add, remove, move, small_move, swap, replace in turn; localisation drift "
        "0, 0.75, 1.5, 2.25, 3 cm (and 0 to 1 degree of yaw) in turn; seeds "
     << kSeed0 << " + pair index; " << (args.frames > 0 ? args.frames : kSuiteFrames)
     << " frames per session (one orbit). PlaneSDF fuses every frame (as `planesdf detect` on the "
        "simulated TUM folders), OctoMap inserts every frame from its camera (every "
     << args.octomap_stride
     << "th pixel in each direction, for speed), point distance compares the whole-scene clouds "
        "(`reference.ply`, `current.ply`).\n\n"
     << table(simulated)
     << (simulated.empty() ? std::string()
                           : "\nBy change kind and by localisation drift (mean F1, mean W per "
                             "pair):\n\n" +
                                 breakdown(simulated))
     << roomSection(rooms, args) << "\n## mOSD pairs (" << mosd.size() << ")\n\n"
     << "Single organised Kinect views; OctoMap inserts each cloud from its sensor origin.\n\n"
     << table(mosd);
#ifndef PLANESDF_HAVE_OCTOMAP
  md << "\nOctoMap row missing: the OctoMap adapter is not built (PLANESDF_BUILD_OCTOMAP=OFF).\n";
#endif
  json j;
  j["simulated"] = datasetJson(simulated);
  j["mosd"] = datasetJson(mosd);
  for (const auto& [form, pairs] : rooms) j["room_" + form] = datasetJson(pairs);
  j["tol"] = Config{}.voxel_size;
  j["octomap_stride"] = args.octomap_stride;
  j["seconds"] = msSince(t0) / 1000.0;
  io::writeFileAtomic(args.suite + "/comparison.md", [&](std::ostream& o) { o << md.str(); });
  io::writeFileAtomic(args.suite + "/comparison.json",
                      [&](std::ostream& o) { o << j.dump(2) << "\n"; });
  std::printf("%s", md.str().c_str());
  std::printf("-> %s/comparison.md, %s/comparison.json (%.0f s)\n", args.suite.c_str(),
              args.suite.c_str(), msSince(t0) / 1000.0);
  return kExitOk;
}

}  // namespace planesdf::cli
