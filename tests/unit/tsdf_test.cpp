// Tests of the block-sparse TSDF volume and its fusion against analytic scenes rendered here:
// a plane (z = 0 in the local frame, normal +z), a sphere resting on it and a box on it, seen
// from a ring of pinhole cameras.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <random>
#include <set>
#include <stdexcept>
#include <vector>

#include "analytic_scene.hpp"
#include "planesdf/error.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInfD = std::numeric_limits<double>::infinity();

// ---- analytic scenes ------------------------------------------------------------------------

struct Scene {
  bool plane = true;
  double plane_half = 1.0;  ///< the plane is the square |x|, |y| <= plane_half
  double floor_z = kNaN;    ///< optional second plane below (out of band)
  double ceiling_z = kNaN;  ///< optional plane above, seen from below
  bool sphere = false;
  Eigen::Vector3d sphere_c{0.0, 0.0, 0.1};
  double sphere_r = 0.1;
  bool box = false;
  Eigen::Vector3d box_c{0.0, 0.0, 0.05};
  Eigen::Vector3d box_half{0.08, 0.05, 0.05};

  /// Distance t > 0 along o + t * dir to the first surface, or +inf.
  double raycast(const Eigen::Vector3d& o, const Eigen::Vector3d& dir) const {
    double best = kInfD;
    const auto consider = [&](double t) {
      if (t > 1e-9 && t < best) best = t;
    };
    const auto horizontal = [&](double z0, double half) {
      if (std::isnan(z0) || dir.z() == 0.0) return;
      const double t = (z0 - o.z()) / dir.z();
      const Eigen::Vector3d p = o + t * dir;
      if (std::abs(p.x()) <= half && std::abs(p.y()) <= half) consider(t);
    };
    if (plane) horizontal(0.0, plane_half);
    horizontal(floor_z, kInfD);
    horizontal(ceiling_z, kInfD);
    if (sphere) {
      const Eigen::Vector3d oc = o - sphere_c;
      const double a = dir.squaredNorm(), b = oc.dot(dir),
                   c = oc.squaredNorm() - sphere_r * sphere_r;
      const double disc = b * b - a * c;
      if (disc >= 0.0) consider((-b - std::sqrt(disc)) / a);
    }
    if (box) {
      double t0 = -kInfD, t1 = kInfD;
      for (int i = 0; i < 3; ++i) {
        const double lo = box_c[i] - box_half[i], hi = box_c[i] + box_half[i];
        if (dir[i] == 0.0) {
          if (o[i] < lo || o[i] > hi) return best;
          continue;
        }
        double a = (lo - o[i]) / dir[i], b = (hi - o[i]) / dir[i];
        if (a > b) std::swap(a, b);
        t0 = std::max(t0, a);
        t1 = std::min(t1, b);
      }
      if (t0 <= t1) consider(t0);
    }
    return best;
  }

  /// Signed distance to the scene (exact outside the solids; union by min; the plane as
  /// unbounded). Scalar code: it runs per voxel, also in unoptimised sanitizer builds.
  double sdf(double x, double y, double z) const {
    double d = plane ? z : kInfD;
    if (sphere) {
      const double dx = x - sphere_c.x(), dy = y - sphere_c.y(), dz = z - sphere_c.z();
      d = std::min(d, std::sqrt(dx * dx + dy * dy + dz * dz) - sphere_r);
    }
    if (box) {
      const double qx = std::abs(x - box_c.x()) - box_half.x();
      const double qy = std::abs(y - box_c.y()) - box_half.y();
      const double qz = std::abs(z - box_c.z()) - box_half.z();
      const double ox = std::max(qx, 0.0), oy = std::max(qy, 0.0), oz = std::max(qz, 0.0);
      d = std::min(d, std::sqrt(ox * ox + oy * oy + oz * oz) +
                          std::min(std::max(qx, std::max(qy, qz)), 0.0));
    }
    return d;
  }
  /// True away from the plane's rim (where the unbounded-plane distance is wrong).
  bool inside(double x, double y) const {
    return std::max(std::abs(x), std::abs(y)) < plane_half - 0.05;
  }
};

Intrinsics smallCamera() {
  return test::pinhole(320, 240, 262.5);
}

using test::lookAt;

std::vector<Pose> ring(int n, double radius, double height, const Eigen::Vector3d& target) {
  std::vector<Pose> poses;
  for (int k = 0; k < n; ++k) {
    const double a = 2.0 * M_PI * k / n + 0.3;
    poses.push_back(
        lookAt(Eigen::Vector3d(radius * std::cos(a), radius * std::sin(a), height), target));
  }
  return poses;
}

