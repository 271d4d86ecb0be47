// `planesdf bench [--frames N] [--json FILE]`: the end-to-end benchmark of issue 7 on a fixed
// simulated tabletop sequence (PlaneSDF integrate per frame, the same frames into an OctoMap
// OcTree, one detectChanges), and `planesdf bench --suite DIR`: the paper-style comparison of
// issue 5 (PlaneSDF, point-distance and OctoMap differencing on simulated and mOSD pairs).
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>

#include "bench_render.hpp"
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
#include "session_input.hpp"
#include "timing.hpp"
#ifdef PLANESDF_HAVE_OCTOMAP
#include "planesdf/octomap/octomap_baseline.hpp"
#endif

namespace planesdf::cli {

Sequence renderSession(const sim::Scene& scene, const sim::Session& session, int session_index,
                       int max_frames, const std::string& label) {
  const std::vector<Pose> truth = sim::trajectoryPoses(session.trajectory);
  const Pose E = sim::localisationErrorPose(session.localisation_error);
  const std::size_t n =
      max_frames > 0 ? std::min<std::size_t>(truth.size(), max_frames) : truth.size();
  Sequence s;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint64_t seed =
        (static_cast<std::uint64_t>(scene.seed) << 32) ^ (std::uint64_t(session_index) << 24) ^ i;
    s.frames.push_back(sim::renderDepth(scene, session, truth[i], seed));
    if ((i + 1) % 10 == 0)
      std::cerr << "bench: " << label << " frame " << (i + 1) << "/" << n << "\n";
    s.true_poses.push_back(truth[i]);
    s.poses.push_back(E * truth[i]);
  }
  std::cerr << "bench: rendered " << n << " " << label << " frames\n";
  return s;
}

