// End-to-end plane detection on the real mOSD Kinect scenes (camera frame, y down, the table is
// the dominant plane; up is not given and is estimated).

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include "planesdf/io/pcd.hpp"
#include "planesdf/plane.hpp"
#include "test_support.hpp"

namespace planesdf {
namespace {

using test::kPi;

std::vector<std::string> sceneFiles() {
  std::vector<std::string> files;
  const std::filesystem::path dir = test::mosdDir() + "/scenes";
  if (!std::filesystem::is_directory(dir)) return files;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (e.path().extension() == ".pcd") files.push_back(e.path().string());
  }
  std::sort(files.begin(), files.end());
  return files;
}

double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180.0 / kPi;
}

// Fraction of the valid points within `dist` of the plane.
double fractionNear(const PointCloud& cloud, const Plane& plane, double dist) {
  std::size_t near = 0, valid = 0;
  for (const Eigen::Vector3f& p : cloud.points) {
    if (!p.allFinite()) continue;
    ++valid;
    if (std::abs(plane.signedDistance(p.cast<double>())) <= dist) ++near;
  }
  return valid ? static_cast<double>(near) / static_cast<double>(valid) : 0.0;
}

const Plane* dominantHorizontal(const std::vector<Plane>& planes) {
  const Plane* best = nullptr;
  for (const Plane& p : planes) {
    if (p.orientation == Plane::Orientation::Horizontal && (!best || p.support > best->support)) {
      best = &p;
    }
  }
  return best;
}

TEST(MosdPlanes, WholeCloudDetectionFindsTheTableWithUpAuto) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  const std::vector<std::string> files = sceneFiles();
  ASSERT_GE(files.size(), 20u);
  Config cfg;
  cfg.up_auto = true;
  double worst_ms = 0.0;
  for (const std::string& path : files) {
    SCOPED_TRACE(path);
    const PointCloud cloud = io::readPcd(path);
    const auto t0 = std::chrono::steady_clock::now();
    const PlaneSegmentation seg = segmentPlanes(cloud, cfg);
    worst_ms = std::max(
        worst_ms,
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    const Plane* table = dominantHorizontal(seg.planes);
    ASSERT_NE(table, nullptr);
    // The table: > 30 % of the valid points within 1.5 cm, normal roughly camera -y (the camera
    // looks down at it), pointing toward the camera, and the estimated up is its normal.
    EXPECT_GT(fractionNear(cloud, *table, 0.015), 0.30);
    EXPECT_GT(table->normal.dot(Eigen::Vector3d(0, -1, 0)), 0.7) << table->normal.transpose();
    EXPECT_GT(table->signedDistance(Eigen::Vector3d::Zero()), 0.2);
    EXPECT_LT(angleDeg(seg.up, table->normal), 2.0);
    EXPECT_EQ(table->id, 0) << "the table is the largest plane";
    // Every plane is horizontal or vertical w.r.t. the estimated up and faces the camera.
    for (const Plane& p : seg.planes) {
      EXPECT_TRUE(classifyOrientation(p.normal, seg.up, cfg.orientation_tolerance_deg));
      EXPECT_GT(p.signedDistance(Eigen::Vector3d::Zero()), 0.0);
      EXPECT_GE(p.support, static_cast<std::size_t>(cfg.min_plane_support));
    }
  }
  std::cout << "[timing] segmentPlanes on mOSD (640x480), slowest scene: " << worst_ms << " ms\n";
}

TEST(MosdPlanes, RansacAndTrackerAgreeWithWholeCloudDetection) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  // Scenes of one group share the camera pose: the tracker must keep one table id across them.
  const std::vector<std::string> group = {"learn43", "learn44", "test31", "test32", "test33"};
  Config cfg;
  cfg.up_auto = true;
  PlaneTracker tracker(cfg);
  int table_id = -1;
  double worst_ms = 0.0;
  for (const std::string& name : group) {
    SCOPED_TRACE(name);
    const PointCloud cloud = io::readPcd(test::mosdDir() + "/scenes/" + name + ".pcd");
    const std::vector<Plane> planes = detectPlanes(cloud, cfg);
    const Plane* table = dominantHorizontal(planes);
    ASSERT_NE(table, nullptr);
    const auto t0 = std::chrono::steady_clock::now();
    const std::vector<PlaneObservation> obs =
        detectPlanesRansac(cloud.points, Eigen::Vector3d::Zero(), cfg);
    worst_ms = std::max(
        worst_ms,
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    ASSERT_FALSE(obs.empty());
    EXPECT_LT(angleDeg(obs.front().plane.normal, table->normal), 2.0);
    EXPECT_NEAR(obs.front().plane.offset, table->offset, 0.01);
    const std::vector<int> ids = tracker.integrate(cloud.points, Eigen::Vector3d::Zero());
    ASSERT_FALSE(ids.empty());
    if (table_id < 0) table_id = ids.front();
    EXPECT_EQ(ids.front(), table_id);
  }
  const Plane* table = tracker.plane(table_id);
  ASSERT_NE(table, nullptr);
  EXPECT_GT(table->normal.dot(Eigen::Vector3d(0, -1, 0)), 0.7);
  EXPECT_GE(tracker.refinementCount(table_id), 2);
  std::cout << "[timing] detectPlanesRansac on mOSD (640x480), slowest frame: " << worst_ms
            << " ms\n";
}

}  // namespace
}  // namespace planesdf
