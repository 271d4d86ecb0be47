// Unit tests of the plane stage: frames, orientation classes, least squares, Ceres refinement,
// normals, error handling.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

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

// `count` points on {n·x + d = 0} within a square of half-size `half` around the foot of the
// origin, Gaussian noise `sigma` along n.
std::vector<Eigen::Vector3f> samplePlane(const Eigen::Vector3d& n, double d, double half,
                                         std::size_t count, double sigma, std::mt19937& rng) {
  const Eigen::Vector3d u = n.unitOrthogonal();
  const Eigen::Vector3d v = n.cross(u);
  const Eigen::Vector3d foot = -d * n;
  std::uniform_real_distribution<double> uni(-half, half);
  std::normal_distribution<double> noise(0.0, sigma);
  std::vector<Eigen::Vector3f> pts;
  for (std::size_t i = 0; i < count; ++i) {
    pts.push_back((foot + uni(rng) * u + uni(rng) * v + noise(rng) * n).cast<float>());
  }
  return pts;
}

void expectOrthonormalFrame(const Plane& p) {
  const Eigen::Matrix3d r = p.frame_axes;
  EXPECT_LT((r.transpose() * r - Eigen::Matrix3d::Identity()).norm(), 1e-9);
  EXPECT_NEAR(r.determinant(), 1.0, 1e-9);
  EXPECT_LT((r.col(2) - p.normal).norm(), 1e-9);
  EXPECT_NEAR(p.signedDistance(p.frame_origin), 0.0, 1e-9);
}

TEST(PlaneFrame, DeterministicRightHandedFrameOnThePlane) {
  const Eigen::Vector3d up(0, 0, 1);
  // Horizontal: u is world x (least aligned with up), v = n x u.
  const Plane table = makePlane({0, 0, 2}, -1.5, {0.3, 0.4, 9.0}, up, 7);
  EXPECT_EQ(table.id, 7);
  EXPECT_NEAR(table.offset, -0.75, 1e-12);  // normalised with the normal
  expectOrthonormalFrame(table);
  EXPECT_LT((table.frame_axes.col(0) - Eigen::Vector3d::UnitX()).norm(), 1e-12);
  EXPECT_LT((table.frame_origin - Eigen::Vector3d(0.3, 0.4, 0.75)).norm(), 1e-12);
  // Vertical: v is up projected into the plane.
  const Plane wall = makePlane({-1, 0, 0}, 2.0, {2.0, 0.5, 1.0}, up);
  expectOrthonormalFrame(wall);
  EXPECT_LT((wall.frame_axes.col(1) - up).norm(), 1e-12);
  // Same inputs, same frame.
  EXPECT_EQ(makePlane({-1, 0, 0}, 2.0, {2.0, 0.5, 1.0}, up).frame_axes, wall.frame_axes);
  // (u, v, h) round trip; h is the signed distance.
  const Eigen::Vector3d p(1.7, -0.2, 0.3);
  const Eigen::Vector3d local = wall.toLocal(p);
  EXPECT_NEAR(local.z(), wall.signedDistance(p), 1e-12);
  EXPECT_NEAR(local.z(), 0.3, 1e-12);
  EXPECT_LT((wall.toWorld(local) - p).norm(), 1e-12);
  EXPECT_LT((wall.frame() * local - p).norm(), 1e-12);
}

