// Whole-cloud detection, up estimation, per-frame RANSAC and the plane tracker on synthetic
// scenes: sampled surfaces (unorganised) and ray-cast depth images (organised).

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <ctime>
#include <iostream>
#include <limits>
#include <random>

#include "analytic_scene.hpp"
#include "planesdf/error.hpp"
#include "planesdf/plane.hpp"
#include "test_support.hpp"

namespace planesdf {
namespace {

using test::kPi;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180.0 / kPi;
}

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// --- sampled surfaces --------------------------------------------------------------------------

// Jittered grid on the rectangle origin + [0,a]·ea + [0,b]·eb with spacing h, Gaussian noise
// sigma along the rectangle normal.
void sampleRect(std::vector<Eigen::Vector3f>& out, const Eigen::Vector3d& origin,
                const Eigen::Vector3d& ea, double a, const Eigen::Vector3d& eb, double b, double h,
                double sigma, std::mt19937& rng) {
  const Eigen::Vector3d n = ea.cross(eb).normalized();
  std::uniform_real_distribution<double> jitter(-0.3 * h, 0.3 * h);
  std::normal_distribution<double> noise(0.0, sigma);
  for (double s = 0.5 * h; s < a; s += h) {
    for (double t = 0.5 * h; t < b; t += h) {
      const Eigen::Vector3d p =
          origin + (s + jitter(rng)) * ea + (t + jitter(rng)) * eb + noise(rng) * n;
      out.push_back(p.cast<float>());
    }
  }
}

void sampleBoxSides(std::vector<Eigen::Vector3f>& out, const Eigen::Vector3d& lo,
                    const Eigen::Vector3d& hi, double h, double sigma, std::mt19937& rng,
                    bool top = true) {
  const Eigen::Vector3d s = hi - lo;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY(),
                        ez = Eigen::Vector3d::UnitZ();
  sampleRect(out, lo, ex, s.x(), ez, s.z(), h, sigma, rng);
  sampleRect(out, {lo.x(), hi.y(), lo.z()}, ex, s.x(), ez, s.z(), h, sigma, rng);
  sampleRect(out, lo, ey, s.y(), ez, s.z(), h, sigma, rng);
  sampleRect(out, {hi.x(), lo.y(), lo.z()}, ey, s.y(), ez, s.z(), h, sigma, rng);
  if (top) sampleRect(out, {lo.x(), lo.y(), hi.z()}, ex, s.x(), ey, s.y(), h, sigma, rng);
}

void sampleCylinder(std::vector<Eigen::Vector3f>& out, const Eigen::Vector2d& c, double r,
                    double height, double h, double sigma, std::mt19937& rng) {
  std::normal_distribution<double> noise(0.0, sigma);
  const int around = static_cast<int>(2 * kPi * r / h);
  for (double z = 0.5 * h; z < height; z += h) {
    for (int k = 0; k < around; ++k) {
      const double a = 2 * kPi * k / around;
      const double rr = r + noise(rng);
      out.emplace_back(static_cast<float>(c.x() + rr * std::cos(a)),
                       static_cast<float>(c.y() + rr * std::sin(a)), static_cast<float>(z));
    }
  }
}

// Floor z = 0, wall x = 2, a 1 m x 1 m table top at z = 0.75 on four round legs with a 3 cm
// apron, a 20 x 20 x 15 cm box on the table; 5 mm spacing, 2 mm noise. No sensor.
PointCloud syntheticRoom() {
  std::mt19937 rng(42);
  const double h = 0.005, sigma = 0.002;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY(),
                        ez = Eigen::Vector3d::UnitZ();
  PointCloud cloud;
  auto& p = cloud.points;
  sampleRect(p, {-0.5, -1.0, 0.0}, ex, 2.5, ey, 2.0, h, sigma, rng);             // floor
  sampleRect(p, {2.0, -1.0, 0.0}, ey, 2.0, ez, 1.5, h, sigma, rng);              // wall
  sampleRect(p, {0.0, -0.5, 0.75}, ex, 1.0, ey, 1.0, h, sigma, rng);             // table top
  sampleBoxSides(p, {0.0, -0.5, 0.72}, {1.0, 0.5, 0.75}, h, sigma, rng, false);  // apron
  for (double x : {0.05, 0.95}) {
    for (double y : {-0.45, 0.45}) sampleCylinder(p, {x, y}, 0.025, 0.72, h, sigma, rng);
  }
  sampleBoxSides(p, {0.4, -0.1, 0.75}, {0.6, 0.1, 0.9}, h, sigma, rng);  // box
  cloud.width = static_cast<std::uint32_t>(p.size());
  return cloud;
}

const Plane* findPlane(const std::vector<Plane>& planes, const Eigen::Vector3d& n, double d) {
  for (const Plane& p : planes) {
    if (angleDeg(p.normal, n) < 5.0 && std::abs(p.offset - d) < 0.05) return &p;
  }
  return nullptr;
}

TEST(PlaneDetect, SyntheticRoomYieldsExactlyFloorTableAndWall) {
  const PointCloud cloud = syntheticRoom();
  Config cfg;
  const auto t0 = std::chrono::steady_clock::now();
  const PlaneSegmentation seg = segmentPlanes(cloud, cfg);
  std::cout << "[timing] segmentPlanes unorganised " << cloud.size() << " points: " << msSince(t0)
            << " ms\n";
  ASSERT_EQ(seg.planes.size(), 3u);
  struct Expect {
    const char* name;
    Eigen::Vector3d n;
    double d;
    Plane::Orientation o;
    std::size_t min_support;
  };
  // Free side: horizontal planes along +up, the wall toward the scene centroid (-x).
  const Expect expected[] = {
      {"floor", {0, 0, 1}, 0.0, Plane::Orientation::Horizontal, 150000},
      {"table", {0, 0, 1}, -0.75, Plane::Orientation::Horizontal, 35000},
      {"wall", {-1, 0, 0}, 2.0, Plane::Orientation::Vertical, 100000},
  };
  for (const Expect& e : expected) {
    const Plane* p = findPlane(seg.planes, e.n, e.d);
    ASSERT_NE(p, nullptr) << e.name;
    EXPECT_LT(angleDeg(p->normal, e.n), 1.0) << e.name;
    EXPECT_LT(std::abs(p->offset - e.d), 0.005) << e.name;
    EXPECT_EQ(p->orientation, e.o) << e.name;
    EXPECT_GE(p->support, e.min_support) << e.name;
    EXPECT_EQ(seg.planes[static_cast<std::size_t>(p->id)].id, p->id);
  }
  // The table's extent is the 1 m x 1 m top (within a couple of centimetres).
  const Plane* table = findPlane(seg.planes, {0, 0, 1}, -0.75);
  const Eigen::Vector2d size = table->extent.sizes();
  EXPECT_NEAR(size.x(), 1.0, 0.03);
  EXPECT_NEAR(size.y(), 1.0, 0.03);
  // Labels agree with support and ids.
  std::vector<std::size_t> counts(seg.planes.size(), 0);
  for (int l : seg.labels) {
    if (l >= 0) ++counts[static_cast<std::size_t>(l)];
  }
  for (const Plane& p : seg.planes) EXPECT_EQ(counts[static_cast<std::size_t>(p.id)], p.support);
  // Sorted by support, floor first.
  EXPECT_GE(seg.planes[0].support, seg.planes[1].support);
  EXPECT_GE(seg.planes[1].support, seg.planes[2].support);
}

TEST(PlaneDetect, TiltedPlaneIsRejectedByTheOrientationFilter) {
  std::mt19937 rng(7);
  PointCloud cloud;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY();
  sampleRect(cloud.points, {-1, -1, 0}, ex, 2.0, ey, 2.0, 0.01, 0.002, rng);  // floor, 40k
  // A 1.5 m x 1.5 m ramp tilted 30 deg about x, 0.5 m above the floor: 22k points.
  const Eigen::Vector3d up_slope(0, std::cos(kPi / 6), std::sin(kPi / 6));
  sampleRect(cloud.points, {-0.75, -0.5, 0.5}, ex, 1.5, up_slope, 1.5, 0.01, 0.002, rng);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  Config cfg;
  const std::vector<Plane> planes = detectPlanes(cloud, cfg);
  ASSERT_EQ(planes.size(), 1u);
  EXPECT_LT(angleDeg(planes[0].normal, {0, 0, 1}), 1.0);
  EXPECT_NEAR(planes[0].offset, 0.0, 0.005);
  // With a 35 deg tolerance the ramp is kept as horizontal.
  cfg.orientation_tolerance_deg = 35;
  const std::vector<Plane> lenient = detectPlanes(cloud, cfg);
  ASSERT_EQ(lenient.size(), 2u);
  EXPECT_NEAR(angleDeg(lenient[1].normal, {0, 0, 1}), 30.0, 1.0);
}

TEST(PlaneDetect, ParallelPlanesSplitByOffsetAndCoplanarPartsByConnectivity) {
  // Floor z = 0 (2 m x 2 m) and two 0.5 m x 1 m platforms at z = 0.10, 0.8 m apart: 1 cm
  // spacing, 2 mm noise. The platforms are 10 cm (> offset_split) above the floor, so the one
  // normal cluster splits by offset; the two platforms are coplanar but not connected.
  std::mt19937 rng(9);
  PointCloud cloud;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY();
  sampleRect(cloud.points, {-1, -1, 0}, ex, 2.0, ey, 2.0, 0.01, 0.002, rng);
  sampleRect(cloud.points, {-0.9, -0.5, 0.1}, ex, 0.5, ey, 1.0, 0.01, 0.002, rng);
  sampleRect(cloud.points, {0.4, -0.5, 0.1}, ex, 0.5, ey, 1.0, 0.01, 0.002, rng);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  Config cfg;
  const std::vector<Plane> planes = detectPlanes(cloud, cfg);
  ASSERT_EQ(planes.size(), 3u);
  EXPECT_NEAR(planes[0].offset, 0.0, 0.005);
  EXPECT_GT(planes[0].support, 38000u);
  for (int k : {1, 2}) {
    EXPECT_LT(angleDeg(planes[k].normal, {0, 0, 1}), 1.0);
    EXPECT_NEAR(planes[k].offset, -0.1, 0.005);
    EXPECT_NEAR(static_cast<double>(planes[k].support), 5000.0, 250.0);
    EXPECT_NEAR(planes[k].extent.sizes().minCoeff(), 0.5, 0.03);
  }
  // Disjoint extents: the frame origins (inlier centroids) are 1.3 m apart along x.
  EXPECT_NEAR(std::abs(planes[1].frame_origin.x() - planes[2].frame_origin.x()), 1.3, 0.02);

  cfg.plane_connect_cell = 0.0;  // no connectivity split: one plane for both platforms
  const std::vector<Plane> merged = detectPlanes(cloud, cfg);
  ASSERT_EQ(merged.size(), 2u);
  EXPECT_NEAR(merged[1].offset, -0.1, 0.005);
  EXPECT_NEAR(static_cast<double>(merged[1].support), 10000.0, 500.0);
}

TEST(PlaneDetect, AWholeCloudPlaneNeedsACorePlaneMinWidthWide) {
  // Floor z = 0; in the plane x = 0.5 the end of a table (two legs 5 cm wide and 0.72 m tall,
  // under a top edge 3 cm tall and 0.8 m long: 3,800 points in one connected part, more than
  // min_plane_support); in the plane x = -0.5 a panel 0.3 m x 0.8 m. 5 mm spacing, 2 mm noise.
  // The frame has no part plane_min_width (12 cm) wide, so it is no surface; the panel is.
  std::mt19937 rng(21);
  PointCloud cloud;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY(),
                        ez = Eigen::Vector3d::UnitZ();
  const double h = 0.005, sigma = 0.002;
  sampleRect(cloud.points, {-1, -1, 0}, ex, 2.0, ey, 2.0, 0.01, sigma, rng);
  for (const double y : {-0.4, 0.35})
    sampleRect(cloud.points, {0.5, y, 0.0}, ey, 0.05, ez, 0.72, h, sigma, rng);
  sampleRect(cloud.points, {0.5, -0.4, 0.72}, ey, 0.8, ez, 0.03, h, sigma, rng);
  sampleRect(cloud.points, {-0.5, -0.4, 0.0}, ey, 0.8, ez, 0.3, h, sigma, rng);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  Config cfg;
  std::vector<Plane> planes = detectPlanes(cloud, cfg);
  EXPECT_EQ(planes.size(), 2u);
  EXPECT_NE(findPlane(planes, {0, 0, 1}, 0.0), nullptr);
  EXPECT_NE(findPlane(planes, {1, 0, 0}, 0.5), nullptr);   // the panel (normal toward the centroid)
  EXPECT_EQ(findPlane(planes, {-1, 0, 0}, 0.5), nullptr);  // the frame
  cfg.plane_min_width = 0.0;                               // no core needed: the frame is a plane
  planes = detectPlanes(cloud, cfg);
  EXPECT_EQ(planes.size(), 3u);
}

TEST(PlaneDetect, APanelSeenFromBothSidesIsItsFrontFace) {
  // A reconstruction of a 2.5 cm panel (x = 1 to 1.025, 0.4 m x 1.5 m) on a 3 m x 3 m floor:
  // the back face sampled everywhere, the front face (toward the scene, -x) more sparsely above
  // 1 m, as cameras below the panel's top see it. A plane fitted to both faces lies between them
  // and tilts; the plane is the front face, vertical.
  std::mt19937 rng(11);
  PointCloud cloud;
  const Eigen::Vector3d ey = Eigen::Vector3d::UnitY(), ez = Eigen::Vector3d::UnitZ();
  sampleRect(cloud.points, {-1.5, -1.5, 0}, Eigen::Vector3d::UnitX(), 3.0, ey, 3.0, 0.01, 0.001,
             rng);
  sampleRect(cloud.points, {1.025, -0.2, 0}, ey, 0.4, ez, 1.5, 0.007, 0.0015, rng);
  sampleRect(cloud.points, {1.0, -0.2, 0}, ey, 0.4, ez, 1.0, 0.007, 0.0015, rng);
  sampleRect(cloud.points, {1.0, -0.2, 1.0}, ey, 0.4, ez, 0.5, 0.02, 0.0015, rng);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  const PlaneSegmentation seg = segmentPlanes(cloud, Config{});
  int vertical = 0;
  for (const Plane& p : seg.planes) {
    if (p.orientation != Plane::Orientation::Vertical) continue;
    ++vertical;
    EXPECT_LT(angleDeg(p.normal, -Eigen::Vector3d::UnitX()), 0.3);
    // On the front face at the bottom and at the top of the panel.
    for (const double z : {0.1, 1.4})
      EXPECT_NEAR(p.signedDistance(Eigen::Vector3d(1.0, 0.0, z)), 0.0, 0.003) << "z " << z;
  }
  EXPECT_EQ(vertical, 1);
}

TEST(PlaneDetect, ANoisyWallClaimsItsWholeNoiseLayer) {
  // A raw far wall: the plane y = 1, 2 m x 2 m, 5 mm spacing, 2.5 cm Gaussian noise, over a
  // clean floor. A panel 0.6 m x 0.7 m turned 15 degrees stands in front of it; its plane crosses
  // the wall at x = 0.75. The wall's inliers (within ransac_inlier_dist, 1.5 cm) leave a shell
  // of noise beyond; where the panel's plane crosses it, a plane. With the points' noise the
  // wall claims its whole layer.
  std::mt19937 rng(5);
  PointCloud cloud;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY(),
                        ez = Eigen::Vector3d::UnitZ();
  sampleRect(cloud.points, {-1, -1, 0}, ex, 2.0, ey, 2.0, 0.01, 0.001, rng);
  sampleRect(cloud.points, {-1, 1, 0}, ex, 2.0, ez, 2.0, 0.005, 0.025, rng);
  const double yaw = 15.0 * kPi / 180.0;
  const Eigen::Vector3d along(std::cos(yaw), std::sin(yaw), 0.0);
  sampleRect(cloud.points, Eigen::Vector3d(0, 0.8, 0) - 0.3 * along, along, 0.6, ez, 0.7, 0.005,
             0.002, rng);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  const Config cfg;
  std::vector<float> noise;
  bool noisy = false;
  const std::vector<Eigen::Vector3f> normals = estimateNormals(cloud, cfg, nullptr, &noise, &noisy);
  ASSERT_TRUE(noisy);
  const auto offWall = [](const PlaneSegmentation& s) {  // planes through the wall, tilted
    int n = 0;
    for (const Plane& p : s.planes)
      n += std::abs(p.frame_origin.y() - 1.0) < 0.1 &&
           std::abs(p.normal.y()) < std::cos(2.0 * kPi / 180.0);
    return n;
  };
  const PlaneSegmentation with = segmentPlanes(cloud, cfg, normals, noise);
  EXPECT_EQ(with.planes.size(), 3u);
  EXPECT_EQ(offWall(with), 0);
  EXPECT_GE(offWall(segmentPlanes(cloud, cfg, normals)), 1);  // the shell left over
  EXPECT_THROW(segmentPlanes(cloud, cfg, normals, std::vector<float>(3, 0.01f)), Error);
}

// --- ray-cast depth images ---------------------------------------------------------------------

struct Box {
  Eigen::Vector3d lo, hi;
};

// Floor, back wall at y = 3, side wall at x = 2.2, a 1.6 m x 1.3 m table (top z = 0.75) on legs
// and three objects on it.
std::vector<Box> tabletopScene() {
  return {
      {{-6, -6, -0.05}, {6, 6, 0.0}},         // floor
      {{-6, 3.0, 0.0}, {6, 3.1, 2.5}},        // back wall
      {{2.2, -6, 0.0}, {2.3, 6, 2.5}},        // side wall
      {{-0.8, 0.3, 0.72}, {0.8, 1.6, 0.75}},  // table top
      {{-0.78, 0.32, 0}, {-0.74, 0.36, 0.72}}, {{0.74, 0.32, 0}, {0.78, 0.36, 0.72}},
      {{-0.78, 1.54, 0}, {-0.74, 1.58, 0.72}}, {{0.74, 1.54, 0}, {0.78, 1.58, 0.72}},
      {{-0.3, 0.8, 0.75}, {-0.2, 0.9, 0.9}},  // objects
      {{0.1, 1.0, 0.75}, {0.25, 1.1, 0.8}},    {{0.3, 0.6, 0.75}, {0.36, 0.66, 0.95}},
  };
}

bool hitBox(const Box& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double& t) {
  double t0 = 0.0, t1 = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12) {
      if (o[a] < b.lo[a] || o[a] > b.hi[a]) return false;
      continue;
    }
    double ta = (b.lo[a] - o[a]) / d[a], tb = (b.hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  t = t0;
  return t0 > 1e-9;
}

// Camera-to-world pose at `pos` looking at `target` (world z up), rolled about the optical axis.
Pose lookAt(const Eigen::Vector3d& pos, const Eigen::Vector3d& target, double roll_deg = 0) {
  Pose pose = test::lookAt(pos, target);
  pose.linear() = pose.linear() * Eigen::AngleAxisd(roll_deg * kPi / 180, Eigen::Vector3d::UnitZ());
  return pose;
}

// A 640x480 Kinect-like depth image (f = 525) of `scene` ray-cast from `pose`, depth noise
// 1.5 mm * z^2, returned as an organised cloud in the camera frame (`world` = false) or in the
// world frame with sensor_pose = pose.
PointCloud renderDepth(const std::vector<Box>& scene, const Pose& pose, unsigned seed, bool world,
                       int width = 640, int height = 480) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  PointCloud cloud;
  cloud.width = static_cast<std::uint32_t>(width);
  cloud.height = static_cast<std::uint32_t>(height);
  const double f = 525.0 * width / 640.0;
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      const Eigen::Vector3d ray_c((c - 0.5 * (width - 1)) / f, (r - 0.5 * (height - 1)) / f, 1.0);
      const Eigen::Vector3d ray_w = pose.linear() * ray_c;
      double best = std::numeric_limits<double>::infinity();
      for (const Box& b : scene) {
        double t;
        if (hitBox(b, pose.translation(), ray_w, t)) best = std::min(best, t);
      }
      if (!(best < 4.0)) {
        cloud.points.emplace_back(kNaN, kNaN, kNaN);
        continue;
      }
      const double z = best + 0.0015 * best * best * noise(rng);
      const Eigen::Vector3d pc = z * ray_c;
      cloud.points.push_back((world ? pose * pc : pc).cast<float>());
    }
  }
  if (world) cloud.sensor_pose = pose;
  return cloud;
}

