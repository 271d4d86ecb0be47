// Tests of the height map, the object map, the 2D mask helpers and their pictures, on TSDF
// volumes filled with analytic signed distances (a plane h = 0 with a box and a cylinder on it)
// and on volumes fused from depth frames rendered here by ray casting.

#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <limits>
#include <random>
#include <vector>

#include "analytic_scene.hpp"
#include "planesdf/error.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/tsdf.hpp"
#include "test_support.hpp"

namespace planesdf {
namespace {

constexpr double kVoxel = 0.007;
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---- analytic scene: plane h = 0, a box and a cylinder standing on it -------------------------

struct Box {
  Eigen::Vector2d center;  ///< (u, v) of the footprint centre
  Eigen::Vector3d half;    ///< half extents; the box spans h in [0, 2 * half.z()]
  double sdf(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d c(center.x(), center.y(), half.z());
    const Eigen::Vector3d q = (p - c).cwiseAbs() - half;
    return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
  }
  bool footprintContains(const Eigen::Vector2d& uv) const {
    return std::abs(uv.x() - center.x()) <= half.x() && std::abs(uv.y() - center.y()) <= half.y();
  }
};

struct Cylinder {
  Eigen::Vector2d center;
  double radius = 0.04;
  double top = 0.12;  ///< spans h in [0, top]
  double sdf(const Eigen::Vector3d& p) const {
    const double dr = (p.head<2>() - center).norm() - radius;
    const double dz = std::abs(p.z() - 0.5 * top) - 0.5 * top;
    return std::min(std::max(dr, dz), 0.0) + Eigen::Vector2d(dr, dz).cwiseMax(0.0).norm();
  }
  bool footprintContains(const Eigen::Vector2d& uv) const { return (uv - center).norm() <= radius; }
};

const Box kBox{Eigen::Vector2d(-0.10, 0.05), Eigen::Vector3d(0.05, 0.03, 0.04)};  // 10x6x8 cm
const Cylinder kCylinder{Eigen::Vector2d(0.10, -0.05), 0.04, 0.12};               // r 4, h 12 cm

double sceneSdf(const Eigen::Vector3d& p) {
  return std::min({p.z(), kBox.sdf(p), kCylinder.sdf(p)});
}

/// Fills every voxel of the blocks covering [-half_alloc, half_alloc]^2 x [h_lo, h_hi] from
/// `sdf` (clamped to the truncation). A voxel is observed (weight 1) when its centre's (u, v)
/// lies inside `observed_half` (a square) and it is in free space or within the truncation of
/// the surface, as a depth sensor would see it; deeper voxels stay unobserved. Nothing is
/// higher than `top` (so the sdf is only evaluated below top + truncation).
void fillVolume(TsdfVolume& vol, const std::function<double(const Eigen::Vector3d&)>& sdf,
                double half_alloc, double observed_half, double h_lo = -0.05, double h_hi = 0.33,
                double top = 0.13) {
  const Eigen::Vector3i lo = vol.blockIndexAt(Eigen::Vector3d(-half_alloc, -half_alloc, h_lo));
  const Eigen::Vector3i hi = vol.blockIndexAt(Eigen::Vector3d(half_alloc, half_alloc, h_hi));
  const double trunc = vol.truncation();
  for (int bz = lo.z(); bz <= hi.z(); ++bz)
    for (int by = lo.y(); by <= hi.y(); ++by)
      for (int bx = lo.x(); bx <= hi.x(); ++bx) {
        TsdfBlock& b = vol.allocateBlock(Eigen::Vector3i(bx, by, bz));
        for (int i = 0; i < kTsdfBlockVoxels; ++i) {
          const Eigen::Vector3d c = vol.voxelCenter(b.voxelIndex(i));
          if (std::abs(c.x()) > observed_half || std::abs(c.y()) > observed_half) continue;
          const double d = c.z() >= top + trunc ? trunc : std::clamp(sdf(c), -kInf, trunc);
          if (d >= -trunc) b.voxels[static_cast<std::size_t>(i)] = {static_cast<float>(d), 1.0f};
        }
      }
}

Config testConfig() {
  Config cfg;
  cfg.voxel_size = kVoxel;
  cfg.threads = 2;
  return cfg;
}

/// The standard scene (testConfig()): allocated over 0.7 x 0.7 m, observed over the central
/// 0.5 x 0.5 m. Built once.
const TsdfVolume& sceneVolume() {
  static const TsdfVolume vol = [] {
    TsdfVolume v(testConfig());
    fillVolume(v, sceneSdf, 0.35, 0.25);
    return v;
  }();
  return vol;
}

bool insideSquare(const Eigen::Vector2d& uv, double half) {
  return std::abs(uv.x()) <= half && std::abs(uv.y()) <= half;
}

/// Inclusive cell range [first, last] whose centres lie in [lo, hi] along one axis.
Eigen::Vector2i cellRange(double lo, double hi, int origin) {
  return Eigen::Vector2i(static_cast<int>(std::ceil(lo / kVoxel - 0.5)) - origin,
                         static_cast<int>(std::floor(hi / kVoxel - 0.5)) - origin);
}

// ---- height map -------------------------------------------------------------------------------

TEST(HeightMap, GridCoversTheAllocatedBlocksAndMapsCoordinates) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  EXPECT_TRUE(computeHeightMap(vol, cfg).empty());
  vol.allocateBlock(Eigen::Vector3i(-2, 3, 0));
  vol.allocateBlock(Eigen::Vector3i(1, 5, -1));
  const HeightMap hm = computeHeightMap(vol, cfg);
  EXPECT_EQ(hm.width, 4 * 8);
  EXPECT_EQ(hm.height, 3 * 8);
  EXPECT_EQ(hm.i0, -16);
  EXPECT_EQ(hm.j0, 24);
  EXPECT_DOUBLE_EQ(hm.cell_size, kVoxel);
  ASSERT_EQ(hm.heights.size(), hm.numCells());
  // Nothing is observed: every cell, allocated column or not, is unobserved.
  EXPECT_EQ(hm.numObserved(), 0u);
  EXPECT_EQ(hm.at(0, 0), kUnobserved);
  // Cell (x, y) is voxel column (i0 + x, j0 + y).
  const Eigen::Vector2d c = hm.cellCenter(3, 5);
  EXPECT_NEAR(c.x(), (-16 + 3 + 0.5) * kVoxel, 1e-12);
  EXPECT_NEAR(c.y(), (24 + 5 + 0.5) * kVoxel, 1e-12);
  EXPECT_EQ(hm.cellOf(c), Eigen::Vector2i(3, 5));
  EXPECT_EQ(hm.cellOf(c + Eigen::Vector2d(0.49 * kVoxel, -0.49 * kVoxel)), Eigen::Vector2i(3, 5));
  EXPECT_EQ(hm.cellOf(c - Eigen::Vector2d(0.51 * kVoxel, 0.0)), Eigen::Vector2i(2, 5));
  EXPECT_EQ(hm.cellOf(vol.voxelCenter(Eigen::Vector3i(-16, 24, 0)).head<2>()),
            Eigen::Vector2i(0, 0));
  EXPECT_TRUE(hm.inBounds(0, 0));
  EXPECT_TRUE(hm.inBounds(31, 23));
  EXPECT_FALSE(hm.inBounds(32, 0));
  EXPECT_FALSE(hm.inBounds(0, -1));
  EXPECT_EQ(hm.cellOf(Eigen::Vector2d(std::nan(""), 0.0)).x(), -1);
  // Blocks kilometres apart: a clear error instead of a 6e9-cell allocation.
  vol.allocateBlock(Eigen::Vector3i(10000, 10000, 0));
  EXPECT_THROW(computeHeightMap(vol, cfg), Error);
}

TEST(HeightMap, BlocksAtTheIndexLimitAreRefusedBeyondTheMemoryLimit) {
  // Two blocks at the ends of the map format's index range: 8,388,608 x 8 cells, inside
  // kMaxHeightMapCells but about 3 GB with the grids detection derives from them.
  Config cfg;
  cfg.memory_limit_mb = 256;
  TsdfVolume vol(cfg);
  vol.allocateBlock(Eigen::Vector3i(-(1 << 20) + 1, 0, 0));
  vol.allocateBlock(Eigen::Vector3i(0, 0, 0));
  try {
    computeHeightMap(vol, cfg);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("height map of 8388608 x 8 cells"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("memory limit of 256 MB"), std::string::npos) << e.what();
  }
  cfg.memory_limit_mb = 0;  // the blocks of a table top stay well inside the default budget
  TsdfVolume near(cfg);
  near.allocateBlock(Eigen::Vector3i(-100, -100, 0));
  near.allocateBlock(Eigen::Vector3i(100, 100, 0));
  EXPECT_EQ(computeHeightMap(near, cfg).numCells(), std::size_t{1608} * 1608);
}

TEST(HeightMap, BoxAndCylinderHeightsFlatZeroOutsideUnobserved) {
  const Config cfg = testConfig();
  const TsdfVolume& vol = sceneVolume();
  const HeightMap hm = computeHeightMap(vol, cfg);
  ASSERT_FALSE(hm.empty());
  int box_cells = 0, cyl_cells = 0, flat_cells = 0, unobserved_cells = 0;
  for (int y = 0; y < hm.height; ++y)
    for (int x = 0; x < hm.width; ++x) {
      const Eigen::Vector2d uv = hm.cellCenter(x, y);
      const float h = hm.at(x, y);
      if (!insideSquare(uv, 0.25)) {
        EXPECT_EQ(h, kUnobserved) << x << "," << y;
        ++unobserved_cells;
      } else if (kBox.footprintContains(uv)) {
        EXPECT_NEAR(h, 0.08, kVoxel) << x << "," << y;
        ++box_cells;
      } else if (kCylinder.footprintContains(uv)) {
        EXPECT_NEAR(h, 0.12, kVoxel) << x << "," << y;
        ++cyl_cells;
      } else {
        EXPECT_GE(h, 0.0f);
        EXPECT_LE(h, cfg.h_obj) << x << "," << y;
        ++flat_cells;
      }
    }
  EXPECT_GT(box_cells, 100);
  EXPECT_GT(cyl_cells, 90);
  EXPECT_GT(flat_cells, 4000);
  EXPECT_GT(unobserved_cells, 3000);
  // The analytic SDF is linear above the tops: the interpolated crossings are exact.
  const Eigen::Vector2i b = hm.cellOf(kBox.center + Eigen::Vector2d(0.001, 0.001));
  EXPECT_NEAR(hm.at(b.x(), b.y()), 0.08, 1e-5);
  const Eigen::Vector2i c = hm.cellOf(kCylinder.center + Eigen::Vector2d(0.001, 0.001));
  EXPECT_NEAR(hm.at(c.x(), c.y()), 0.12, 1e-5);
}

TEST(HeightMap, FreeSpaceSeenOnlyHighUpIsUnobserved) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  // Column (0, 0): free voxels only from h = 5 cm up. Column (1, 0): free all the way down to
  // the first voxel (centre 3.5 mm <= h_obj). Column (2, 0): free down to the second voxel
  // (centre 10.5 mm > h_obj = 10 mm). Column (3, 0): observed below the plane only, free.
  for (int k = 0; k < 40; ++k) {
    const double h = (k + 0.5) * kVoxel;
    const TsdfVoxel free{static_cast<float>(vol.truncation()), 1.0f};
    vol.allocateBlock(TsdfVolume::blockOfVoxel({0, 0, k}));
    if (h >= 0.05) *vol.voxel({0, 0, k}) = free;
    *vol.voxel({1, 0, k}) = free;
    if (k >= 1) *vol.voxel({2, 0, k}) = free;
  }
  vol.allocateBlock(Eigen::Vector3i(0, 0, -1));
  *vol.voxel({3, 0, -1}) = TsdfVoxel{0.02f, 1.0f};
  const HeightMap hm = computeHeightMap(vol, cfg);
  const auto cell = [&](int i, int j) { return hm.at(i - hm.i0, j - hm.j0); };
  EXPECT_EQ(cell(0, 0), kUnobserved);
  EXPECT_EQ(cell(1, 0), 0.0f);
  EXPECT_EQ(cell(2, 0), kUnobserved);
  EXPECT_EQ(cell(3, 0), 0.0f);
  EXPECT_EQ(cell(4, 0), kUnobserved);  // allocated, never observed
}

