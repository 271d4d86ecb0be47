// The session map against analytic scenes rendered here: a table with a box and a cylinder seen
// from a ring of depth frames, a sphere resting against a wall, and save/load.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <set>

#include "analytic_scene.hpp"
#include "change/change_internal.hpp"
#include "map/map_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/map.hpp"
#include "test_support.hpp"

namespace {
using namespace planesdf;
using test::AnalyticScene;
using test::Primitive;

constexpr double kVoxel = 0.007;
const Eigen::Vector3d kBoxMin(0.05, 0.02, 0.75), kBoxMax(0.15, 0.08, 0.83);  // 10 x 6 x 8 cm
const Eigen::Vector3d kCylBase(-0.15, -0.10, 0.75);                          // r 4 cm, h 12 cm

AnalyticScene tableScene() {
  AnalyticScene s;
  s.primitives.push_back(Primitive::halfSpace(Eigen::Vector3d::UnitZ(), 0.0));   // floor
  s.primitives.push_back(Primitive::box({-0.6, -0.4, 0.72}, {0.6, 0.4, 0.75}));  // table top
  s.primitives.push_back(Primitive::box(kBoxMin, kBoxMax));
  s.primitives.push_back(Primitive::cylinder(kCylBase, 0.04, 0.12));
  return s;
}

/// The map of the table scene seen from 12 poses around it (built once).
const Map& tableMap() {
  static const Map map = [] {
    Map m{Config{}};
    const AnalyticScene scene = tableScene();
    const Intrinsics k;
    for (const Pose& T : test::ringPoses({0, 0, 0.75}, 0.9, 0.55, 12))
      m.integrate(test::renderDepth(scene, k, T), T);
    return m;
  }();
  return map;
}

/// Fuses the table scene seen from `n` poses on a ring into both maps, frame by frame.
void fuseRingIntoBoth(int n, Map& a, Map& b) {
  const AnalyticScene scene = tableScene();
  for (const Pose& T : test::ringPoses({0, 0, 0.75}, 0.9, 0.55, n)) {
    const DepthFrame f = test::renderDepth(scene, Intrinsics{}, T);
    a.integrate(f, T);
    b.integrate(f, T);
  }
}

/// Voxels of `a` whose sdf or weight differ in `b` (block by block index); a block count or
/// a block missing in `b` counts every voxel of `a` as differing.
std::size_t differingVoxels(const TsdfVolume& a, const TsdfVolume& b) {
  if (a.numBlocks() != b.numBlocks()) return a.numVoxels() + 1;
  std::size_t differing = 0;
  for (std::size_t s = 0; s < a.numBlocks(); ++s) {
    const TsdfBlock& ba = a.block(s);
    const TsdfBlock* bb = b.findBlock(ba.index);
    if (bb == nullptr) {
      differing += ba.voxels.size();
      continue;
    }
    for (std::size_t v = 0; v < ba.voxels.size(); ++v)
      differing +=
          ba.voxels[v].sdf != bb->voxels[v].sdf || ba.voxels[v].weight != bb->voxels[v].weight;
  }
  return differing;
}

const PlaneSdf* planeAtHeight(const Map& m, double z) {
  const PlaneSdf* found = nullptr;
  for (const auto& ps : m.planes())
    if (ps.plane.normal.z() > 0.99 && std::abs(-ps.plane.offset - z) < 0.02) {
      EXPECT_EQ(found, nullptr) << "two planes at height " << z;
      found = &ps;
    }
  return found;
}

TEST(Map, FindsTheTableAndFloorPlanesExactly) {
  const Map& m = tableMap();
  const PlaneSdf* table = planeAtHeight(m, 0.75);
  ASSERT_NE(table, nullptr);
  EXPECT_LT(std::acos(std::min(1.0, table->plane.normal.z())) * 180 / M_PI, 0.2);
  EXPECT_NEAR(-table->plane.offset, 0.75, 0.001);
  EXPECT_EQ(table->plane.orientation, Plane::Orientation::Horizontal);
  EXPECT_NE(planeAtHeight(m, 0.0), nullptr);  // the floor is seen beyond the table
  for (const auto& ps : m.planes()) EXPECT_EQ(ps.plane.id, &ps - m.planes().data());
}

TEST(Map, TableTsdfIsWithinHalfAVoxelNearTheSurface) {
  const Map& m = tableMap();
  const PlaneSdf* table = planeAtHeight(m, 0.75);
  ASSERT_NE(table, nullptr);
  const AnalyticScene scene = tableScene();
  const Pose to_world = table->plane.frame();
  double se = 0;
  std::size_t n = 0;
  table->volume.forEachBlock([&](const TsdfBlock& b) {
    TsdfVolume::forEachObservedVoxel(b, [&](const Eigen::Vector3i& v, const TsdfVoxel& vox) {
      const double truth = scene.sdf(to_world * table->volume.voxelCenter(v));
      if (std::abs(truth) > kVoxel) return;
      se += (vox.sdf - truth) * (vox.sdf - truth);
      ++n;
    });
  });
  ASSERT_GT(n, 5000u);
  EXPECT_LT(std::sqrt(se / n), 0.5 * kVoxel);
}

TEST(Map, HeightAndObjectMapsHoldTheBoxAndTheCylinder) {
  const Map& m = tableMap();
  const PlaneSdf* table = planeAtHeight(m, 0.75);
  ASSERT_NE(table, nullptr);
  const Config cfg;
  const HeightMap hm = computeHeightMap(table->volume, cfg);
  const Pose to_local = table->plane.frame().inverse();
  auto heightAt = [&](const Eigen::Vector3d& world) {
    const Eigen::Vector3d l = to_local * world;
    const Eigen::Vector2i c = hm.cellOf(l.head<2>());
    return hm.inBounds(c.x(), c.y()) ? hm.at(c.x(), c.y()) : -2.0f;
  };
  EXPECT_NEAR(heightAt({0.10, 0.05, 0.8}), 0.08, kVoxel);
  EXPECT_NEAR(heightAt({-0.15, -0.10, 0.8}), 0.12, kVoxel);
  EXPECT_NEAR(heightAt({0.35, -0.25, 0.75}), 0.0, cfg.h_obj);  // bare table

  const ObjectMap om = computeObjectMap(hm, cfg);
  ASSERT_EQ(om.numObjects(), 2);
  const double cell_area = kVoxel * kVoxel;
  std::vector<double> areas;
  for (const auto& o : om.objects) areas.push_back(o.area * cell_area);
  std::sort(areas.begin(), areas.end());
  // ±1 cell around each perimeter.
  const double cyl = M_PI * 0.04 * 0.04, box = 0.10 * 0.06;
  EXPECT_NEAR(areas[0], cyl, 2 * M_PI * 0.04 * kVoxel);
  EXPECT_NEAR(areas[1], box, 2 * (0.10 + 0.06) * kVoxel);
}

TEST(Map, SphereRestingOnAWallHasItsDiameterAsHeight) {
  // A wall at x = 2 (room on the -x side) and a ball of radius 8 cm touching it.
  AnalyticScene scene;
  scene.primitives.push_back(Primitive::halfSpace(-Eigen::Vector3d::UnitX(), -2.0));
  scene.primitives.push_back(Primitive::halfSpace(Eigen::Vector3d::UnitZ(), 0.0));
  const Eigen::Vector3d c(1.92, 0.0, 1.0);
  scene.primitives.push_back(Primitive::sphere(c, 0.08));
  Map m{Config{}};
  const Intrinsics k;
  for (int i = -3; i <= 3; ++i) {
    const double a = i * 0.25;
    const Eigen::Vector3d eye = c + Eigen::Vector3d(-std::cos(a), std::sin(a), 0.2) * 1.0;
    const Pose T = test::lookAt(eye, c);
    m.integrate(test::renderDepth(scene, k, T), T);
  }
  const PlaneSdf* wall = nullptr;
  for (const auto& ps : m.planes())
    if (ps.plane.normal.x() < -0.99) wall = &ps;
  ASSERT_NE(wall, nullptr);
  EXPECT_EQ(wall->plane.orientation, Plane::Orientation::Vertical);
  EXPECT_NEAR(wall->plane.signedDistance({2.0, 0.3, 1.3}), 0.0, 0.002);
  const HeightMap hm = computeHeightMap(wall->volume, Config{});
  const Eigen::Vector3d l = wall->plane.frame().inverse() * c;
  const Eigen::Vector2i cell = hm.cellOf(l.head<2>());
  ASSERT_TRUE(hm.inBounds(cell.x(), cell.y()));
  EXPECT_NEAR(hm.at(cell.x(), cell.y()), 0.16, kVoxel);
}

TEST(Map, AFrameLookingAwayTouchesNoBlock) {
  Map m = tableMap();
  AnalyticScene sky;  // nothing to see above the table
  const Pose up = test::lookAt({0, 0, 2.0}, {0, 0, 5.0}, Eigen::Vector3d::UnitY());
  const IntegrateStats s = m.integrate(test::renderDepth(sky, Intrinsics{}, up), up);
  EXPECT_EQ(s.blocks_updated, 0u);
  EXPECT_TRUE(s.changed_planes.empty());
  EXPECT_TRUE(s.new_planes.empty());
}

TEST(Map, SaveLoadRoundTripIsExact) {
  const Map& m = tableMap();
  test::TempDir tmp;
  const std::string path = tmp.file("table.psdf");
  m.save(path);
  const Map back = Map::load(path);
  EXPECT_EQ(back.serialize(), m.serialize());
  ASSERT_EQ(back.planes().size(), m.planes().size());
  for (std::size_t i = 0; i < m.planes().size(); ++i) {
    EXPECT_EQ(back.planes()[i].plane.normal, m.planes()[i].plane.normal);
    EXPECT_EQ(back.planes()[i].plane.frame().matrix(), m.planes()[i].plane.frame().matrix());
    EXPECT_EQ(back.planes()[i].volume.numBlocks(), m.planes()[i].volume.numBlocks());
  }
  EXPECT_EQ(back.points().size(), m.points().size());
  EXPECT_EQ(back.frames(), m.frames());
}

TEST(Map, LoadedMapKeepsIntegrating) {
  Map back = Map::deserialize(tableMap().serialize(), "mem");
  const std::size_t planes = back.planes().size();
  const Pose T = test::lookAt({0.9, 0.3, 1.3}, {0, 0, 0.75});
  const IntegrateStats s = back.integrate(test::renderDepth(tableScene(), Intrinsics{}, T), T);
  EXPECT_EQ(back.planes().size(), planes);  // same planes recognised, no duplicates
  EXPECT_GT(s.blocks_updated, 0u);
  // The loaded map remembers which cells hold a kept point: a frame seen again keeps exactly
  // what it keeps in the map that never left memory (and not every point a second time).
  Map same = tableMap();
  same.integrate(test::renderDepth(tableScene(), Intrinsics{}, T), T);
  EXPECT_EQ(back.points().size(), same.points().size());
  EXPECT_TRUE(back.points() == same.points());
}

TEST(Map, CorruptTruncatedAndForeignFilesNameTheFile) {
  test::TempDir tmp;
  const std::string good = tableMap().serialize();
  auto errorOf = [&](const std::string& bytes, const std::string& name) -> std::string {
    const std::string path = tmp.file(name);
    test::writeBytes(path, bytes);
    try {
      Map::load(path);
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      return e.what();
    }
    return "no error";
  };
  std::string flipped = good;
  flipped[good.size() / 2] ^= 0x40;
  EXPECT_NE(errorOf(flipped, "flipped.psdf").find("checksum"), std::string::npos);
  EXPECT_NE(errorOf(good.substr(0, good.size() - 100), "cut.psdf").find("truncated"),
            std::string::npos);
  EXPECT_NE(errorOf("ply\nformat ascii 1.0\n", "foreign.psdf").find("not a planesdf map"),
            std::string::npos);
  EXPECT_NE(errorOf("", "empty.psdf").find("not a planesdf map"), std::string::npos);
  std::string future = good;
  future[8] = 99;  // version
  EXPECT_NE(errorOf(future, "future.psdf").find("version 99"), std::string::npos);
  EXPECT_THROW(Map::load(tmp.file("missing.psdf")), Error);
  const std::string fifo = tmp.file("pipe.psdf");  // open() would block until a writer came
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_THROW(Map::load(fifo), Error);
}

TEST(Map, PointCellKeysOfFarAndNonFinitePointsAreDefined) {
  // A loaded map's points are keyed with cellKeyOf; a point at 1.9e38 made the conversion of its
  // cell index to an integer undefined (UBSan, found by tests/fuzz/psdf_fuzz.cpp).
  using detail::cellKeyOf;
  const double cell = 0.0035;
  EXPECT_EQ(cellKeyOf({0.001f, 0.0f, 0.0f}, cell), cellKeyOf({0.002f, 0.0f, 0.0f}, cell));
  EXPECT_NE(cellKeyOf({0.001f, 0.0f, 0.0f}, cell), cellKeyOf({0.004f, 0.0f, 0.0f}, cell));
  EXPECT_NE(cellKeyOf({-0.001f, 0.0f, 0.0f}, cell), cellKeyOf({0.001f, 0.0f, 0.0f}, cell));
  const float inf = std::numeric_limits<float>::infinity();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const float x : {1e30f, -1e30f, 1.8989e38f, inf, -inf, nan}) {
    const std::uint64_t key = cellKeyOf({x, 0.0f, x}, cell);
    EXPECT_LT(key, std::uint64_t{1} << 63) << x;
    EXPECT_EQ(key, cellKeyOf({x, 0.0f, x}, cell)) << x;
  }
  EXPECT_EQ(cellKeyOf({1e30f, 0.0f, 0.0f}, cell), cellKeyOf({inf, 0.0f, 0.0f}, cell));
  EXPECT_EQ(cellKeyOf({-1e30f, 0.0f, 0.0f}, cell), cellKeyOf({nan, 0.0f, 0.0f}, cell));
}