// The camera 0.6 m above the table, looking down 30 deg at it (like a Kinect on a tripod).
Pose kinectPose(double dx = 0.0, double yaw_deg = 0.0) {
  const Eigen::Vector3d pos(dx, 0.0, 1.35);
  const double yaw = yaw_deg * kPi / 180;
  const Eigen::Vector3d dir(std::sin(yaw) * std::cos(kPi / 6), std::cos(yaw) * std::cos(kPi / 6),
                            -std::sin(kPi / 6));
  return lookAt(pos, pos + dir);
}

TEST(PlaneDetect, EstimateUpInACameraFrameSceneWithYDown) {
  const Pose pose = kinectPose();
  const PointCloud cloud = renderDepth(tabletopScene(), pose, 1, /*world=*/false);
  // World up seen from the camera: (0, -cos 30, -sin 30), i.e. camera -y tilted toward -z.
  const Eigen::Vector3d expected = pose.linear().transpose() * Eigen::Vector3d::UnitZ();
  EXPECT_LT(angleDeg(expected, {0, -std::cos(kPi / 6), -std::sin(kPi / 6)}), 1e-6);
  Config cfg;
  cfg.up_auto = true;
  const Eigen::Vector3d up = estimateUp(cloud, cfg);
  EXPECT_LT(angleDeg(up, expected), 1.0) << up.transpose();
  EXPECT_GT(up.dot(Eigen::Vector3d(0, -1, 0)), 0.8);

  // Whole-cloud detection with up_auto: the table is the largest plane, horizontal, normal
  // toward the camera (= up), 0.6 m below the camera.
  const auto t0 = std::chrono::steady_clock::now();
  const PlaneSegmentation seg = segmentPlanes(cloud, cfg);
  std::cout << "[timing] segmentPlanes organised 640x480: " << msSince(t0) << " ms, "
            << seg.planes.size() << " planes\n";
  EXPECT_LT(angleDeg(seg.up, expected), 1.0);
  ASSERT_FALSE(seg.planes.empty());
  const Plane& table = seg.planes.front();
  EXPECT_EQ(table.orientation, Plane::Orientation::Horizontal);
  EXPECT_LT(angleDeg(table.normal, expected), 1.0);
  EXPECT_NEAR(table.offset, 0.6, 0.01);  // camera at the origin, 0.6 m above the top
  EXPECT_GT(table.support, cloud.countValid() / 3);
  for (const Plane& p : seg.planes) EXPECT_GT(p.offset, 0.0) << "normal toward the sensor";
}