DepthFrame render(const Scene& scene, const Intrinsics& K, const Pose& T_local_camera) {
  DepthFrame f;
  f.intrinsics = K;
  f.depth.assign(static_cast<std::size_t>(K.width) * K.height, 0.0f);
  const Eigen::Vector3d o = T_local_camera.translation();
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d ray((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      const double t = scene.raycast(o, T_local_camera.linear() * ray);  // t = depth (ray z = 1)
      if (std::isfinite(t)) f.depth[static_cast<std::size_t>(v) * K.width + u] = float(t);
    }
  return f;
}

Config testConfig(int threads = 2) {
  Config cfg;
  cfg.threads = threads;
  return cfg;
}

void fuseRing(TsdfVolume& vol, const Scene& scene, const std::vector<Pose>& poses,
              const Config& cfg) {
  for (const Pose& T : poses) integrateDepth(vol, render(scene, smallCamera(), T), T, cfg);
}

/// Calls f(x, y, z, voxel) with the local centre of every observed voxel. Plain loops (not
/// TsdfVolume::forEachObservedVoxel) keep the scans fast in unoptimised sanitizer builds.
template <class F>
void forEachObservedCentre(const TsdfVolume& vol, F&& f) {
  const double vs = vol.voxelSize();
  for (std::size_t s = 0; s < vol.numBlocks(); ++s) {
    const TsdfBlock& b = vol.block(s);
    const int bx = b.index.x() * 8, by = b.index.y() * 8, bz = b.index.z() * 8;
    for (int i = 0; i < kTsdfBlockVoxels; ++i) {
      const TsdfVoxel& v = b.voxels[i];
      if (!(v.weight > 0.0f)) continue;
      f((bx + (i & 7) + 0.5) * vs, (by + ((i >> 3) & 7) + 0.5) * vs, (bz + (i >> 6) + 0.5) * vs, v);
    }
  }
}

/// RMSE (in voxels) of observed voxels within `band_voxels` of the true surface (away from the
/// plane's rim), and their count.
std::pair<double, std::size_t> surfaceRmse(const TsdfVolume& vol, const Scene& scene,
                                           double band_voxels = 1.0) {
  const double vs = vol.voxelSize();
  double ss = 0.0;
  std::size_t n = 0;
  forEachObservedCentre(vol, [&](double x, double y, double z, const TsdfVoxel& v) {
    if (!scene.inside(x, y)) return;
    const double truth = scene.sdf(x, y, z);
    if (std::abs(truth) > band_voxels * vs) return;
    ss += (v.sdf - truth) * (v.sdf - truth);
    ++n;
  });
  return {n ? std::sqrt(ss / n) / vs : kInfD, n};
}

bool sameVoxels(const TsdfBlock& a, const TsdfBlock& b) {
  return std::memcmp(a.voxels.data(), b.voxels.data(), sizeof(a.voxels)) == 0;
}

bool sameVolumes(const TsdfVolume& a, const TsdfVolume& b) {
  if (a.numBlocks() != b.numBlocks()) return false;
  for (std::size_t s = 0; s < a.numBlocks(); ++s)
    if (a.block(s).index != b.block(s).index || !sameVoxels(a.block(s), b.block(s))) return false;
  return true;
}

const Eigen::Vector3d kTarget(0.0, 0.0, 0.05);

// ---- the volume -----------------------------------------------------------------------------

TEST(TsdfVolume, BlockLayoutAndGlobalIndexing) {
  EXPECT_EQ(sizeof(TsdfVoxel), 8u);
  TsdfVolume vol(0.01, 0.04);
  EXPECT_DOUBLE_EQ(vol.blockSize(), 0.08);
  bool created = false;
  TsdfBlock& b = vol.allocateBlock(Eigen::Vector3i(-1, -1, -1), &created);
  EXPECT_TRUE(created);
  vol.allocateBlock(Eigen::Vector3i(-1, -1, -1), &created);
  EXPECT_FALSE(created);
  EXPECT_EQ(vol.numBlocks(), 1u);
  EXPECT_EQ(vol.numVoxels(), 512u);
  // Global voxel (-1, -1, -1) is the last voxel of block (-1, -1, -1); (0, 0, 0) has no block.
  b.voxels[511] = {0.25f, 2.0f};
  ASSERT_NE(vol.voxel(Eigen::Vector3i(-1, -1, -1)), nullptr);
  EXPECT_EQ(vol.voxel(Eigen::Vector3i(-1, -1, -1))->sdf, 0.25f);
  EXPECT_EQ(vol.voxel(Eigen::Vector3i(0, 0, 0)), nullptr);
  EXPECT_EQ(vol.voxel(Eigen::Vector3i(-8, -8, -8)), &b.voxels[0]);
  EXPECT_EQ(vol.voxel(Eigen::Vector3i(-9, -8, -8)), nullptr);
  EXPECT_EQ(vol.voxelIndexAt(Eigen::Vector3d(-0.0001, 0.0001, 0.0199)), Eigen::Vector3i(-1, 0, 1));
  EXPECT_EQ(vol.blockIndexAt(Eigen::Vector3d(-0.0001, 0.0801, 0.05)), Eigen::Vector3i(-1, 1, 0));
  EXPECT_TRUE(
      vol.voxelCenter(Eigen::Vector3i(-1, 0, 2)).isApprox(Eigen::Vector3d(-0.005, 0.005, 0.025)));
  EXPECT_EQ(b.voxelIndex(511), Eigen::Vector3i(-1, -1, -1));
  int seen = 0;
  TsdfVolume::forEachObservedVoxel(b, [&](const Eigen::Vector3i& g, const TsdfVoxel& v) {
    EXPECT_EQ(g, Eigen::Vector3i(-1, -1, -1));
    EXPECT_EQ(v.weight, 2.0f);
    ++seen;
  });
  EXPECT_EQ(seen, 1);
  // Keys round-trip at the range limits.
  for (const Eigen::Vector3i& k :
       {Eigen::Vector3i(-(1 << 20), (1 << 20) - 1, 0), Eigen::Vector3i(5, -7, 123456)}) {
    EXPECT_TRUE(blockIndexInRange(k));
    EXPECT_EQ(detail::unpackBlockKey(detail::packBlockKey(k)), k);
  }
  EXPECT_FALSE(blockIndexInRange(Eigen::Vector3i(1 << 20, 0, 0)));
  EXPECT_THROW(vol.allocateBlock(Eigen::Vector3i(1 << 20, 0, 0)), Error);
  EXPECT_THROW(TsdfVolume(0.0, 0.1), Error);
}

TEST(TsdfVolume, ManyBlocksLookupCopyAndMemoryPerVoxel) {
  TsdfVolume vol(0.007, 0.028);
  for (int z = -2; z < 3; ++z)
    for (int y = -20; y < 20; ++y)
      for (int x = -20; x < 20; ++x)
        vol.allocateBlock(Eigen::Vector3i(x, y, z)).voxels[7].weight = float(x);
  ASSERT_EQ(vol.numBlocks(), 5u * 40 * 40);
  for (int z = -2; z < 3; ++z)
    for (int y = -20; y < 20; ++y)
      for (int x = -20; x < 20; ++x) {
        const TsdfBlock* b = vol.findBlock(Eigen::Vector3i(x, y, z));
        ASSERT_NE(b, nullptr);
        EXPECT_EQ(b->index, Eigen::Vector3i(x, y, z));
      }
  EXPECT_EQ(vol.findBlock(Eigen::Vector3i(20, 0, 0)), nullptr);
  Eigen::Vector3i lo, hi;
  ASSERT_TRUE(vol.blockBounds(&lo, &hi));
  EXPECT_EQ(lo, Eigen::Vector3i(-20, -20, -2));
  EXPECT_EQ(hi, Eigen::Vector3i(19, 19, 2));
  const double bytes_per_voxel = double(vol.memoryBytes()) / double(vol.numVoxels());
  EXPECT_LE(bytes_per_voxel, 12.0);
  EXPECT_GE(bytes_per_voxel, 8.0);
  const TsdfVolume copy = vol;
  EXPECT_TRUE(sameVolumes(copy, vol));
  EXPECT_EQ(copy.findBlock(Eigen::Vector3i(3, 4, 1))->voxels[7].weight, 3.0f);
  // The compact per-slot index array agrees with the blocks, also in a copy and after clear().
  const std::vector<Eigen::Vector3i> indices = vol.blockIndices();
  ASSERT_EQ(indices.size(), vol.numBlocks());
  for (std::size_t s = 0; s < vol.numBlocks(); ++s) {
    ASSERT_EQ(vol.blockIndex(s), vol.block(s).index);
    ASSERT_EQ(copy.blockIndex(s), copy.block(s).index);
    ASSERT_EQ(indices[s], vol.block(s).index);
  }
  vol.clear();
  EXPECT_TRUE(vol.blockIndices().empty());
  vol.allocateBlock(Eigen::Vector3i(5, -6, 7));
  EXPECT_EQ(vol.blockIndex(0), Eigen::Vector3i(5, -6, 7));
}

TEST(TsdfVolume, SampleIsTrilinearWhereObservedElseNearest) {
  TsdfVolume vol(0.01, 0.05);
  const auto field = [](const Eigen::Vector3d& p) {
    return 0.3 * p.x() - 0.2 * p.y() + 0.1 * p.z();
  };
  for (int z = -1; z < 1; ++z)
    for (int y = -1; y < 1; ++y)
      for (int x = -1; x < 1; ++x) {
        TsdfBlock& b = vol.allocateBlock(Eigen::Vector3i(x, y, z));
        for (int i = 0; i < kTsdfBlockVoxels; ++i)
          b.voxels[i] = {float(field(vol.voxelCenter(b.voxelIndex(i)))), 1.0f};
      }
  for (const Eigen::Vector3d& p :
       {Eigen::Vector3d(0.0, 0.0, 0.0), Eigen::Vector3d(0.0123, -0.031, 0.004),
        Eigen::Vector3d(-0.05, 0.04, -0.0301)}) {
    const auto s = vol.sample(p);
    ASSERT_TRUE(s.has_value());
    EXPECT_TRUE(s->interpolated);
    EXPECT_NEAR(s->sdf, field(p), 1e-6);
  }
  // An unobserved neighbour: fall back to the voxel containing p.
  vol.voxel(Eigen::Vector3i(1, 1, 1))->weight = 0.0f;
  const Eigen::Vector3d p(0.0141, 0.0142, 0.0115);  // in voxel (1, 1, 1)
  EXPECT_FALSE(vol.sample(p).has_value());
  const Eigen::Vector3d r(0.0095, 0.0105, 0.0112);  // voxel (0, 1, 1), neighbours include (1, 1, 1)
  const auto s = vol.sample(r);
  ASSERT_TRUE(s.has_value());
  EXPECT_FALSE(s->interpolated);
  EXPECT_FLOAT_EQ(s->sdf, vol.voxel(Eigen::Vector3i(0, 1, 1))->sdf);
  // min_weight excludes everything of weight 1; outside the allocated blocks: nothing.
  EXPECT_FALSE(vol.sample(Eigen::Vector3d(0.0, 0.0, 0.0), 2.0f).has_value());
  EXPECT_FALSE(vol.sample(Eigen::Vector3d(1.0, 0.0, 0.0)).has_value());
}

// ---- projective fusion ----------------------------------------------------------------------

TEST(TsdfFusion, PlaneRmseZeroCrossingAndFreeSpace) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  fuseRing(vol, scene, ring(8, 0.8, 0.6, kTarget), cfg);
  ASSERT_GT(vol.numBlocks(), 100u);
  const auto [rmse, n] = surfaceRmse(vol, scene);
  EXPECT_GT(n, 10000u);
  EXPECT_LT(rmse, 0.5);
  // Zero crossing along h in every observed column near the centre.
  const double vs = vol.voxelSize();
  int columns = 0;
  for (int j = -40; j < 40; j += 3)
    for (int i = -40; i < 40; i += 3) {
      for (int k = -6; k < 6; ++k) {
        const TsdfVoxel* a = vol.voxel(Eigen::Vector3i(i, j, k));
        const TsdfVoxel* b = vol.voxel(Eigen::Vector3i(i, j, k + 1));
        if (!a || !b || a->weight <= 0 || b->weight <= 0 || a->sdf >= 0 || b->sdf < 0) continue;
        const double h = (k + 0.5) * vs + vs * a->sdf / (a->sdf - b->sdf);
        EXPECT_LT(std::abs(h), 0.5 * vs) << "column " << i << "," << j;
        ++columns;
      }
    }
  EXPECT_GT(columns, 600);
  // Every observed voxel clearly above the plane is free (positive), and the band above the
  // truncation is carved to +truncation.
  std::size_t free_voxels = 0;
  std::size_t not_free = 0, not_positive = 0;
  forEachObservedCentre(vol, [&](double, double, double h, const TsdfVoxel& v) {
    if (h > 2 * vs && !(v.sdf > 0.0f)) ++not_positive;
    if (h > 1.5 * vol.truncation()) {
      if (std::abs(v.sdf - float(vol.truncation())) > 1e-6f) ++not_free;
      ++free_voxels;
    }
  });
  EXPECT_EQ(not_positive, 0u);
  EXPECT_EQ(not_free, 0u);
  EXPECT_GT(free_voxels, 1000u);
}

