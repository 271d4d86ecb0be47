// Mapping end to end: the real mOSD scenes fuse and their table is found; `planesdf fuse` on a
// cloud, on a TUM folder written here, and on bad input.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "analytic_scene.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/io/pcd.hpp"
#include "planesdf/io/ply.hpp"
#include "planesdf/io/tum.hpp"
#include "planesdf/map.hpp"
#include "test_support.hpp"

namespace {
using namespace planesdf;

TEST(MosdMap, ScenesFuseAndTheTableCarriesTheObjects) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  Config cfg;
  cfg.up_auto = true;
  for (const char* name : {"learn0", "test31", "test45", "test62"}) {
    SCOPED_TRACE(name);
    const PointCloud c = io::readPcd(test::mosdDir() + "/scenes/" + name + ".pcd");
    const Map m = Map::fromCloud(c, cfg);
    ASSERT_FALSE(m.planes().empty());
    // The table: the plane with the largest support, facing the camera (camera y points down).
    const PlaneSdf* table = &m.planes()[0];
    for (const auto& ps : m.planes())
      if (ps.plane.support > table->plane.support) table = &ps;
    EXPECT_EQ(table->plane.orientation, Plane::Orientation::Horizontal);
    EXPECT_LT(table->plane.normal.y(), -0.7);
    EXPECT_GT(table->plane.signedDistance(Eigen::Vector3d::Zero()), 0.3);  // sensor above it
    // Most valid points within 1.5 cm of the table or above it in the band.
    std::size_t near = 0;
    for (const auto& p : c.points)
      if (PointCloud::isValid(p) && std::abs(table->plane.signedDistance(p.cast<double>())) < 0.015)
        ++near;
    EXPECT_GT(static_cast<double>(near) / c.countValid(), 0.3);
    const ObjectMap om = computeObjectMap(computeHeightMap(table->volume, cfg), cfg);
    EXPECT_GE(om.numObjects(), 1);  // every mOSD scene has objects on the table
    EXPECT_GT(m.points().size(), 5000u);
  }
}

TEST(FuseCli, CloudToMapAndPictures) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  test::TempDir tmp;
  const std::string out = tmp.file("t31.psdf");
  const auto r = test::runCli("fuse '" + test::mosdDir() + "/scenes/test31.pcd' --up auto --out '" +
                              out + "' --pictures '" + tmp.file("pics") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const Map m = Map::load(out);
  EXPECT_GE(m.planes().size(), 1u);
  EXPECT_TRUE(std::filesystem::exists(tmp.file("pics/plane_0_height.png")));
  EXPECT_TRUE(std::filesystem::exists(tmp.file("pics/plane_0_objects.png")));
}

TEST(FuseCli, ConfigFileSetsTheMapsConfigAndFlagsOverrideIt) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  test::TempDir tmp;
  {
    std::ofstream cfg(tmp.file("cfg.json"));
    cfg << R"({"voxel_size": 0.01, "fuse_band": 0.25})";
  }
  const std::string out = tmp.file("t31.psdf");
  const auto r = test::runCli("fuse '" + test::mosdDir() + "/scenes/test31.pcd' --up auto --out '" +
                              out + "' --config '" + tmp.file("cfg.json") + "' --band 0.2");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const Map m = Map::load(out);
  EXPECT_EQ(m.config().voxel_size, 0.01);
  EXPECT_EQ(m.config().fuse_band, 0.2);
}

// A 160 x 120 pinhole camera: small TUM folders for the CLI.
Intrinsics smallCamera() {
  return test::pinhole(160, 120, 130.0);
}

/// A floor, plus a 10 cm box when `box`.
test::AnalyticScene floorScene(bool box) {
  test::AnalyticScene scene;
  scene.primitives.push_back(test::Primitive::halfSpace(Eigen::Vector3d::UnitZ(), 0.0));
  if (box) scene.primitives.push_back(test::Primitive::box({-0.05, -0.05, 0.0}, {0.05, 0.05, 0.1}));
  return scene;
}

/// `n` views of `scene` from a ring 0.8 m around the origin (smallCamera), as a TUM folder.
void writeRingSequence(const std::string& folder, const test::AnalyticScene& scene, int n) {
  const std::vector<Pose> poses = test::ringPoses({0, 0, 0}, 0.8, 0.6, n);
  std::vector<DepthFrame> frames;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    frames.push_back(test::renderDepth(scene, smallCamera(), poses[i]));
    frames.back().timestamp = 1.0 + 0.1 * static_cast<double>(i);
  }
  io::writeTumSequence(folder, frames, poses);
}