TEST(PlaneRansac, FindsTheTablePlaneInADepthFrame) {
  const Pose pose = kinectPose();
  const PointCloud frame = renderDepth(tabletopScene(), pose, 3, /*world=*/true);
  Config cfg;
  std::vector<PlaneObservation> obs;
  double ms = 1e9, cpu_ms = 1e9;  // best of 5 (the first call also pays for page faults)
  for (int rep = 0; rep < 5; ++rep) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::clock_t c0 = std::clock();
    obs = detectPlanesRansac(frame.points, pose.translation(), cfg, Eigen::Vector3d::UnitZ());
    cpu_ms = std::min(cpu_ms, 1000.0 * static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC);
    ms = std::min(ms, msSince(t0));
  }
  std::cout << "[timing] detectPlanesRansac 640x480: " << ms << " ms wall, " << cpu_ms
            << " ms cpu, " << obs.size() << " planes\n";
  ASSERT_FALSE(obs.empty());
  const Plane& table = obs.front().plane;
  EXPECT_LT(angleDeg(table.normal, {0, 0, 1}), 1.0);
  EXPECT_NEAR(table.offset, -0.75, 0.005);
  EXPECT_EQ(table.orientation, Plane::Orientation::Horizontal);
  EXPECT_EQ(table.support, obs.front().inliers.size());
  EXPECT_GT(table.support, frame.countValid() / 3);
  for (std::uint32_t i : obs.front().inliers) {
    ASSERT_LE(std::abs(table.signedDistance(frame.points[i].cast<double>())),
              cfg.ransac_inlier_dist + 1e-4);
  }
  // The extent covers the visible table top (<= 1.6 m x 1.3 m).
  EXPECT_LE(table.extent.sizes().maxCoeff(), 1.7);
  EXPECT_GE(table.extent.sizes().minCoeff(), 0.8);
  // Deterministic.
  const auto again =
      detectPlanesRansac(frame.points, pose.translation(), cfg, Eigen::Vector3d::UnitZ());
  ASSERT_EQ(again.size(), obs.size());
  for (std::size_t k = 0; k < obs.size(); ++k) {
    EXPECT_EQ(again[k].plane.normal, obs[k].plane.normal);
    EXPECT_EQ(again[k].inliers, obs[k].inliers);
  }
  // Every returned plane is horizontal or vertical and faces the sensor.
  for (const PlaneObservation& o : obs) {
    EXPECT_GT(o.plane.signedDistance(pose.translation()), 0.0);
    const double frac = o.plane.orientation == Plane::Orientation::Horizontal
                            ? cfg.ransac_min_horizontal_frac
                            : cfg.ransac_min_inlier_frac;
    EXPECT_GE(o.plane.support, static_cast<std::size_t>(frac * frame.countValid()));
  }
}

