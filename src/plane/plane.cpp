// Plane geometry: the plane frame, orientation classes, least-squares fits, config validation.

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>

#include "../numeric.hpp"
#include "plane_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/plane.hpp"

#ifdef _OPENMP
#endif

namespace planesdf {
namespace {

using detail::kPi;
double deg2rad(double deg) {
  return deg * kPi / 180.0;
}

// Unit vector, or `fallback` when `v` is (near) zero or not finite.
Eigen::Vector3d unitOr(const Eigen::Vector3d& v, const Eigen::Vector3d& fallback) {
  const double n = v.norm();
  if (!(n > 1e-12) || !std::isfinite(n)) return fallback;
  return v / n;
}

void require(bool ok, const std::string& message) {
  if (!ok) throw Error("config", message);
}

}  // namespace

// --- Plane ---------------------------------------------------------------------------------------

Pose Plane::frame() const {
  Pose pose = Pose::Identity();
  pose.linear() = frame_axes;
  pose.translation() = frame_origin;
  return pose;
}

Eigen::Vector3d Plane::toWorld(const Eigen::Vector3d& uvh) const {
  return frame_origin + frame_axes * uvh;
}

void Plane::extendExtent(const std::vector<Eigen::Vector3f>& points) {
  const Eigen::Vector3d eu = frame_axes.col(0);
  const Eigen::Vector3d ev = frame_axes.col(1);
  for (const Eigen::Vector3f& pf : points) {
    if (!pf.allFinite()) continue;
    const Eigen::Vector3d d = pf.cast<double>() - frame_origin;
    extent.extend(Eigen::Vector2d(eu.dot(d), ev.dot(d)));
  }
}

// --- geometry helpers ----------------------------------------------------------------------------

Eigen::Matrix3d planeAxes(const Eigen::Vector3d& normal, const Eigen::Vector3d& up) {
  const Eigen::Vector3d n = unitOr(normal, Eigen::Vector3d::UnitZ());
  const Eigen::Vector3d u_axis = unitOr(up, Eigen::Vector3d::UnitZ());
  Eigen::Vector3d x;
  Eigen::Vector3d y;
  if (std::abs(n.dot(u_axis)) < 0.7) {
    // Vertical-ish: v = up projected into the plane, u = v x n.
    y = (u_axis - u_axis.dot(n) * n).normalized();
    x = y.cross(n);
  } else {
    // Horizontal-ish: u = the world axis least aligned with up, projected into the plane.
    int axis = 0;
    u_axis.cwiseAbs().minCoeff(&axis);
    const Eigen::Vector3d r = Eigen::Vector3d::Unit(axis);
    x = unitOr(r - r.dot(n) * n, n.unitOrthogonal());
    y = n.cross(x);
  }
  Eigen::Matrix3d axes;
  axes.col(0) = x;
  axes.col(1) = y;
  axes.col(2) = n;
  return axes;
}

Plane makePlane(const Eigen::Vector3d& normal, double offset, const Eigen::Vector3d& anchor,
                const Eigen::Vector3d& up, int id) {
  Plane plane;
  const double len = normal.norm();
  plane.id = id;
  plane.normal = len > 1e-12 ? Eigen::Vector3d(normal / len) : Eigen::Vector3d::UnitZ();
  plane.offset = len > 1e-12 ? offset / len : offset;
  plane.frame_axes = planeAxes(plane.normal, up);
  plane.frame_origin = anchor - plane.signedDistance(anchor) * plane.normal;
  return plane;
}

void updatePlaneGeometry(Plane& plane, const Eigen::Vector3d& normal, double offset) {
  const double len = normal.norm();
  if (!(len > 1e-12) || !std::isfinite(len) || !std::isfinite(offset)) return;
  const Eigen::Vector3d n = normal / len;
  const Eigen::Quaterniond turn = Eigen::Quaterniond::FromTwoVectors(plane.frame_axes.col(2), n);
  Eigen::Matrix3d axes = turn.toRotationMatrix() * plane.frame_axes;
  // Re-orthonormalise (keeps column 2 exactly the normal).
  axes.col(2) = n;
  axes.col(0) = (axes.col(0) - axes.col(0).dot(n) * n).normalized();
  axes.col(1) = n.cross(axes.col(0));
  plane.normal = n;
  plane.offset = offset / len;
  plane.frame_axes = axes;
  plane.frame_origin -= plane.signedDistance(plane.frame_origin) * n;
}

std::optional<Plane::Orientation> classifyOrientation(const Eigen::Vector3d& normal,
                                                      const Eigen::Vector3d& up,
                                                      double tolerance_deg) {
  const double c =
      std::abs(unitOr(normal, Eigen::Vector3d::Zero()).dot(unitOr(up, Eigen::Vector3d::UnitZ())));
  const double tol = deg2rad(tolerance_deg);
  if (c >= std::cos(tol)) return Plane::Orientation::Horizontal;
  if (c <= std::sin(tol)) return Plane::Orientation::Vertical;
  return std::nullopt;
}

bool fitPlaneLeastSquares(const std::vector<Eigen::Vector3f>& points, Eigen::Vector3d& normal,
                          double& offset) {
  return detail::fitPlanePca(points, detail::validIndices(points), normal, offset);
}

std::optional<Eigen::Vector3d> sensorOrigin(const PointCloud& cloud) {
  if (cloud.isOrganized() || cloud.sensor_pose.matrix() != Pose::Identity().matrix()) {
    return cloud.sensor_pose.translation();
  }
  return std::nullopt;
}

void validatePlaneConfig(const Config& c) {
  require(c.up.allFinite() && c.up.norm() > 1e-9, "up must be a finite non-zero vector");
  require(c.ransac_inlier_dist > 0.0, "ransac_inlier_dist must be > 0");
  require(c.ransac_min_inlier_frac > 0.0 && c.ransac_min_inlier_frac <= 1.0,
          "ransac_min_inlier_frac must be in (0, 1]");
  require(c.ransac_min_horizontal_frac > 0.0 && c.ransac_min_horizontal_frac <= 1.0,
          "ransac_min_horizontal_frac must be in (0, 1]");
  require(c.ransac_iterations >= 1, "ransac_iterations must be >= 1");
  require(c.ransac_max_planes_per_frame >= 0, "ransac_max_planes_per_frame must be >= 0");
  require(c.ransac_max_samples >= 3, "ransac_max_samples must be >= 3");
  require(c.track_pixel_stride >= 1 && c.track_pixel_stride <= 64,
          "track_pixel_stride must be in [1, 64]");
  require(c.plane_merge_angle_deg > 0.0 && c.plane_merge_angle_deg < 90.0,
          "plane_merge_angle_deg must be in (0, 90)");
  require(c.plane_merge_offset >= 0.0, "plane_merge_offset must be >= 0");
  require(c.plane_merge_extent_gap >= 0.0, "plane_merge_extent_gap must be >= 0");
  require(c.plane_merge_coplanar >= 0.0, "plane_merge_coplanar must be >= 0");
  require(c.plane_min_extent >= 0.0, "plane_min_extent must be >= 0");
  require(c.plane_min_width >= 0.0, "plane_min_width must be >= 0");
  require(c.plane_reservoir_size >= 3, "plane_reservoir_size must be >= 3");
  require(c.normal_knn >= 3, "normal_knn must be >= 3");
  require(c.normal_fit_points >= 3, "normal_fit_points must be >= 3");
  require(c.normal_window >= 0.0, "normal_window must be >= 0");
  require(c.vmf_lambda_deg > 0.0 && c.vmf_lambda_deg < 90.0, "vmf_lambda_deg must be in (0, 90)");
  require(c.offset_split > 0.0, "offset_split must be > 0");
  require(c.min_plane_support >= 3, "min_plane_support must be >= 3");
  require(c.plane_connect_cell >= 0.0, "plane_connect_cell must be >= 0");
  require(c.orientation_tolerance_deg >= 0.0 && c.orientation_tolerance_deg < 45.0,
          "orientation_tolerance_deg must be in [0, 45)");
  require(c.refine_loss_scale > 0.0, "refine_loss_scale must be > 0");
  require(c.refine_min_new_inliers >= 1, "refine_min_new_inliers must be >= 1");
  require(c.refine_max_points >= 3, "refine_max_points must be >= 3");
  require(c.threads >= 0, "threads must be >= 0");
}

// --- internal helpers ----------------------------------------------------------------------------

namespace detail {

std::vector<std::uint32_t> validIndices(const std::vector<Eigen::Vector3f>& points) {
  std::vector<std::uint32_t> out;
  out.reserve(points.size());
  const float* xyz = xyzData(points);
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (finite3(xyz + 3 * i)) out.push_back(static_cast<std::uint32_t>(i));
  }
  return out;
}

std::vector<std::uint32_t> evenSubsample(const std::vector<std::uint32_t>& indices,
                                         std::size_t max_count) {
  if (indices.size() <= max_count) return indices;
  std::vector<std::uint32_t> out(max_count);
  const double step = static_cast<double>(indices.size()) / static_cast<double>(max_count);
  for (std::size_t i = 0; i < max_count; ++i) {
    out[i] = indices[static_cast<std::size_t>(static_cast<double>(i) * step)];
  }
  return out;
}

Eigen::Vector3d centroidOf(const std::vector<Eigen::Vector3f>& points,
                           const std::vector<std::uint32_t>& indices) {
  const float* xyz = xyzData(points);
  double sx = 0.0, sy = 0.0, sz = 0.0;
  for (std::uint32_t i : indices) {
    sx += xyz[3 * i];
    sy += xyz[3 * i + 1];
    sz += xyz[3 * i + 2];
  }
  const Eigen::Vector3d sum(sx, sy, sz);
  return indices.empty() ? sum : Eigen::Vector3d(sum / static_cast<double>(indices.size()));
}

bool fitPlanePca(const std::vector<Eigen::Vector3f>& points,
                 const std::vector<std::uint32_t>& indices, Eigen::Vector3d& normal,
                 double& offset) {
  if (indices.size() < 3) return false;
  const Eigen::Vector3d c = centroidOf(points, indices);
  const float* xyz = xyzData(points);
  double xx = 0, xy = 0, xz = 0, yy = 0, yz = 0, zz = 0;
  for (std::uint32_t i : indices) {
    const double x = xyz[3 * i] - c.x();
    const double y = xyz[3 * i + 1] - c.y();
    const double z = xyz[3 * i + 2] - c.z();
    xx += x * x;
    xy += x * y;
    xz += x * z;
    yy += y * y;
    yz += y * z;
    zz += z * z;
  }
  Eigen::Matrix3d cov;
  cov << xx, xy, xz, xy, yy, yz, xz, yz, zz;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
  if (es.info() != Eigen::Success) return false;
  const Eigen::Vector3d ev = es.eigenvalues();
  // Collinear points: the two smallest eigenvalues both vanish.
  if (!(ev(1) > 1e-12 * std::max(ev(2), 1e-300))) return false;
  normal = es.eigenvectors().col(0).normalized();
  offset = -normal.dot(c);
  return normal.allFinite() && std::isfinite(offset);
}

void orientToward(Eigen::Vector3d& normal, double& offset, const Eigen::Vector3d& target) {
  if (normal.dot(target) + offset < 0.0) {
    normal = -normal;
    offset = -offset;
  }
}

Eigen::AlignedBox2d extentOf(const Plane& plane, const std::vector<Eigen::Vector3f>& points,
                             const std::vector<std::uint32_t>& indices) {
  Eigen::AlignedBox2d box;
  if (indices.empty()) return box;
  // Single precision relative to the frame origin (sub-micrometre for scenes of metres), with 8
  // independent min/max lanes so the loop vectorises.
  const Eigen::Vector3f eu = plane.frame_axes.col(0).cast<float>();
  const Eigen::Vector3f ev = plane.frame_axes.col(1).cast<float>();
  const Eigen::Vector3f o = plane.frame_origin.cast<float>();
  const float ux = eu.x(), uy = eu.y(), uz = eu.z(), vx = ev.x(), vy = ev.y(), vz = ev.z();
  const float ox = o.x(), oy = o.y(), oz = o.z();
  const float* xyz = xyzData(points);
  constexpr std::size_t kLanes = 8;
  const float inf = std::numeric_limits<float>::infinity();
  std::array<float, kLanes> ulo, uhi, vlo, vhi;
  ulo.fill(inf);
  vlo.fill(inf);
  uhi.fill(-inf);
  vhi.fill(-inf);
  const std::size_t m = indices.size();
  for (std::size_t i = 0; i < m; i += kLanes) {
    const std::size_t lanes = std::min(kLanes, m - i);
    for (std::size_t l = 0; l < lanes; ++l) {
      const float* p = xyz + 3 * indices[i + l];
      const float dx = p[0] - ox, dy = p[1] - oy, dz = p[2] - oz;
      const float u = ux * dx + uy * dy + uz * dz;
      const float v = vx * dx + vy * dy + vz * dz;
      ulo[l] = u < ulo[l] ? u : ulo[l];
      uhi[l] = u > uhi[l] ? u : uhi[l];
      vlo[l] = v < vlo[l] ? v : vlo[l];
      vhi[l] = v > vhi[l] ? v : vhi[l];
    }
  }
  box.extend(Eigen::Vector2d(*std::min_element(ulo.begin(), ulo.end()),
                             *std::min_element(vlo.begin(), vlo.end())));
  box.extend(Eigen::Vector2d(*std::max_element(uhi.begin(), uhi.end()),
                             *std::max_element(vhi.begin(), vhi.end())));
  return box;
}

Plane planeFromInliers(const Eigen::Vector3d& normal, double offset,
                       const std::vector<Eigen::Vector3f>& points,
                       const std::vector<std::uint32_t>& inliers, const Eigen::Vector3d& up) {
  Plane plane = makePlane(normal, offset, centroidOf(points, inliers), up);
  plane.support = inliers.size();
  plane.extent = extentOf(plane, points, inliers);
  return plane;
}

std::vector<Eigen::Vector3f> gatherPoints(const std::vector<Eigen::Vector3f>& points,
                                          const std::vector<std::uint32_t>& indices,
                                          std::size_t max_count) {
  const std::vector<std::uint32_t> pick = evenSubsample(indices, max_count);
  std::vector<Eigen::Vector3f> out;
  out.reserve(pick.size());
  for (std::uint32_t i : pick) out.push_back(points[i]);
  return out;
}

}  // namespace detail
}  // namespace planesdf
