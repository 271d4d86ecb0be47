// PlaneSDF registration (paper §III-B); see registration.hpp. The in-plane refinement is in
// inplane_refinement.cpp.

#include "planesdf/registration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "../numeric.hpp"
#include "planesdf/error.hpp"

namespace planesdf {
namespace {

using detail::kPi;

void validateRegistrationConfig(const Config& cfg) {
  if (!(cfg.delta_n >= -1.0 && cfg.delta_n <= 1.0)) {
    throw Error("config", "delta_n must be in [-1, 1], got " + std::to_string(cfg.delta_n));
  }
  if (!(cfg.delta_d >= 0.0) || !std::isfinite(cfg.delta_d)) {
    throw Error("config", "delta_d must be finite and >= 0, got " + std::to_string(cfg.delta_d));
  }
}

/// Smallest rotation taking unit `a` onto unit `b` (antiparallel: a half turn about an axis
/// orthogonal to a; never happens for matched planes since delta_n is checked first).
Eigen::Matrix3d minimalRotation(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return Eigen::Quaterniond::FromTwoVectors(a, b).toRotationMatrix();
}

}  // namespace

Eigen::Vector3d planeAnchor(const Plane& plane) {
  if (plane.extent.isEmpty()) return plane.frame_origin;
  const Eigen::Vector2d c = plane.extent.center();
  return plane.toWorld(Eigen::Vector3d(c.x(), c.y(), 0.0));
}

Pose planeCorrection(const Plane& source, const Plane& target) {
  const Eigen::Vector3d ns = source.normal.normalized();
  const Eigen::Vector3d nt = target.normal.normalized();
  const Eigen::Vector3d p = planeAnchor(source);
  const Eigen::Matrix3d R = minimalRotation(ns, nt);
  // C(x) = R (x - p) + p - n_t (n_t·p + d_t)
  Pose C = Pose::Identity();
  C.linear() = R;
  C.translation() = p - R * p - nt * target.signedDistance(p);
  return C;
}

Pose relativePlaneTransform(const Plane& source, const Plane& target) {
  Pose T =
      target.frame().inverse(Eigen::Isometry) * planeCorrection(source, target) * source.frame();
  // Exactly a yaw + in-plane shift (removes rounding in the h row / column).
  Eigen::Matrix3d L = T.linear();
  const double yaw = std::atan2(L(1, 0), L(0, 0));
  T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation().z() = 0.0;
  return T;
}

std::vector<PlaneMatch> registerPlanes(const std::vector<Plane>& source,
                                       const std::vector<Plane>& target, const Config& cfg) {
  validateRegistrationConfig(cfg);
  std::vector<PlaneMatch> matches;
  for (std::size_t i = 0; i < source.size(); ++i) {
    const Plane& s = source[i];
    const Eigen::Vector3d ns = s.normal.normalized();
    const Eigen::Vector3d anchor = planeAnchor(s);
    bool found = false;
    PlaneMatch best;
    for (std::size_t j = 0; j < target.size(); ++j) {
      const Plane& t = target[j];
      const Eigen::Vector3d nt = t.normal.normalized();
      const double cosn = ns.dot(nt);
      if (!(cosn >= cfg.delta_n)) continue;
      const double gap = nt.dot(anchor) + t.offset / t.normal.norm();
      if (!(std::abs(gap) <= cfg.delta_d)) continue;
      const Pose T = relativePlaneTransform(s, t);
      double overlap = 0.0;
      if (!s.extent.isEmpty() && !t.extent.isEmpty()) {
        Eigen::AlignedBox2d carried;
        for (int k = 0; k < 4; ++k) {
          const Eigen::Vector2d c =
              s.extent.corner(static_cast<Eigen::AlignedBox2d::CornerType>(k));
          carried.extend((T * Eigen::Vector3d(c.x(), c.y(), 0.0)).head<2>());
        }
        Eigen::AlignedBox2d grown = t.extent;
        grown.min().array() -= kRegistrationExtentMargin;
        grown.max().array() += kRegistrationExtentMargin;
        const Eigen::AlignedBox2d inter = carried.intersection(grown);
        if (inter.isEmpty()) continue;
        overlap = inter.sizes().prod();
      }
      const bool better =
          !found || overlap > best.overlap + 1e-9 ||
          (overlap >= best.overlap - 1e-9 && std::abs(gap) < std::abs(best.offset_gap));
      if (better) {
        found = true;
        best.source_id = s.id >= 0 ? s.id : static_cast<int>(i);
        best.target_id = t.id >= 0 ? t.id : static_cast<int>(j);
        best.T_target_source_local = T;
        best.cos_normal = cosn;
        best.offset_gap = gap;
        best.overlap = overlap;
      }
    }
    if (found) matches.push_back(best);
  }
  return matches;
}

bool duplicateOf(const Plane& b, const Plane& a, const Config& cfg) {
  if (a.id == b.id || a.orientation != b.orientation || a.extent.isEmpty() || b.extent.isEmpty())
    return false;
  if (a.normal.dot(b.normal) < std::cos(cfg.plane_merge_angle_deg * kPi / 180.0)) return false;
  if (std::abs(a.signedDistance(planeAnchor(b))) > 2.0 * cfg.ransac_inlier_dist) return false;
  if (b.support > a.support || (b.support == a.support && b.id < a.id)) return false;
  Eigen::AlignedBox2d carried;  // b's extent in a's frame
  for (int k = 0; k < 4; ++k) {
    const Eigen::Vector2d c = b.extent.corner(static_cast<Eigen::AlignedBox2d::CornerType>(k));
    carried.extend(a.toLocal(b.toWorld(Eigen::Vector3d(c.x(), c.y(), 0.0))).head<2>());
  }
  const Eigen::AlignedBox2d inside = carried.intersection(a.extent);
  return !inside.isEmpty() && inside.sizes().prod() >= 0.5 * b.extent.sizes().prod();
}

namespace {

/// The planes of `map` that are no duplicate of another of its planes.
std::vector<Plane> distinctPlanes(const Map& map, const Config& cfg) {
  std::vector<Plane> out;
  for (const PlaneSdf& b : map.planes()) {
    bool duplicate = false;
    for (const PlaneSdf& a : map.planes())
      duplicate = duplicate || duplicateOf(b.plane, a.plane, cfg);
    if (!duplicate) out.push_back(b.plane);
  }
  return out;
}

}  // namespace

std::vector<PlaneMatch> registerPlanes(const Map& source, const Map& target, const Config& cfg) {
  return registerPlanes(distinctPlanes(source, cfg), distinctPlanes(target, cfg), cfg);
}

}  // namespace planesdf
