// The MRPT adapter's 3D range scan conversion: MRPT sensor axes (x forward, y left, z up) to the
// OpenCV optical frame, checked at a known pixel against MRPT's own unprojection; and a rawlog
// written here with MRPT's archive, read back through readRawlog.
#include <gtest/gtest.h>
#include <mrpt/io/CFileGZOutputStream.h>
#include <mrpt/maps/CSimplePointsMap.h>
#include <mrpt/obs/CObservation3DRangeScan.h>
#include <mrpt/obs/CObservationRobotPose.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/poses/CPose3D.h>
#include <mrpt/serialization/CArchive.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>

#include <nlohmann/json.hpp>

#include "analytic_scene.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/map.hpp"
#include "planesdf/mrpt/pose_conversion.hpp"
#include "planesdf/mrpt/range_scan.hpp"
#include "test_support.hpp"

namespace {
using planesdf::DepthFrame;
using planesdf::Pose;
namespace ma = planesdf::mrpt_adapter;
namespace fs = std::filesystem;
using mrpt::obs::CObservation3DRangeScan;

constexpr double kDeg = M_PI / 180.0;

/// A 64x48 scan (fx = fy = 50, cx = 31.5, cy = 23.5) with one return: `raw` at pixel (u, v).
CObservation3DRangeScan onePixelScan(int u, int v, std::uint16_t raw, bool range_is_depth) {
  CObservation3DRangeScan s;
  s.hasRangeImage = true;
  s.range_is_depth = range_is_depth;
  s.rangeUnits = 0.001f;
  s.rangeImage_setSize(48, 64);
  s.rangeImage.fill(0);
  s.rangeImage(v, u) = raw;
  s.cameraParams.ncols = 64;
  s.cameraParams.nrows = 48;
  s.cameraParams.setIntrinsicParamsFromValues(50.0, 50.0, 31.5, 23.5);
  return s;
}

/// planesdf's back-projection of pixel (u, v) of `f`, placed by `camera_to_world`.
Eigen::Vector3d backProject(const DepthFrame& f, int u, int v, const Pose& camera_to_world) {
  const double d = f.at(u, v);
  const auto& k = f.intrinsics;
  return camera_to_world * Eigen::Vector3d((u - k.cx) * d / k.fx, (v - k.cy) * d / k.fy, d);
}

/// MRPT's own unprojection of the scan's single return, in the world.
Eigen::Vector3d mrptWorldPoint(CObservation3DRangeScan& s, const mrpt::poses::CPose3D& robot) {
  mrpt::maps::CSimplePointsMap pts;
  mrpt::obs::T3DPointsProjectionParams pp;
  pp.takeIntoAccountSensorPoseOnRobot = true;
  pp.robotPoseInTheWorld = robot;
  pp.USE_SSE2 = false;
  s.unprojectInto(pts, pp);
  EXPECT_EQ(pts.size(), 1u);
  float x = 0, y = 0, z = 0;
  if (pts.size() == 1) pts.getPoint(0, x, y, z);
  return {x, y, z};
}

TEST(MrptRangeScan, AxesAtTheOriginAreForwardLeftUp) {
  // Sensor and robot at the origin: the principal point at 2 m is 2 m forward (+x); a pixel
  // right of it is to the right (-y), a pixel above it is up (+z).
  for (const auto& [u, v, expected] : {std::tuple{31, 23, Eigen::Vector3d(2.0, 0.02, 0.02)},
                                       std::tuple{56, 23, Eigen::Vector3d(2.0, -0.98, 0.02)},
                                       std::tuple{31, 3, Eigen::Vector3d(2.0, 0.02, 0.82)}}) {
    const CObservation3DRangeScan s = onePixelScan(u, v, 2000, true);
    const DepthFrame f = ma::toDepthFrame(s);
    EXPECT_FLOAT_EQ(f.at(u, v), 2.0f);
    const Eigen::Vector3d p = backProject(f, u, v, ma::cameraPose(s));
    EXPECT_LT((p - expected).norm(), 1e-9) << "pixel " << u << "," << v << ": " << p.transpose();
  }
}

TEST(MrptRangeScan, KnownPixelLandsWhereMrptPutsIt) {
  const mrpt::poses::CPose3D robot(1.0, -2.0, 0.3, 40 * kDeg, 5 * kDeg, -3 * kDeg);
  const mrpt::poses::CPose3D sensor(0.2, 0.05, 1.1, -10 * kDeg, 20 * kDeg, 0.0);
  CObservation3DRangeScan s = onePixelScan(40, 10, 2000, true);
  s.sensorPose = sensor;
  // By hand, MRPT's formula: local (x, (cx - u) x / fx, (cy - v) x / fy).
  const double x = 2.0, y = (31.5 - 40) * x / 50.0, z = (23.5 - 10) * x / 50.0;
  mrpt::math::TPoint3D world;
  (robot + sensor).composePoint(mrpt::math::TPoint3D(x, y, z), world);
  const Eigen::Vector3d by_hand(world.x, world.y, world.z);

  const DepthFrame f = ma::toDepthFrame(s);
  const Eigen::Vector3d ours = backProject(f, 40, 10, ma::cameraPose(s, ma::toPose(robot)));
  EXPECT_LT((ours - by_hand).norm(), 1e-9) << ours.transpose() << " vs " << by_hand.transpose();
  EXPECT_LT((ours - mrptWorldPoint(s, robot)).norm(), 1e-4);
}

TEST(MrptRangeScan, RangesAreConvertedToDepth) {
  // range_is_depth = false: 2.5 m along the ray of pixel (5, 40).
  const mrpt::poses::CPose3D robot(0.5, 0.5, 0.0, 90 * kDeg, 0.0, 0.0);
  CObservation3DRangeScan s = onePixelScan(5, 40, 2500, false);
  const DepthFrame f = ma::toDepthFrame(s);
  const Eigen::Vector3d ours = backProject(f, 5, 40, ma::cameraPose(s, ma::toPose(robot)));
  EXPECT_NEAR((ours - Eigen::Vector3d(0.5, 0.5, 0.0)).norm(), 2.5, 1e-6);
  EXPECT_LT((ours - mrptWorldPoint(s, robot)).norm(), 1e-4);
}

TEST(MrptRangeScan, ToRangeScanInvertsTheConversion) {
  DepthFrame f;
  f.intrinsics = {60.0, 61.0, 20.0, 15.0, 40, 30};
  f.depth.assign(40 * 30, 0.0f);
  for (int i = 0; i < 40 * 30; i += 7) f.depth[i] = 0.5f + 0.001f * (i % 900);
  f.timestamp = 1700000000.25;
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.3, -1.0, 1.2);
  CObservation3DRangeScan s;
  ma::toRangeScan(f, T, s);
  const DepthFrame back = ma::toDepthFrame(s);
  ASSERT_EQ(back.depth.size(), f.depth.size());
  for (std::size_t i = 0; i < f.depth.size(); ++i) EXPECT_NEAR(back.depth[i], f.depth[i], 5e-4);
  EXPECT_NEAR(back.timestamp, f.timestamp, 1e-5);
  EXPECT_LT((ma::cameraPose(s).matrix() - T.matrix()).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(MrptRangeScan, NoRangeImageIsAnError) {
  CObservation3DRangeScan s;
  EXPECT_THROW(ma::toDepthFrame(s, "scan 3"), planesdf::Error);
}

// ---- rawlog ---------------------------------------------------------------------------------

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() /
           ("planesdf_mrpt_rawlog_" +
            std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
};

/// Frame i: 32x24, a slanted depth ramp with holes, and a pose on a circle.
std::pair<DepthFrame, Pose> syntheticFrame(int i) {
  DepthFrame f;
  f.intrinsics = {30.0, 30.0, 15.5, 11.5, 32, 24};
  f.timestamp = 10.0 + i / 30.0;
  for (int v = 0; v < 24; ++v)
    for (int u = 0; u < 32; ++u)
      f.depth.push_back((u + v + i) % 11 == 0 ? 0.0f : 0.8f + 0.01f * u + 0.02f * v + 0.1f * i);
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(0.4 * i, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
               Eigen::AngleAxisd(-2.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(std::cos(0.4 * i), std::sin(0.4 * i), 1.3);
  return {f, T};
}

TEST(MrptRawlog, RoundTripOfObservationsAndSensoryFrames) {
  TempDir dir;
  const std::string path = (dir.path / "scans.rawlog").string();
  // Scans 0 and 1 as bare observations (full pose in sensorPose), then a robot pose and scan 2
  // in a CSensoryFrame with its sensor pose relative to the robot.
  mrpt::poses::CPose3D robot(2.0, 1.0, 0.0, 30 * kDeg, 0.0, 0.0);
  std::vector<Pose> expected_poses;
  {
    mrpt::io::CFileGZOutputStream out(path);
    auto arch = mrpt::serialization::archiveFrom(out);
    for (int i = 0; i < 2; ++i) {
      const auto [f, T] = syntheticFrame(i);
      auto s = CObservation3DRangeScan::Create();
      ma::toRangeScan(f, T, *s);
      s->sensorLabel = "KINECT";
      arch << *s;
      expected_poses.push_back(T);
    }
    auto rp = mrpt::obs::CObservationRobotPose::Create();
    rp->pose.mean = robot;
    arch << *rp;
    const auto [f, T] = syntheticFrame(2);
    auto s = CObservation3DRangeScan::Create();
    ma::toRangeScan(f, T, *s);  // T is now relative to the robot
    s->sensorLabel = "KINECT";
    mrpt::obs::CSensoryFrame sf;
    sf.insert(s);
    arch << sf;
    expected_poses.push_back(ma::toPose(robot) * T);
  }
  const std::vector<ma::RawlogScan> scans = ma::loadRawlog(path);
  ASSERT_EQ(scans.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    const DepthFrame f = syntheticFrame(i).first;
    const DepthFrame& g = scans[i].frame;
    EXPECT_EQ(g.intrinsics.width, 32);
    EXPECT_DOUBLE_EQ(g.intrinsics.fx, 30.0);
    ASSERT_EQ(g.depth.size(), f.depth.size());
    double worst = 0.0;
    for (std::size_t k = 0; k < f.depth.size(); ++k)
      worst = std::max(worst, std::abs(static_cast<double>(g.depth[k] - f.depth[k])));
    EXPECT_LE(worst, 0.0005 + 1e-6) << "scan " << i;  // rangeUnits 1 mm, rounded
    EXPECT_LT((scans[i].pose.matrix() - expected_poses[i].matrix()).cwiseAbs().maxCoeff(), 1e-9)
        << "scan " << i;
    EXPECT_NEAR(g.timestamp, f.timestamp, 1e-5);
    EXPECT_EQ(scans[i].sensor_label, "KINECT");
  }
}

TEST(MrptRawlog, ErrorsNameTheFile) {
  TempDir dir;
  const std::string missing = (dir.path / "missing.rawlog").string();
  try {
    ma::loadRawlog(missing);
    FAIL() << "no error";
  } catch (const planesdf::Error& e) {
    EXPECT_EQ(e.path(), missing);
  }
  const std::string garbage = (dir.path / "garbage.rawlog").string();
  std::ofstream(garbage) << "this is not an MRPT archive, just some text to read\n";
  try {
    ma::loadRawlog(garbage);
    FAIL() << "no error";
  } catch (const planesdf::Error& e) {
    EXPECT_EQ(e.path(), garbage) << e.what();
  }
}

// ---- the CLI reads rawlogs -------------------------------------------------------------------

/// An analytic tabletop session (8 views on a ring) written as a rawlog of 3D range scans.
void writeSessionRawlog(const std::string& path, const planesdf::test::AnalyticScene& scene) {
  mrpt::io::CFileGZOutputStream out(path);
  auto arch = mrpt::serialization::archiveFrom(out);
  for (const Pose& T : planesdf::test::ringPoses({0, 0, 0.75}, 0.9, 0.55, 8)) {
    CObservation3DRangeScan s;
    ma::toRangeScan(planesdf::test::renderDepth(scene, planesdf::Intrinsics{}, T), T, s);
    arch << s;
  }
}

TEST(MrptRawlog, CliDetectsChangesBetweenTwoRawlogs) {
  // Runs in the Release pass; builds without the CLI (the sanitizer pass) cannot run it.
  if (planesdf::test::cliPath().empty()) GTEST_SKIP() << "the planesdf CLI is not built";
  using planesdf::test::Primitive;
  planesdf::test::TempDir dir;
  const std::string before = dir.path() + "/before.rawlog", after = dir.path() + "/after.rawlog";
  // The box is removed, a sphere is added, the cylinder moved 20 cm.
  writeSessionRawlog(
      before, planesdf::test::tableWith({Primitive::box({0.05, 0.02, 0.75}, {0.15, 0.08, 0.83}),
                                         Primitive::cylinder({-0.15, -0.10, 0.75}, 0.04, 0.12)}));
  writeSessionRawlog(
      after, planesdf::test::tableWith({Primitive::sphere({-0.12, 0.15, 0.80}, 0.05),
                                        Primitive::cylinder({0.05, -0.10, 0.75}, 0.04, 0.12)}));
  const auto r =
      planesdf::test::runCli("detect " + before + " " + after + " --out " + dir.path() + "/out");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const auto events =
      nlohmann::json::parse(planesdf::io::readFile(dir.path() + "/out/changes.json"));
  std::multiset<std::string> types;
  for (const auto& e : events) types.insert(e.at("type").get<std::string>());
  EXPECT_EQ(types, (std::multiset<std::string>{"added", "moved", "removed"})) << events.dump(1);

  const auto fused = planesdf::test::runCli("fuse " + before + " --out " + dir.path() + "/b.psdf");
  ASSERT_EQ(fused.exit_code, 0) << fused.out;
  EXPECT_EQ(planesdf::Map::load(dir.path() + "/b.psdf").frames(), 8u);

  // info takes what fuse and detect take, whatever the extension's case.
  std::filesystem::copy_file(dir.path() + "/b.psdf", dir.path() + "/B.PSDF");
  const auto map_info = planesdf::test::runCli("info " + dir.path() + "/B.PSDF");
  EXPECT_EQ(map_info.exit_code, 0) << map_info.out;
  EXPECT_NE(map_info.out.find("plane 0"), std::string::npos) << map_info.out;
  const auto log_info = planesdf::test::runCli("info " + before);
  EXPECT_EQ(log_info.exit_code, 0) << log_info.out;
  EXPECT_NE(log_info.out.find("3D range scans: 8"), std::string::npos) << log_info.out;
  EXPECT_NE(log_info.out.find("640x480"), std::string::npos) << log_info.out;

  const std::string missing = dir.path() + "/missing.rawlog";
  const auto bad = planesdf::test::runCli("fuse " + missing + " --out " + dir.path() + "/m.psdf");
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.out.find(missing), std::string::npos) << bad.out;
}

}  // namespace
