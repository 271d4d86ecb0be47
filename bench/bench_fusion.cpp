// Google Benchmark: fusing one 640x480 depth frame of a tabletop (table plane about 1 m from the
// camera, a few objects, 7 mm voxels, 0.3 m band) into a PlaneSDF volume that already holds the
// scene. The scene is analytic and rendered here, so the benchmark needs no data files.
//
//   bench_fusion [--benchmark_filter=...]   (medians: --benchmark_repetitions=10
//                                            --benchmark_report_aggregates_only=true)

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "planesdf/sim.hpp"
#include "planesdf/tsdf.hpp"

namespace {

using planesdf::Config;
using planesdf::DepthFrame;
using planesdf::Intrinsics;
using planesdf::Pose;
using planesdf::TsdfVolume;

struct Box {
  Eigen::Vector3d c, half;
};
struct Ball {
  Eigen::Vector3d c;
  double r;
};

/// A 1.6 x 1.0 m table (local z = 0) with a ball and three boxes on it.
struct Tabletop {
  std::vector<Box> boxes{{{0.25, 0.1, 0.06}, {0.06, 0.04, 0.06}},
                         {{-0.3, -0.15, 0.1}, {0.05, 0.05, 0.1}},
                         {{-0.1, 0.25, 0.025}, {0.12, 0.07, 0.025}}};
  std::vector<Ball> balls{{{0.0, -0.1, 0.08}, 0.08}};

  double raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
    double best = std::numeric_limits<double>::infinity();
    if (d.z() < 0.0) {
      const double t = -o.z() / d.z();
      const Eigen::Vector3d p = o + t * d;
      if (std::abs(p.x()) <= 0.8 && std::abs(p.y()) <= 0.5) best = t;
    }
    for (const Ball& b : balls) {
      const Eigen::Vector3d oc = o - b.c;
      const double bb = oc.dot(d), a = d.squaredNorm(), c = oc.squaredNorm() - b.r * b.r;
      const double disc = bb * bb - a * c;
      if (disc >= 0.0) {
        const double t = (-bb - std::sqrt(disc)) / a;
        if (t > 0.0) best = std::min(best, t);
      }
    }
    for (const Box& b : boxes) {
      double t0 = 0.0, t1 = best;
      for (int i = 0; i < 3 && t0 <= t1; ++i) {
        double ta = (b.c[i] - b.half[i] - o[i]) / d[i], tb = (b.c[i] + b.half[i] - o[i]) / d[i];
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tb);
      }
      if (t0 <= t1 && t0 > 0.0) best = t0;
    }
    return best;
  }
};

using planesdf::sim::lookAt;

DepthFrame render(const Tabletop& scene, const Pose& T) {
  DepthFrame f;  // default intrinsics: 640x480 Kinect
  const Intrinsics& K = f.intrinsics;
  f.depth.assign(static_cast<std::size_t>(K.width) * K.height, 0.0f);
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d ray((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      const double t = scene.raycast(T.translation(), T.linear() * ray);
      if (std::isfinite(t)) f.depth[static_cast<std::size_t>(v) * K.width + u] = float(t);
    }
  return f;
}

/// Camera k of a ring 0.8 m from the table centre, 0.65 m above it (about 1 m from the table).
Pose ringPose(int k, int n) {
  const double a = 2.0 * M_PI * k / n;
  return lookAt(Eigen::Vector3d(0.8 * std::cos(a), 0.8 * std::sin(a), 0.65),
                Eigen::Vector3d(0.0, 0.0, 0.05));
}

struct Fixture {
  Config cfg;
  TsdfVolume volume{cfg};
  std::vector<DepthFrame> frames;
  std::vector<Pose> poses;

  Fixture() {
    const Tabletop scene;
    constexpr int kViews = 12;
    for (int k = 0; k < kViews; ++k) {
      poses.push_back(ringPose(k, kViews));
      frames.push_back(render(scene, poses.back()));
      planesdf::integrateDepth(volume, frames.back(), poses.back(), cfg);
    }
  }
};

const Fixture& fixture() {
  static const Fixture f;
  return f;
}

/// One frame into a copy of the full scene volume; state.range(0) = threads (0 = all cores).
void BM_FuseTabletopFrame(benchmark::State& state) {
  const Fixture& f = fixture();
  Config cfg = f.cfg;
  cfg.threads = static_cast<int>(state.range(0));
  TsdfVolume vol = f.volume;
  std::size_t k = 0, blocks = 0;
  for (auto _ : state) {
    const auto res = planesdf::integrateDepth(vol, f.frames[k], f.poses[k], cfg);
    blocks += res.updated_blocks.size();
    k = (k + 5) % f.frames.size();
    benchmark::DoNotOptimize(res.num_voxel_updates);
  }
  state.counters["blocks_in_volume"] = static_cast<double>(vol.numBlocks());
  state.counters["blocks_updated"] =
      benchmark::Counter(static_cast<double>(blocks), benchmark::Counter::kAvgIterations);
  state.counters["bytes_per_voxel"] =
      static_cast<double>(vol.memoryBytes()) / static_cast<double>(vol.numVoxels());
}
BENCHMARK(BM_FuseTabletopFrame)
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->ComputeStatistics("min", [](const std::vector<double>& v) {
      return *std::min_element(v.begin(), v.end());
    });

/// Sampling the fused volume at random points near the table (random access by the later stages).
void BM_SampleVolume(benchmark::State& state) {
  const Fixture& f = fixture();
  std::uint64_t s = 12345;
  const auto next = [&] {
    s = s * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(s >> 11) / 9007199254740992.0;
  };
  for (auto _ : state) {
    const Eigen::Vector3d p(next() - 0.5, next() - 0.5, 0.2 * next());
    benchmark::DoNotOptimize(f.volume.sample(p));
  }
}
BENCHMARK(BM_SampleVolume);

}  // namespace

BENCHMARK_MAIN();