TEST(HeightMap, SplattedColumnsWithoutFreeSpaceUseTheTopFace) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  vol.allocateBlock(Eigen::Vector3i(0, 0, 0));
  vol.allocateBlock(Eigen::Vector3i(0, 0, 1));
  vol.allocateBlock(Eigen::Vector3i(0, 0, -1));
  // Column (0, 0): only inside-surface voxels k = 9, 10 (a splat without its free side): the
  // surface is the top face of voxel 10, h = 11 voxels.
  *vol.voxel({0, 0, 10}) = {-0.001f, 1.0f};
  *vol.voxel({0, 0, 9}) = {-0.008f, 1.0f};
  // Column (1, 0): the full splat around a surface at h = 0.05: crossing interpolated.
  const double s = 0.05;
  for (int k = 3; k <= 11; ++k) {
    const double h = (k + 0.5) * kVoxel;
    *vol.voxel({1, 0, k}) = {static_cast<float>(h - s), 1.0f};
  }
  // Column (2, 0): a surface voxel directly below unobserved space at h < 0: the plane, 0.
  *vol.voxel({2, 0, -2}) = {-0.002f, 1.0f};
  // Column (3, 0): negative voxels under a gap (unallocated block above): top face of k = 15.
  *vol.voxel({3, 0, 15}) = {-0.003f, 1.0f};
  *vol.voxel({3, 0, 14}) = {-0.010f, 1.0f};
  // Column (4, 0): the upper voxel is free but not adjacent (k = 12 free, k = 11 unobserved,
  // k = 10 inside): top face of k = 10.
  *vol.voxel({4, 0, 12}) = {0.02f, 1.0f};
  *vol.voxel({4, 0, 10}) = {-0.002f, 1.0f};
  const HeightMap hm = computeHeightMap(vol, cfg);
  const auto cell = [&](int i) { return hm.at(i - hm.i0, -hm.j0); };
  EXPECT_NEAR(cell(0), 11 * kVoxel, 1e-6);
  EXPECT_NEAR(cell(1), s, 1e-6);
  EXPECT_EQ(cell(2), 0.0f);
  EXPECT_NEAR(cell(3), 16 * kVoxel, 1e-6);
  EXPECT_NEAR(cell(4), 11 * kVoxel, 1e-6);
  // Top faces were never seen from above; the crossing was.
  const auto unseen = [&](int i) { return hm.unseenAbove(i - hm.i0, -hm.j0); };
  EXPECT_TRUE(unseen(0));
  EXPECT_FALSE(unseen(1));
  EXPECT_TRUE(unseen(2));
  EXPECT_TRUE(unseen(3));
  EXPECT_TRUE(unseen(4));

  // A splatted cloud (integratePointsWithNormals) of a box on a plane.
  Config scfg = cfg;
  TsdfVolume svol(scfg);
  std::vector<Eigen::Vector3f> pts, nrm;
  const double step = 0.003;
  for (double v = -0.15; v <= 0.15; v += step)
    for (double u = -0.15; u <= 0.15; u += step) {
      const Eigen::Vector2d uv(u, v);
      const bool on_box = kBox.footprintContains(uv + kBox.center);
      pts.emplace_back(float(u + kBox.center.x()), float(v + kBox.center.y()),
                       on_box ? 0.08f : 0.0f);
      nrm.emplace_back(0.f, 0.f, 1.f);
    }
  integratePointsWithNormals(svol, pts, nrm, scfg);
  const HeightMap shm = computeHeightMap(svol, scfg);
  int box = 0, flat = 0;
  for (int y = 0; y < shm.height; ++y)
    for (int x = 0; x < shm.width; ++x) {
      const Eigen::Vector2d uv = shm.cellCenter(x, y);
      if (!insideSquare(uv - kBox.center, 0.14)) continue;
      const Eigen::Vector2d q = (uv - kBox.center).cwiseAbs() - kBox.half.head<2>();
      if (q.maxCoeff() < -1.5 * kVoxel) {
        EXPECT_NEAR(shm.at(x, y), 0.08, kVoxel) << x << "," << y;
        ++box;
      } else if (q.maxCoeff() > 1.5 * kVoxel) {
        EXPECT_NEAR(shm.at(x, y), 0.0, kVoxel) << x << "," << y;
        ++flat;
      }
    }
  EXPECT_GT(box, 60);
  EXPECT_GT(flat, 1000);
}