TEST(TsdfFusion, DepthBeyondSurfaceMaxDepthOnlyCarvesFreeSpace) {
  // The plane is seen from about 1 m: with surface_max_depth 0.5 m no voxel near it is fused,
  // but the space in front of it is carved to +truncation as before.
  Config cfg = testConfig();
  cfg.surface_max_depth = 0.5;
  TsdfVolume vol(cfg);
  fuseRing(vol, Scene{}, ring(8, 0.8, 0.6, kTarget), cfg);
  std::size_t free_voxels = 0, near_surface = 0;
  forEachObservedCentre(vol, [&](double, double, double, const TsdfVoxel& v) {
    if (v.sdf < float(vol.truncation()) - 1e-6f)
      ++near_surface;
    else
      ++free_voxels;
  });
  EXPECT_EQ(near_surface, 0u);
  EXPECT_GT(free_voxels, 1000u);
}

TEST(TsdfFusion, SphereOnPlaneRmseAndFreeSpace) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.sphere = true;
  fuseRing(vol, scene, ring(10, 0.7, 0.5, kTarget), cfg);
  const auto [rmse, n] = surfaceRmse(vol, scene);
  EXPECT_GT(n, 10000u);
  EXPECT_LT(rmse, 0.5);
  const double vs = vol.voxelSize();
  // Near the sphere alone (away from the contact crease), and free space in front.
  std::size_t near_sphere = 0;
  double ss = 0.0;
  std::size_t not_positive = 0, free_voxels = 0;
  forEachObservedCentre(vol, [&](double x, double y, double z, const TsdfVoxel& v) {
    if (!scene.inside(x, y)) return;
    if (scene.sdf(x, y, z) >= 2 * vs) {
      ++free_voxels;
      if (!(v.sdf > 0.0f)) ++not_positive;
    }
    const Eigen::Vector3d c(x, y, z);
    const double ds = (c - scene.sphere_c).norm() - scene.sphere_r;
    if (std::abs(ds) <= vs && z > 0.05) {
      ss += (v.sdf - ds) * (v.sdf - ds);
      ++near_sphere;
    }
  });
  EXPECT_GT(free_voxels, 10000u);
  EXPECT_EQ(not_positive, 0u);
  EXPECT_GT(near_sphere, 2000u);
  EXPECT_LT(std::sqrt(ss / near_sphere) / vs, 0.5);
}

TEST(TsdfFusion, NoisyDepthSphereOnPlaneRmse) {
  // Kinect-like axial noise, sigma = 1.5 mm * d^2 (about 0.2 voxel at 1 m), averaged over views.
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.sphere = true;
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.0015f);
  for (const Pose& T : ring(12, 0.7, 0.5, kTarget)) {
    DepthFrame f = render(scene, smallCamera(), T);
    for (float& d : f.depth)
      if (d > 0.0f) d += noise(rng) * d * d;
    integrateDepth(vol, f, T, cfg);
  }
  const auto [rmse, n] = surfaceRmse(vol, scene);
  EXPECT_GT(n, 10000u);
  EXPECT_LT(rmse, 0.5);
}

