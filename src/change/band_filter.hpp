#pragma once
// The band pre-test and the height-map maximum shared by the plane maps' point bucketing and
// the pair comparison's point loops.

#include <algorithm>

#include <Eigen/Core>

#include "planesdf/height_map.hpp"
#include "planesdf/plane.hpp"

namespace planesdf::detail {

/// Cheap pre-test of the points a pair's point loops keep: height above `plane` (its local z)
/// within [lo, hi], with 1 mm of slack for rounding (the loops test exactly).
struct BandFilter {
  Eigen::Vector3d n;
  double d, lo, hi;
  BandFilter(const Plane& plane, double lo_h, double hi_h)
      : n(plane.frame_axes.col(2)),
        d(-plane.frame_axes.col(2).dot(plane.frame_origin)),
        lo(lo_h - 1e-3),
        hi(hi_h + 1e-3) {}
  bool operator()(const Eigen::Vector3f& p) const {
    const double h = n.dot(p.cast<double>()) + d;
    return h >= lo && h <= hi;
  }
};

/// Largest observed height of a height map (0 when none).
inline double maxHeight(const HeightMap& hm) {
  float m = 0.0f;
  for (const float h : hm.heights)
    if (h != kUnobserved) m = std::max(m, h);
  return static_cast<double>(m);
}

}  // namespace planesdf::detail