TEST(HeightMap, CrossingsBelowThePlaneAreZeroLowOnesAreKept) {
  const Config cfg = testConfig();
  // The plane 4 mm low: every observed cell is 0. The plane 5 mm high: 5 mm, below h_obj.
  for (const double offset : {-0.004, 0.005}) {
    TsdfVolume vol(cfg);
    fillVolume(
        vol, [&](const Eigen::Vector3d& p) { return p.z() - offset; }, 0.05, 1.0);
    const HeightMap hm = computeHeightMap(vol, cfg);
    ASSERT_EQ(hm.numObserved(), hm.numCells());
    for (const float h : hm.heights) EXPECT_NEAR(h, std::max(offset, 0.0), 1e-6);
    EXPECT_EQ(computeObjectMap(hm, cfg).numObjects(), 0);
  }
}

TEST(HeightMap, VoxelsBelowWMinAreUnobserved) {
  Config cfg = testConfig();
  TsdfVolume vol = sceneVolume();
  cfg.w_min = 2.0f;  // every voxel has weight 1
  EXPECT_EQ(computeHeightMap(vol, cfg).numObserved(), 0u);
  // Raise the weight of one column only: it alone is observed, with the box height.
  cfg.w_min = 1.5f;
  const HeightMap ref = computeHeightMap(vol, testConfig());
  const Eigen::Vector2i c = ref.cellOf(kBox.center);
  for (int k = -8; k < 48; ++k) {
    TsdfVoxel* v = vol.voxel({ref.i0 + c.x(), ref.j0 + c.y(), k});
    if (v && v->weight > 0.0f) v->weight = 3.0f;
  }
  const HeightMap hm = computeHeightMap(vol, cfg);
  EXPECT_EQ(hm.numObserved(), 1u);
  EXPECT_NEAR(hm.at(c.x(), c.y()), 0.08, 1e-5);
}

TEST(HeightMap, SameResultForAnyThreadCountAndFastOnATable) {
  // A 1.5 m x 1.5 m table at 7 mm, fully observed, with the box and the cylinder on it.
  // The flat table is one block column copied everywhere (cheap under sanitizers), then the
  // central part is filled with the objects.
  Config cfg = testConfig();
  TsdfVolume vol(cfg);
  TsdfVolume flat(cfg);
  fillVolume(flat, sceneSdf, 0.0, 1.0);  // the block column at (0, 0): plane only
  const Eigen::Vector3i lo = vol.blockIndexAt(Eigen::Vector3d(-0.75, -0.75, 0.0));
  const Eigen::Vector3i hi = vol.blockIndexAt(Eigen::Vector3d(0.75, 0.75, 0.0));
  flat.forEachBlock([&](const TsdfBlock& b) {
    for (int by = lo.y(); by <= hi.y(); ++by)
      for (int bx = lo.x(); bx <= hi.x(); ++bx)
        vol.allocateBlock(Eigen::Vector3i(bx, by, b.index.z())).voxels = b.voxels;
  });
  fillVolume(vol, sceneSdf, 0.2, 1.0);
  cfg.threads = 1;
  const HeightMap one = computeHeightMap(vol, cfg);
  cfg.threads = 2;
  const HeightMap two = computeHeightMap(vol, cfg);
  EXPECT_EQ(one.heights, two.heights);
  EXPECT_GE(one.numCells(), 45000u);
  // The worst case: the whole band allocated and observed (fusion allocates only blocks near
  // surfaces). Best of several runs per thread count: the machine may be shared.
  double best_ms = kInf;
  for (const int threads : {1, 2}) {
    cfg.threads = threads;
    double best = kInf;
    for (int rep = 0; rep < 9; ++rep) {
      const auto t0 = std::chrono::steady_clock::now();
      const HeightMap hm = computeHeightMap(vol, cfg);
      const auto t1 = std::chrono::steady_clock::now();
      best = std::min(best, std::chrono::duration<double, std::milli>(t1 - t0).count());
      ASSERT_EQ(hm.numCells(), one.numCells());
    }
    std::printf("[ timing   ] computeHeightMap: %zu cells, %zu blocks, %d thread(s): %.2f ms\n",
                one.numCells(), vol.numBlocks(), threads, best);
    best_ms = std::min(best_ms, best);
  }
#if defined(NDEBUG) && !defined(__SANITIZE_ADDRESS__)
  EXPECT_LT(best_ms, 10.0);
#endif
}