TEST(PlaneRansac, AForeshortenedBoardIsAPlaneAndAsSmallAVerticalPatchIsNot) {
  // A wall (about 80 % of the points), a floor strip, a shelf board and a vertical patch of the
  // same size as the board (2 % of the points each), 1 mm noise.
  std::mt19937 rng(7);
  std::vector<Eigen::Vector3f> pts;
  const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY(),
                        ez = Eigen::Vector3d::UnitZ();
  sampleRect(pts, {0, 3, 0}, ex, 3.0, ez, 2.5, 0.02, 0.001, rng);
  sampleRect(pts, {0, 2, 0}, ex, 3.0, ey, 0.6, 0.025, 0.001, rng);
  const std::size_t before_board = pts.size();
  sampleRect(pts, {1.0, 2.6, 1.2}, ex, 0.9, ey, 0.3, 0.025, 0.001, rng);
  const std::size_t board = pts.size() - before_board;
  sampleRect(pts, {2.0, 1.0, 0.5}, ez, 0.3, ex, 0.9, 0.025, 0.001, rng);  // faces -y
  ASSERT_GT(board, pts.size() / 70);  // between the two fractions
  ASSERT_LT(board, pts.size() / 40);
  const Eigen::Vector3d sensor(1.5, 0.0, 1.5);
  Config cfg;
  const auto has = [](const std::vector<PlaneObservation>& obs, const Eigen::Vector3d& n,
                      double d) {
    for (const PlaneObservation& o : obs)
      if (o.plane.normal.dot(n) > 0.999 && std::abs(o.plane.offset - d) < 0.005) return true;
    return false;
  };
  const auto obs = detectPlanesRansac(pts, sensor, cfg, ez);
  EXPECT_TRUE(has(obs, ez, -1.2));   // the board
  EXPECT_FALSE(has(obs, -ey, 1.0));  // the vertical patch
  EXPECT_TRUE(has(obs, -ey, 3.0));   // the wall
  cfg.ransac_min_horizontal_frac = cfg.ransac_min_inlier_frac;
  EXPECT_FALSE(has(detectPlanesRansac(pts, sensor, cfg, ez), ez, -1.2));
}