TEST(TsdfFusion, BoxOnPlaneRmse) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.box = true;
  fuseRing(vol, scene, ring(12, 0.7, 0.5, kTarget), cfg);
  const auto [rmse, n] = surfaceRmse(vol, scene);
  EXPECT_GT(n, 10000u);
  EXPECT_LT(rmse, 0.5);
  // The top face's zero crossing sits at h = 0.10.
  const double vs = vol.voxelSize();
  const auto top = vol.sample(Eigen::Vector3d(0.01, 0.005, 0.10));
  ASSERT_TRUE(top.has_value());
  EXPECT_LT(std::abs(top->sdf), 0.5 * vs);
}

TEST(TsdfFusion, OnlyHalfTheTruncationBehindTheSurfaceIsFused) {
  // Seen from above, a table top's thickness is unknown: a 3 cm top (4.3 voxels) would get
  // "inside" values near its unseen underside if the whole truncation (4 voxels) behind the
  // surface were fused. Flat plane: the tangent-plane distance of a voxel is its height.
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  fuseRing(vol, scene, ring(8, 0.8, 0.6, kTarget), cfg);
  const double half_trunc = 0.5 * vol.truncation();
  double min_h = kInfD;
  std::size_t behind = 0;
  forEachObservedCentre(vol, [&](double x, double y, double h, const TsdfVoxel& v) {
    if (!scene.inside(x, y)) return;
    min_h = std::min(min_h, h);
    if (h < 0.0) {
      ++behind;
      EXPECT_LT(std::abs(v.sdf - h), 1e-3) << "at h = " << h;  // exact plane
    }
  });
  EXPECT_GE(min_h, -half_trunc);
  EXPECT_LT(min_h, -half_trunc + vol.voxelSize());  // the band behind is there: 2 voxels
  EXPECT_GT(behind, 10000u);
}

TEST(TsdfFusion, FreeSpaceBesideABoxIsObservedWithItsTrueDistance) {
  // The silhouette guard must neither leave the free space around a small object unobserved
  // nor let a fringe of "inside" values grow around it: the voxels 0.5 to 1.5 voxels outside
  // the box's sides (over its height) are observed, positive, within half a voxel of their true
  // distance; and next to nothing more than one voxel outside the box is inside (negative)
  // above the plane, so its footprint in a height map is exact.
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.box = true;
  fuseRing(vol, scene, ring(12, 0.7, 0.5, kTarget), cfg);
  const double vs = vol.voxelSize();
  const double top = scene.box_c.z() + scene.box_half.z();
  std::size_t beside = 0, observed = 0, fringe = 0;
  double ss = 0.0;
  for (int k = 1; (k + 0.5) * vs < top - vs; ++k)
    for (int j = -20; j <= 20; ++j)
      for (int i = -20; i <= 20; ++i) {
        const double x = (i + 0.5) * vs, y = (j + 0.5) * vs, h = (k + 0.5) * vs;
        const double truth = scene.sdf(x, y, h);
        const TsdfVoxel* v = vol.voxel(Eigen::Vector3i(i, j, k));
        const bool seen = v != nullptr && v->weight > 0.0f;
        if (truth > vs && seen && v->sdf < 0.0f) ++fringe;
        if (truth < 0.5 * vs || truth > 1.5 * vs || truth >= h) continue;  // beside the sides
        ++beside;
        if (!seen) continue;
        ++observed;
        ss += (v->sdf - truth) * (v->sdf - truth);
      }
  ASSERT_GT(beside, 300u);
  EXPECT_EQ(observed, beside);
  EXPECT_LT(std::sqrt(ss / std::max<std::size_t>(observed, 1)) / vs, 0.5);
  // Behind-surface values are dropped within |sdf| * sin(ray, normal) of a silhouette (the exact
  // far-rim geometry), measured in whole pixels: a stray voxel or two may stay (< 1 %).
  EXPECT_LE(fringe, beside / 100);
}

TEST(TsdfFusion, NothingOutsideTheBandIsAllocatedOrObserved) {
  Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.plane_half = 0.3;  // a table ...
  scene.floor_z = -0.7;    // ... above a floor (out of band)
  scene.box = true;
  scene.box_c = Eigen::Vector3d(0.05, 0.0, 0.25);
  scene.box_half = Eigen::Vector3d(0.05, 0.05, 0.25);  // 0.5 m tall: its top is out of band
  fuseRing(vol, scene, ring(8, 0.9, 0.8, kTarget), cfg);
  ASSERT_GT(vol.numBlocks(), 0u);
  const double lo = -cfg.below_band - vol.truncation(), hi = cfg.fuse_band + vol.truncation();
  const double bs = vol.blockSize(), vs = vol.voxelSize();
  double max_h = -kInfD, min_h = kInfD;
  vol.forEachBlock([&](const TsdfBlock& b) {
    EXPECT_GT((b.index.z() + 1) * bs, lo);  // the block reaches into the voxel band
    EXPECT_LT(b.index.z() * bs, hi);
  });
  forEachObservedCentre(vol, [&](double, double, double h, const TsdfVoxel&) {
    max_h = std::max(max_h, h);
    min_h = std::min(min_h, h);
  });
  EXPECT_LE(max_h, hi);
  EXPECT_GE(min_h, lo);
  EXPECT_GT(max_h, hi - 2 * vs);  // the tall box's side is fused up to the band's top
  // No surface from the out-of-band box top (h = 0.5) or floor: above the box only free space.
  const auto above = vol.sample(Eigen::Vector3d(0.05, 0.0, 0.31));
  if (above) {
    EXPECT_GT(above->sdf, 0.0f);
  }
}