/// The definition of computeHeightMap, written as plainly as possible: one column at a time,
/// every voxel looked up by index.
/// `unseen` receives whether the height is a top face (HeightMap::unseen_above).
float referenceColumn(const TsdfVolume& vol, int i, int j, int k_lo, int k_hi, const Config& cfg,
                      bool* unseen) {
  *unseen = false;
  const double vs = vol.voxelSize();
  const auto observed = [&](const TsdfVoxel* v) {
    return v != nullptr && v->weight > 0.0f && v->weight >= cfg.w_min;
  };
  bool free_low = false;
  for (int k = k_hi; k >= k_lo; --k) {
    const TsdfVoxel* v = vol.voxel({i, j, k});
    const TsdfVoxel* up = vol.voxel({i, j, k + 1});
    if (!observed(v)) continue;
    if (v->sdf > 0.0f) {
      free_low = free_low || (k + 0.5) * vs <= cfg.h_obj;
      continue;
    }
    if (!observed(up)) {
      *unseen = true;
      return static_cast<float>(std::max(0.0, (k + 1) * vs));
    }
    if (up->sdf > 0.0f)
      return static_cast<float>(std::max(0.0, (k + 0.5) * vs + vs * v->sdf / (v->sdf - up->sdf)));
  }
  return free_low ? 0.0f : kUnobserved;
}

/// Compares computeHeightMap with referenceColumn on every `stride`-th column along x and y.
void expectMatchesReference(const TsdfVolume& vol, const Config& cfg, int stride = 1) {
  const HeightMap hm = computeHeightMap(vol, cfg);
  Eigen::Vector3i lo, hi;
  ASSERT_TRUE(vol.blockBounds(&lo, &hi));
  int mismatches = 0;
  for (int y = 0; y < hm.height; y += stride)
    for (int x = 0; x < hm.width; x += stride) {
      bool unseen = false;
      const float want =
          referenceColumn(vol, hm.i0 + x, hm.j0 + y, lo.z() * kTsdfBlockSide,
                          hi.z() * kTsdfBlockSide + kTsdfBlockSide - 1, cfg, &unseen);
      if ((std::abs(hm.at(x, y) - want) > 1e-6f || hm.unseenAbove(x, y) != unseen) &&
          ++mismatches < 10)
        ADD_FAILURE() << "cell " << x << "," << y << ": " << hm.at(x, y) << " != " << want
                      << " or unseen above " << hm.unseenAbove(x, y) << " != " << unseen;
    }
  EXPECT_EQ(mismatches, 0);
}

TEST(HeightMap, MatchesAPlainPerColumnWalkOnRandomVolumes) {
  Config cfg = testConfig();
  cfg.w_min = 2.0f;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  const auto uniform = [&] { return unit(rng); };
  TsdfVolume vol(cfg);
  // 6 x 5 block columns, each a random subset of block layers -2..4 (gaps included); blocks
  // are random mixes, or uniformly free / unobserved / below w_min (the walk's fast paths).
  for (int by = 0; by < 5; ++by)
    for (int bx = 0; bx < 6; ++bx)
      for (int bz = -2; bz <= 4; ++bz) {
        if (uniform() < 0.3f) continue;
        TsdfBlock& b = vol.allocateBlock(Eigen::Vector3i(bx, by, bz));
        const float kind = uniform();
        for (TsdfVoxel& v : b.voxels) {
          if (kind < 0.2f) {
            v = {0.01f + 0.02f * uniform(), 3.0f};  // all free
          } else if (kind < 0.3f) {
            v = {-0.01f, 1.0f};  // all below w_min
          } else if (kind < 0.4f) {
            v = {};  // all unobserved
          } else {
            const float r = uniform();
            const float w = r < 0.15f ? 0.0f : (r < 0.25f ? 1.0f : 2.0f + 5.0f * uniform());
            const float sdf = uniform() < 0.3f ? -0.03f * uniform() : 0.03f * uniform();
            v = {r < 0.3f && r >= 0.25f ? 0.0f : sdf, w};
          }
        }
      }
  expectMatchesReference(vol, cfg);
  cfg.threads = 1;
  expectMatchesReference(vol, cfg);
  cfg.simd = false;  // the default builds of the block classification and layer walk
  expectMatchesReference(vol, cfg);
  // The analytic scene, with its fully free blocks.
  Config scfg = testConfig();
  expectMatchesReference(sceneVolume(), scfg, 2);
}

