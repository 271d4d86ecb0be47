// Tests of PlaneSDF registration (paper §III-B): plane matching by normal, offset gap and extent
// overlap, and the relative plane-local transform.

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/error.hpp"
#include "planesdf/map.hpp"
#include "planesdf/plane.hpp"
#include "planesdf/registration.hpp"

namespace planesdf {
namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;
const Eigen::Vector3d kUp = Eigen::Vector3d::UnitZ();

/// A plane through `point` with `normal`, extent ±half in its own frame around the anchor.
Plane planeAt(const Eigen::Vector3d& normal, const Eigen::Vector3d& point, int id,
              Eigen::Vector2d half = Eigen::Vector2d(0.5, 0.4)) {
  const Eigen::Vector3d n = normal.normalized();
  Plane p = makePlane(n, -n.dot(point), point, kUp, id);
  p.extent = Eigen::AlignedBox2d(-half, half);
  return p;
}

Plane table(double z, int id) {
  return planeAt(kUp, Eigen::Vector3d(1.0, 0.5, z), id);
}
Plane wall(double x, int id) {
  return planeAt(Eigen::Vector3d::UnitX(), Eigen::Vector3d(x, 0.0, 1.2), id,
                 Eigen::Vector2d(1.5, 1.0));
}

TEST(Registration, MatchesTableToTableAndWallToWall) {
  const Config cfg;
  const std::vector<Plane> src{table(0.70, 0), wall(-2.0, 1)};
  // Target: floor, wall (1 cm off), table (5 mm higher), in another order.
  const std::vector<Plane> tgt{table(0.0, 0), wall(-1.99, 1), table(0.705, 2)};
  const std::vector<PlaneMatch> m = registerPlanes(src, tgt, cfg);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m[0].source_id, 0);
  EXPECT_EQ(m[0].target_id, 2);
  EXPECT_NEAR(m[0].offset_gap, -0.005, 1e-9);
  EXPECT_NEAR(m[0].cos_normal, 1.0, 1e-12);
  EXPECT_GT(m[0].overlap, 0.7);
  EXPECT_EQ(m[1].source_id, 1);
  EXPECT_EQ(m[1].target_id, 1);
  EXPECT_NEAR(std::abs(m[1].offset_gap), 0.01, 1e-9);
}

TEST(Registration, ASecondFitOfAWallIsADuplicateATableBesideATableIsNot) {
  const Config cfg;
  // A 3 x 2 m wall, and a 2 x 1.2 m patch of it fitted 1.5 cm off and 0.3 degrees tilted.
  Plane w = wall(-2.0, 0);
  w.support = 50000;
  const Eigen::Vector3d n(std::cos(0.3 * kDeg), std::sin(0.3 * kDeg), 0.0);
  Plane patch = planeAt(n, Eigen::Vector3d(-1.985, 0.4, 1.0), 1, Eigen::Vector2d(1.0, 0.6));
  patch.support = 20000;
  EXPECT_TRUE(duplicateOf(patch, w, cfg));
  EXPECT_FALSE(duplicateOf(w, patch, cfg));  // the larger one stays
  // 4 cm off (beyond two RANSAC inlier distances): a separate surface, such as a panel.
  Plane panel = planeAt(n, Eigen::Vector3d(-1.96, 0.4, 1.0), 1, Eigen::Vector2d(1.0, 0.6));
  panel.support = 20000;
  EXPECT_FALSE(duplicateOf(panel, w, cfg));
  // Mostly beyond the wall's extent: another wall segment, not a second fit of this one.
  Plane beyond = planeAt(n, Eigen::Vector3d(-1.985, 2.2, 1.0), 1, Eigen::Vector2d(1.0, 0.6));
  beyond.support = 20000;
  EXPECT_FALSE(duplicateOf(beyond, w, cfg));
  // A desk 3 cm above another, beside it: extents apart, two planes.
  Plane low = table(0.70, 2), high = planeAt(kUp, Eigen::Vector3d(2.2, 0.5, 0.73), 3);
  low.support = high.support = 10000;
  EXPECT_FALSE(duplicateOf(high, low, cfg));
  EXPECT_FALSE(duplicateOf(low, high, cfg));
  // Not the other orientation, and never itself.
  EXPECT_FALSE(duplicateOf(w, w, cfg));
  EXPECT_FALSE(duplicateOf(table(0.70, 4), w, cfg));
}

TEST(Registration, RejectsHigherAndTiltedPlanes) {
  const Config cfg;
  const std::vector<Plane> src{table(0.70, 0)};
  const Eigen::Vector3d tilted =
      Eigen::AngleAxisd(25.0 * kDeg, Eigen::Vector3d::UnitX()) * kUp;  // cos = 0.906 < 0.95
  std::vector<Plane> tgt{table(1.00, 0), planeAt(tilted, Eigen::Vector3d(1.0, 0.5, 0.7), 1)};
  EXPECT_TRUE(registerPlanes(src, tgt, cfg).empty());
  // A plane 15 cm higher is within delta_d = 0.2 and matches; the same table wins over it.
  tgt.push_back(table(0.85, 2));
  auto m = registerPlanes(src, tgt, cfg);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0].target_id, 2);
  tgt.push_back(table(0.71, 3));
  m = registerPlanes(src, tgt, cfg);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0].target_id, 3);
  // The opposite free side never matches.
  EXPECT_TRUE(registerPlanes(src, {planeAt(-kUp, Eigen::Vector3d(1.0, 0.5, 0.7), 0)}, cfg).empty());
}