TEST(TsdfFusion, UpdatesExactlyTheAllocatedBlocksInTheFrustum) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.sphere = true;
  fuseRing(vol, scene, ring(8, 0.8, 0.6, kTarget), cfg);
  // A close-up, oblique view of one side: only part of the volume is in view.
  const Pose T = lookAt(Eigen::Vector3d(0.45, 0.1, 0.25), Eigen::Vector3d(0.1, 0.05, 0.0));
  const Intrinsics K = smallCamera();
  const DepthFrame frame = render(scene, K, T);
  const TsdfVolume before = vol;
  const IntegrationResult res = integrateDepth(vol, frame, T, cfg);

  // Brute force: blocks with a voxel centre in the image, depth range and voxel band.
  const double band_lo = -cfg.below_band - vol.truncation(),
               band_hi = cfg.fuse_band + vol.truncation();
  const Pose T_cl = T.inverse();
  const Eigen::Matrix3d R = T_cl.linear();
  const Eigen::Vector3d t = T_cl.translation();
  const double vs = vol.voxelSize();
  std::set<std::size_t> certain, possible;
  for (std::size_t s = 0; s < vol.numBlocks(); ++s) {
    const Eigen::Vector3i b0 = vol.block(s).index * kTsdfBlockSide;
    for (int i = 0; i < kTsdfBlockVoxels; ++i) {  // scalar code: fast in sanitizer builds too
      const double c[3] = {(b0.x() + (i & 7) + 0.5) * vs, (b0.y() + ((i >> 3) & 7) + 0.5) * vs,
                           (b0.z() + (i >> 6) + 0.5) * vs};
      double pc[3];
      for (int r = 0; r < 3; ++r) pc[r] = R(r, 0) * c[0] + R(r, 1) * c[1] + R(r, 2) * c[2] + t[r];
      const double u = K.fx * pc[0] / pc[2] + K.cx, v = K.fy * pc[1] / pc[2] + K.cy;
      const auto inside = [&](double m, double e) {
        return pc[2] >= cfg.min_depth + e && pc[2] <= cfg.max_depth - e && u >= -0.5 + m &&
               u < K.width - 0.5 - m && v >= -0.5 + m && v < K.height - 0.5 - m &&
               c[2] >= band_lo + e && c[2] <= band_hi - e;
      };
      if (inside(0.01, 1e-5)) certain.insert(s);
      if (inside(-0.01, -1e-5)) possible.insert(s);
    }
  }
  std::set<std::size_t> updated;
  for (const Eigen::Vector3i& b : res.updated_blocks) updated.insert(std::size_t(vol.blockSlot(b)));
  EXPECT_EQ(updated.size(), res.updated_blocks.size());
  EXPECT_TRUE(std::includes(updated.begin(), updated.end(), certain.begin(), certain.end()));
  EXPECT_TRUE(std::includes(possible.begin(), possible.end(), updated.begin(), updated.end()));
  if (certain == possible) {
    EXPECT_EQ(updated.size(), certain.size());
  }
  EXPECT_GT(updated.size(), 20u);
  EXPECT_LT(updated.size(), vol.numBlocks() / 2);  // a partial view
  // Blocks not updated are bit-identical; changed blocks are a subset of the updated ones.
  for (std::size_t s = 0; s < before.numBlocks(); ++s)
    if (!updated.count(s)) {
      EXPECT_TRUE(sameVoxels(vol.block(s), before.block(s))) << "slot " << s;
    }
  for (const Eigen::Vector3i& b : res.changed_blocks) EXPECT_TRUE(updated.count(vol.blockSlot(b)));
  EXPECT_FALSE(res.changed_blocks.empty());
  EXPECT_GT(vol.revision(), before.revision());
}

TEST(TsdfFusion, CameraLookingAwayUpdatesNothing) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.sphere = true;
  scene.plane_half = 0.5;
  fuseRing(vol, scene, ring(8, 0.8, 0.6, kTarget), cfg);
  const TsdfVolume before = vol;
  // Looking up at a ceiling (valid depths, out of band), then horizontally away from the scene.
  Scene ceiling;
  ceiling.plane = false;
  ceiling.ceiling_z = 2.5;
  for (const Pose& T : {lookAt(Eigen::Vector3d(0.0, 0.0, 0.6), Eigen::Vector3d(0.01, 0.0, 2.0)),
                        lookAt(Eigen::Vector3d(1.0, 0.0, 0.2), Eigen::Vector3d(3.0, 0.0, 0.6))}) {
    const IntegrationResult res = integrateDepth(vol, render(ceiling, smallCamera(), T), T, cfg);
    EXPECT_TRUE(res.updated_blocks.empty());
    EXPECT_TRUE(res.allocated_blocks.empty());
    EXPECT_FALSE(res.changed());
  }
  EXPECT_TRUE(sameVolumes(vol, before));
  EXPECT_EQ(vol.revision(), before.revision());
}

TEST(TsdfFusion, InvalidDepthsChangeNothing) {
  Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.sphere = true;
  const std::vector<Pose> poses = ring(6, 0.8, 0.6, kTarget);
  fuseRing(vol, scene, poses, cfg);
  const TsdfVolume before = vol;
  DepthFrame frame = render(scene, smallCamera(), poses[0]);
  const float bad[] = {0.0f,
                       std::numeric_limits<float>::quiet_NaN(),
                       std::numeric_limits<float>::infinity(),
                       -1.0f,
                       0.1f /* < min_depth */,
                       9.0f /* > max_depth */};
  for (std::size_t i = 0; i < frame.depth.size(); ++i) frame.depth[i] = bad[i % 6];
  const IntegrationResult res = integrateDepth(vol, frame, poses[0], cfg);
  EXPECT_EQ(res.num_points_fused, 0u);
  EXPECT_EQ(res.num_voxel_updates, 0u);
  EXPECT_FALSE(res.changed());
  EXPECT_FALSE(res.updated_blocks.empty());  // in view, but nothing to fuse
  EXPECT_TRUE(sameVolumes(vol, before));
  EXPECT_EQ(vol.revision(), before.revision());
  // Into an empty volume: nothing allocated.
  TsdfVolume empty(cfg);
  integrateDepth(empty, frame, poses[0], cfg);
  EXPECT_EQ(empty.numBlocks(), 0u);
  EXPECT_EQ(empty.revision(), 0u);
}

/// The sphere on the plane with a box beside it.
Scene sphereAndBox() {
  Scene scene;
  scene.sphere = true;
  scene.box = true;
  scene.box_c = Eigen::Vector3d(0.2, 0.1, 0.04);
  scene.box_half = Eigen::Vector3d(0.04, 0.06, 0.04);
  return scene;
}

TEST(TsdfFusion, SameResultWithOneAndTwoThreads) {
  const Scene scene = sphereAndBox();
  const std::vector<Pose> poses = ring(6, 0.8, 0.6, kTarget);
  TsdfVolume one(testConfig(1)), two(testConfig(2));
  for (const Pose& T : poses) {
    const DepthFrame f = render(scene, smallCamera(), T);
    const IntegrationResult r1 = integrateDepth(one, f, T, testConfig(1));
    const IntegrationResult r2 = integrateDepth(two, f, T, testConfig(2));
    EXPECT_EQ(r1.updated_blocks, r2.updated_blocks);
    EXPECT_EQ(r1.allocated_blocks, r2.allocated_blocks);
    EXPECT_EQ(r1.num_voxel_updates, r2.num_voxel_updates);
  }
  EXPECT_TRUE(sameVolumes(one, two));
  EXPECT_EQ(one.revision(), two.revision());
}

