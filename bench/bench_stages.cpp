// Google Benchmark: the per-frame and per-plane-pair stages after fusion, on the simulator's
// tabletop preset (seed 7, 640x480 Kinect-like frames, 7 mm voxels): per-frame RANSAC plane
// detection, height-map extraction of the table plane, the eq. 2 height comparison of one
// registered plane pair (with cleaning and blobs), and the 3D features of every key voxel of the
// largest changed blob. Single-threaded (Config::threads = 1); wall time. The maps are built once
// from 12 frames per session (about a 1/3 of a minute of set-up on one core); no data files are
// needed.
//
//   bench_stages [--benchmark_filter=...]   (medians: --benchmark_repetitions=10
//                                            --benchmark_report_aggregates_only=true)

#include <benchmark/benchmark.h>

#include <algorithm>
#include <vector>

#include "change/change_internal.hpp"
#include "planesdf/map.hpp"
#include "planesdf/plane.hpp"
#include "planesdf/sim.hpp"
#include "planesdf/validation.hpp"

namespace {

using planesdf::Config;
using planesdf::DepthFrame;
using planesdf::Map;
using planesdf::Pose;

constexpr int kFrames = 12;

std::vector<Eigen::Vector3f> backProject(const DepthFrame& f, const Pose& T) {
  const planesdf::Intrinsics& k = f.intrinsics;
  std::vector<Eigen::Vector3f> pts;
  pts.reserve(f.depth.size());
  for (int v = 0; v < k.height; ++v)
    for (int u = 0; u < k.width; ++u) {
      const float z = f.at(u, v);
      if (!DepthFrame::isValidDepth(z)) continue;
      const Eigen::Vector3d p((u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z);
      pts.push_back((T * p).cast<float>());
    }
  return pts;
}

struct Fixture {
  Config cfg;
  planesdf::sim::Scene scene = planesdf::sim::makePreset("tabletop", 7);
  std::vector<DepthFrame> frames;
  std::vector<Pose> poses;
  Map reference{cfg}, current{cfg};
  planesdf::ChangeSet set;

  Fixture() {
    cfg.threads = 1;
    planesdf::sim::PresetOptions opt;
    opt.frames = kFrames;
    scene = planesdf::sim::makePreset("tabletop", 7, opt);
    reference = Map(cfg);
    current = Map(cfg);
    for (int session = 0; session < 2; ++session) {
      const auto& s = session == 0 ? scene.reference : scene.current;
      const std::vector<Pose> truth = planesdf::sim::trajectoryPoses(s.trajectory);
      const Pose E = planesdf::sim::localisationErrorPose(s.localisation_error);
      for (std::size_t i = 0; i < truth.size(); ++i) {
        const DepthFrame f = planesdf::sim::renderDepth(scene, s, truth[i], 100 * session + i);
        (session == 0 ? reference : current).integrate(f, E * truth[i]);
        if (session == 0) {
          frames.push_back(f);
          poses.push_back(E * truth[i]);
        }
      }
    }
    planesdf::DetectOptions o;
    o.keep_stages = true;
    set = planesdf::detectChanges(reference, current, cfg, o);
  }

  /// The reference plane with the most voxels.
  const planesdf::PlaneSdf& largestPlane() const {
    return *std::max_element(
        reference.planes().begin(), reference.planes().end(),
        [](const auto& a, const auto& b) { return a.volume.numVoxels() < b.volume.numVoxels(); });
  }
};

const Fixture& fixture() {
  static const Fixture f;
  return f;
}

/// Per-frame sequential RANSAC on one back-projected 640x480 frame (about 300k points).
void BM_DetectPlanesFrame(benchmark::State& state) {
  const Fixture& f = fixture();
  std::vector<std::vector<Eigen::Vector3f>> clouds;
  for (std::size_t i = 0; i < f.frames.size(); i += 4)
    clouds.push_back(backProject(f.frames[i], f.poses[i]));
  std::size_t k = 0, planes = 0;
  for (auto _ : state) {
    const std::size_t i = k++ % clouds.size();
    const auto obs = planesdf::detectPlanesRansac(clouds[i], f.poses[4 * i].translation(), f.cfg);
    planes += obs.size();
    benchmark::DoNotOptimize(obs.data());
  }
  state.counters["planes"] =
      benchmark::Counter(static_cast<double>(planes), benchmark::Counter::kAvgIterations);
}
BENCHMARK(BM_DetectPlanesFrame)->Unit(benchmark::kMillisecond)->UseRealTime();

/// Height map (TSDF zero crossing per column) of the largest plane's volume.
void BM_HeightMap(benchmark::State& state) {
  const Fixture& f = fixture();
  const planesdf::PlaneSdf& p = f.largestPlane();
  for (auto _ : state) benchmark::DoNotOptimize(planesdf::computeHeightMap(p.volume, f.cfg));
  state.counters["voxels"] = static_cast<double>(p.volume.numVoxels());
}
BENCHMARK(BM_HeightMap)->Unit(benchmark::kMillisecond)->UseRealTime();

/// Height map plus object map, structure cells masked (what detection computes per plane).
void BM_PlaneMaps(benchmark::State& state) {
  const Fixture& f = fixture();
  const planesdf::PlaneSdf& p = f.largestPlane();
  for (auto _ : state)
    benchmark::DoNotOptimize(planesdf::computePlaneMaps(p, f.reference.planes(), f.cfg));
}
BENCHMARK(BM_PlaneMaps)->Unit(benchmark::kMillisecond)->UseRealTime();

/// Eq. 2 comparison, cleaning, free-space evidence and blobs of the largest registered pair.
void BM_HeightComparison(benchmark::State& state) {
  const Fixture& f = fixture();
  const planesdf::PlanePairResult* best = nullptr;
  for (const auto& r : f.set.pairs)
    if (r.reference_to_current && !r.source_heights.empty() &&
        (best == nullptr || r.source_heights.numCells() > best->source_heights.numCells()))
      best = &r;
  if (best == nullptr) {
    state.SkipWithError("no registered plane pair");
    return;
  }
  const planesdf::PlaneSdf* tgt = f.current.findPlane(best->match.target_id);
  const Pose T = best->match.T_target_source_local;
  for (auto _ : state) {
    const auto c = planesdf::detectHeightChange(best->source_heights, best->target_heights,
                                                best->source_objects, T, f.cfg, &tgt->volume);
    benchmark::DoNotOptimize(c.blobs.data());
  }
  state.counters["cells"] = static_cast<double>(best->source_heights.numCells());
}
BENCHMARK(BM_HeightComparison)->Unit(benchmark::kMillisecond)->UseRealTime();

/// Key voxels and the source features of all of them, for the largest changed blob.
void BM_BlobFeatures(benchmark::State& state) {
  const Fixture& f = fixture();
  const planesdf::ChangeRegion* region = nullptr;
  const Map* map = nullptr;
  for (const planesdf::ChangeEvent& e : f.set.events)
    for (const bool ref_side : {true, false}) {
      const planesdf::ChangeRegion& r = ref_side ? e.reference : e.current;
      if (!r.empty() && (region == nullptr || r.voxels.size() > region->voxels.size())) {
        region = &r;
        map = ref_side ? &f.reference : &f.current;
      }
    }
  if (region == nullptr) {
    state.SkipWithError("no change event");
    return;
  }
  const planesdf::TsdfVolume& vol = map->findPlane(region->plane_id)->volume;
  // The blob as the validation sees it: every observed voxel of its columns, plane to band top.
  const std::vector<Eigen::Vector3i> blob = planesdf::blobVoxelsFromColumns(
      vol, region->columns, -f.cfg.truncation_voxels,
      static_cast<int>(f.cfg.fuse_band / f.cfg.voxel_size), f.cfg.w_min);
  std::size_t keys = 0;
  for (auto _ : state) {
    const auto kv = planesdf::keyVoxels(vol, blob, f.cfg);
    for (const auto& k : kv) benchmark::DoNotOptimize(planesdf::featureAt(vol, k.voxel, f.cfg));
    keys += kv.size();
  }
  state.counters["blob_voxels"] = static_cast<double>(blob.size());
  state.counters["key_voxels"] =
      benchmark::Counter(static_cast<double>(keys), benchmark::Counter::kAvgIterations);
}
BENCHMARK(BM_BlobFeatures)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