TEST(Map, ReadsVersionOneMapsAndCatchesTheirCorruption) {
  // Version 1 had the same layout with a byte-wise FNV-1a checksum; such files still load, and
  // are the same map (written back as the current version, byte for byte what the original
  // writes).
  const Map m = tableMap();
  const std::string current = m.serialize();
  std::string v1 = current;
  const std::uint32_t one = 1;
  std::memcpy(&v1[8], &one, sizeof(one));
  std::uint64_t h = 1469598103934665603ull;
  for (std::size_t i = 24; i + 8 < v1.size(); ++i) {
    h ^= static_cast<unsigned char>(v1[i]);
    h *= 1099511628211ull;
  }
  std::memcpy(&v1[v1.size() - 8], &h, sizeof(h));
  EXPECT_EQ(Map::deserialize(v1, "v1.psdf").serialize(), current);
  std::string flipped = v1;
  flipped[flipped.size() / 2] ^= 0x01;
  EXPECT_THROW(Map::deserialize(flipped, "v1.psdf"), Error);
  // The current checksum catches a flipped bit in every part of the payload.
  for (const std::size_t at : {std::size_t{24}, current.size() / 3, current.size() - 9}) {
    std::string bad = current;
    bad[at] ^= 0x01;
    EXPECT_THROW(Map::deserialize(bad, "bad.psdf"), Error) << at;
  }
}