TEST(TsdfFusion, SimdKernelIsBitIdenticalToTheScalarCode) {
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
  if (!__builtin_cpu_supports("avx2")) GTEST_SKIP() << "no AVX2: only the scalar code runs";
#else
  GTEST_SKIP() << "not x86-64: only the scalar code runs";
#endif
  // Noisy frames with holes and flying values exercise every branch of the voxel loop: free
  // space, the truncation band, behind-surface limits, both silhouette guards, grazing and
  // out-of-band pixels; with the behind guard on and off.
  const Scene scene = sphereAndBox();
  std::mt19937 rng(11);
  std::normal_distribution<float> noise(0.0f, 0.002f);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (const bool guard_behind : {true, false}) {
    Config simd = testConfig(2), scalar = testConfig(2);
    simd.silhouette_guard_behind = scalar.silhouette_guard_behind = guard_behind;
    simd.fuse_band = scalar.fuse_band = 0.06;  // the sphere's top is out of the band
    // Weights reach the cap within the 6 frames in one run.
    simd.max_weight = scalar.max_weight = guard_behind ? 100.0f : 4.0f;
    scalar.simd = false;
    TsdfVolume a(simd), b(scalar);
    std::size_t updates = 0;
    for (const Pose& T : ring(6, 0.8, 0.6, kTarget)) {
      DepthFrame f = render(scene, smallCamera(), T);
      for (float& d : f.depth) {
        const float r = uni(rng);
        if (r < 0.02f)
          d = 0.0f;
        else if (r < 0.03f)
          d += 0.1f;  // a flying pixel
        else
          d += noise(rng);
      }
      const IntegrationResult ra = integrateDepth(a, f, T, simd);
      const IntegrationResult rb = integrateDepth(b, f, T, scalar);
      EXPECT_EQ(ra.updated_blocks, rb.updated_blocks);
      EXPECT_EQ(ra.changed_blocks, rb.changed_blocks);
      EXPECT_EQ(ra.num_voxel_updates, rb.num_voxel_updates);
      updates += ra.num_voxel_updates;
    }
    EXPECT_GT(updates, 100000u);
    EXPECT_TRUE(sameVolumes(a, b)) << "guard_behind " << guard_behind;
  }
}

TEST(TsdfFusion, OneFrameAnalysisSharedByTwoVolumesEqualsFusingEachAlone) {
  const Scene scene = sphereAndBox();
  const Config cfg = testConfig();
  // Two volumes in different local frames (as a Map's planes are): the scene's, and one raised
  // by 3 cm and turned by 20 deg about z (a coplanar band offset from the first).
  Pose lift = Pose::Identity();
  lift.linear() = Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  lift.translation() = Eigen::Vector3d(0.01, -0.02, 0.03);
  TsdfVolume a1(cfg), b1(cfg), a2(cfg), b2(cfg);
  DepthFrameAnalysis analysis;
  EXPECT_TRUE(analysis.empty());
  EXPECT_THROW(integrateDepth(a2, analysis, Pose::Identity(), cfg), Error);
  for (const Pose& T : ring(5, 0.8, 0.6, kTarget)) {
    const DepthFrame f = render(scene, smallCamera(), T);
    const Pose T_b = lift.inverse() * T;
    const IntegrationResult ra1 = integrateDepth(a1, f, T, cfg);
    const IntegrationResult rb1 = integrateDepth(b1, f, T_b, cfg);
    analysis.analyse(f, a2.truncation(), cfg);
    const IntegrationResult ra2 = integrateDepth(a2, analysis, T, cfg);
    const IntegrationResult rb2 = integrateDepth(b2, analysis, T_b, cfg);
    EXPECT_EQ(ra1.updated_blocks, ra2.updated_blocks);
    EXPECT_EQ(ra1.allocated_blocks, ra2.allocated_blocks);
    EXPECT_EQ(ra1.num_voxel_updates, ra2.num_voxel_updates);
    EXPECT_EQ(ra1.num_points_fused, ra2.num_points_fused);
    EXPECT_EQ(rb1.changed_blocks, rb2.changed_blocks);
    EXPECT_EQ(rb1.num_voxel_updates, rb2.num_voxel_updates);
  }
  EXPECT_TRUE(sameVolumes(a1, a2));
  EXPECT_TRUE(sameVolumes(b1, b2));
  EXPECT_GT(b1.numBlocks(), 50u);
  // An analysis made for another truncation or depth range is refused.
  Config coarse = cfg;
  coarse.truncation_voxels = 6;
  TsdfVolume c(coarse);
  EXPECT_THROW(integrateDepth(c, analysis, Pose::Identity(), coarse), Error);
  Config near = cfg;
  near.max_depth = 2.0;
  EXPECT_THROW(integrateDepth(a2, analysis, Pose::Identity(), near), Error);
  Config surfaces = cfg;
  surfaces.surface_max_depth = 1.0;
  EXPECT_THROW(integrateDepth(a2, analysis, Pose::Identity(), surfaces), Error);
}

TEST(TsdfFusion, AnalysisWithATaskAlongsideIsTheSameAndRunsItOnce) {
  // analyse(frame, ..., alongside) shares the threads with the caller's task: the analysis
  // (checked through fusion: same volume byte for byte) is that of analyse(frame, ...) on one
  // thread, for one and two threads; the task runs exactly once per call, and its exception
  // comes out of analyse after the pass (a later call works).
  const Scene scene = sphereAndBox();
  for (const int threads : {1, 2}) {
    const Config cfg = testConfig(threads);
    TsdfVolume plain(cfg), shared(cfg);
    DepthFrameAnalysis a, b;
    int runs = 0;
    double work = 0.0;
    const std::function<void()> task = [&] {
      ++runs;
      for (int i = 1; i < 200000; ++i) work += 1.0 / i;  // about a millisecond
    };
    int frames = 0;
    for (const Pose& T : ring(4, 0.8, 0.6, kTarget)) {
      const DepthFrame f = render(scene, smallCamera(), T);
      a.analyse(f, plain.truncation(), testConfig(1));
      b.analyse(f, shared.truncation(), cfg, task);
      ++frames;
      EXPECT_EQ(runs, frames);
      const IntegrationResult ra = integrateDepth(plain, a, T, cfg);
      const IntegrationResult rb = integrateDepth(shared, b, T, cfg);
      EXPECT_EQ(ra.num_voxel_updates, rb.num_voxel_updates);
      EXPECT_EQ(ra.updated_blocks, rb.updated_blocks);
    }
    EXPECT_GT(work, 0.0);
    EXPECT_GT(plain.numBlocks(), 50u);
    EXPECT_TRUE(sameVolumes(plain, shared)) << threads << " threads";
    const DepthFrame f = render(scene, smallCamera(), ring(4, 0.8, 0.6, kTarget)[0]);
    const std::function<void()> failing = [] { throw std::runtime_error("tracking failed"); };
    try {
      b.analyse(f, shared.truncation(), cfg, failing);
      ADD_FAILURE() << "no exception";
    } catch (const std::runtime_error& e) {
      EXPECT_STREQ(e.what(), "tracking failed");
    }
    b.analyse(f, shared.truncation(), cfg, task);
    EXPECT_EQ(runs, frames + 1);
    // A frame refused by the analysis is refused before the task runs.
    DepthFrame bad = f;
    bad.depth.resize(10);
    EXPECT_THROW(b.analyse(bad, shared.truncation(), cfg, task), Error);
    EXPECT_EQ(runs, frames + 1);
  }
}