namespace {

using nlohmann::json;

double peakRssMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

json numberOrNull(double v) {
  return std::isfinite(v) ? json(v) : json(nullptr);
}

void writeText(const std::string& path, const std::string& text) {
  io::writeFileAtomic(path, [&](std::ostream& out) { out << text; });
}

std::size_t mapVoxels(const Map& map) {
  std::size_t n = 0;
  for (const PlaneSdf& p : map.planes()) n += p.volume.numVoxels();
  return n;
}

/// The room pair of issue 7's detection target: the `room` preset (seed kBenchRoomSeed, the demo's
/// room) fused frame by frame, then detectChanges run kRoomDetectRuns times on the same maps.
struct RoomFigures {
  std::size_t frames = 0;
  double integrate_ms_median = 0.0;
  std::vector<double> detect_ms;  ///< per run, in order
  /// Per run, in order: ChangeSet's phase times (maps, correction, forward, backward).
  std::vector<double> maps_ms, correction_ms, forward_ms, backward_ms;
  std::size_t events = 0;
  std::size_t voxels = 0;
  std::size_t map_bytes = 0;
};

constexpr unsigned kBenchRoomSeed = 1;
constexpr int kRoomDetectRuns = 3;

RoomFigures roomBench(int max_frames, int threads) {
  const sim::Scene scene = sim::makePreset("room", kBenchRoomSeed);
  std::cerr << "bench: room preset, seed " << kBenchRoomSeed << "\n";
  const Sequence ref = renderSession(scene, scene.reference, 0, max_frames, "room reference");
  const Sequence cur = renderSession(scene, scene.current, 1, max_frames, "room current");
  Config cfg;
  cfg.threads = threads;
  Map reference(cfg), current(cfg);
  std::vector<double> integrate_ms;
  for (const auto& [seq, map] : {std::pair<const Sequence*, Map*>{&ref, &reference},
                                 std::pair<const Sequence*, Map*>{&cur, &current}})
    for (std::size_t i = 0; i < seq->frames.size(); ++i) {
      const auto t0 = Clock::now();
      map->integrate(seq->frames[i], seq->poses[i]);
      integrate_ms.push_back(msSince(t0));
      if ((i + 1) % 10 == 0 || i + 1 == seq->frames.size())
        std::cerr << "bench: room fused " << (i + 1) << "/" << seq->frames.size() << "\n";
    }
  RoomFigures r;
  r.frames = ref.frames.size();
  r.integrate_ms_median = quantile(integrate_ms, 0.5);
  for (int k = 0; k < kRoomDetectRuns; ++k) {
    const auto td = Clock::now();
    const ChangeSet set = detectChanges(reference, current, cfg);
    r.detect_ms.push_back(msSince(td));
    r.maps_ms.push_back(set.maps_ms);
    r.correction_ms.push_back(set.correction_ms);
    r.forward_ms.push_back(set.forward_ms);
    r.backward_ms.push_back(set.backward_ms);
    r.events = set.events.size();
    std::cerr << "bench: room detectChanges " << r.detect_ms.back() << " ms, " << r.events
              << " events\n";
  }
  r.voxels = mapVoxels(reference) + mapVoxels(current);
  r.map_bytes = reference.memoryBytes() + current.memoryBytes();
  return r;
}

/// The tabletop sequence: both sessions fused frame by frame (the reference's frames timed stage
/// by stage), then one detectChanges.
struct TabletopFigures {
  std::vector<double> integrate_ms, integrate_cpu_ms, current_ms, tracking_ms, points_ms, fusion_ms;
  double reserve_ms = 0.0;
  double detect_ms = 0.0;
  std::size_t events = 0;
  double peak_rss_mb = 0.0;  ///< after the maps and the detection
  std::size_t map_bytes = 0, map_bytes_in_use = 0, voxels = 0, planes = 0;
};

TabletopFigures tabletopBench(const Sequence& ref, const Sequence& cur, const Config& cfg,
                              int reserve_mb) {
  TabletopFigures f;
  Map reference(cfg), current(cfg);
  // As a real-time pipeline does at start-up: the maps' block memory is faulted in before the
  // first frame (fresh memory costs a page fault and zeroing per page; see Map::reserveMemory).
  const auto reserve_bytes = static_cast<std::size_t>(reserve_mb) << 20;
  const auto tr = Clock::now();
  reference.reserveMemory(reserve_bytes);
  current.reserveMemory(reserve_bytes);
  f.reserve_ms = msSince(tr);
  std::cerr << "bench: reserved " << reserve_mb << " MiB of block memory per map in "
            << f.reserve_ms << " ms\n";
  for (std::size_t i = 0; i < ref.frames.size(); ++i) {
    const auto t0 = Clock::now();
    const double cpu0 = processCpuMs();
    const IntegrateStats st = reference.integrate(ref.frames[i], ref.poses[i]);
    f.integrate_ms.push_back(msSince(t0));
    f.integrate_cpu_ms.push_back(processCpuMs() - cpu0);
    f.tracking_ms.push_back(st.tracking_ms);
    f.points_ms.push_back(st.points_ms);
    f.fusion_ms.push_back(st.fusion_ms);
    std::cerr << "bench: planesdf integrate " << (i + 1) << "/" << ref.frames.size() << ": "
              << f.integrate_ms.back() << " ms\n";
  }
  for (std::size_t i = 0; i < cur.frames.size(); ++i) {
    const auto t0 = Clock::now();
    current.integrate(cur.frames[i], cur.poses[i]);
    f.current_ms.push_back(msSince(t0));
  }
  const auto td = Clock::now();
  f.events = detectChanges(reference, current, cfg).events.size();
  f.detect_ms = msSince(td);
  std::cerr << "bench: detectChanges " << f.detect_ms << " ms, " << f.events << " events\n";
  f.peak_rss_mb = peakRssMb();
  f.map_bytes = reference.memoryBytes();
  f.map_bytes_in_use = reference.memoryBytes() - reference.reservedBytes();
  f.voxels = mapVoxels(reference);
  f.planes = reference.planes().size();
  return f;
}

/// The same reference frames into an OctoMap OcTree at the same resolution and range.
struct OctomapFigures {
  std::vector<double> insert_ms;  ///< empty without the adapter
  double bytes = std::nan("");
  std::string note;
};

OctomapFigures octomapBench([[maybe_unused]] const Sequence& ref,
                            [[maybe_unused]] const Config& cfg) {
  OctomapFigures o;
#ifdef PLANESDF_HAVE_OCTOMAP
  octomap_adapter::OccupancyOptions oo;
  oo.resolution = cfg.voxel_size;
  oo.max_range = cfg.max_depth;
  octomap_adapter::OccupancyMap tree(oo);
  for (std::size_t i = 0; i < ref.frames.size(); ++i) {
    o.insert_ms.push_back(tree.insertFrame(ref.frames[i], ref.poses[i]));
    std::cerr << "bench: octomap insertPointCloud " << (i + 1) << "/" << ref.frames.size() << ": "
              << o.insert_ms.back() << " ms\n";
  }
  o.bytes = static_cast<double>(tree.memoryBytes());
  o.note = "octomap::OcTree insertPointCloud from the camera centre, same frames, " +
           std::to_string(oo.resolution) + " m, max range " + std::to_string(oo.max_range) +
           " m, discretize on";
#else
  o.note = "the OctoMap adapter is not built (PLANESDF_BUILD_OCTOMAP=OFF)";
#endif
  return o;
}

json benchJson(const sim::Scene& scene, std::size_t frames, const Config& cfg, int reserve_mb,
               double peak_rss_mb, const TabletopFigures& t, const OctomapFigures& o,
               const RoomFigures& room) {
  json j;
  j["scene"] = "tabletop";
  j["seed"] = kBenchSeed;
  j["frames"] = frames;
  j["width"] = scene.sensor.intrinsics.width;
  j["height"] = scene.sensor.intrinsics.height;
  j["voxel_size"] = cfg.voxel_size;
  j["threads"] = cfg.threads;
  j["integrate_ms_median"] = quantile(t.integrate_ms, 0.5);
  j["integrate_cpu_ms_median"] = quantile(t.integrate_cpu_ms, 0.5);  // all threads' CPU time
  j["integrate_ms_p95"] = quantile(t.integrate_ms, 0.95);
  j["integrate_ms_max"] = quantile(t.integrate_ms, 1.0);
  // The stages of Map::integrate (IntegrateStats): tracking and the kept points run beside the
  // per-pixel pass; fusion is the TSDF update of the plane volumes.
  j["tracking_ms_median"] = quantile(t.tracking_ms, 0.5);
  j["points_ms_median"] = quantile(t.points_ms, 0.5);
  j["fusion_ms_median"] = quantile(t.fusion_ms, 0.5);
  j["fusion_ms_p95"] = quantile(t.fusion_ms, 0.95);
  j["current_integrate_ms_median"] = numberOrNull(quantile(t.current_ms, 0.5));
  j["octomap_ms_median"] = numberOrNull(quantile(o.insert_ms, 0.5));
  j["octomap_ms_p95"] = numberOrNull(quantile(o.insert_ms, 0.95));
  j["octomap_bytes"] = numberOrNull(o.bytes);
  j["octomap_note"] = o.note;
  j["detect_ms"] = t.detect_ms;
  j["events"] = t.events;
  j["peak_rss_mb"] = peak_rss_mb;  // before the room pair
  j["peak_rss_mb_before_octomap"] = t.peak_rss_mb;
  j["map_bytes"] = t.map_bytes;
  j["map_bytes_in_use"] = t.map_bytes_in_use;
  j["reserve_mb"] = reserve_mb;
  j["reserve_ms"] = t.reserve_ms;
  j["voxels"] = t.voxels;
  j["planes"] = t.planes;
  j["room_frames"] = room.frames;
  j["room_integrate_ms_median"] = room.integrate_ms_median;
  j["detect_room_ms"] = quantile(room.detect_ms, 0.5);
  j["detect_room_ms_runs"] = room.detect_ms;
  j["detect_room_maps_ms"] = quantile(room.maps_ms, 0.5);
  j["detect_room_correction_ms"] = quantile(room.correction_ms, 0.5);
  j["detect_room_forward_ms"] = quantile(room.forward_ms, 0.5);
  j["detect_room_backward_ms"] = quantile(room.backward_ms, 0.5);
  j["room_events"] = room.events;
  j["room_voxels"] = room.voxels;
  j["room_map_bytes"] = room.map_bytes;
  return j;
}

void printMedianP95(const char* what, const std::vector<double>& v, const char* unit = "ms") {
  std::printf("  %-34s %10.1f %10.1f %s\n", what, quantile(v, 0.5), quantile(v, 0.95), unit);
}

void printBench(const json& j, const TabletopFigures& t, const OctomapFigures& o,
                const RoomFigures& room) {
  std::printf("planesdf bench: tabletop seed %u, %zu frames of %dx%d, voxel %.1f mm\n", kBenchSeed,
              j["frames"].get<std::size_t>(), j["width"].get<int>(), j["height"].get<int>(),
              j["voxel_size"].get<double>() * 1000);
  std::printf("  %-34s %10s %10s\n", "", "median", "p95");
  printMedianP95("planesdf Map::integrate / frame", t.integrate_ms);
  printMedianP95("  CPU time of all threads / frame", t.integrate_cpu_ms);
  printMedianP95("  of which TSDF fusion (all planes)", t.fusion_ms);
  printMedianP95("  beside the per-pixel pass: tracking", t.tracking_ms);
  printMedianP95("  then the kept object points", t.points_ms);
  if (!o.insert_ms.empty())
    printMedianP95("octomap insertPointCloud / frame", o.insert_ms);
  else
    std::printf("  octomap: n/a (%s)\n", o.note.c_str());
  std::printf("  %-34s %10.1f ms (%zu events)\n", "detectChanges (one scene pair)", t.detect_ms,
              t.events);
  std::printf("  %-34s %10.1f ms (median of %d; %zu events, %zu + %zu frames)\n",
              "detectChanges (room pair)", quantile(room.detect_ms, 0.5), kRoomDetectRuns,
              room.events, room.frames, room.frames);
  std::printf("  %-34s %10.1f ms, correction %.1f ms, pairs %.1f + %.1f ms (medians)\n",
              "  of which plane maps", quantile(room.maps_ms, 0.5),
              quantile(room.correction_ms, 0.5), quantile(room.forward_ms, 0.5),
              quantile(room.backward_ms, 0.5));
  std::printf("  %-34s %10.1f MB (%.1f MB in use, %.1f MB of the reserve unused)\n",
              "map memory (reference)", t.map_bytes / 1e6, t.map_bytes_in_use / 1e6,
              (t.map_bytes - t.map_bytes_in_use) / 1e6);
  std::printf("  %-34s %10.1f ms (%d MiB per map, before the frames)\n", "memory reserve",
              t.reserve_ms, j["reserve_mb"].get<int>());
  if (std::isfinite(o.bytes)) std::printf("  %-34s %10.1f MB\n", "octomap memory", o.bytes / 1e6);
  std::printf("  %-34s %10zu in %zu planes\n", "voxels", t.voxels, t.planes);
  std::printf("  %-34s %10.1f MB (before the room pair)\n", "peak RSS",
              j["peak_rss_mb"].get<double>());
}

/// `--load N`: N processes that each keep a core busy while the benchmark runs, as a host's
/// other work does. Processes, not threads, so the CPU time figures stay planesdf's own; each
/// dies with the benchmark (PR_SET_PDEATHSIG) or when this is destroyed.
class BusyLoad {
 public:
  explicit BusyLoad(int n) {
    for (int k = 0; k < n; ++k) {
      const pid_t pid = fork();
      if (pid < 0) throw Error("--load", "cannot start a busy process");
      if (pid == 0) spin();
      pids_.push_back(pid);
    }
  }
  BusyLoad(const BusyLoad&) = delete;
  BusyLoad& operator=(const BusyLoad&) = delete;
  ~BusyLoad() {
    for (const pid_t pid : pids_) kill(pid, SIGKILL);
    for (const pid_t pid : pids_) waitpid(pid, nullptr, 0);
  }