TEST(PlaneFrame, UpdateMovesTheFrameWithThePlane) {
  const Eigen::Vector3d up(0, 0, 1);
  Plane plane = makePlane({0, 0, 1}, -0.75, {1, 2, 0.75}, up);
  plane.extent.extend(Eigen::Vector2d(-0.5, -0.5));
  plane.extent.extend(Eigen::Vector2d(0.5, 0.5));
  const Eigen::Vector3d tilted = Eigen::AngleAxisd(0.01, Eigen::Vector3d::UnitY()) * up;
  updatePlaneGeometry(plane, 3.0 * tilted, 3.0 * -0.76);
  expectOrthonormalFrame(plane);
  EXPECT_LT((plane.normal - tilted).norm(), 1e-12);
  EXPECT_NEAR(plane.offset, -0.76, 1e-12);
  // The smallest rotation: u turns by the same 0.01 rad about y, origin moves ~1 cm.
  EXPECT_NEAR(angleDeg(plane.frame_axes.col(0), Eigen::Vector3d::UnitX()), 0.01 * 180 / kPi, 1e-6);
  EXPECT_LT((plane.frame_origin - Eigen::Vector3d(1, 2, 0.75)).norm(), 0.03);
  EXPECT_FALSE(plane.extent.isEmpty());  // kept
}

TEST(PlaneOrientation, ClassifiesAgainstUpWithTolerance) {
  const Eigen::Vector3d up(0, 0, 1);
  auto rotated = [](double deg) {
    return Eigen::Vector3d(std::sin(deg * kPi / 180), 0, std::cos(deg * kPi / 180));
  };
  EXPECT_EQ(classifyOrientation(rotated(0), up, 10), Plane::Orientation::Horizontal);
  EXPECT_EQ(classifyOrientation(-rotated(9.5), up, 10), Plane::Orientation::Horizontal);
  EXPECT_EQ(classifyOrientation(rotated(90), up, 10), Plane::Orientation::Vertical);
  EXPECT_EQ(classifyOrientation(rotated(80.5), up, 10), Plane::Orientation::Vertical);
  EXPECT_FALSE(classifyOrientation(rotated(10.5), up, 10).has_value());
  EXPECT_FALSE(classifyOrientation(rotated(30), up, 10).has_value());
  EXPECT_FALSE(classifyOrientation(rotated(79.5), up, 10).has_value());
}

TEST(PlaneFit, LeastSquaresRecoversAnExactPlaneAndRejectsDegenerateInput) {
  std::mt19937 rng(3);
  const Eigen::Vector3d n = Eigen::Vector3d(1, 2, 3).normalized();
  std::vector<Eigen::Vector3f> pts = samplePlane(n, -0.4, 1.0, 500, 0.0, rng);
  pts.emplace_back(kNaN, 0.0f, 0.0f);  // ignored
  Eigen::Vector3d fit;
  double d = 0;
  ASSERT_TRUE(fitPlaneLeastSquares(pts, fit, d));
  if (fit.dot(n) < 0) {
    fit = -fit;
    d = -d;
  }
  EXPECT_LT(angleDeg(fit, n), 1e-3);
  EXPECT_NEAR(d, -0.4, 1e-5);
  const std::vector<Eigen::Vector3f> line = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}, {3, 3, 3}};
  EXPECT_FALSE(fitPlaneLeastSquares(line, fit, d));
  EXPECT_FALSE(fitPlaneLeastSquares({{0, 0, 0}, {1, 0, 0}}, fit, d));
}

