// The OctoMap adapter's conversions: invalid points dropped, transforms applied, occupancy after
// inserting a converted cloud.
#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <cmath>
#include <limits>

#include "planesdf/octomap/octomap_conversion.hpp"

namespace {
using planesdf::PointCloud;
using planesdf::Pose;
namespace oa = planesdf::octomap_adapter;

PointCloud wallCloud() {
  // A 0.5 m x 0.5 m wall at x = 1 sampled every 1 cm, plus NaN points that must be dropped.
  PointCloud c;
  for (int i = 0; i < 50; ++i)
    for (int j = 0; j < 50; ++j)
      c.points.emplace_back(1.0f, -0.25f + 0.01f * i, -0.25f + 0.01f * j);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  c.points.emplace_back(nan, 0.f, 0.f);
  c.points.emplace_back(0.f, nan, 1.f);
  c.width = static_cast<std::uint32_t>(c.points.size());
  return c;
}

TEST(OctomapConversion, DropsInvalidPointsAndTransforms) {
  const PointCloud c = wallCloud();
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(0.0, 0.0, 2.0);
  const octomap::Pointcloud oc = oa::toOctomap(c, T);
  ASSERT_EQ(oc.size(), 2500u);
  EXPECT_FLOAT_EQ(oc[0].x(), 1.0f);
  EXPECT_FLOAT_EQ(oc[0].z(), -0.25f + 2.0f);
}

TEST(OctomapConversion, PoseMatchesEigen) {
  Pose pose = Pose::Identity();
  pose.linear() = Eigen::AngleAxisd(0.8, Eigen::Vector3d(0, 1, 1).normalized()).toRotationMatrix();
  pose.translation() = Eigen::Vector3d(1, 2, 3);
  const octomath::Pose6D p = oa::toOctomap(pose);
  const octomath::Vector3 x = p.transform(octomath::Vector3(0.5f, -0.5f, 0.25f));
  const Eigen::Vector3d e = pose * Eigen::Vector3d(0.5, -0.5, 0.25);
  EXPECT_NEAR(x.x(), e.x(), 1e-5);
  EXPECT_NEAR(x.y(), e.y(), 1e-5);
  EXPECT_NEAR(x.z(), e.z(), 1e-5);
}

TEST(OctomapConversion, InsertedWallIsOccupiedAndRayIsFree) {
  const double res = 0.02;
  octomap::OcTree tree(res);
  tree.insertPointCloud(oa::toOctomap(wallCloud()), octomap::point3d(0, 0, 0));
  const octomap::OcTreeNode* wall = tree.search(1.0, 0.0, 0.0);
  ASSERT_NE(wall, nullptr);
  EXPECT_TRUE(tree.isNodeOccupied(wall));
  const octomap::OcTreeNode* free = tree.search(0.5, 0.0, 0.0);
  ASSERT_NE(free, nullptr);
  EXPECT_FALSE(tree.isNodeOccupied(free));
  EXPECT_EQ(tree.search(0.5, 2.0, 0.0), nullptr);  // never observed
}

}  // namespace