TEST(HeightMap, AWindowTrimsTheGridByWholeRoughnessTilesAndKeepsItsCells) {
  Config cfg = testConfig();
  cfg.roughness_tile = 16;  // two blocks: the trimmed origin moves by whole pairs of blocks
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  TsdfVolume vol(cfg);
  for (int by = -3; by <= 9; ++by)
    for (int bx = -4; bx <= 12; ++bx)
      for (TsdfVoxel& v : vol.allocateBlock(Eigen::Vector3i(bx, by, 0)).voxels)
        v = {unit(rng) < 0.5f ? -0.01f : 0.02f, 1.0f + 4.0f * unit(rng)};
  const HeightMap full = computeHeightMap(vol, cfg);
  const double block = kVoxel * kTsdfBlockSide;
  // Blocks 3..5 in u and 1..2 in v: the grid starts at the tile boundary below (block 2, block
  // 1) and ends at the one above (block 5, block 2).
  const Eigen::AlignedBox2d window(Eigen::Vector2d(3.2 * block, 1.5 * block),
                                   Eigen::Vector2d(5.5 * block, 2.9 * block));
  const HeightMap trimmed = computeHeightMap(vol, cfg, window);
  EXPECT_EQ(trimmed.i0, 2 * kTsdfBlockSide);
  EXPECT_EQ(trimmed.j0, 1 * kTsdfBlockSide);
  EXPECT_EQ(trimmed.width, 4 * kTsdfBlockSide);
  EXPECT_EQ(trimmed.height, 2 * kTsdfBlockSide);
  EXPECT_EQ((trimmed.i0 - full.i0) % cfg.roughness_tile, 0);
  EXPECT_EQ((trimmed.j0 - full.j0) % cfg.roughness_tile, 0);
  int differing = 0;
  for (int y = 0; y < trimmed.height; ++y)
    for (int x = 0; x < trimmed.width; ++x) {
      const int fx = x + trimmed.i0 - full.i0, fy = y + trimmed.j0 - full.j0;
      differing += trimmed.at(x, y) != full.at(fx, fy) ||
                   trimmed.unseenAbove(x, y) != full.unseenAbove(fx, fy);
    }
  EXPECT_EQ(differing, 0);
  // Its roughness tiles are the full map's.
  const RoughnessMap rt = computeRoughness(trimmed, cfg), rf = computeRoughness(full, cfg);
  const int dtx = (trimmed.i0 - full.i0) / cfg.roughness_tile;
  const int dty = (trimmed.j0 - full.j0) / cfg.roughness_tile;
  for (int ty = 0; ty < rt.tiles_y; ++ty)
    for (int tx = 0; tx < rt.tiles_x; ++tx)
      EXPECT_EQ(rt.sigma[static_cast<std::size_t>(ty * rt.tiles_x + tx)],
                rf.sigma[static_cast<std::size_t>((ty + dty) * rf.tiles_x + tx + dtx)]);
  // A window past the last block column is clipped to it; one beside every block gives nothing.
  const HeightMap edge =
      computeHeightMap(vol, cfg,
                       Eigen::AlignedBox2d(Eigen::Vector2d(11.5 * block, -9.0 * block),
                                           Eigen::Vector2d(40.0 * block, -2.5 * block)));
  EXPECT_EQ(edge.i0 + edge.width, full.i0 + full.width);
  EXPECT_EQ(edge.j0, full.j0);
  EXPECT_TRUE(computeHeightMap(vol, cfg,
                               Eigen::AlignedBox2d(Eigen::Vector2d(20.0 * block, 0.0),
                                                   Eigen::Vector2d(21.0 * block, block)))
                  .empty());
}

// ---- end to end: depth frames rendered by ray casting and fused ---------------------------