TEST(Map, SameMapOnOneAndTwoThreads) {
  // With two threads, plane tracking and the frame's per-pixel analysis run side by side, and
  // fusion and the kept points are split over blocks and points; the map is the same byte for
  // byte as the single-threaded one.
  Config one, two;
  one.threads = 1;
  two.threads = 2;
  Map a{one}, b{two};
  fuseRingIntoBoth(4, a, b);
  ASSERT_EQ(a.planes().size(), 2u);
  ASSERT_EQ(b.planes().size(), 2u);
  for (std::size_t i = 0; i < 2; ++i) {
    const PlaneSdf &pa = a.planes()[i], &pb = b.planes()[i];
    EXPECT_EQ(pa.plane.normal, pb.plane.normal);
    EXPECT_EQ(pa.plane.offset, pb.plane.offset);
    EXPECT_EQ(differingVoxels(pa.volume, pb.volume), 0u) << "plane " << i;
  }
  EXPECT_GT(a.points().size(), 1000u);
  EXPECT_EQ(a.points(), b.points());
}

TEST(Map, ReservedMemoryHoldsTheSameMapAndIsCounted) {
  // Blocks go to the reserve first; the fused map is the same byte for byte, and memoryBytes
  // counts what the reserve still holds.
  Map plain{Config{}}, reserved{Config{}};
  constexpr std::size_t kChunk = std::size_t{2} << 20;
  reserved.reserveMemory(5 * kChunk - 100, 200000);  // rounded up to 5 chunks
  EXPECT_EQ(reserved.reservedBytes(), 5 * kChunk);
  EXPECT_EQ(plain.reservedBytes(), 0u);
  EXPECT_GE(reserved.memoryBytes(), 5 * kChunk + 200000 * sizeof(Eigen::Vector3f));
  EXPECT_TRUE(reserved.points().empty());
  fuseRingIntoBoth(3, plain, reserved);
  ASSERT_EQ(reserved.planes().size(), 2u);
  ASSERT_EQ(plain.planes().size(), 2u);
  // Two planes took a chunk each at least (their first blocks).
  EXPECT_LE(reserved.reservedBytes(), 3 * kChunk);
  for (std::size_t i = 0; i < 2; ++i)
    EXPECT_EQ(differingVoxels(plain.planes()[i].volume, reserved.planes()[i].volume), 0u)
        << "plane " << i;
  EXPECT_EQ(plain.points(), reserved.points());
  EXPECT_GE(reserved.memoryBytes() - reserved.reservedBytes(),
            reserved.planes()[0].volume.memoryBytes() + reserved.planes()[1].volume.memoryBytes());
  // A request beyond the machine's memory is an error that reserves nothing (not a crash of
  // the process by the kernel's OOM killer).
  const std::size_t before = reserved.reservedBytes();
  try {
    reserved.reserveMemory(std::size_t{1} << 60);
    ADD_FAILURE() << "an exabyte reserve was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("exceed this machine's"), std::string::npos) << e.what();
  }
  EXPECT_THROW(reserved.reserveMemory(0, std::size_t{1} << 58), Error);
  EXPECT_EQ(reserved.reservedBytes(), before);
}

