#pragma once
// The band points of a plane pair's cells: one pass over a map's points with a single-precision
// pre-test, and the chunk boxes that let it skip the chunks a region's box does not meet (see
// comparePlanePair's point loops).

#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <vector>

#include "../map/map_internal.hpp"
#include "band_filter.hpp"
#include "change_internal.hpp"

namespace planesdf::detail {

/// The chunk boxes of `points` held by `chunks` (computed on the first call), or nullptr when
/// `chunks` is null, made for other points, or built before points were added (a
/// ChangeDetector keeps the maps of an unchanged plane while the map's points grow).
const std::vector<Eigen::AlignedBox3f>* chunkBoxes(const std::shared_ptr<PointChunks>& chunks,
                                                   const std::vector<Eigen::Vector3f>& points);

/// The chunk boxes of the points `maps` was computed with, when those are `points`.
const std::vector<Eigen::AlignedBox3f>* chunkBoxes(const PlaneMaps& maps,
                                                   const std::vector<Eigen::Vector3f>& points);

/// Calls f(i, c, z), in input order, for each point i of `points` that bucketBandPoints puts in
/// cell c (row-major) of `hm` (the plane's band, from half the object threshold to the map's
/// top plus one cell) when c lies in `box` (cells, inclusive) and want(c); z is the point's
/// height above the plane. A single-precision pre-test of the band and of the box's extent
/// (8 points at a time; its margin never drops a point the exact test keeps) leaves few points
/// to the exact test: a candidate's points cost one pass over the map's points, not the
/// bucketing of the whole band.
template <class Want, class F>
void forBandPointsIn(const Plane& plane, const HeightMap& hm,
                     const std::vector<Eigen::Vector3f>& points,
                     const std::vector<Eigen::AlignedBox3f>* chunks, const Config& cfg,
                     const Eigen::AlignedBox2i& box, Want&& want, F&& f) {
  if (hm.empty() || box.isEmpty() || points.empty()) return;
  const BandFilter in_band(plane, 0.5 * cfg.h_obj, maxHeight(hm) + hm.cell_size);
  // The box's cells grown by one, in plane-local metres.
  const double cs = hm.cell_size;
  const Eigen::Vector2d lo_uv((hm.i0 + box.min().x() - 1) * cs, (hm.j0 + box.min().y() - 1) * cs);
  const Eigen::Vector2d hi_uv((hm.i0 + box.max().x() + 2) * cs, (hm.j0 + box.max().y() + 2) * cs);
  // With chunk boxes: only the chunks that meet the world box of those cells and the band's
  // heights (grown by 1 mm).
  Eigen::AlignedBox3f region;
  if (chunks != nullptr) {
    for (int k = 0; k < 8; ++k) {
      const Eigen::Vector3d l((k & 1) ? hi_uv.x() : lo_uv.x(), (k & 2) ? hi_uv.y() : lo_uv.y(),
                              (k & 4) ? in_band.hi + 1e-3 : in_band.lo - 1e-3);
      region.extend(plane.toWorld(l).cast<float>());
    }
    region.min().array() -= 1e-3f;
    region.max().array() += 1e-3f;
  }
  // One band per pre-test: the heights, then u and v over the grown cells.
  const auto bandAlong = [&](int axis, double lo, double hi) {
    const Eigen::Vector3d n = plane.frame_axes.col(axis);
    return std::vector<detail::BandF>{{static_cast<float>(n.x()), static_cast<float>(n.y()),
                                       static_cast<float>(n.z()),
                                       static_cast<float>(-n.dot(plane.frame_origin)),
                                       static_cast<float>(lo), static_cast<float>(hi)}};
  };
  const std::vector<detail::BandF> bands[3] = {bandAlong(2, in_band.lo, in_band.hi),
                                               bandAlong(0, lo_uv.x(), hi_uv.x()),
                                               bandAlong(1, lo_uv.y(), hi_uv.y())};
  constexpr std::size_t kChunk = 512;
  alignas(64) std::uint8_t maybe[3][kChunk];
  static_assert(detail::kPointChunk % kChunk == 0, "pre-test chunks tile the point chunks");
  for (std::size_t begin = 0; begin < points.size(); begin += kChunk) {
    if (chunks != nullptr && !(*chunks)[begin / detail::kPointChunk].intersects(region)) {
      begin += detail::kPointChunk - kChunk - begin % detail::kPointChunk;  // the whole chunk
      continue;
    }
    const std::size_t m = std::min(kChunk, points.size() - begin);
    for (int b = 0; b < 3; ++b)
      detail::bandPretest(points[begin].data(), static_cast<int>(m), bands[b], maybe[b], cfg.simd);
    for (std::size_t k = 0; k < m; ++k) {
      if ((maybe[0][k] & maybe[1][k] & maybe[2][k]) == 0) continue;
      const std::size_t i = begin + k;
      if (!in_band(points[i])) continue;
      const Eigen::Vector3d l = plane.toLocal(points[i].cast<double>());
      const Eigen::Vector2i c = hm.cellOf(l.head<2>());
      if (!hm.inBounds(c.x(), c.y()) || !box.contains(c)) continue;
      const std::size_t cell = hm.index(c.x(), c.y());
      if (want(cell)) f(i, cell, l.z());
    }
  }
}

}  // namespace planesdf::detail