TEST(PlaneRefine, NoisyTiltedPlaneWithOutliersWithinTenthsOfADegreeAndAMillimetre) {
  // 20k points on a 2 m x 2 m plane tilted 25 deg, 1 cm Gaussian noise, 20 % outliers spread
  // uniformly in a box 0.5 m on either side. The statistical floor is far below the bounds
  // (normal ~0.01 deg, offset ~0.1 mm); what is tested is the robustness to the outliers and
  // convergence from an initial guess 3 deg and 3 cm off.
  std::mt19937 rng(20240611);
  const Eigen::Vector3d n_true =
      (Eigen::AngleAxisd(25 * kPi / 180, Eigen::Vector3d(1, 1, 0).normalized()) *
       Eigen::Vector3d::UnitZ())
          .normalized();
  const double d_true = -1.2;
  std::vector<Eigen::Vector3f> pts = samplePlane(n_true, d_true, 1.0, 16000, 0.01, rng);
  const Eigen::Vector3d foot = -d_true * n_true;
  std::uniform_real_distribution<double> box(-1.0, 1.0);
  std::uniform_real_distribution<double> height(-0.5, 0.5);
  const Eigen::Vector3d u = n_true.unitOrthogonal();
  const Eigen::Vector3d v = n_true.cross(u);
  for (int i = 0; i < 4000; ++i) {
    pts.push_back((foot + box(rng) * u + box(rng) * v + height(rng) * n_true).cast<float>());
  }
  const Eigen::Vector3d n0 = Eigen::AngleAxisd(3 * kPi / 180, Eigen::Vector3d::UnitX()) * n_true;
  Plane plane = makePlane(n0, d_true + 0.03, foot, Eigen::Vector3d::UnitZ(), 4);
  Config cfg;
  cfg.refine_max_points = 20000;  // use them all
  ASSERT_TRUE(refinePlane(pts, plane, cfg));
  EXPECT_LT(angleDeg(plane.normal, n_true), 0.2);
  EXPECT_LT(std::abs(plane.offset - d_true), 0.001);
  EXPECT_EQ(plane.id, 4);
  expectOrthonormalFrame(plane);
}

TEST(PlaneRefine, ObjectsOnTheTableDoNotLiftIt) {
  // A table top (z = 0.75, 2 mm noise) and, one-sided, 20 % of points on objects 5-30 cm above
  // it. A least-squares fit lifts the plane by 0.2 * 17.5 cm = 3.5 cm; the Cauchy loss (1 cm)
  // gives those points almost no pull: expected offset error well under a millimetre.
  std::mt19937 rng(11);
  std::vector<Eigen::Vector3f> pts = samplePlane({0, 0, 1}, -0.75, 0.6, 8000, 0.002, rng);
  std::uniform_real_distribution<double> xy(-0.6, 0.6), up(0.05, 0.30);
  for (int i = 0; i < 2000; ++i)
    pts.emplace_back(static_cast<float>(xy(rng)), static_cast<float>(xy(rng)),
                     static_cast<float>(0.75 + up(rng)));
  Plane plane = makePlane({0.01, 0.0, 1.0}, -0.76, {0, 0, 0.76}, {0, 0, 1});
  ASSERT_TRUE(refinePlane(pts, plane, Config{}));
  EXPECT_LT(angleDeg(plane.normal, {0, 0, 1}), 0.1);
  EXPECT_NEAR(plane.offset, -0.75, 0.0005);
}

TEST(PlaneRefine, KeepsTheFreeSideAndRejectsTooFewPoints) {
  std::mt19937 rng(5);
  const std::vector<Eigen::Vector3f> pts = samplePlane({0, 0, 1}, -0.75, 0.5, 2000, 0.002, rng);
  // Normal pointing down (free side below, e.g. a ceiling) must stay pointing down.
  Plane plane = makePlane({0.02, 0, -1}, 0.74, {0, 0, 0.75}, {0, 0, 1});
  ASSERT_TRUE(refinePlane(pts, plane, Config{}));
  EXPECT_LT(angleDeg(plane.normal, {0, 0, -1}), 0.2);
  EXPECT_NEAR(plane.offset, 0.75, 0.001);

  const Plane before = plane;
  EXPECT_FALSE(refinePlane({{0, 0, 0}, {1, 0, 0}, {kNaN, 0, 0}}, plane, Config{}));
  EXPECT_EQ(plane.normal, before.normal);
  EXPECT_EQ(plane.offset, before.offset);
}