 private:
  [[noreturn]] static void spin() {
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    volatile double x = 1.0;
    for (;;) x = x * 1.0000001 + 1e-9;
  }
  std::vector<pid_t> pids_;
};

int runSingleBench(const BenchArgs& args) {
  const sim::Scene scene = sim::makePreset("tabletop", kBenchSeed);
  Config cfg;
  cfg.threads = args.threads;
  std::cerr << "bench: tabletop preset, seed " << kBenchSeed << ", 640x480 frames, voxel "
            << cfg.voxel_size * 1000 << " mm, threads " << cfg.threads << ", load " << args.load
            << "\n";
  const Sequence ref = renderSession(scene, scene.reference, 0, args.frames, "reference");
  const Sequence cur = renderSession(scene, scene.current, 1, args.frames, "current");
  const BusyLoad load(args.load);
  const TabletopFigures tabletop = tabletopBench(ref, cur, cfg, args.reserve_mb);
  const OctomapFigures octomap = octomapBench(ref, cfg);
  const double peak_rss_mb = peakRssMb();
  // The room pair last, with the tabletop maps freed: its maps are larger than everything above.
  const RoomFigures room = roomBench(args.frames, cfg.threads);
  json j = benchJson(scene, ref.frames.size(), cfg, args.reserve_mb, peak_rss_mb, tabletop, octomap,
                     room);
  j["load"] = args.load;
  printBench(j, tabletop, octomap, room);
  if (!args.json.empty()) {
    writeText(args.json, j.dump(2) + "\n");
    std::printf("-> %s\n", args.json.c_str());
  }
  return kExitOk;
}

}  // namespace

int runBench(const BenchArgs& args) {
  if (args.frames < 0) throw Error("--frames", "must be at least 1 (or 0 for all)");
  if (!args.suite.empty()) return runSuite(args);
  if (args.stream) return runStreamBench(args);
  return runSingleBench(args);
}

}  // namespace planesdf::cli