TEST(PlaneTracker, RefinementsThinOutGeometricallyAndKeepThePlaneExact) {
  // The same view 40 times: every frame brings as many inliers, so a refinement every
  // refine_min_new_inliers would run in every frame; with the geometric schedule (refine when
  // the inliers gained reach half of those seen at the last refinement) the count grows like
  // log_1.5(frames): frames 1, 2, 3, 5, 8, 12, 18, 27, 41 -> 8 refinements within 40 frames.
  const std::vector<Box> scene = tabletopScene();
  Config cfg;
  PlaneTracker tracker(cfg);
  const Pose pose = kinectPose();
  int table_id = -1;
  for (int f = 0; f < 40; ++f) {
    const PointCloud frame = renderDepth(scene, pose, 100 + f, /*world=*/true, 320, 240);
    const std::vector<int> ids = tracker.integrate(frame.points, pose.translation());
    ASSERT_FALSE(ids.empty());
    if (f == 0) table_id = ids.front();
    EXPECT_EQ(ids.front(), table_id) << "frame " << f;
  }
  const Plane table = *tracker.plane(table_id);
  EXPECT_GE(tracker.refinementCount(table_id), 6);
  EXPECT_LE(tracker.refinementCount(table_id), 9);
  EXPECT_LT(angleDeg(table.normal, {0, 0, 1}), 0.2);
  EXPECT_NEAR(table.offset, -0.75, 0.001);
}