TEST(PlaneNormals, KnnNormalsOfASphereMatchTheAnalyticNormal) {
  // 40k points uniform on a sphere of radius 0.5 m: k = 20 neighbours span ~2 cm, so the PCA
  // normal of the curved patch deviates from the radial direction by well under 1 deg.
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  const Eigen::Vector3d centre(1.0, -2.0, 0.5);
  PointCloud cloud;
  for (int i = 0; i < 40000; ++i) {
    const Eigen::Vector3d dir = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    cloud.points.push_back((centre + 0.5 * dir).cast<float>());
  }
  cloud.points[17] = Eigen::Vector3f(kNaN, kNaN, kNaN);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  Config cfg;
  std::vector<float> curvature;
  std::vector<Eigen::Vector3f> normals = estimateNormals(cloud, cfg, &curvature);
  ASSERT_EQ(normals.size(), cloud.size());
  EXPECT_FALSE(normals[17].allFinite());
  int bad = 0;
  double worst = 0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (i == 17) continue;
    const Eigen::Vector3d radial = (cloud.points[i].cast<double>() - centre).normalized();
    ASSERT_TRUE(normals[i].allFinite()) << i;
    const double err =
        std::acos(std::min(1.0, std::abs(radial.dot(normals[i].cast<double>())))) * 180 / kPi;
    worst = std::max(worst, err);
    if (err > 3.0) ++bad;
    EXPECT_LT(curvature[i], 0.05f);
  }
  EXPECT_EQ(bad, 0) << "worst " << worst << " deg";

  // With a sensor at the centre, normals are oriented toward it (inward).
  cloud.sensor_pose.translation() = centre;
  normals = estimateNormals(cloud, cfg);
  for (std::size_t i = 0; i < cloud.size(); i += 97) {
    if (i == 17) continue;
    EXPECT_GT(normals[i].cast<double>().dot(centre - cloud.points[i].cast<double>()), 0.0) << i;
  }
}

TEST(PlaneNormals, ANoiseLayerAsThickAsTheNeighbourhoodTakesTheFlattestScale) {
  // 1 m x 1 m at 30k points / m^2 with sigma = 1.5 cm (a raw accumulated wall seen from 3 m):
  // the 20 nearest neighbours span ~1.5 cm, less than the layer, so their plane is random. At
  // 320 (~5.8 cm) the tilt error is about sigma / (r sqrt(k) / 2) ~ 2 degrees.
  std::mt19937 rng(11);
  const double sigma = 0.015;
  PointCloud cloud;
  cloud.points = samplePlane({0, 0, 1}, 0.0, 0.5, 30000, sigma, rng);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  cloud.height = 1;
  const auto errors = [&](const Config& cfg, std::vector<float>* spread) {
    const std::vector<Eigen::Vector3f> n = estimateNormals(cloud, cfg, nullptr, spread);
    std::vector<double> deg;
    for (std::size_t i = 0; i < n.size(); ++i)
      if (std::abs(cloud.points[i].x()) < 0.3f && std::abs(cloud.points[i].y()) < 0.3f)
        deg.push_back(angleDeg(n[i].cast<double>().cwiseAbs(), Eigen::Vector3d::UnitZ()));
    std::sort(deg.begin(), deg.end());
    return deg;
  };
  Config cfg;
  cfg.normal_knn_max = 16 * cfg.normal_knn;
  std::vector<float> spread;
  const std::vector<double> multi = errors(cfg, &spread);
  ASSERT_GT(multi.size(), 9000u);
  EXPECT_LT(multi[multi.size() / 2], 5.0);
  EXPECT_LT(multi[multi.size() * 95 / 100], 12.0);
  // The spread is the layer's noise at the chosen scale.
  std::vector<float> s(spread.begin(), spread.end());
  std::nth_element(s.begin(), s.begin() + s.size() / 2, s.end());
  EXPECT_NEAR(s[s.size() / 2], sigma, 0.3 * sigma);
  // 320 neighbours' extent read as 80 of a one-in-four subsample: the tilt error doubles.
  cfg.normal_fit_points = 80;
  const std::vector<double> sub = errors(cfg, nullptr);
  EXPECT_GT(sub[sub.size() / 2], 1.3 * multi[multi.size() / 2]);
  EXPECT_LT(sub[sub.size() / 2], 3.0 * multi[multi.size() / 2]);
  cfg.normal_fit_points = 320;
  cfg.normal_knn_max = cfg.normal_knn;  // one scale
  const std::vector<double> single = errors(cfg, nullptr);
  EXPECT_GT(single[single.size() / 2], 20.0);
}

