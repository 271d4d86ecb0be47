// Google Benchmark: 3D voxel validation (paper §III-D) of a mug-sized blob. Source and target are
// PlaneSDF volumes (7 mm voxels, 4-voxel truncation) filled with the analytic truncated SDF of a
// mug (hollow cylinder, r = 4 cm, h = 10 cm) on the plane h = 0 plus 1 mm of Gaussian noise; the
// blob is every observed voxel in the columns within 5 cm of the mug (about 22k voxels). The
// target holds either the same mug (independent noise) or a book stack.
//
//   bench_validation [--benchmark_filter=...]   (medians: --benchmark_repetitions=10
//                                                --benchmark_report_aggregates_only=true)

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <vector>

#include "planesdf/tsdf.hpp"
#include "planesdf/validation.hpp"

namespace {

using planesdf::Config;
using planesdf::Pose;
using planesdf::TsdfVolume;
using Sdf = std::function<double(const Eigen::Vector3d&)>;

double boxSdf(const Eigen::Vector3d& p, const Eigen::Vector3d& c, const Eigen::Vector3d& half) {
  const Eigen::Vector3d q = (p - c).cwiseAbs() - half;
  return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
}

double cylinderSdf(const Eigen::Vector3d& p, double r, double z0, double z1) {
  const Eigen::Vector2d d(std::hypot(p.x(), p.y()) - r,
                          std::abs(p.z() - 0.5 * (z0 + z1)) - 0.5 * (z1 - z0));
  return std::min(std::max(d.x(), d.y()), 0.0) + d.cwiseMax(0.0).norm();
}

double mugSdf(const Eigen::Vector3d& p) {
  return std::max(cylinderSdf(p, 0.04, 0.0, 0.10), -cylinderSdf(p, 0.034, 0.006, 0.30));
}

double booksSdf(const Eigen::Vector3d& p) {
  return std::min({boxSdf(p, {0.0, 0.0, 0.02}, {0.10, 0.075, 0.02}),
                   boxSdf(p, {0.01, -0.005, 0.06}, {0.085, 0.06, 0.02}),
                   boxSdf(p, {-0.015, 0.01, 0.10}, {0.07, 0.05, 0.02})});
}

/// The plane h = 0 with `object` on it, truncated, plus N(0, 1 mm), over 40 x 40 x 33 cm.
TsdfVolume makeVolume(const Sdf& object, unsigned seed) {
  TsdfVolume vol(Config{});
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauss(0.0, 0.001);
  const Eigen::Vector3i a = vol.voxelIndexAt({-0.2, -0.2, -0.03});
  const Eigen::Vector3i b = vol.voxelIndexAt({0.2, 0.2, 0.30});
  const double tr = vol.truncation();
  for (int k = a.z(); k <= b.z(); ++k)
    for (int j = a.y(); j <= b.y(); ++j)
      for (int i = a.x(); i <= b.x(); ++i) {
        const Eigen::Vector3i g(i, j, k);
        vol.allocateBlock(TsdfVolume::blockOfVoxel(g));
        const Eigen::Vector3d c = vol.voxelCenter(g);
        const double d = std::min(c.z(), object(c));
        const double n = gauss(rng);
        if (d < -tr) continue;
        planesdf::TsdfVoxel* v = vol.voxel(g);
        v->sdf = static_cast<float>(std::clamp(d + n, -tr, tr));
        v->weight = 5.0f;
      }
  return vol;
}

/// Observed voxels of the columns within 5 cm of the mug's footprint.
std::vector<Eigen::Vector3i> mugBlob(const TsdfVolume& vol) {
  std::vector<Eigen::Vector2i> columns;
  for (int j = -30; j <= 30; ++j)
    for (int i = -30; i <= 30; ++i) {
      const Eigen::Vector3d c = vol.voxelCenter(Eigen::Vector3i(i, j, 0));
      if (std::hypot(c.x(), c.y()) <= 0.09) columns.emplace_back(i, j);
    }
  return planesdf::blobVoxelsFromColumns(vol, columns, 0, 45, Config{}.w_min);
}

struct Fixture {
  TsdfVolume mug1 = makeVolume(mugSdf, 1);
  TsdfVolume mug2 = makeVolume(mugSdf, 2);
  TsdfVolume books = makeVolume(booksSdf, 3);
  std::vector<Eigen::Vector3i> blob = mugBlob(mug1);
};

const Fixture& fixture() {
  static const Fixture f;
  return f;
}

/// validateBlob of the mug blob; range(0) = threads (0 = all cores), range(1) = 0: same mug,
/// 1: book stack.
void BM_ValidateMugBlob(benchmark::State& state) {
  const Fixture& f = fixture();
  Config cfg;
  cfg.threads = static_cast<int>(state.range(0));
  const TsdfVolume& target = state.range(1) ? f.books : f.mug2;
  planesdf::BlobValidation r;
  for (auto _ : state) {
    r = planesdf::validateBlob(f.mug1, target, Pose::Identity(), f.blob, cfg);
    benchmark::DoNotOptimize(r.mean_similarity);
  }
  state.counters["blob_voxels"] = static_cast<double>(f.blob.size());
  state.counters["key_voxels"] = r.key_voxels;
  state.counters["scored"] = r.scored;
  state.counters["mean_similarity"] = r.mean_similarity;
}
BENCHMARK(BM_ValidateMugBlob)
    ->ArgsProduct({{1, 0}, {0, 1}})
    ->ArgNames({"threads", "books"})
    ->Unit(benchmark::kMillisecond);

/// Key voxel selection alone (dense Hessians over the blob's box, det extrema).
void BM_KeyVoxelsMugBlob(benchmark::State& state) {
  const Fixture& f = fixture();
  const Config cfg;
  std::size_t n = 0;
  for (auto _ : state) {
    n = planesdf::keyVoxels(f.mug1, f.blob, cfg).size();
    benchmark::DoNotOptimize(n);
  }
  state.counters["key_voxels"] = static_cast<double>(n);
}
BENCHMARK(BM_KeyVoxelsMugBlob)->Unit(benchmark::kMillisecond);

/// One source feature plus one target feature through the public building blocks (each
/// computes the Hessians of its own 7x7x7 patch).
void BM_FeaturePair(benchmark::State& state) {
  const Fixture& f = fixture();
  const Config cfg;
  const std::vector<planesdf::KeyVoxel> keys = planesdf::keyVoxels(f.mug1, f.blob, cfg);
  if (keys.empty()) {
    state.SkipWithError("no key voxel");
    return;
  }
  std::size_t k = 0;
  for (auto _ : state) {
    const Eigen::Vector3i v = keys[k++ % keys.size()].voxel;
    const auto src = planesdf::featureAt(f.mug1, v, cfg);
    const auto dst = planesdf::featureAt(f.mug2, v, src->ranges, cfg);
    benchmark::DoNotOptimize(dst);
  }
}
BENCHMARK(BM_FeaturePair)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
