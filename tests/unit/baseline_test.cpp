// Tests for the point-distance differencing baseline (issue 5): an analytic scene (a box on a
// plane, removed in the current session), a scene against itself, clustering, downsampling and
// the detect-format outputs scored by evaluateChanges.

#include "planesdf/baseline.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <tuple>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/eval.hpp"
#include "planesdf/io/ply.hpp"
#include "test_support.hpp"

namespace {

using planesdf::BaselineParams;
using planesdf::BaselineResult;
using planesdf::PointCloud;

constexpr float kStep = 0.003f;  // sampling of the analytic surfaces (m)

/// The plane z = 0 over [-0.5, 0.5]^2 sampled every 3 mm.
std::vector<Eigen::Vector3f> planePoints() {
  std::vector<Eigen::Vector3f> p;
  for (float y = -0.5f; y <= 0.5f; y += kStep)
    for (float x = -0.5f; x <= 0.5f; x += kStep) p.emplace_back(x, y, 0.0f);
  return p;
}

/// The visible surface (top and four sides) of the box [-0.05, 0.05]^2 x [0, 0.12].
std::vector<Eigen::Vector3f> boxPoints() {
  std::vector<Eigen::Vector3f> p;
  const float h = 0.05f, top = 0.12f;
  for (float a = -h; a <= h; a += kStep) {
    for (float b = -h; b <= h; b += kStep) p.emplace_back(a, b, top);
    for (float z = 0.0f; z <= top; z += kStep) {
      p.emplace_back(a, -h, z);
      p.emplace_back(a, h, z);
      p.emplace_back(-h, a, z);
      p.emplace_back(h, a, z);
    }
  }
  return p;
}

PointCloud cloudOf(const std::vector<Eigen::Vector3f>& points) {
  PointCloud c;
  c.points = points;
  c.width = static_cast<std::uint32_t>(points.size());
  return c;
}

TEST(PointDistanceBaseline, ARemovedBoxIsExactlyItsPointsAwayFromThePlane) {
  const std::vector<Eigen::Vector3f> plane = planePoints(), box = boxPoints();
  std::vector<Eigen::Vector3f> scene = plane;
  scene.insert(scene.end(), box.begin(), box.end());
  const BaselineParams params;
  const BaselineResult r = planesdf::pointDistanceBaseline(cloudOf(scene), cloudOf(plane), params);

  EXPECT_EQ(r.added.size(), 0u);
  EXPECT_EQ(r.added_clusters, 0);
  EXPECT_EQ(r.removed_clusters, 1);
  // Every removed point is a box point (not a plane point) ...
  for (const Eigen::Vector3f& p : r.removed.points) {
    const bool on_box = std::abs(p.x()) <= 0.0501f && std::abs(p.y()) <= 0.0501f && p.z() > 0.0f;
    EXPECT_TRUE(on_box) << p.transpose();
  }
  // ... and every box point farther from the plane than the distance plus a cell diagonal
  // (decisions are taken on cell centroids) is removed; none nearer than the distance minus that.
  const double slack = params.voxel * std::sqrt(3.0);
  std::set<std::tuple<float, float, float>> removed;
  for (const Eigen::Vector3f& p : r.removed.points) removed.insert({p.x(), p.y(), p.z()});
  int must = 0;
  for (const Eigen::Vector3f& p : box) {
    const bool in = removed.count({p.x(), p.y(), p.z()}) > 0;
    if (p.z() > params.distance + slack) {
      ++must;
      EXPECT_TRUE(in) << p.transpose();
    }
    if (p.z() < params.distance - slack) {
      EXPECT_FALSE(in) << p.transpose();
    }
  }
  EXPECT_GT(must, 1000);
  const planesdf::ScalarField* ids = r.removed.field(planesdf::kChangeIdField);
  ASSERT_NE(ids, nullptr);
  for (double id : ids->values) EXPECT_EQ(id, 1.0);
}

TEST(PointDistanceBaseline, ASceneAgainstItselfReportsNothing) {
  std::vector<Eigen::Vector3f> scene = planePoints();
  const std::vector<Eigen::Vector3f> box = boxPoints();
  scene.insert(scene.end(), box.begin(), box.end());
  const BaselineResult r = planesdf::pointDistanceBaseline(cloudOf(scene), cloudOf(scene));
  EXPECT_EQ(r.removed.size(), 0u);
  EXPECT_EQ(r.added.size(), 0u);
}

TEST(PointDistanceBaseline, AnAddedBoxIsAddedAndScoresPerfectly) {
  const std::vector<Eigen::Vector3f> plane = planePoints(), box = boxPoints();
  std::vector<Eigen::Vector3f> scene = plane;
  scene.insert(scene.end(), box.begin(), box.end());
  const BaselineResult r = planesdf::pointDistanceBaseline(cloudOf(plane), cloudOf(scene));
  EXPECT_EQ(r.removed.size(), 0u);
  ASSERT_GT(r.added.size(), 0u);
  EXPECT_EQ(r.added_clusters, 1);

  // Written in the detect format and read back, it scores precision 1 against the box as GT.
  planesdf::test::TempDir tmp;
  planesdf::writeBaselineOutputs(tmp.path(), r);
  PointCloud gt = cloudOf(box);
  gt.addField(planesdf::kObjectIdField, planesdf::ScalarType::Int32, 7.0);
  const planesdf::EvalResult e = planesdf::evaluateChanges(
      planesdf::io::readPly(tmp.file("removed_points.ply")),
      planesdf::io::readPly(tmp.file("added_points.ply")), PointCloud{}, gt, 0.007);
  EXPECT_DOUBLE_EQ(e.added.precision, 1.0);
  EXPECT_GT(e.added.recall, 0.7);
  EXPECT_EQ(e.pooled.missed, 0);
  EXPECT_EQ(e.pooled.wrong, 0);
  EXPECT_DOUBLE_EQ(e.removed.f1, 1.0);  // no GT, no prediction
}

TEST(PointDistanceBaseline, EuclideanClustersSplitsAndDropsSmallClusters) {
  std::vector<Eigen::Vector3f> p;
  for (int i = 0; i < 20; ++i) p.emplace_back(0.01f * i, 0.0f, 0.0f);         // one chain
  for (int i = 0; i < 20; ++i) p.emplace_back(1.0f + 0.01f * i, 0.0f, 0.0f);  // another
  for (int i = 0; i < 3; ++i) p.emplace_back(5.0f + 0.01f * i, 0.0f, 0.0f);   // too small
  p.emplace_back(std::nanf(""), 0.0f, 0.0f);                                  // invalid
  const std::vector<int> label = planesdf::euclideanClusters(p, 0.015, 5);
  ASSERT_EQ(label.size(), p.size());
  for (int i = 0; i < 20; ++i) EXPECT_EQ(label[i], 0);
  for (int i = 20; i < 40; ++i) EXPECT_EQ(label[i], 1);
  for (int i = 40; i < 44; ++i) EXPECT_EQ(label[i], -1);
}

TEST(PointDistanceBaseline, VoxelDownsampleKeepsOneCentroidPerCell) {
  const std::vector<Eigen::Vector3f> p{{0.001f, 0.001f, 0.001f},
                                       {0.003f, 0.003f, 0.003f},
                                       {-0.001f, 0.0f, 0.0f},
                                       {std::nanf(""), 0.0f, 0.0f}};
  const planesdf::DownsampledCloud d = planesdf::voxelDownsample(p, 0.007);
  ASSERT_EQ(d.centroids.size(), 2u);
  std::size_t members = 0;
  for (const auto& m : d.members) members += m.size();
  EXPECT_EQ(members, 3u);
  EXPECT_THROW(planesdf::voxelDownsample(p, 0.0), planesdf::Error);
  BaselineParams bad;
  bad.distance = -1.0;
  EXPECT_THROW(planesdf::pointDistanceBaseline(cloudOf(p), cloudOf(p), bad), planesdf::Error);
}

}  // namespace