TEST(PlaneNormals, AStepKeepsItsFineScaleNormalsWhereItsNeighboursAreSmooth) {
  // A disc 10 cm in radius standing 2 cm off a wall (z = 0), points every 5 mm with 1 mm noise,
  // as in a reconstruction. At the disc's side the 20 nearest are not flat, but 80 or 320 span
  // the wall and the face, two parallel planes, and would be flatter. Most of those points are
  // smooth at the fine scale: the roughness is a line, not a noise layer, so the side keeps its
  // radial normals.
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.001);
  const double r = 0.1, h = 0.02, step = 0.005;
  PointCloud cloud;
  for (double x = -0.4; x <= 0.4; x += step)
    for (double y = -0.4; y <= 0.4; y += step) {
      const double rho = std::hypot(x, y);
      cloud.points.emplace_back(x, y, (rho < r ? h : 0.0) + noise(rng));
    }
  std::vector<std::size_t> side;
  for (double a = 0.0; a < 2 * kPi; a += step / r)
    for (double z = step / 2; z < h; z += step) {
      side.push_back(cloud.points.size());
      cloud.points.emplace_back(r * std::cos(a), r * std::sin(a), z + noise(rng));
    }
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  cloud.height = 1;
  const auto radialShare = [&](const Config& cfg) {
    const std::vector<Eigen::Vector3f> n = estimateNormals(cloud, cfg);
    int radial = 0;
    for (const std::size_t i : side) {
      const Eigen::Vector3d out(cloud.points[i].x(), cloud.points[i].y(), 0.0);
      radial += std::abs(n[i].cast<double>().dot(out.normalized())) > std::cos(kPi / 4) ? 1 : 0;
    }
    return static_cast<double>(radial) / static_cast<double>(side.size());
  };
  Config cfg;
  cfg.normal_knn_max = cfg.normal_knn;
  const double single = radialShare(cfg);
  cfg.normal_knn_max = 16 * cfg.normal_knn;
  const double thin = radialShare(cfg);  // not a noisy cloud: one scale
  cfg.noisy_cloud_share = 0.0;           // taken as noisy
  cfg.normal_rough_share = 0.0;          // the flattest scale wherever the fine one is rough
  const double flattest = radialShare(cfg);
  cfg.normal_rough_share = 0.5;
  const double multi = radialShare(cfg);
  EXPECT_NEAR(thin, single, 1e-9);
  EXPECT_GT(multi, single - 0.05);
  EXPECT_LT(flattest, single - 0.2);
}

TEST(PlaneNormals, OnlyACloudWithLayersThickerThanAVoxelIsNoisy) {
  // 1 m x 1 m at 30k points / m^2: 1 mm of noise is a reconstruction's surface, 1.5 cm a raw
  // accumulated wall at 3 m. The 20 nearest neighbours of the thick layer lie ~8 mm (RMS) from
  // their plane, more than the 7 mm voxel, for most points; those of the thin one ~1 mm.
  std::mt19937 rng(12);
  const auto noisy = [&](double sigma) {
    PointCloud cloud;
    cloud.points = samplePlane({0, 0, 1}, 0.0, 0.5, 30000, sigma, rng);
    cloud.width = static_cast<std::uint32_t>(cloud.points.size());
    cloud.height = 1;
    std::vector<float> spread;
    bool is_noisy = false;
    estimateNormals(cloud, Config{}, nullptr, &spread, &is_noisy);
    EXPECT_EQ(is_noisy, isNoisyCloud(spread, Config{}));
    return is_noisy;
  };
  EXPECT_FALSE(noisy(0.001));
  EXPECT_TRUE(noisy(0.015));
  // Organised clouds are never noisy in this sense (no spread).
  EXPECT_FALSE(isNoisyCloud({}, Config{}));
}