/// Distance along o + t * dir to the plane h = 0 or the box, or +inf.
double raycastBoxOnPlane(const Eigen::Vector3d& o, const Eigen::Vector3d& dir, const Box& box) {
  double best = kInf;
  if (dir.z() < 0.0) best = -o.z() / dir.z();
  const Eigen::Vector3d lo(box.center.x() - box.half.x(), box.center.y() - box.half.y(), 0.0);
  const Eigen::Vector3d hi(box.center.x() + box.half.x(), box.center.y() + box.half.y(),
                           2.0 * box.half.z());
  double t0 = -kInf, t1 = kInf;
  for (int a = 0; a < 3; ++a) {
    if (dir[a] == 0.0) {
      if (o[a] < lo[a] || o[a] > hi[a]) return best;
      continue;
    }
    double ta = (lo[a] - o[a]) / dir[a], tb = (hi[a] - o[a]) / dir[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  if (t0 <= t1 && t0 > 0.0) best = std::min(best, t0);
  return best;
}

using test::lookAt;

DepthFrame renderDepth(const Box& box, const Pose& T_local_camera) {
  DepthFrame f;
  f.intrinsics.width = 320;
  f.intrinsics.height = 240;
  f.intrinsics.fx = f.intrinsics.fy = 262.5;
  f.intrinsics.cx = 159.5;
  f.intrinsics.cy = 119.5;
  const Intrinsics& K = f.intrinsics;
  f.depth.assign(static_cast<std::size_t>(K.width) * K.height, 0.0f);
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d ray((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);  // z = 1: t = depth
      const double t =
          raycastBoxOnPlane(T_local_camera.translation(), T_local_camera.linear() * ray, box);
      if (std::isfinite(t)) f.depth[static_cast<std::size_t>(v) * K.width + u] = float(t);
    }
  return f;
}

TEST(HeightMapFusion, FusedDepthFramesOfABoxGiveItsHeight) {
  const Config cfg = testConfig();
  const Box box{Eigen::Vector2d(0.02, -0.01), Eigen::Vector3d(0.05, 0.03, 0.04)};
  TsdfVolume vol(cfg);
  for (int n = 0; n < 6; ++n) {
    const double a = 2.0 * M_PI * n / 6 + 0.2;
    const Pose T = lookAt(Eigen::Vector3d(0.6 * std::cos(a), 0.6 * std::sin(a), 0.55),
                          Eigen::Vector3d(box.center.x(), box.center.y(), 0.03));
    integrateDepth(vol, renderDepth(box, T), T, cfg);
  }
  expectMatchesReference(vol, cfg, 3);
  const HeightMap hm = computeHeightMap(vol, cfg);
  ASSERT_FALSE(hm.empty());
  int top = 0, flat = 0;
  for (int y = 0; y < hm.height; ++y)
    for (int x = 0; x < hm.width; ++x) {
      const Eigen::Vector2d q = (hm.cellCenter(x, y) - box.center).cwiseAbs() - box.half.head<2>();
      const double r = (hm.cellCenter(x, y) - box.center).norm();
      if (q.maxCoeff() < -kVoxel) {
        EXPECT_NEAR(hm.at(x, y), 0.08, kVoxel) << x << "," << y;
        ++top;
      } else if (q.maxCoeff() > vol.truncation() + kVoxel && r < 0.3) {
        EXPECT_GE(hm.at(x, y), 0.0f) << x << "," << y;       // observed ...
        EXPECT_LE(hm.at(x, y), cfg.h_obj) << x << "," << y;  // ... and flat
        ++flat;
      }
    }
  EXPECT_GT(top, 80);
  EXPECT_GT(flat, 4000);
  // One object, the box, with its footprint.
  const ObjectMap om = computeObjectMap(hm, cfg);
  const ObjectInfo* biggest = &om.objects[0];
  for (const ObjectInfo& o : om.objects)
    if (o.area > biggest->area) biggest = &o;
  // Projective fusion also writes negative distances up to the truncation behind the box's top
  // edges as seen from the far side, which the height map faithfully reports as a ring of
  // cells a bit lower than the top: the footprint may grow by up to the truncation.
  const double cells = 0.10 * 0.06 / (kVoxel * kVoxel);
  const double perimeter = 2 * (0.10 + 0.06) / kVoxel;
  const double tr = vol.truncation();
  const double grown = (0.10 + 2 * tr) * (0.06 + 2 * tr) / (kVoxel * kVoxel);
  EXPECT_GE(biggest->area, cells - perimeter);
  EXPECT_LE(biggest->area, grown);
  EXPECT_NEAR(biggest->max_height, 0.08, kVoxel);
  EXPECT_NEAR((biggest->centroid - box.center).norm(), 0.0, kVoxel);
  int big_objects = 0;
  for (const ObjectInfo& o : om.objects) big_objects += o.area >= 5;
  EXPECT_EQ(big_objects, 1);
}

// ---- object map ------------------------------------------------------------------------------

TEST(ObjectMap, TwoObjectsWithAreasBoundingBoxesAndCentroids) {
  const Config cfg = testConfig();
  const HeightMap hm = computeHeightMap(sceneVolume(), cfg);
  const ObjectMap om = computeObjectMap(hm, cfg);
  ASSERT_TRUE(om.sameGeometry(hm));
  ASSERT_EQ(om.numObjects(), 2);
  // Raster order (v first): the cylinder (lower v) is label 1, the box label 2.
  const ObjectInfo& cyl = om.object(1);
  const ObjectInfo& box = om.object(2);
  EXPECT_EQ(cyl.label, 1);
  EXPECT_EQ(box.label, 2);
  const double box_cells = 0.10 * 0.06 / (kVoxel * kVoxel);
  const double box_perimeter = 2 * (0.10 + 0.06) / kVoxel;
  EXPECT_NEAR(box.area, box_cells, box_perimeter);
  const double cyl_cells = M_PI * 0.04 * 0.04 / (kVoxel * kVoxel);
  const double cyl_perimeter = 2 * M_PI * 0.04 / kVoxel;
  EXPECT_NEAR(cyl.area, cyl_cells, cyl_perimeter);
  // Exactly the cells whose centre lies in the footprint.
  int in_box = 0, in_cyl = 0;
  for (int y = 0; y < hm.height; ++y)
    for (int x = 0; x < hm.width; ++x) {
      in_box += kBox.footprintContains(hm.cellCenter(x, y));
      in_cyl += kCylinder.footprintContains(hm.cellCenter(x, y));
      if (kBox.footprintContains(hm.cellCenter(x, y))) {
        EXPECT_EQ(om.at(x, y), 2);
      }
      if (kCylinder.footprintContains(hm.cellCenter(x, y))) {
        EXPECT_EQ(om.at(x, y), 1);
      }
    }
  EXPECT_EQ(box.area, in_box);
  EXPECT_EQ(cyl.area, in_cyl);
  // Bounding boxes within one cell of the footprints.
  const auto expectBox = [&](const ObjectInfo& o, Eigen::Vector2d lo, Eigen::Vector2d hi) {
    const Eigen::Vector2i xs = cellRange(lo.x(), hi.x(), hm.i0);
    const Eigen::Vector2i ys = cellRange(lo.y(), hi.y(), hm.j0);
    EXPECT_NEAR(o.bbox_min.x(), xs[0], 1);
    EXPECT_NEAR(o.bbox_max.x(), xs[1], 1);
    EXPECT_NEAR(o.bbox_min.y(), ys[0], 1);
    EXPECT_NEAR(o.bbox_max.y(), ys[1], 1);
  };
  expectBox(box, kBox.center - kBox.half.head<2>(), kBox.center + kBox.half.head<2>());
  expectBox(cyl, kCylinder.center.array() - kCylinder.radius,
            kCylinder.center.array() + kCylinder.radius);
  EXPECT_EQ(box.bbox_max.x() - box.bbox_min.x() + 1, 14);  // 10 cm / 7 mm = 14.3
  EXPECT_NEAR(box.max_height, 0.08, 1e-5);
  EXPECT_NEAR(cyl.max_height, 0.12, 1e-5);
  EXPECT_LT((box.centroid - kBox.center).norm(), 0.5 * kVoxel);
  EXPECT_LT((cyl.centroid - kCylinder.center).norm(), 0.5 * kVoxel);
  // Every labelled cell is higher than h_obj, every higher cell is labelled.
  for (std::size_t i = 0; i < hm.numCells(); ++i)
    EXPECT_EQ(om.labels[i] != 0, hm.heights[i] > cfg.h_obj);
}

HeightMap syntheticMap(int w, int h, float fill) {
  HeightMap hm;
  hm.width = w;
  hm.height = h;
  hm.cell_size = kVoxel;
  hm.heights.assign(hm.numCells(), fill);
  return hm;
}

TEST(ObjectMap, DiagonallyTouchingObjectsAreOne) {
  Config cfg = testConfig();
  cfg.object_min_solidity = 0.0;  // the brief's plain components: the lone cell is an object too
  HeightMap hm = syntheticMap(20, 12, 0.0f);
  // Two 3x3 squares touching at one corner: (2..4, 2..4) and (5..7, 5..7).
  for (int y = 2; y <= 4; ++y)
    for (int x = 2; x <= 4; ++x) hm.at(x, y) = 0.05f;
  for (int y = 5; y <= 7; ++y)
    for (int x = 5; x <= 7; ++x) hm.at(x, y) = 0.07f;
  hm.at(15, 2) = 0.02f;         // a third object, one cell
  hm.at(15, 8) = 0.009f;        // below h_obj: not an object
  hm.at(12, 10) = kUnobserved;  // unobserved: not an object
  const ObjectMap om = computeObjectMap(hm, cfg);
  ASSERT_EQ(om.numObjects(), 2);
  EXPECT_EQ(om.object(1).area, 18);
  EXPECT_EQ(om.object(1).bbox_min, Eigen::Vector2i(2, 2));
  EXPECT_EQ(om.object(1).bbox_max, Eigen::Vector2i(7, 7));
  EXPECT_FLOAT_EQ(om.object(1).max_height, 0.07f);
  EXPECT_EQ(om.object(2).area, 1);
  EXPECT_EQ(om.at(15, 2), 2);
  EXPECT_EQ(om.at(15, 8), 0);
  EXPECT_EQ(om.at(12, 10), 0);
  EXPECT_NEAR(om.object(1).centroid.x(), 5.0 * kVoxel, 1e-9);  // mean cell centre (4.5 + 0.5)
  // 4-connectivity separates the squares.
  const Components four = connectedComponents(maskAbove(hm, float(cfg.h_obj)), 1, 4);
  EXPECT_EQ(four.count(), 3);
  EXPECT_EQ(four.areas, (std::vector<int>{9, 1, 9}));
}

TEST(ObjectMap, SpeckleKeepsOnlyItsOpeningAndSolidObjectsStayWhole) {
  // The default speckle filter on the same map: the two squares (a component of 18 cells, 2 of
  // them with a full 3x3 neighbourhood: 11 %) stay whole; the lone cell (no such cell) is none.
  HeightMap hm = syntheticMap(20, 12, 0.0f);
  for (int y = 2; y <= 4; ++y)
    for (int x = 2; x <= 4; ++x) hm.at(x, y) = 0.05f;
  for (int y = 5; y <= 7; ++y)
    for (int x = 5; x <= 7; ++x) hm.at(x, y) = 0.07f;
  hm.at(15, 2) = 0.02f;
  const ObjectMap om = computeObjectMap(hm, testConfig());
  ASSERT_EQ(om.numObjects(), 1);
  EXPECT_EQ(om.object(1).area, 18);
  EXPECT_EQ(om.at(15, 2), 0);
}

TEST(ObjectMap, SensorSpeckleOnAFarSurfaceIsNoObject) {
  // A far wall's height map: every cell independently a few mm above h_obj with probability
  // 0.45 (single noisy observations; at that density the noise cells percolate into one
  // 8-connected cluster across the map), plus a 12 x 12 cell box (8.4 cm) and a 3 x 3 cell box
  // (2.1 cm, the smallest solid object) standing in it. Only a full 3x3 square of noise cells
  // survives the filter, with probability 0.45^9 = 7.6e-4 per cell.
  const int w = 200, h = 150;
  HeightMap hm = syntheticMap(w, h, 0.0f);
  std::mt19937 rng(11);
  std::bernoulli_distribution noisy(0.45);
  int noise_cells = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      if (noisy(rng)) {
        hm.at(x, y) = 0.013f;
        ++noise_cells;
      }
  for (int y = 60; y < 72; ++y)
    for (int x = 90; x < 102; ++x) hm.at(x, y) = 0.08f;
  for (int y = 20; y < 23; ++y)
    for (int x = 30; x < 33; ++x) hm.at(x, y) = 0.03f;

  Config plain = testConfig();
  plain.object_min_solidity = 0.0;
  const ObjectMap before = computeObjectMap(hm, plain);
  // Without the filter the box is part of a noise cluster of thousands of cells.
  ASSERT_GT(before.at(95, 65), 0);
  EXPECT_GT(before.object(before.at(95, 65)).area, 20 * 144);

  const ObjectMap om = computeObjectMap(hm, testConfig());
  // Each box is an object: its cells, plus at most the noise cells of 3x3 squares of object
  // cells overlapping its border (a one-cell ring around it: 4 * 13 + 1 more cells at most).
  ASSERT_GT(om.at(95, 65), 0);
  const ObjectInfo& box = om.object(om.at(95, 65));
  EXPECT_GE(box.area, 144);
  EXPECT_LE(box.area, 144 + 4 * 14);
  EXPECT_NEAR(box.max_height, 0.08f, 1e-6);
  for (int y = 60; y < 72; ++y)
    for (int x = 90; x < 102; ++x) EXPECT_EQ(om.at(x, y), om.at(95, 65));
  ASSERT_GT(om.at(31, 21), 0);
  EXPECT_GE(om.object(om.at(31, 21)).area, 9);
  EXPECT_LE(om.object(om.at(31, 21)).area, 9 + 4 * 5);
  // What is left of the noise: a few squares of about 9 cells (expected 0.45^9 * 30000 = 23 seed
  // cells), far from the 13.5 k noise cells and hundreds of objects of the plain map.
  std::size_t labelled = 0;
  for (const int l : om.labels) labelled += l > 0 ? 1 : 0;
  const std::size_t boxes = static_cast<std::size_t>(box.area + om.object(om.at(31, 21)).area);
  EXPECT_LT(labelled - boxes, static_cast<std::size_t>(noise_cells) / 20);
  EXPECT_LT(om.numObjects(), 60);
  EXPECT_GT(before.numObjects(), 200);
}

/// Reference labelling for connectedComponents: a breadth-first flood fill from each unlabelled
/// on-cell in raster order, then the area filter and renumbering.
Components floodFillComponents(const Mask2D& m, int min_area, int connectivity) {
  std::vector<int> labels(m.cells.size(), 0);
  std::vector<int> areas;
  for (int y0 = 0; y0 < m.height; ++y0)
    for (int x0 = 0; x0 < m.width; ++x0) {
      if (!m.at(x0, y0) || labels[m.index(x0, y0)] != 0) continue;
      const int label = static_cast<int>(areas.size()) + 1;
      std::vector<std::pair<int, int>> queue{{x0, y0}};
      labels[m.index(x0, y0)] = label;
      for (std::size_t k = 0; k < queue.size(); ++k)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            if (connectivity == 4 && dx != 0 && dy != 0) continue;
            const int x = queue[k].first + dx, y = queue[k].second + dy;
            if (!m.inBounds(x, y) || !m.at(x, y) || labels[m.index(x, y)] != 0) continue;
            labels[m.index(x, y)] = label;
            queue.emplace_back(x, y);
          }
      areas.push_back(static_cast<int>(queue.size()));
    }
  Components cc;
  std::vector<int> remap(areas.size() + 1, 0);
  for (std::size_t l = 0; l < areas.size(); ++l)
    if (areas[l] >= min_area) {
      cc.areas.push_back(areas[l]);
      remap[l + 1] = cc.count();
    }
  for (int& l : labels) l = remap[static_cast<std::size_t>(l)];
  cc.labels = std::move(labels);
  return cc;
}

TEST(ObjectMapMask, ComponentsMatchAFloodFillOnRandomMasks) {
  // Runs joined by a union-find label like a flood fill: the same components, numbered in
  // raster order of their first cell, on masks where components merge rows below their first
  // cells (U and W shapes at every density), for both connectivities and area filters.
  std::mt19937 rng(11);
  int merged = 0;
  for (const auto& [w, h] : {std::pair<int, int>{1, 1}, {1, 40}, {40, 1}, {37, 29}, {64, 64}})
    for (const double density : {0.2, 0.45, 0.6, 0.9}) {
      Mask2D m = Mask2D::zeros(syntheticMap(w, h, 0.0f).geometry());
      std::bernoulli_distribution on(density);
      for (auto& c : m.cells) c = on(rng) ? 1 : 0;
      for (const int connectivity : {8, 4})
        for (const int min_area : {1, 3}) {
          SCOPED_TRACE(testing::Message() << w << "x" << h << " density " << density << " conn "
                                          << connectivity << " min " << min_area);
          const Components got = connectedComponents(m, min_area, connectivity);
          const Components want = floodFillComponents(m, min_area, connectivity);
          EXPECT_EQ(got.areas, want.areas);
          EXPECT_EQ(got.labels, want.labels);
          merged += got.count() > 1 ? 1 : 0;
        }
    }
  EXPECT_GT(merged, 10);
}

TEST(ObjectMapMask, ComponentsAreaFilterAndDilation) {
  Mask2D m = Mask2D::zeros(syntheticMap(10, 8, 0.0f).geometry());
  ASSERT_EQ(m.cells.size(), 80u);
  m.set(1, 1);
  m.set(2, 2);                              // diagonal pair: one 8-connected component of 2
  for (int x = 5; x < 9; ++x) m.set(x, 5);  // a bar of 4
  m.set(9, 0);                              // a single cell in a corner
  EXPECT_EQ(m.count(), 7u);
  const Components all = connectedComponents(m);
  EXPECT_EQ(all.count(), 3);
  EXPECT_EQ(all.areas, (std::vector<int>{1, 2, 4}));  // raster order: (9, 0) first
  EXPECT_EQ(all.labels[m.index(9, 0)], 1);
  EXPECT_EQ(all.labels[m.index(2, 2)], 2);
  const Components big = connectedComponents(m, 2);
  EXPECT_EQ(big.areas, (std::vector<int>{2, 4}));
  EXPECT_EQ(big.labels[m.index(9, 0)], 0);
  EXPECT_EQ(big.labels[m.index(6, 5)], 2);
  const Mask2D cleaned = removeSmallComponents(m, 3);
  EXPECT_EQ(cleaned.count(), 4u);
  EXPECT_TRUE(cleaned.at(5, 5));
  EXPECT_FALSE(cleaned.at(1, 1));
  EXPECT_TRUE(cleaned.sameGeometry(m));
  // Dilation: a square element, clipped at the border.
  Mask2D one = Mask2D::zeros(m.geometry());
  one.set(4, 4);
  EXPECT_EQ(dilate(one, 1).count(), 9u);
  EXPECT_EQ(dilate(one, 2).count(), 25u);
  EXPECT_TRUE(dilate(one, 2).at(2, 6));
  EXPECT_FALSE(dilate(one, 2).at(1, 4));
  EXPECT_EQ(dilate(one, 0).cells, one.cells);
  // Erosion: the 5x5 square of dilate(one, 2) erodes back to the 3x3 and the single cell; a cell
  // on the grid's border never survives (outside is off).
  EXPECT_EQ(erode(dilate(one, 2), 1).cells, dilate(one, 1).cells);
  EXPECT_EQ(erode(dilate(one, 2), 2).cells, one.cells);
  EXPECT_EQ(erode(one, 1).count(), 0u);
  EXPECT_EQ(erode(one, 0).cells, one.cells);
  Mask2D corner = Mask2D::zeros(m.geometry());
  corner.set(0, 0);
  EXPECT_EQ(dilate(corner, 1).count(), 4u);
  EXPECT_EQ(dilate(corner, 20).count(), 80u);
  // The diagonal pair: two overlapping 3x3 (14), the bar: 6x3 (18), the corner cell: 2x2 (4).
  EXPECT_EQ(dilate(m, 1).count(), 14u + 18u + 4u);
}

// ---- pictures ----------------------------------------------------------------------------------

TEST(HeightMapPictures, PngsReadBackWithTheirLayoutAndColours) {
  const Config cfg = testConfig();
  const HeightMap hm = computeHeightMap(sceneVolume(), cfg);
  const ObjectMap om = computeObjectMap(hm, cfg);
  test::TempDir dir;
  const std::string hpath = dir.file("height.png"), opath = dir.file("objects.png");
  writeHeightMapPng(hpath, hm);
  writeObjectMapPng(opath, om);
  const int s = picturePixelsPerCell(hm);
  EXPECT_GE(hm.width * s, 400);
  const cv::Mat himg = cv::imread(hpath, cv::IMREAD_COLOR);
  ASSERT_FALSE(himg.empty());
  EXPECT_EQ(himg.cols, hm.width * s + kPictureLegendWidth);
  EXPECT_EQ(himg.rows, std::max(hm.height * s, kPictureLegendMinHeight) + kPictureCaptionHeight);
  const auto pixel = [&](const cv::Mat& img, const Eigen::Vector2i& c) {
    return img.at<cv::Vec3b>((hm.height - 1 - c.y()) * s + s / 2, c.x() * s + s / 2);
  };
  EXPECT_EQ(pixel(himg, {0, 0}), cv::Vec3b(0, 0, 0));  // unobserved corner: black
  const Eigen::Vector2i flat = hm.cellOf(Eigen::Vector2d(0.0, 0.2));
  ASSERT_EQ(hm.at(flat.x(), flat.y()), 0.0f);
  EXPECT_EQ(pixel(himg, flat), cv::Vec3b(80, 80, 80));  // flat: dark grey
  const cv::Vec3b top = pixel(himg, hm.cellOf(kCylinder.center));
  EXPECT_NE(top, cv::Vec3b(80, 80, 80));
  EXPECT_GT(std::max({top[0], top[1], top[2]}), 120);  // a bright colour-map colour
  // The object map: black background, a colour on objects.
  const cv::Mat oimg = cv::imread(opath, cv::IMREAD_COLOR);
  ASSERT_FALSE(oimg.empty());
  EXPECT_EQ(oimg.cols, std::max(om.width * s, kPictureMinWidth));
  EXPECT_EQ(oimg.rows, om.height * s + kPictureCaptionHeight);
  EXPECT_EQ(pixel(oimg, {0, 0}), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(pixel(oimg, flat), cv::Vec3b(0, 0, 0));
  const cv::Vec3b box_px = pixel(oimg, om.object(2).bbox_min);
  const cv::Vec3b cyl_px = pixel(oimg, hm.cellOf(kCylinder.center + Eigen::Vector2d(0.03, 0.0)));
  EXPECT_NE(box_px, cv::Vec3b(0, 0, 0));
  EXPECT_NE(cyl_px, cv::Vec3b(0, 0, 0));
  EXPECT_NE(box_px, cyl_px);
  // Empty maps give a small picture rather than an error.
  writeHeightMapPng(dir.file("empty.png"), HeightMap{});
  EXPECT_FALSE(cv::imread(dir.file("empty.png")).empty());
}

TEST(HeightMapPictures, BadPathThrowsNamingItAndLeavesNoFile) {
  const Config cfg = testConfig();
  const HeightMap hm = computeHeightMap(sceneVolume(), cfg);
  test::TempDir dir;
  const std::string missing = dir.file("no/such/folder/height.png");
  for (int which = 0; which < 2; ++which) {
    try {
      if (which == 0)
        writeHeightMapPng(missing, hm);
      else
        writeObjectMapPng(missing, computeObjectMap(hm, cfg));
      ADD_FAILURE() << "no error";
    } catch (const Error& e) {
      EXPECT_EQ(e.path(), missing);
      EXPECT_NE(std::string(e.what()).find(missing), std::string::npos);
    }
  }
  EXPECT_FALSE(std::filesystem::exists(dir.file("no")));
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  EXPECT_THROW(writeHeightMapPng(dir.file("h.png"), hm, 0.0f), Error);
  EXPECT_FALSE(std::filesystem::exists(dir.file("h.png")));
}

}  // namespace
}  // namespace planesdf