TEST(Map, IntegrateReportsItsStageTimes) {
  // Tracking, then the kept points, then fusion are disjoint intervals of the call: each takes
  // some time and together no more than the whole call. For a cloud as well.
  Map m{Config{}};
  const AnalyticScene scene = tableScene();
  for (const Pose& T : test::ringPoses({0, 0, 0.75}, 0.9, 0.55, 2)) {
    const IntegrateStats st = m.integrate(test::renderDepth(scene, Intrinsics{}, T), T);
    EXPECT_GT(st.tracking_ms, 0.0);
    EXPECT_GT(st.points_ms, 0.0);
    EXPECT_GT(st.fusion_ms, 0.0);
    EXPECT_LE(st.tracking_ms + st.points_ms + st.fusion_ms, st.milliseconds);
  }
  ASSERT_EQ(m.planes().size(), 2u);
  PointCloud cloud;
  for (int i = 0; i < 2000; ++i)
    cloud.points.emplace_back(0.001f * static_cast<float>(i % 50),
                              0.001f * static_cast<float>(i / 50), 0.8f);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  const IntegrateStats st = m.integrate(cloud, Pose::Identity());
  EXPECT_GT(st.tracking_ms, 0.0);
  EXPECT_GT(st.fusion_ms, 0.0);
  EXPECT_LE(st.tracking_ms + st.points_ms + st.fusion_ms, st.milliseconds);
}

TEST(Map, AnUnorganisedCloudMarksTheMapSplattedAndTheMarkIsSaved) {
  Map m = Map::deserialize(tableMap().serialize(), "mem");
  EXPECT_FALSE(m.splatted());
  EXPECT_EQ(surfaceRimCells(m), 0);
  PointCloud cloud;
  for (int i = 0; i < 2000; ++i)
    cloud.points.emplace_back(0.001f * static_cast<float>(i % 50),
                              0.001f * static_cast<float>(i / 50), 0.8f);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  m.integrate(cloud, Pose::Identity());
  ASSERT_TRUE(m.splatted());
  EXPECT_EQ(surfaceRimCells(m), 1);  // splat_radius_voxels = 1
  const Map back = Map::deserialize(m.serialize(), "mem");
  EXPECT_TRUE(back.splatted());
  EXPECT_EQ(back.serialize(), m.serialize());
}