TEST(PlaneSmoothing, ProjectionCollapsesDepthNoiseAndDropsOutliers) {
  // 1 m x 1 m of z = 0.5 at 40k points / m^2 with sigma = 8 mm (an accumulated room cloud at
  // 2-3 m), 50 flying points 6 cm above it. With k = 80 the local fit's error is about
  // sigma / sqrt(k) in offset plus its tilt over the ~1 cm lever: ~1.5 mm RMS, bound 0.25 sigma.
  std::mt19937 rng(5);
  const double sigma = 0.008;
  std::vector<Eigen::Vector3f> pts = samplePlane({0, 0, 1}, -0.5, 0.5, 40000, sigma, rng);
  std::uniform_real_distribution<double> uni(-0.4, 0.4);
  for (int i = 0; i < 50; ++i) pts.emplace_back(uni(rng), uni(rng), 0.56f);
  Config cfg;
  cfg.cloud_smooth_knn = 80;
  const std::vector<Eigen::Vector3f> out = projectToLocalPlanes(pts, cfg);
  ASSERT_EQ(out.size(), pts.size());
  double sum_sq = 0;
  int kept = 0;
  for (std::size_t i = 0; i < 40000; ++i) {
    if (!out[i].allFinite()) continue;
    sum_sq += (out[i].z() - 0.5) * (out[i].z() - 0.5);
    ++kept;
  }
  EXPECT_GT(kept, 0.97 * 40000);  // |d| > 2.5 rms drops ~1.2 % of a Gaussian
  EXPECT_LT(std::sqrt(sum_sq / kept), 0.25 * sigma);
  for (std::size_t i = 40000; i < pts.size(); ++i) EXPECT_FALSE(out[i].allFinite()) << i;

  // An exact surface keeps every point where it is; k = 0 copies.
  std::vector<Eigen::Vector3f> exact = samplePlane({0, 0, 1}, -0.5, 0.5, 5000, 0.0, rng);
  const std::vector<Eigen::Vector3f> same = projectToLocalPlanes(exact, cfg);
  for (std::size_t i = 0; i < exact.size(); ++i) {
    ASSERT_TRUE(same[i].allFinite()) << i;
    EXPECT_LT((same[i] - exact[i]).norm(), 1e-5) << i;
  }
  cfg.cloud_smooth_knn = 0;
  EXPECT_EQ(projectToLocalPlanes(pts, cfg), pts);
}

TEST(PlaneNormals, OrganisedWindowNormalsPointToTheSensorAndSkipHoles) {
  // A 160x120 depth image (f = 130 px) of a tilted plane ~1.5 m away, 0.5 mm noise along the
  // ray, with a hole. Pixel pitch ~1.2 cm, so the window is the minimum 5x5 (3x3 in corners).
  // Slope error ~ sigma / (rms lever arm * sqrt(n)): 0.5 mm / (1.6 cm * 5) ~ 0.4 deg inside,
  // ~1 deg in corners; the bounds allow the tails of 19k samples.
  std::mt19937 rng(2);
  std::normal_distribution<double> noise(0.0, 0.0005);
  PointCloud cloud;
  cloud.width = 160;
  cloud.height = 120;
  const Eigen::Vector3d n_true = Eigen::Vector3d(0.2, -0.3, -1).normalized();  // toward camera
  const double d_true = 1.5;  // the camera (origin) is on the positive side
  for (int r = 0; r < 120; ++r) {
    for (int c = 0; c < 160; ++c) {
      const Eigen::Vector3d ray((c - 79.5) / 130.0, (r - 59.5) / 130.0, 1.0);
      const double t = -d_true / n_true.dot(ray);
      const bool hole = r > 50 && r < 60 && c > 70 && c < 90;
      cloud.points.push_back(hole ? Eigen::Vector3f(kNaN, kNaN, kNaN)
                                  : ((t + noise(rng)) * ray).cast<float>());
    }
  }
  const std::vector<Eigen::Vector3f> normals = estimateNormals(cloud, Config{});
  int checked = 0;
  double sum_sq = 0;
  for (int r = 0; r < 120; ++r) {
    for (int c = 0; c < 160; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * 160 + c;
      if (!cloud.points[i].allFinite()) {
        EXPECT_FALSE(normals[i].allFinite());
        continue;
      }
      ASSERT_TRUE(normals[i].allFinite()) << i;
      const double err = angleDeg(normals[i].cast<double>(), n_true);
      const bool border = r < 2 || c < 2 || r >= 118 || c >= 158;
      EXPECT_LT(err, border ? 6.0 : 3.0) << "pixel " << r << "," << c;
      sum_sq += err * err;
      ++checked;
    }
  }
  EXPECT_GT(checked, 18000);
  EXPECT_LT(std::sqrt(sum_sq / checked), 1.0);
}

