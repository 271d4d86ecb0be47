// `planesdf bench [--frames N] [--json FILE]`: the end-to-end benchmark of issue 7 on a fixed
// simulated tabletop sequence (PlaneSDF integrate per frame, the same frames into an OctoMap
// OcTree, one detectChanges), and `planesdf bench --suite DIR`: the paper-style comparison of
// issue 5 (PlaneSDF, point-distance and OctoMap differencing on simulated and mOSD pairs).
#include <sys/resource.h>

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

RoomFigures roomBench(int max_frames) {
  const sim::Scene scene = sim::makePreset("room", kBenchRoomSeed);
  std::cerr << "bench: room preset, seed " << kBenchRoomSeed << "\n";
  const Sequence ref = renderSession(scene, scene.reference, 0, max_frames, "room reference");
  const Sequence cur = renderSession(scene, scene.current, 1, max_frames, "room current");
  Config cfg;
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

int runSingleBench(const BenchArgs& args) {
  const sim::Scene scene = sim::makePreset("tabletop", kBenchSeed);
  std::cerr << "bench: tabletop preset, seed " << kBenchSeed << ", 640x480 frames, voxel "
            << Config{}.voxel_size * 1000 << " mm\n";
  const Sequence ref = renderSession(scene, scene.reference, 0, args.frames, "reference");
  const Sequence cur = renderSession(scene, scene.current, 1, args.frames, "current");

  Config cfg;
  std::vector<double> integrate_ms, integrate_cpu_ms, current_ms, tracking_ms, points_ms, fusion_ms;
  Map reference(cfg), current(cfg);
  // As a real-time pipeline does at start-up: the maps' block memory is faulted in before the
  // first frame (fresh memory costs a page fault and zeroing per page; see Map::reserveMemory).
  const auto reserve_bytes = static_cast<std::size_t>(args.reserve_mb) << 20;
  const auto tr = Clock::now();
  reference.reserveMemory(reserve_bytes);
  current.reserveMemory(reserve_bytes);
  const double reserve_ms = msSince(tr);
  std::cerr << "bench: reserved " << args.reserve_mb << " MiB of block memory per map in "
            << reserve_ms << " ms\n";
  for (std::size_t i = 0; i < ref.frames.size(); ++i) {
    const auto t0 = Clock::now();
    const double cpu0 = processCpuMs();
    const IntegrateStats st = reference.integrate(ref.frames[i], ref.poses[i]);
    integrate_ms.push_back(msSince(t0));
    integrate_cpu_ms.push_back(processCpuMs() - cpu0);
    tracking_ms.push_back(st.tracking_ms);
    points_ms.push_back(st.points_ms);
    fusion_ms.push_back(st.fusion_ms);
    std::cerr << "bench: planesdf integrate " << (i + 1) << "/" << ref.frames.size() << ": "
              << integrate_ms.back() << " ms\n";
  }
  for (std::size_t i = 0; i < cur.frames.size(); ++i) {
    const auto t0 = Clock::now();
    current.integrate(cur.frames[i], cur.poses[i]);
    current_ms.push_back(msSince(t0));
  }
  const double rss_planesdf = peakRssMb();
  const auto td = Clock::now();
  const ChangeSet set = detectChanges(reference, current, cfg);
  const double detect_ms = msSince(td);
  std::cerr << "bench: detectChanges " << detect_ms << " ms, " << set.events.size() << " events\n";

  std::vector<double> octomap_ms;
  std::string octomap_note;
  double octomap_bytes = std::nan("");
#ifdef PLANESDF_HAVE_OCTOMAP
  octomap_adapter::OccupancyOptions oo;
  oo.resolution = cfg.voxel_size;
  oo.max_range = cfg.max_depth;
  octomap_adapter::OccupancyMap tree(oo);
  for (std::size_t i = 0; i < ref.frames.size(); ++i) {
    octomap_ms.push_back(tree.insertFrame(ref.frames[i], ref.poses[i]));
    std::cerr << "bench: octomap insertPointCloud " << (i + 1) << "/" << ref.frames.size() << ": "
              << octomap_ms.back() << " ms\n";
  }
  octomap_bytes = static_cast<double>(tree.memoryBytes());
  octomap_note = "octomap::OcTree insertPointCloud from the camera centre, same frames, " +
                 std::to_string(oo.resolution) + " m, max range " + std::to_string(oo.max_range) +
                 " m, discretize on";
#else
  octomap_note = "the OctoMap adapter is not built (PLANESDF_BUILD_OCTOMAP=OFF)";
#endif

  json j;
  j["scene"] = "tabletop";
  j["seed"] = kBenchSeed;
  j["frames"] = ref.frames.size();
  j["width"] = scene.sensor.intrinsics.width;
  j["height"] = scene.sensor.intrinsics.height;
  j["voxel_size"] = cfg.voxel_size;
  j["threads"] = cfg.threads;
  j["integrate_ms_median"] = quantile(integrate_ms, 0.5);
  j["integrate_cpu_ms_median"] = quantile(integrate_cpu_ms, 0.5);  // all threads' CPU time
  j["integrate_ms_p95"] = quantile(integrate_ms, 0.95);
  j["integrate_ms_max"] = quantile(integrate_ms, 1.0);
  // The stages of Map::integrate (IntegrateStats): tracking and the kept points run beside the
  // per-pixel pass; fusion is the TSDF update of the plane volumes.
  j["tracking_ms_median"] = quantile(tracking_ms, 0.5);
  j["points_ms_median"] = quantile(points_ms, 0.5);
  j["fusion_ms_median"] = quantile(fusion_ms, 0.5);
  j["fusion_ms_p95"] = quantile(fusion_ms, 0.95);
  j["current_integrate_ms_median"] = numberOrNull(quantile(current_ms, 0.5));
  j["octomap_ms_median"] = numberOrNull(quantile(octomap_ms, 0.5));
  j["octomap_ms_p95"] = numberOrNull(quantile(octomap_ms, 0.95));
  j["octomap_bytes"] = numberOrNull(octomap_bytes);
  j["octomap_note"] = octomap_note;
  j["detect_ms"] = detect_ms;
  j["events"] = set.events.size();
  j["peak_rss_mb"] = peakRssMb();
  j["peak_rss_mb_before_octomap"] = rss_planesdf;
  j["map_bytes"] = reference.memoryBytes();
  j["map_bytes_in_use"] = reference.memoryBytes() - reference.reservedBytes();
  j["reserve_mb"] = args.reserve_mb;
  j["reserve_ms"] = reserve_ms;
  j["voxels"] = mapVoxels(reference);
  j["planes"] = reference.planes().size();

  // The room pair last, with the tabletop maps freed: its maps are larger than everything above.
  reference = Map(cfg);
  current = Map(cfg);
  const RoomFigures room = roomBench(args.frames);
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

  std::printf("planesdf bench: tabletop seed %u, %zu frames of %dx%d, voxel %.1f mm\n", kBenchSeed,
              ref.frames.size(), scene.sensor.intrinsics.width, scene.sensor.intrinsics.height,
              cfg.voxel_size * 1000);
  std::printf("  %-34s %10s %10s\n", "", "median", "p95");
  std::printf("  %-34s %10.1f %10.1f ms\n", "planesdf Map::integrate / frame",
              quantile(integrate_ms, 0.5), quantile(integrate_ms, 0.95));
  std::printf("  %-34s %10.1f %10.1f ms\n", "  CPU time of all threads / frame",
              quantile(integrate_cpu_ms, 0.5), quantile(integrate_cpu_ms, 0.95));
  std::printf("  %-34s %10.1f %10.1f ms\n", "  of which TSDF fusion (all planes)",
              quantile(fusion_ms, 0.5), quantile(fusion_ms, 0.95));
  std::printf("  %-34s %10.1f %10.1f ms\n", "  beside the per-pixel pass: tracking",
              quantile(tracking_ms, 0.5), quantile(tracking_ms, 0.95));
  std::printf("  %-34s %10.1f %10.1f ms\n", "  then the kept object points",
              quantile(points_ms, 0.5), quantile(points_ms, 0.95));
  if (!octomap_ms.empty())
    std::printf("  %-34s %10.1f %10.1f ms\n", "octomap insertPointCloud / frame",
                quantile(octomap_ms, 0.5), quantile(octomap_ms, 0.95));
  else
    std::printf("  octomap: n/a (%s)\n", octomap_note.c_str());
  std::printf("  %-34s %10.1f ms (%zu events)\n", "detectChanges (one scene pair)", detect_ms,
              set.events.size());
  std::printf("  %-34s %10.1f ms (median of %d; %zu events, %zu + %zu frames)\n",
              "detectChanges (room pair)", quantile(room.detect_ms, 0.5), kRoomDetectRuns,
              room.events, room.frames, room.frames);
  std::printf("  %-34s %10.1f ms, correction %.1f ms, pairs %.1f + %.1f ms (medians)\n",
              "  of which plane maps", quantile(room.maps_ms, 0.5),
              quantile(room.correction_ms, 0.5), quantile(room.forward_ms, 0.5),
              quantile(room.backward_ms, 0.5));
  std::printf("  %-34s %10.1f MB (%.1f MB in use, %.1f MB of the reserve unused)\n",
              "map memory (reference)", j["map_bytes"].get<double>() / 1e6,
              j["map_bytes_in_use"].get<double>() / 1e6,
              (j["map_bytes"].get<double>() - j["map_bytes_in_use"].get<double>()) / 1e6);
  std::printf("  %-34s %10.1f ms (%d MiB per map, before the frames)\n", "memory reserve",
              reserve_ms, args.reserve_mb);
  if (std::isfinite(octomap_bytes))
    std::printf("  %-34s %10.1f MB\n", "octomap memory", octomap_bytes / 1e6);
  std::printf("  %-34s %10zu in %zu planes\n", "voxels", j["voxels"].get<std::size_t>(),
              j["planes"].get<std::size_t>());
  std::printf("  %-34s %10.1f MB (before the room pair)\n", "peak RSS",
              j["peak_rss_mb"].get<double>());
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