TEST(TsdfFusion, VoxelsHiddenBehindAnOccluderAreUntouched) {
  // A plane fused from above, then seen from the side past a box standing on it: plane voxels
  // in the box's shadow (the box surface more than a truncation in front of them along their
  // line of sight) keep their values; the visible plane keeps being fused.
  const Config cfg = testConfig();
  Scene open;
  open.plane_half = 0.6;
  TsdfVolume vol(cfg);
  for (const Pose& T : ring(6, 0.3, 0.9, kTarget))
    integrateDepth(vol, render(open, smallCamera(), T), T, cfg);
  Scene boxed = open;
  boxed.box = true;
  boxed.box_c = Eigen::Vector3d(0.0, 0.0, 0.15);
  boxed.box_half = Eigen::Vector3d(0.05, 0.25, 0.15);
  const Pose T = lookAt(Eigen::Vector3d(-0.7, 0.0, 0.35), Eigen::Vector3d(0.3, 0.0, 0.0));
  const TsdfVolume before = vol;
  integrateDepth(vol, render(boxed, smallCamera(), T), T, cfg);
  const Pose T_cl = T.inverse();
  const Intrinsics K = smallCamera();
  const double vs = vol.voxelSize(), trunc = vol.truncation();
  std::size_t shadowed = 0, shadowed_changed = 0, visible_changed = 0;
  for (std::size_t s = 0; s < before.numBlocks(); ++s) {  // slots keep allocation order
    const Eigen::Vector3i b0 = vol.block(s).index * kTsdfBlockSide;
    for (int i = 0; i < kTsdfBlockVoxels; ++i) {
      const Eigen::Vector3d c((b0.x() + (i & 7) + 0.5) * vs, (b0.y() + ((i >> 3) & 7) + 0.5) * vs,
                              (b0.z() + (i >> 6) + 0.5) * vs);
      if (std::abs(c.z()) > 2 * vs || !open.inside(c.x(), c.y()) || std::abs(c.x()) < 0.1) continue;
      const Eigen::Vector3d pc = T_cl * c;
      const double u = K.fx * pc.x() / pc.z() + K.cx, v = K.fy * pc.y() / pc.z() + K.cy;
      if (pc.z() < cfg.min_depth || u < 1 || v < 1 || u > K.width - 2 || v > K.height - 2) continue;
      // Depth of the first surface seen by the voxel's pixel (nearest pixel centre; a ray with
      // z = 1 per unit t), also on the voxel's own line of sight.
      const double ui = std::floor(u + 0.5), vi = std::floor(v + 0.5);
      const Eigen::Vector3d pixel_ray((ui - K.cx) / K.fx, (vi - K.cy) / K.fy, 1.0);
      const double hit = std::max(boxed.raycast(T.translation(), T.linear() * pixel_ray),
                                  boxed.raycast(T.translation(), T.linear() * (pc / pc.z())));
      const TsdfVoxel& now = vol.block(s).voxels[i];
      const TsdfVoxel& was = before.block(s).voxels[i];
      const bool changed = now.weight != was.weight || now.sdf != was.sdf;
      if (hit < pc.z() - trunc - 0.02) {
        ++shadowed;
        shadowed_changed += changed;
      } else if (std::abs(hit - pc.z()) < 0.5 * trunc) {
        visible_changed += changed;
      }
    }
  }
  EXPECT_GT(shadowed, 500u);
  EXPECT_EQ(shadowed_changed, 0u);
  EXPECT_GT(visible_changed, 500u);
}

TEST(TsdfFusion, WeightsAreCappedAndRevisionTracksChanges) {
  Config cfg = testConfig();
  cfg.max_weight = 3.0f;
  TsdfVolume vol(cfg);
  Scene scene;
  const Pose T = ring(1, 0.8, 0.6, kTarget)[0];
  const DepthFrame f = render(scene, smallCamera(), T);
  const IntegrationResult first = integrateDepth(vol, f, T, cfg);
  EXPECT_EQ(vol.revision(), 1u);
  EXPECT_FALSE(first.allocated_blocks.empty());
  EXPECT_LE(first.changed_blocks.size(), vol.numBlocks());
  EXPECT_GT(first.changed_blocks.size(), vol.numBlocks() * 9 / 10);
  EXPECT_EQ(vol.blocksChangedSince(0).size(), vol.numBlocks());
  for (int i = 0; i < 5; ++i) integrateDepth(vol, f, T, cfg);
  float max_w = 0.0f;
  vol.forEachBlock([&](const TsdfBlock& b) {
    for (const TsdfVoxel& v : b.voxels) max_w = std::max(max_w, v.weight);
  });
  EXPECT_EQ(max_w, 3.0f);
  // The same frame at the weight cap changes nothing more: same revision.
  const std::uint64_t rev = vol.revision();
  const IntegrationResult again = integrateDepth(vol, f, T, cfg);
  EXPECT_FALSE(again.changed());
  EXPECT_EQ(vol.revision(), rev);
  EXPECT_TRUE(vol.blocksChangedSince(rev).empty());
  EXPECT_THROW(integrateDepth(vol, DepthFrame{}, T, cfg), Error);  // 640x480 with no depth
}

TEST(TsdfFusion, MemoryPerAllocatedVoxelIsAtMostTwelveBytes) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  Scene scene;
  scene.sphere = true;
  fuseRing(vol, scene, ring(8, 0.8, 0.6, kTarget), cfg);
  ASSERT_GT(vol.numBlocks(), 100u);
  EXPECT_LE(double(vol.memoryBytes()) / double(vol.numVoxels()), 12.0);
}

// ---- splats ---------------------------------------------------------------------------------

TEST(TsdfSplat, SampledSphereWithNormals) {
  const Config cfg = testConfig();
  TsdfVolume vol(cfg);
  const Eigen::Vector3f c(0.02f, -0.01f, 0.15f);
  const float r = 0.1f;
  std::vector<Eigen::Vector3f> pts, nrm;
  const int n = 20000;  // Fibonacci sphere: about 2.5 mm spacing
  for (int i = 0; i < n; ++i) {
    const double z = 1.0 - 2.0 * (i + 0.5) / n, rho = std::sqrt(1.0 - z * z);
    const double a = M_PI * (3.0 - std::sqrt(5.0)) * i;
    const Eigen::Vector3f d(float(rho * std::cos(a)), float(rho * std::sin(a)), float(z));
    pts.push_back(c + r * d);
    nrm.push_back(d * 3.0f);  // not unit: normalised by the function
  }
  pts.push_back(Eigen::Vector3f(0.0f, 0.0f, std::nanf("")));  // skipped
  nrm.push_back(Eigen::Vector3f::UnitZ());
  pts.push_back(Eigen::Vector3f(0.0f, 0.0f, 0.1f));  // zero normal: skipped
  nrm.push_back(Eigen::Vector3f::Zero());
  const IntegrationResult res = integratePointsWithNormals(vol, pts, nrm, cfg);
  EXPECT_EQ(res.num_points_fused, std::size_t(n));
  EXPECT_FALSE(res.updated_blocks.empty());
  const double vs = vol.voxelSize();
  double ss = 0.0;
  std::size_t near = 0, wrong_sign = 0;
  std::size_t over_truncation = 0;
  forEachObservedCentre(vol, [&](double x, double y, double z, const TsdfVoxel& v) {
    const double truth = (Eigen::Vector3d(x, y, z) - c.cast<double>()).norm() - r;
    if (std::abs(v.sdf) > vol.truncation() + 1e-6) ++over_truncation;
    if (std::abs(truth) > 2 * vs && (truth > 0) != (v.sdf > 0)) ++wrong_sign;
    if (std::abs(truth) <= vs) {
      ss += (v.sdf - truth) * (v.sdf - truth);
      ++near;
    }
  });
  EXPECT_EQ(over_truncation, 0u);
  EXPECT_GT(near, 5000u);
  EXPECT_LT(std::sqrt(ss / near) / vs, 0.5);
  EXPECT_EQ(wrong_sign, 0u);
  // One and two threads agree bit for bit.
  TsdfVolume one(cfg);
  integratePointsWithNormals(one, pts, nrm, testConfig(1));
  EXPECT_TRUE(sameVolumes(one, vol));
  EXPECT_THROW(integratePointsWithNormals(vol, pts, {}, cfg), Error);
}