/// A cloud without a viewpoint, sampled every cm: a 2 x 2 m floor at z = 0 and both faces (at
/// z_under and z_top) of a slab 2 * half_x by 2 * half_y cm centred over the origin.
PointCloud floorAndSlab(float z_under, float z_top, int half_x, int half_y) {
  PointCloud cloud;
  for (int i = -100; i <= 100; ++i)
    for (int j = -100; j <= 100; ++j)
      cloud.points.emplace_back(0.01f * static_cast<float>(i), 0.01f * static_cast<float>(j), 0.0f);
  for (const float z : {z_under, z_top})
    for (int i = -half_x; i <= half_x; ++i)
      for (int j = -half_y; j <= half_y; ++j)
        cloud.points.emplace_back(0.01f * static_cast<float>(i), 0.01f * static_cast<float>(j), z);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  return cloud;
}

/// The plane of `m` at z = 0 facing up, or nullptr.
const PlaneSdf* floorOf(const Map& m) {
  for (const PlaneSdf& p : m.planes())
    if (std::abs(p.plane.offset) < 0.01 && p.plane.normal.z() > 0.99) return &p;
  return nullptr;
}

TEST(Map, CloudFusionBeyondTheMemoryLimitIsRefusedBeforeAllocating) {
  // A 1 mm voxel with a 10 m band: every point of the cloud is in every plane's band and the
  // blocks would take hundreds of MB; with a 64 MB budget the map refuses them.
  Config cfg;
  cfg.voxel_size = 0.001;
  cfg.fuse_band = 10.0;
  cfg.memory_limit_mb = 64;
  try {
    Map::fromCloud(floorAndSlab(0.17f, 0.20f, 30, 20), cfg);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("new TSDF blocks at voxel_size 0.001"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("memory limit"), std::string::npos) << e.what();
  }
}

TEST(Map, DepthFrameBeyondTheMemoryLimitIsRefusedAndLeavesTheMapUnchanged) {
  Config cfg;
  cfg.memory_limit_mb = 256;
  Map m(cfg);
  DepthFrame f;
  f.intrinsics.width = f.intrinsics.height = 4096;  // about 1 GB of fusion buffers
  f.intrinsics.cx = f.intrinsics.cy = 2047.5;
  f.depth.assign(std::size_t{4096} * 4096, 1.0f);
  try {
    m.integrate(f, Pose::Identity());
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), "depth frame");
    EXPECT_NE(e.message().find("4096x4096"), std::string::npos) << e.what();
    EXPECT_NE(e.message().find("memory limit of 256 MB"), std::string::npos) << e.what();
  }
  EXPECT_EQ(m.frames(), 0u);
  EXPECT_TRUE(m.planes().empty());
}

TEST(Map, TheUndersideOfASlabFacesDownWithoutAViewpoint) {
  // A cloud without a viewpoint: a floor and a low table top 3 cm thick (faces at 17 and 20 cm),
  // both faces sampled. Inside the slab the floor's SDF is negative: the underside faces down
  // (facing up like the top, it would make the slab's inside free space).
  const Config cfg;
  const Map m = Map::fromCloud(floorAndSlab(0.17f, 0.20f, 30, 20), cfg);
  const PlaneSdf* floor = floorOf(m);
  ASSERT_NE(floor, nullptr);
  int inside = 0, negative = 0;
  for (double x = -0.2; x <= 0.2; x += 0.02)
    for (double y = -0.1; y <= 0.1; y += 0.02) {
      const Eigen::Vector3d w(x, y, 0.185);
      const TsdfVoxel* v = floor->volume.voxel(floor->volume.voxelIndexAt(floor->plane.toLocal(w)));
      if (v == nullptr || !(v->weight > 0.0f)) continue;
      ++inside;
      negative += v->sdf < -0.5f * static_cast<float>(cfg.voxel_size) ? 1 : 0;
    }
  EXPECT_GT(inside, 100);
  EXPECT_EQ(negative, inside);
}

TEST(Map, AnObjectsTopInACloudWithoutAPixelGridIsNoPlane) {
  // Whole-scene clouds without a pixel grid keep supports only, as streams do: the faces of a
  // 45 x 45 cm box (shorter than plane_min_extent) are no plane, those of a 90 x 30 cm board are.
  const Config cfg;
  const auto raisedPlanes = [](const Map& m) {
    int n = 0;
    for (const PlaneSdf& p : m.planes())
      n += std::abs(p.plane.offset) > 0.1 && std::abs(p.plane.normal.z()) > 0.99;
    return n;
  };
  const Map box = Map::fromCloud(floorAndSlab(0.17f, 0.20f, 22, 22), cfg);
  EXPECT_NE(floorOf(box), nullptr);
  EXPECT_EQ(raisedPlanes(box), 0);
  const Map board = Map::fromCloud(floorAndSlab(0.17f, 0.20f, 45, 15), cfg);
  EXPECT_NE(floorOf(board), nullptr);
  EXPECT_GE(raisedPlanes(board), 1);
}