TEST(PlaneTracker, MergesOnePlaneSeenInFiveFramesAndKeepsIdsStable) {
  const std::vector<Box> scene = tabletopScene();
  Config cfg;
  PlaneTracker tracker(cfg);
  int table_id = -1;
  std::size_t table_support = 0;
  for (int f = 0; f < 5; ++f) {
    const Pose pose = kinectPose(0.05 * f, -4.0 * f);  // turning away from the side wall
    const PointCloud frame = renderDepth(scene, pose, 10 + f, /*world=*/true, 320, 240);
    const auto obs = detectPlanesRansac(frame.points, pose.translation(), cfg, *tracker.up());
    const std::vector<int> ids = tracker.merge(obs, frame.points);
    ASSERT_EQ(ids.size(), obs.size());
    ASSERT_FALSE(ids.empty());
    // The table (largest plane in every frame) always lands in the same global plane.
    if (f == 0) table_id = ids.front();
    EXPECT_EQ(ids.front(), table_id) << "frame " << f;
    table_support += obs.front().inliers.size();
  }
  ASSERT_NE(tracker.plane(table_id), nullptr);
  const Plane table = *tracker.plane(table_id);
  EXPECT_EQ(table.support, table_support);
  EXPECT_LT(angleDeg(table.normal, {0, 0, 1}), 0.5);
  EXPECT_NEAR(table.offset, -0.75, 0.003);
  EXPECT_GE(tracker.refinementCount(table_id), 2);
  EXPECT_LE(tracker.reservoirSize(table_id), static_cast<std::size_t>(cfg.plane_reservoir_size));
  // One global plane per physical plane: no two global planes that should have merged.
  for (const Plane& a : tracker.planes()) {
    for (const Plane& b : tracker.planes()) {
      if (a.id >= b.id) continue;
      const bool same =
          angleDeg(a.normal, b.normal) < 5 && std::abs(b.signedDistance(a.frame_origin)) < 0.02;
      EXPECT_FALSE(same) << a.id << " and " << b.id;
    }
  }

  // Turn toward the side wall at x = 2.2: it appears as a new plane with the next id; the old
  // planes keep their ids and parameters are only refined.
  const std::vector<Plane> before = tracker.planes();
  const Pose side = lookAt({0.5, 1.0, 1.2}, {2.2, 1.2, 1.0});
  const PointCloud frame = renderDepth(scene, side, 99, /*world=*/true, 320, 240);
  const std::vector<int> ids = tracker.integrate(frame.points, side.translation());
  ASSERT_FALSE(ids.empty());
  const int wall_id = ids.front();
  ASSERT_GE(wall_id, static_cast<int>(before.size()));
  const Plane& wall = *tracker.plane(wall_id);
  EXPECT_EQ(wall.orientation, Plane::Orientation::Vertical);
  EXPECT_LT(angleDeg(wall.normal, {-1, 0, 0}), 1.0);
  EXPECT_NEAR(wall.offset, 2.2, 0.01);
  ASSERT_GE(tracker.planes().size(), before.size() + 1);
  for (const Plane& old : before) {
    const Plane* now = tracker.plane(old.id);
    ASSERT_NE(now, nullptr);
    EXPECT_EQ(now->id, old.id);
    EXPECT_LT(angleDeg(now->normal, old.normal), 1.0);
    EXPECT_GE(now->support, old.support);
  }
  for (std::size_t i = 0; i < tracker.planes().size(); ++i) {
    EXPECT_EQ(tracker.planes()[i].id, static_cast<int>(i));
  }
}