TEST(TsdfSplat, FreeSpaceInFrontOfANoisyLayerOutvotesAnOutlier) {
  // Points of z = 0.1 with normals +z and one outlier 4.35 cm above (beyond the 2.8 cm
  // truncation), at a voxel centre. Reaching two truncations in front, the layer's points vote
  // "free" (clamped to the truncation) where the outlier alone put a surface.
  const Config cfg = testConfig();
  std::vector<Eigen::Vector3f> pts, nrm;
  const float vs = static_cast<float>(cfg.voxel_size);
  for (int i = -20; i <= 20; ++i)
    for (int j = -20; j <= 20; ++j) {
      pts.emplace_back((i + 0.5f) * vs * 0.5f, (j + 0.5f) * vs * 0.5f, 0.1f);
      nrm.push_back(Eigen::Vector3f::UnitZ());
    }
  const Eigen::Vector3f outlier(0.5f * vs, 0.5f * vs, 20.5f * vs);
  pts.push_back(outlier);
  nrm.push_back(Eigen::Vector3f::UnitZ());
  const float trunc = static_cast<float>(cfg.truncation());
  ASSERT_LT(trunc, outlier.z() - 0.1f);
  const auto sdfAtOutlier = [&](const std::vector<float>* front) {
    TsdfVolume vol(cfg);
    integratePointsWithNormals(vol, pts, nrm, cfg, front);
    const Eigen::Vector3i v = (outlier / vs).array().floor().cast<int>();
    const TsdfVoxel* x = vol.voxel(v);
    return x ? x->sdf : std::numeric_limits<float>::quiet_NaN();
  };
  EXPECT_LT(std::abs(sdfAtOutlier(nullptr)), 0.5f * vs);
  const std::vector<float> front(pts.size(), 2.0f * trunc);
  EXPECT_GT(sdfAtOutlier(&front), 0.5f * trunc);
  // A reach at or below the truncation is the truncation; the arrays must agree in length.
  TsdfVolume a(cfg), b(cfg);
  const std::vector<float> short_front(pts.size(), 0.0f);
  integratePointsWithNormals(a, pts, nrm, cfg, &short_front);
  integratePointsWithNormals(b, pts, nrm, cfg);
  EXPECT_TRUE(sameVolumes(a, b));
  const std::vector<float> wrong(3, trunc);
  EXPECT_THROW(integratePointsWithNormals(a, pts, nrm, cfg, &wrong), Error);
}

// ---- organised clouds -----------------------------------------------------------------------

TEST(TsdfCloud, OrganizedCloudIntrinsicsDepthAndIntegration) {
  const Config cfg = testConfig();
  Scene scene;
  scene.sphere = true;
  const Intrinsics K;  // 640x480 Kinect
  const Pose T_local_camera = ring(1, 0.8, 0.6, kTarget)[0];
  const DepthFrame frame = render(scene, K, T_local_camera);
  // The cloud's frame differs from the sensor frame (PCD VIEWPOINT).
  Pose sensor = Pose::Identity();
  sensor.linear() =
      Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  sensor.translation() = Eigen::Vector3d(0.3, -0.2, 1.0);
  PointCloud cloud;
  cloud.width = 640;
  cloud.height = 480;
  cloud.sensor_pose = sensor;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < 480; ++v)
    for (int u = 0; u < 640; ++u) {
      const double d = frame.at(u, v);
      if (d <= 0) {
        cloud.points.emplace_back(nan, nan, nan);
        continue;
      }
      const Eigen::Vector3d pc(d * (u - K.cx) / K.fx, d * (v - K.cy) / K.fy, d);
      cloud.points.push_back((sensor * pc).cast<float>());
    }
  double rms = -1.0;
  const Intrinsics est = estimateIntrinsics(cloud, &rms);
  EXPECT_NEAR(est.fx, 525.0, 0.05);
  EXPECT_NEAR(est.fy, 525.0, 0.05);
  EXPECT_NEAR(est.cx, 319.5, 0.05);
  EXPECT_NEAR(est.cy, 239.5, 0.05);
  EXPECT_EQ(est.width, 640);
  EXPECT_EQ(est.height, 480);
  EXPECT_LT(rms, 0.01);
  const DepthFrame back = depthFromOrganizedCloud(cloud, est);
  ASSERT_EQ(back.depth.size(), frame.depth.size());
  for (std::size_t i = 0; i < frame.depth.size(); ++i)
    ASSERT_NEAR(back.depth[i], frame.depth[i], 2e-6f * (1.0f + frame.depth[i])) << i;
  // Fused through the cloud path vs directly: the same blocks and nearly the same values.
  const Pose T_local_cloud = T_local_camera * sensor.inverse();
  TsdfVolume a(cfg), b(cfg);
  integrateOrganizedCloud(a, cloud, T_local_cloud, cfg, &K);
  integrateDepth(b, frame, T_local_camera, cfg);
  ASSERT_EQ(a.numBlocks(), b.numBlocks());
  std::size_t differ = 0;
  for (std::size_t s = 0; s < a.numBlocks(); ++s) {
    ASSERT_EQ(a.block(s).index, b.block(s).index);
    for (int i = 0; i < kTsdfBlockVoxels; ++i) {
      const TsdfVoxel &va = a.block(s).voxels[i], &vb = b.block(s).voxels[i];
      if (va.weight != vb.weight || std::abs(va.sdf - vb.sdf) > 1e-4f) ++differ;
    }
  }
  EXPECT_LE(differ, a.numVoxels() / 1000);  // rounding may flip a pixel at a depth edge
  // Not organised: a clear error.
  PointCloud flat;
  flat.points.assign(10, Eigen::Vector3f(0, 0, 1));
  flat.width = 10;
  EXPECT_THROW(estimateIntrinsics(flat), Error);
  EXPECT_THROW(depthFromOrganizedCloud(flat, K), Error);
}

}  // namespace
}  // namespace planesdf