TEST(Map, TheUndersideOfABoardOverTheBandIsNoObjectOnTheFloor) {
  // A cloud without a viewpoint: a 2 x 2 m floor and a board 2 cm thick whose underside lies
  // 29.5 cm above it (in the floor's 30 cm band) and its top 31.5 cm (just above). The board's
  // plane compares its underside; on the floor it stands as nothing.
  const Config cfg;
  const Map m = Map::fromCloud(floorAndSlab(0.295f, 0.315f, 45, 15), cfg);
  const PlaneSdf* floor = floorOf(m);
  ASSERT_NE(floor, nullptr);
  for (const bool with_planes : {false, true}) {
    const HeightMap hm = with_planes ? computePlaneMaps(*floor, m.planes(), cfg).heights
                                     : computeHeightMap(floor->volume, cfg);
    int under = 0, object = 0;
    for (int y = 0; y < hm.height; ++y)
      for (int x = 0; x < hm.width; ++x) {
        const Eigen::Vector2d uv = hm.cellCenter(x, y);
        const Eigen::Vector3d w = floor->plane.toWorld(Eigen::Vector3d(uv.x(), uv.y(), 0.0));
        if (std::abs(w.x()) > 0.4 || std::abs(w.y()) > 0.1) continue;
        ++under;
        object += hm.at(x, y) > static_cast<float>(cfg.h_obj) ? 1 : 0;
      }
    EXPECT_GT(under, 1000);
    // The floor's own volume holds the underside at the top of its band; the maps leave it out.
    if (with_planes) {
      EXPECT_EQ(object, 0);
    } else {
      EXPECT_GT(object, under / 2);
    }
  }
}

/// A reconstruction-like cloud without a viewpoint, sampled every 5 mm: a 2 x 2 m floor at
/// z = 0 with no points under the objects, a 20 x 20 x 10 cm box at (-0.4, 0) and a square ring
/// 40 cm wide, 8 cm high, with a 16 cm hole at (0.4, 0): their tops and side faces.
PointCloud boxAndRing() {
  constexpr float s = 0.005f;
  const auto inBox = [](float x, float y) {
    return std::abs(x + 0.4f) < 0.1f && std::abs(y) < 0.1f;
  };
  const auto inRing = [](float x, float y) {
    const float r = std::max(std::abs(x - 0.4f), std::abs(y));
    return r < 0.2f && r > 0.08f;
  };
  PointCloud cloud;
  for (int i = -200; i <= 200; ++i)
    for (int j = -200; j <= 200; ++j) {
      const float x = s * static_cast<float>(i), y = s * static_cast<float>(j);
      if (inBox(x, y))
        cloud.points.emplace_back(x, y, 0.10f);
      else if (inRing(x, y))
        cloud.points.emplace_back(x, y, 0.08f);
      else
        cloud.points.emplace_back(x, y, 0.0f);
    }
  // Side faces: a square of half size h centred at (cx, 0), from 0 to height z.
  const auto sides = [&](float cx, float h, float z) {
    for (float z0 = s; z0 < z; z0 += s)
      for (float t = -h; t <= h + 1e-4f; t += s) {
        cloud.points.emplace_back(cx + t, -h, z0);
        cloud.points.emplace_back(cx + t, h, z0);
        cloud.points.emplace_back(cx - h, t, z0);
        cloud.points.emplace_back(cx + h, t, z0);
      }
  };
  sides(-0.4f, 0.1f, 0.10f);
  sides(0.4f, 0.2f, 0.08f);
  sides(0.4f, 0.08f, 0.08f);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  return cloud;
}

TEST(Map, SideFacesOfACloudWithoutViewpointsFaceOutOfTheObject) {
  // Side faces turned inward would put free space inside the object and grow its footprint by
  // the truncation outside; facing out, the floor's height map holds each footprint to within
  // the splat's one-cell rim, and the ring's hole stays floor.
  const Config cfg;
  const Map m = Map::fromCloud(boxAndRing(), cfg);
  const PlaneSdf* floor = floorOf(m);
  ASSERT_NE(floor, nullptr);
  const HeightMap hm = computePlaneMaps(*floor, m.planes(), cfg).heights;
  const double rim = hm.cell_size + 1e-6;  // one cell of splat rim
  int box_in = 0, box_object = 0, ring_in = 0, ring_object = 0, hole_in = 0, hole_object = 0,
      outside_object = 0;
  for (int y = 0; y < hm.height; ++y)
    for (int x = 0; x < hm.width; ++x) {
      const Eigen::Vector2d uv = hm.cellCenter(x, y);
      const Eigen::Vector3d w = floor->plane.toWorld(Eigen::Vector3d(uv.x(), uv.y(), 0.0));
      if (std::abs(w.x()) > 0.95 || std::abs(w.y()) > 0.95) continue;
      const bool object = hm.at(x, y) > static_cast<float>(cfg.h_obj);
      const double box_r = std::max(std::abs(w.x() + 0.4), std::abs(w.y()));
      const double ring_r = std::max(std::abs(w.x() - 0.4), std::abs(w.y()));
      if (box_r < 0.1 - rim) {
        ++box_in;
        box_object += object;
      } else if (ring_r < 0.2 - rim && ring_r > 0.08 + rim) {
        ++ring_in;
        ring_object += object;
      } else if (ring_r < 0.08 - rim) {
        ++hole_in;
        hole_object += object;
      } else if (box_r > 0.1 + rim && ring_r > 0.2 + rim) {
        outside_object += object;
      }
    }
  EXPECT_GT(box_in, 600);
  EXPECT_EQ(box_object, box_in);
  EXPECT_GT(ring_in, 2000);
  EXPECT_EQ(ring_object, ring_in);
  EXPECT_GT(hole_in, 300);
  EXPECT_EQ(hole_object, 0);
  EXPECT_EQ(outside_object, 0);
}

