// Soak: one map fed 10,000 frames of the same tabletop, as a headset that keeps looking around one
// room for five and a half minutes at 30 Hz. Nothing may grow with the frame count once the
// scene has been seen: planes, blocks, kept points, memory, time per frame. The map must still
// be right.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <vector>

#include <unistd.h>

#include "analytic_scene.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/map.hpp"

namespace planesdf {
namespace {

struct MapSize {
  std::size_t planes = 0, blocks = 0, points = 0, bytes = 0;
};

/// Resident set size of this process, MB (0 when /proc is not there).
double residentMb() {
  std::ifstream statm("/proc/self/statm");
  double pages = 0.0, resident = 0.0;
  statm >> pages >> resident;
  return resident * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

MapSize sizeOf(const Map& map) {
  MapSize s;
  s.planes = map.planes().size();
  for (const PlaneSdf& p : map.planes()) s.blocks += p.volume.numBlocks();
  s.points = map.points().size();
  s.bytes = map.memoryBytes();
  return s;
}

TEST(Soak, TenThousandFramesOfOneSceneGrowNothingAndKeepTheMapRight) {
  // A 6 cm box and a 10 cm cylinder on the table, seen from 24 poses on two rings at 80x60
  // pixels (small frames keep the run short; the per-frame code paths are the same).
  const test::AnalyticScene scene = test::tableWith(
      {test::Primitive::box({-0.25, -0.1, test::kTableTop}, {-0.15, 0.0, test::kTableTop + 0.06}),
       test::Primitive::cylinder({0.2, 0.1, test::kTableTop}, 0.05, 0.10)});
  const Intrinsics k = test::pinhole(80, 60, 65.0);
  const Eigen::Vector3d centre(0.0, 0.0, test::kTableTop);
  std::vector<Pose> poses = test::ringPoses(centre, 1.2, 0.6, 12);
  for (const Pose& p : test::ringPoses(centre, 0.9, 0.9, 12)) poses.push_back(p);
  std::vector<DepthFrame> frames;
  for (const Pose& p : poses) frames.push_back(test::renderDepth(scene, k, p));

  Config cfg;
  cfg.threads = 1;         // a timing bound that holds beside the other tests on a shared machine
  cfg.voxel_size = 0.012;  // fewer blocks per frame: the soak is about counts, not detail
  Map map(cfg);
  const int kFrames = 10000, kWarmUp = 10 * static_cast<int>(poses.size());
  MapSize warm, peak;
  double warm_rss = 0.0, peak_rss = 0.0;
  std::vector<double> ms;
  for (int i = 0; i < kFrames; ++i) {
    const std::size_t f = static_cast<std::size_t>(i) % poses.size();
    ms.push_back(map.integrate(frames[f], poses[f]).milliseconds);
    if (i + 1 == kWarmUp) {
      warm = sizeOf(map);
      warm_rss = residentMb();
    }
    if (i + 1 > kWarmUp && (i + 1) % 500 == 0) {
      const MapSize s = sizeOf(map);
      peak.planes = std::max(peak.planes, s.planes);
      peak.blocks = std::max(peak.blocks, s.blocks);
      peak.points = std::max(peak.points, s.points);
      peak.bytes = std::max(peak.bytes, s.bytes);
      peak_rss = std::max(peak_rss, residentMb());
    }
  }
  EXPECT_EQ(map.frames(), static_cast<std::uint64_t>(kFrames));
  ASSERT_GE(warm.planes, 2u);  // floor and table top
  // Every view was seen ten times during the warm-up: the same frames again add nothing.
  EXPECT_EQ(peak.planes, warm.planes);
  EXPECT_EQ(peak.blocks, warm.blocks);
  EXPECT_EQ(peak.points, warm.points);
  EXPECT_LE(peak.bytes, warm.bytes + warm.bytes / 100);
  // The process's resident memory is flat too (16 MB: allocator slack, not the map).
  EXPECT_LE(peak_rss, warm_rss + 16.0) << "resident " << warm_rss << " MB after the warm-up";
  // A frame costs no more at the end than after the warm-up: the median of the last 1,000
  // frames within 3 times that of the 1,000 after the warm-up (a bound loose enough for a
  // loaded machine, tight against a cost that grows with the frame count).
  const double early = median({ms.begin() + kWarmUp, ms.begin() + kWarmUp + 1000});
  const double late = median({ms.end() - 1000, ms.end()});
  EXPECT_LE(late, 3.0 * early) << "ms per frame: " << early << " early, " << late << " late";

  // The table's height map still holds the box at 6 cm and the cylinder at 10 cm, to a voxel.
  const PlaneSdf* table = nullptr;
  for (const PlaneSdf& p : map.planes())
    if (std::abs(p.plane.signedDistance({0.0, 0.0, test::kTableTop})) < 0.02 &&
        p.plane.normal.z() > 0.9)
      table = &p;
  ASSERT_NE(table, nullptr);
  const HeightMap hm = computeHeightMap(table->volume, cfg);
  const auto heightAt = [&](const Eigen::Vector3d& world) {
    const Eigen::Vector3d uvh = table->plane.toLocal(world);
    const Eigen::Vector2i c = hm.cellOf(uvh.head<2>());
    return hm.inBounds(c.x(), c.y()) ? static_cast<double>(hm.at(c.x(), c.y())) : -1.0;
  };
  const double tol = cfg.voxel_size;
  EXPECT_NEAR(heightAt({-0.2, -0.05, test::kTableTop}), 0.06, tol);
  EXPECT_NEAR(heightAt({0.2, 0.1, test::kTableTop}), 0.10, tol);
  EXPECT_NEAR(heightAt({0.0, -0.25, test::kTableTop}), 0.0, tol);
}

}  // namespace
}  // namespace planesdf