TEST(Registration, RequiresOverlappingExtents) {
  const Config cfg;
  const std::vector<Plane> src{table(0.70, 0)};
  // Same height, 3 m away: a different table.
  const std::vector<Plane> far{planeAt(kUp, Eigen::Vector3d(4.0, 0.5, 0.70), 0)};
  EXPECT_TRUE(registerPlanes(src, far, cfg).empty());
  // 1.03 m away: extents (1 m wide) 3 cm apart, within the 5 cm margin.
  const std::vector<Plane> near{planeAt(kUp, Eigen::Vector3d(2.03, 0.5, 0.70), 0)};
  EXPECT_EQ(registerPlanes(src, near, cfg).size(), 1u);
  // The larger overlap wins among two coplanar candidates.
  const std::vector<Plane> two{planeAt(kUp, Eigen::Vector3d(1.6, 0.5, 0.70), 0),
                               planeAt(kUp, Eigen::Vector3d(1.1, 0.5, 0.71), 1)};
  const auto m = registerPlanes(src, two, cfg);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0].target_id, 1);
}

TEST(Registration, IdenticalPlanesMapToTheSameWorldPoint) {
  const Config cfg;
  const Plane s = table(0.70, 0);
  // Same plane, other frame: other origin and axes turned 30° about the normal.
  Plane t = planeAt(kUp, Eigen::Vector3d(1.2, 0.3, 0.70), 0);
  t.frame_axes = Eigen::AngleAxisd(30.0 * kDeg, kUp).toRotationMatrix() * t.frame_axes;
  const auto m = registerPlanes(std::vector<Plane>{s}, std::vector<Plane>{t}, cfg);
  ASSERT_EQ(m.size(), 1u);
  const Pose& T = m[0].T_target_source_local;
  for (const Eigen::Vector3d& uvh :
       {Eigen::Vector3d(0.3, -0.2, 0.0), Eigen::Vector3d(-0.4, 0.35, 0.0),
        Eigen::Vector3d(0.1, 0.1, 0.12)}) {
    const Eigen::Vector3d world = s.toWorld(uvh);
    EXPECT_LT((t.toWorld(T * uvh) - world).norm(), 1e-3);
    EXPECT_NEAR((T * uvh).z(), uvh.z(), 1e-12);
  }
}

TEST(Registration, CorrectsOffsetAlongTheNormal) {
  const Config cfg;
  const Plane s = table(0.70, 0);
  const Plane t = table(0.71, 0);  // 1 cm drift along the normal
  const auto m = registerPlanes(std::vector<Plane>{s}, std::vector<Plane>{t}, cfg);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_NEAR(m[0].offset_gap, -0.01, 1e-9);
  const Eigen::Vector3d uvh(0.25, -0.3, 0.0);
  const Eigen::Vector3d moved = t.toWorld(m[0].T_target_source_local * uvh);
  EXPECT_LT((moved - (s.toWorld(uvh) + Eigen::Vector3d(0, 0, 0.01))).norm(), 1e-6);
  // A 1° tilt: source plane points land on the target plane, heights are kept.
  const Eigen::Vector3d n1 = Eigen::AngleAxisd(1.0 * kDeg, Eigen::Vector3d::UnitY()) * kUp;
  const Plane t1 = planeAt(n1, Eigen::Vector3d(1.0, 0.5, 0.71), 0);
  const Pose C = planeCorrection(s, t1);
  EXPECT_NEAR(t1.signedDistance(C * s.toWorld(uvh)), 0.0, 1e-9);
  EXPECT_NEAR(t1.signedDistance(C * s.toWorld(Eigen::Vector3d(0.2, 0.1, 0.05))), 0.05, 1e-9);
  const Pose T1 = relativePlaneTransform(s, t1);
  EXPECT_NEAR((t1.toWorld(T1 * uvh) - C * s.toWorld(uvh)).norm(), 0.0, 1e-9);
}

TEST(Registration, MapsAndConfigChecks) {
  Config cfg;
  const Map empty(cfg);
  EXPECT_TRUE(registerPlanes(empty, empty, cfg).empty());
  cfg.delta_n = 1.5;
  EXPECT_THROW(registerPlanes(std::vector<Plane>{}, std::vector<Plane>{}, cfg), Error);
  cfg = Config{};
  cfg.delta_d = -0.1;
  EXPECT_THROW(registerPlanes(std::vector<Plane>{}, std::vector<Plane>{}, cfg), Error);
}

}  // namespace
}  // namespace planesdf