TEST(Map, BadFramesAreErrors) {
  Map m{Config{}};
  DepthFrame f;
  f.depth.resize(10);
  EXPECT_THROW(m.integrate(f, Pose::Identity()), Error);
  f.intrinsics.fx = -5;
  f.depth.resize(640 * 480);
  EXPECT_THROW(m.integrate(f, Pose::Identity()), Error);
  Config bad;
  bad.voxel_size = -1;
  EXPECT_THROW(Map{bad}, Error);
}

/// The what() of the planesdf::Error `f` throws, or "no error".
template <typename F>
std::string errorOf(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "no error";
}

TEST(Map, NanAndNonRigidPosesAreErrorsThatLeaveTheMapUnchanged) {
  // A NaN pose would drop the frame and a scaled, sheared or mirrored one distort it: both are
  // refused before anything is fused, naming the pose and what is wrong with it.
  Map m = Map::deserialize(tableMap().serialize(), "mem");
  const std::string before = m.serialize();
  const Pose T = test::lookAt({0.9, 0.3, 1.3}, {0, 0, 0.75});
  const DepthFrame f = test::renderDepth(tableScene(), Intrinsics{}, T);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  Pose nan_t = T, nan_r = T, inf_t = T, scaled = T, sheared = T, mirrored = T;
  nan_t.translation().x() = nan;
  nan_r.linear()(1, 2) = nan;
  inf_t.translation().z() = std::numeric_limits<double>::infinity();
  scaled.linear() *= 1.01;
  sheared.linear() = T.linear() * (Eigen::Matrix3d() << 1, 0.01, 0, 0, 1, 0, 0, 0, 1).finished();
  mirrored.linear() = T.linear() * Eigen::Vector3d(1, 1, -1).asDiagonal();
  for (const Pose& p : {nan_t, nan_r, inf_t})
    EXPECT_EQ(errorOf([&] { m.integrate(f, p); }),
              "camera pose: is not finite (NaN or infinite entries)");
  for (const Pose& p : {scaled, sheared}) {
    const std::string what = errorOf([&] { m.integrate(f, p); });
    EXPECT_EQ(what.rfind("camera pose: rotation is not orthonormal", 0), 0u) << what;
  }
  EXPECT_EQ(errorOf([&] { m.integrate(f, mirrored); }),
            "camera pose: rotation has determinant -1, not +1: a reflection is not a rigid motion");
  EXPECT_EQ(m.frames(), tableMap().frames());
  EXPECT_EQ(m.serialize(), before);

  // Unorganised clouds: the pose placing the cloud and the cloud's own sensor pose.
  PointCloud cloud;
  for (int i = 0; i < 2000; ++i)
    cloud.points.emplace_back(0.001f * static_cast<float>(i % 50),
                              0.001f * static_cast<float>(i / 50), 0.8f);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  EXPECT_EQ(errorOf([&] { m.integrate(cloud, nan_t); }),
            "cloud pose: is not finite (NaN or infinite entries)");
  EXPECT_EQ(errorOf([&] { m.integrate(cloud, mirrored); }).rfind("cloud pose: rotation has", 0),
            0u);
  cloud.sensor_pose = scaled;
  EXPECT_EQ(errorOf([&] {
              m.integrate(cloud, Pose::Identity());
            }).rfind("point cloud sensor_pose: rotation is not orthonormal", 0),
            0u);
  EXPECT_THROW(Map::fromCloud(cloud, Config{}), Error);
  EXPECT_EQ(m.serialize(), before);

  // A rotation rounded to float precision (|R^T R - I| ~ 1e-7) is rigid: fused as given.
  Pose rounded = T;
  rounded.linear() = T.linear().cast<float>().cast<double>();
  const IntegrateStats s = m.integrate(f, rounded);
  EXPECT_GT(s.blocks_updated, 0u);
  EXPECT_EQ(m.frames(), tableMap().frames() + 1);
}