/// A frame plane observation of the horizontal rectangle [x0, x1] x [y0, y1] at height z
/// (sampled every 2 cm, appended to `points`).
PlaneObservation horizontalPatch(std::vector<Eigen::Vector3f>& points, double x0, double x1,
                                 double y0, double y1, double z) {
  PlaneObservation o;
  std::vector<Eigen::Vector3f> mine;
  for (double x = x0; x <= x1 + 1e-9; x += 0.02)
    for (double y = y0; y <= y1 + 1e-9; y += 0.02) {
      o.inliers.push_back(static_cast<std::uint32_t>(points.size()));
      points.emplace_back(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
      mine.push_back(points.back());
    }
  o.plane = makePlane({0, 0, 1}, -z, {x0, y0, z}, {0, 0, 1});
  o.plane.extendExtent(mine);
  o.plane.support = o.inliers.size();
  return o;
}

TEST(PlaneTracker, PlanesAFewCentimetresApartMergeOnlyWhereConnected) {
  Config cfg;
  PlaneTracker tracker(cfg);
  std::vector<Eigen::Vector3f> pts;
  // Two desks 4 cm apart in height and 30 cm apart on the floor: two planes (one plane fitted to
  // both would tilt). A third patch 3 cm above the second desk and touching it joins it; floor
  // patches 2 m apart at the same height are one plane.
  const std::vector<PlaneObservation> obs = {
      horizontalPatch(pts, 0.0, 1.2, 0.0, 0.8, 0.72),     // desk A
      horizontalPatch(pts, 1.5, 2.7, 0.0, 0.8, 0.76),     // desk B
      horizontalPatch(pts, 2.72, 3.4, 0.0, 0.8, 0.79),    // touches B
      horizontalPatch(pts, -2.0, 0.0, -2.0, -1.0, 0.0),   // floor
      horizontalPatch(pts, 2.0, 4.0, -2.0, -1.0, 0.005),  // floor, far away, 5 mm higher
  };
  const std::vector<int> ids = tracker.merge(obs, pts);
  ASSERT_EQ(ids.size(), 5u);
  EXPECT_NE(ids[0], ids[1]);
  EXPECT_EQ(ids[2], ids[1]);
  EXPECT_EQ(ids[4], ids[3]);
  EXPECT_EQ(tracker.planes().size(), 3u);
  EXPECT_NEAR(tracker.plane(ids[0])->offset, -0.72, 1e-6);  // desk A untouched by B's points
}

TEST(PlaneTracker, ADeskAndABoardAtTheSameHeightOverTheFloorStayTwoPlanes) {
  Config cfg;
  PlaneTracker tracker(cfg);
  std::vector<Eigen::Vector3f> pts;
  // Over one floor, a desk and a shelf board 2 m away at heights 3 mm apart: two surfaces. A
  // second patch of the desk touching the first joins it; far floor patches still merge.
  const std::vector<PlaneObservation> obs = {
      horizontalPatch(pts, -1.0, 4.0, -2.0, 2.0, 0.0),   // floor
      horizontalPatch(pts, 0.0, 1.2, 0.0, 0.8, 0.750),   // desk
      horizontalPatch(pts, 3.0, 3.9, 1.0, 1.3, 0.753),   // board
      horizontalPatch(pts, 1.22, 1.6, 0.0, 0.8, 0.752),  // the desk's far end
      horizontalPatch(pts, 6.0, 7.0, -2.0, 2.0, 0.002),  // floor beyond a wall gap
  };
  const std::vector<int> ids = tracker.merge(obs, pts);
  ASSERT_EQ(ids.size(), 5u);
  EXPECT_NE(ids[1], ids[2]);
  EXPECT_EQ(ids[3], ids[1]);
  EXPECT_EQ(ids[4], ids[0]);
  EXPECT_EQ(tracker.planes().size(), 3u);
}

TEST(PlaneTracker, ObjectFacesAndTableLegsStartNoPlane) {
  Config cfg;
  PlaneTracker tracker(cfg);
  std::vector<Eigen::Vector3f> pts;
  // A box top (30 x 20 cm), a board-like strip only 5 cm wide (a table leg's face seen as a
  // plane) and a shelf board (0.9 x 0.3 m), with the stream thresholds of Config.
  const std::vector<PlaneObservation> obs = {
      horizontalPatch(pts, 0.0, 0.3, 0.0, 0.2, 0.9),
      horizontalPatch(pts, 1.0, 1.7, 0.0, 0.05, 0.5),
      horizontalPatch(pts, 2.0, 2.9, 0.0, 0.3, 1.1),
  };
  const std::vector<int> ids = tracker.merge(obs, pts, cfg.plane_min_extent, cfg.plane_min_width);
  EXPECT_EQ(ids, (std::vector<int>{-1, -1, 0}));
  // Without the minimum (whole clouds) each is a plane.
  PlaneTracker whole(cfg);
  EXPECT_EQ(whole.merge(obs, pts), (std::vector<int>{0, 1, 2}));
}

TEST(PlaneTracker, ReservoirIsBoundedAndUpAutoIsFixedByTheFirstFrame) {
  Config cfg;
  cfg.up_auto = true;
  cfg.plane_reservoir_size = 5000;
  const std::vector<Box> scene = tabletopScene();
  PlaneTracker tracker(cfg);
  EXPECT_FALSE(tracker.up().has_value());
  for (int f = 0; f < 3; ++f) {
    const Pose pose = kinectPose(0.02 * f);
    const PointCloud frame = renderDepth(scene, pose, 50 + f, /*world=*/true, 320, 240);
    tracker.integrate(frame.points, pose.translation());
  }
  ASSERT_TRUE(tracker.up().has_value());
  EXPECT_LT(angleDeg(*tracker.up(), {0, 0, 1}), 1.0);  // the table's normal, toward the camera
  ASSERT_FALSE(tracker.planes().empty());
  for (const Plane& p : tracker.planes()) {
    EXPECT_LE(tracker.reservoirSize(p.id), 5000u);
    EXPECT_EQ(tracker.reservoirSize(p.id), std::min<std::size_t>(p.support, 5000));
  }
  EXPECT_EQ(tracker.plane(-1), nullptr);
  EXPECT_EQ(tracker.plane(1000), nullptr);
}

TEST(PlaneTracker, RestoredTrackerKeepsIdsAndMergesIntoRestoredPlanes) {
  const std::vector<Box> scene = tabletopScene();
  Config cfg;
  PlaneTracker first(cfg);
  const Pose pose = kinectPose();
  const PointCloud frame = renderDepth(scene, pose, 70, /*world=*/true, 320, 240);
  const std::vector<int> ids = first.integrate(frame.points, pose.translation());
  ASSERT_FALSE(ids.empty());

  PlaneTracker again(cfg);
  again.restore(first.planes(), first.up());
  ASSERT_EQ(again.planes().size(), first.planes().size());
  EXPECT_EQ(again.reservoirSize(ids.front()), 0u);  // reservoirs start empty
  const PointCloud next = renderDepth(scene, kinectPose(0.03), 71, /*world=*/true, 320, 240);
  const std::vector<int> ids2 = again.integrate(next.points, kinectPose(0.03).translation());
  ASSERT_FALSE(ids2.empty());
  EXPECT_EQ(ids2.front(), ids.front());  // the table merges into its restored plane
  EXPECT_GT(again.plane(ids.front())->support, first.plane(ids.front())->support);

  std::vector<Plane> bad = first.planes();
  bad.front().id = 5;
  EXPECT_THROW(again.restore(bad, std::nullopt), Error);
}

}  // namespace
}  // namespace planesdf
