// The OctoMap occupancy-differencing baseline: a box removed from a table seen by one analytic
// camera shows up as removed box points (its cells are free in the current tree), nothing is
// added where the reference saw nothing, and a scene against itself reports nothing.
#include "planesdf/octomap/octomap_baseline.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <tuple>
#include <vector>

#include "analytic_scene.hpp"
#include "planesdf/error.hpp"

namespace {
using planesdf::DepthFrame;
using planesdf::PointCloud;
using planesdf::Pose;
namespace oa = planesdf::octomap_adapter;
namespace t = planesdf::test;

PointCloud backProject(const DepthFrame& f, const Pose& T) {
  PointCloud c;
  const planesdf::Intrinsics& k = f.intrinsics;
  for (int v = 0; v < k.height; ++v)
    for (int u = 0; u < k.width; ++u) {
      const float z = f.at(u, v);
      if (!DepthFrame::isValidDepth(z)) continue;
      const Eigen::Vector3d p((u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z);
      c.points.push_back((T * p).cast<float>());
    }
  c.width = static_cast<std::uint32_t>(c.points.size());
  return c;
}

struct Session {
  DepthFrame frame;
  PointCloud points;
  oa::OccupancyMap tree;
};

Session observe(const t::AnalyticScene& scene, const Pose& T) {
  Session s{t::renderDepth(scene, planesdf::Intrinsics{}, T, 1.5), {}, oa::OccupancyMap{}};
  s.points = backProject(s.frame, T);
  EXPECT_GT(s.tree.insertFrame(s.frame, T), 0.0);
  return s;
}

bool onBox(const Eigen::Vector3f& p) {
  return std::abs(p.x()) <= 0.06f && std::abs(p.y()) <= 0.06f && p.z() >= -0.005f &&
         p.z() <= 0.125f;
}

TEST(OctomapBaseline, ARemovedBoxIsRemovedAndNothingIsAdded) {
  t::AnalyticScene with_box, without_box;
  without_box.primitives.push_back(t::Primitive::halfSpace(Eigen::Vector3d::UnitZ(), 0.0));
  with_box = without_box;
  with_box.primitives.push_back(t::Primitive::box({-0.05, -0.05, 0.0}, {0.05, 0.05, 0.12}));
  const Pose T = t::lookAt({0.0, -0.7, 0.6}, {0.0, 0.0, 0.0});
  const Session ref = observe(with_box, T), cur = observe(without_box, T);
  EXPECT_GT(ref.tree.leafCount(), 0u);
  EXPECT_GT(ref.tree.memoryBytes(), 0u);

  const planesdf::BaselineResult r =
      oa::octomapBaseline(ref.points, ref.tree, cur.points, cur.tree);
  ASSERT_GT(r.removed.size(), 0u);
  EXPECT_GE(r.removed_clusters, 1);
  std::size_t on_box = 0, box_removed_high = 0, box_high = 0;
  for (const Eigen::Vector3f& p : r.removed.points) on_box += onBox(p);
  EXPECT_GE(static_cast<double>(on_box), 0.95 * static_cast<double>(r.removed.size()));
  for (const Eigen::Vector3f& p : ref.points.points)
    if (onBox(p) && p.z() > 0.02f) ++box_high;
  // Recall on the box well above the table: its cells are free now.
  {
    std::vector<Eigen::Vector3f> removed = r.removed.points;
    auto key = [](const Eigen::Vector3f& p) { return std::make_tuple(p.x(), p.y(), p.z()); };
    std::sort(removed.begin(), removed.end(),
              [&](const auto& a, const auto& b) { return key(a) < key(b); });
    for (const Eigen::Vector3f& p : ref.points.points)
      if (onBox(p) && p.z() > 0.02f &&
          std::binary_search(removed.begin(), removed.end(), p,
                             [&](const auto& a, const auto& b) { return key(a) < key(b); }))
        ++box_removed_high;
  }
  ASSERT_GT(box_high, 1000u);
  EXPECT_GE(static_cast<double>(box_removed_high), 0.8 * static_cast<double>(box_high));
  // The table under and behind the box was never seen in the reference: unknown, not added.
  EXPECT_LE(static_cast<double>(r.added.size()), 0.05 * static_cast<double>(r.removed.size()));
}

TEST(OctomapBaseline, ASceneAgainstItselfReportsNothing) {
  t::AnalyticScene scene;
  scene.primitives.push_back(t::Primitive::halfSpace(Eigen::Vector3d::UnitZ(), 0.0));
  scene.primitives.push_back(t::Primitive::box({-0.05, -0.05, 0.0}, {0.05, 0.05, 0.12}));
  const Pose T = t::lookAt({0.0, -0.7, 0.6}, {0.0, 0.0, 0.0});
  const Session a = observe(scene, T);
  const planesdf::BaselineResult r = oa::octomapBaseline(a.points, a.tree, a.points, a.tree);
  EXPECT_EQ(r.removed.size(), 0u);
  EXPECT_EQ(r.added.size(), 0u);
}

TEST(OctomapBaseline, RejectsBadOptions) {
  oa::OccupancyOptions o;
  o.resolution = 0.0;
  EXPECT_THROW(oa::OccupancyMap{o}, planesdf::Error);
  o = {};
  o.pixel_stride = 0;
  EXPECT_THROW(oa::OccupancyMap{o}, planesdf::Error);
}

}  // namespace