TEST(CellBitSet, HoldsExactlyTheInsertedCells) {
  // Random cells around the key origin (2^20 per axis), clustered so that bricks are shared
  // and also spread over distant bricks; checked against a plain set.
  std::mt19937_64 rng(5);
  const auto key = [](std::uint64_t x, std::uint64_t y, std::uint64_t z) {
    return x | (y << 21) | (z << 42);
  };
  detail::CellBitSet set;
  std::set<std::uint64_t> truth;
  std::uniform_int_distribution<std::uint64_t> near(0, 40), far(0, (1u << 21) - 1);
  for (int i = 0; i < 200000; ++i) {
    const bool spread = i % 10 == 0;
    const std::uint64_t base = 1u << 20;
    const std::uint64_t k = spread ? key(far(rng), far(rng), far(rng))
                                   : key(base + near(rng), base - near(rng), base + near(rng));
    EXPECT_EQ(set.insert(k), truth.insert(k).second) << i;
  }
  EXPECT_EQ(set.size(), truth.size());
  EXPECT_GT(truth.size(), 50000u);
  for (const std::uint64_t k : truth) ASSERT_FALSE(set.insert(k));
  // Cells of one brick share its key; the next cell along each axis starts another brick.
  EXPECT_EQ(detail::CellBitSet::brickOf(key(8, 16, 24)),
            detail::CellBitSet::brickOf(key(15, 23, 31)));
  EXPECT_NE(detail::CellBitSet::brickOf(key(15, 16, 24)),
            detail::CellBitSet::brickOf(key(16, 16, 24)));
  EXPECT_NE(detail::CellBitSet::brickOf(key(8, 23, 24)),
            detail::CellBitSet::brickOf(key(8, 24, 24)));
  EXPECT_NE(detail::CellBitSet::brickOf(key(8, 16, 31)),
            detail::CellBitSet::brickOf(key(8, 16, 32)));
}

}  // namespace

TEST(BandPretest, NeverDropsAPointInsideABandAndDropsThoseWellOutside) {
  // Planes of random orientation and offsets up to 10 km; points at random places up to 10 km
  // away, at heights just inside and just outside the band edges (down to 1e-9 m) and well
  // outside. Every point whose exact (double) height is in a band must pass, with and without
  // AVX2; points 5 cm or more outside every band must not.
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  const double lo = 0.005, hi = 0.30;
  for (int trial = 0; trial < 20; ++trial) {
    struct PlaneD {
      Eigen::Vector3d n;
      double d;
    };
    std::vector<PlaneD> planes;
    std::vector<detail::BandF> bands;
    const double scale = trial < 10 ? 5.0 : 1e4;
    for (int k = 0; k < 1 + trial % 3; ++k) {
      const Eigen::Vector3d n = Eigen::Vector3d(unit(rng), unit(rng), unit(rng)).normalized();
      const double d = unit(rng) * scale;
      planes.push_back({n, d});
      const Eigen::Vector3f nf = n.cast<float>();
      bands.push_back({nf.x(), nf.y(), nf.z(), static_cast<float>(d), static_cast<float>(lo),
                       static_cast<float>(hi)});
    }
    const double offsets[] = {-1e-9, 1e-9, -1e-6, 1e-6, -1e-4, 1e-4, 0.0};
    std::vector<Eigen::Vector3f> pts;
    for (int i = 0; i < 1001; ++i) {  // not a multiple of 8: the scalar tail runs too
      const PlaneD& pl = planes[static_cast<std::size_t>(i) % planes.size()];
      const double edge = (i % 4 < 2) ? lo : hi;
      const double off = (i % 5 == 4) ? (i % 2 ? 0.05 : -0.05) : offsets[i % 7];
      const Eigen::Vector3d q(unit(rng) * scale, unit(rng) * scale, unit(rng) * scale);
      // The point at height edge + off above plane pl (then rounded to float).
      const Eigen::Vector3d p = q - (pl.n.dot(q) + pl.d - (edge + off)) * pl.n;
      pts.push_back(p.cast<float>());
    }
    pts.push_back(Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
    const int m = static_cast<int>(pts.size());
    std::vector<std::uint8_t> avx(m, 7), scalar(m, 7);
    detail::bandPretest(pts.front().data(), m, bands, avx.data(), true);
    detail::bandPretest(pts.front().data(), m, bands, scalar.data(), false);
    std::size_t inside = 0, far = 0;
    for (int i = 0; i < m; ++i) {
      const Eigen::Vector3d p = pts[static_cast<std::size_t>(i)].cast<double>();
      bool in = false, all_far = p.allFinite();
      for (const PlaneD& pl : planes) {
        const double h = pl.n.dot(p) + pl.d;
        in = in || (h >= lo && h <= hi);
        all_far = all_far && (h < lo - 0.04 || h > hi + 0.04);
      }
      ASSERT_LE(avx[i], 1);
      ASSERT_LE(scalar[i], 1);
      if (in) {
        ++inside;
        EXPECT_EQ(avx[i], 1) << "trial " << trial << " point " << i;
        EXPECT_EQ(scalar[i], 1) << "trial " << trial << " point " << i;
      }
      if (all_far && scale < 100) {  // the margin grows with the coordinates (4e-7 of 3e4 m)
        ++far;
        EXPECT_EQ(avx[i], 0) << "trial " << trial << " point " << i;
        EXPECT_EQ(scalar[i], 0) << "trial " << trial << " point " << i;
      }
    }
    EXPECT_EQ(avx[m - 1], 0);  // NaN
    EXPECT_GT(inside, 300u);
    if (scale < 100) {
      EXPECT_GT(far, 80u);
    }
  }
}