TEST(PlaneErrors, EmptyAndAllNaNInputGiveEmptyResults) {
  Config cfg;
  PointCloud empty;
  EXPECT_TRUE(detectPlanes(empty, cfg).empty());
  EXPECT_TRUE(estimateNormals(empty, cfg).empty());
  EXPECT_TRUE(detectPlanesRansac({}, Eigen::Vector3d::Zero(), cfg).empty());

  PointCloud nan_cloud;
  nan_cloud.width = 64;
  nan_cloud.height = 48;
  nan_cloud.points.assign(64 * 48, Eigen::Vector3f(kNaN, kNaN, kNaN));
  const PlaneSegmentation seg = segmentPlanes(nan_cloud, cfg);
  EXPECT_TRUE(seg.planes.empty());
  EXPECT_EQ(seg.labels, std::vector<int>(64 * 48, -1));
  for (const Eigen::Vector3f& n : estimateNormals(nan_cloud, cfg)) EXPECT_FALSE(n.allFinite());
  EXPECT_TRUE(detectPlanesRansac(nan_cloud.points, Eigen::Vector3d::Zero(), cfg).empty());

  cfg.up_auto = true;
  cfg.up = Eigen::Vector3d(0, 0, 2);
  EXPECT_EQ(estimateUp(nan_cloud, cfg), Eigen::Vector3d(0, 0, 1));  // falls back to cfg.up
  EXPECT_TRUE(detectPlanes(nan_cloud, cfg).empty());
  PlaneTracker tracker(cfg);
  EXPECT_TRUE(tracker.integrate(nan_cloud.points, Eigen::Vector3d::Zero()).empty());
  EXPECT_TRUE(tracker.planes().empty());
  EXPECT_FALSE(tracker.up().has_value());
}

TEST(PlaneErrors, BadConfigAndInconsistentCloudThrowPlanesdfError) {
  Config cfg;
  cfg.normal_knn = 1;
  EXPECT_THROW(validatePlaneConfig(cfg), Error);
  try {
    detectPlanes(PointCloud{}, cfg);
    FAIL() << "expected planesdf::Error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), "config");
    EXPECT_NE(e.message().find("normal_knn"), std::string::npos);
  }
  cfg = Config{};
  cfg.up = Eigen::Vector3d::Zero();
  EXPECT_THROW(PlaneTracker{cfg}, Error);
  cfg = Config{};
  cfg.vmf_lambda_deg = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(validatePlaneConfig(cfg), Error);

  PointCloud broken;
  broken.points.assign(10, Eigen::Vector3f::Zero());
  broken.width = 4;
  broken.height = 3;  // 12 != 10
  EXPECT_THROW(detectPlanes(broken, Config{}), Error);
}

}  // namespace
}  // namespace planesdf