TEST(FuseCli, TumFolderWithProgress) {
  test::TempDir tmp;
  writeRingSequence(tmp.file("seq"), floorScene(true), 6);
  const auto r = test::runCli("fuse '" + tmp.file("seq") + "' --out '" + tmp.file("m.psdf") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("frame 6/6"), std::string::npos) << r.out;
  const Map m = Map::load(tmp.file("m.psdf"));
  ASSERT_GE(m.planes().size(), 1u);
  EXPECT_NEAR(m.planes()[0].plane.offset, 0.0, 0.005);
  EXPECT_EQ(m.frames(), 6u);
}

TEST(FuseCli, HugeIntrinsicsAreRefusedBeyondTheMemoryLimitNamingTheFolder) {
  test::TempDir tmp;
  writeRingSequence(tmp.file("seq"), floorScene(false), 2);
  test::writeBytes(tmp.file("seq/intrinsics.txt"),
                   "fx 525\nfy 525\ncx 8191.5\ncy 8191.5\nwidth 16384\nheight 16384\n");
  const auto r = test::runCli("fuse '" + tmp.file("seq") + "' --memory-limit-mb 4096 --out '" +
                              tmp.file("m.psdf") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("planesdf: error: " + tmp.file("seq") + ": loading and fusing 16384x16384"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("memory limit of 4096 MB"), std::string::npos) << r.out;
  EXPECT_FALSE(std::filesystem::exists(tmp.file("m.psdf")));
}

TEST(FuseCli, ACloudInMillimetresGetsAHintAboutUnits) {
  // A 2 x 2 m floor with 2 mm of noise, written in millimetres: no plane at 1.5 cm tolerance.
  test::TempDir tmp;
  PointCloud cloud;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> noise(-2.0f, 2.0f);
  for (int i = -100; i <= 100; ++i)
    for (int j = -100; j <= 100; ++j)
      cloud.points.emplace_back(10.0f * static_cast<float>(i), 10.0f * static_cast<float>(j),
                                noise(rng));
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  io::writePly(tmp.file("mm.ply"), cloud);
  const auto r =
      test::runCli("fuse '" + tmp.file("mm.ply") + "' --out '" + tmp.file("m.psdf") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(
      r.out.find(tmp.file("mm.ply") + ": no horizontal or vertical plane found in a cloud 2000"),
      std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("millimetres"), std::string::npos) << r.out;
}

TEST(DetectCli, MapsOfDifferentVoxelSizesNameBothMaps) {
  test::TempDir tmp;
  writeRingSequence(tmp.file("seq"), floorScene(true), 4);
  const std::string fine = tmp.file("fine.psdf"), coarse = tmp.file("coarse.psdf");
  ASSERT_EQ(test::runCli("fuse '" + tmp.file("seq") + "' --out '" + fine + "'").exit_code, 0);
  ASSERT_EQ(
      test::runCli("fuse '" + tmp.file("seq") + "' --voxel 0.01 --out '" + coarse + "'").exit_code,
      0);
  const auto r =
      test::runCli("detect '" + fine + "' '" + coarse + "' --out '" + tmp.file("out") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("planesdf: error: " + fine + " and " + coarse + ": "), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("voxel sizes"), std::string::npos) << r.out;
}

TEST(FuseCli, BadInputsAreOneLineErrors) {
  test::TempDir tmp;
  auto r = test::runCli("fuse '" + tmp.path() + "' --out '" + tmp.file("m.psdf") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("not a TUM"), std::string::npos) << r.out;
  test::writeBytes(tmp.file("junk.psdf"), "PSDFMAP");
  r = test::runCli("fuse '" + tmp.file("junk.psdf") + "' --out '" + tmp.file("m.psdf") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("junk.psdf"), std::string::npos) << r.out;
  r = test::runCli("fuse x.pcd --up 0,0 --out '" + tmp.file("m.psdf") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("--up"), std::string::npos) << r.out;
  EXPECT_FALSE(std::filesystem::exists(tmp.file("m.psdf")));
}

}  // namespace
