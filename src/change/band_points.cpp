// The chunk boxes of a map's points (see band_points.hpp).

#include "band_points.hpp"

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <limits>
#include <mutex>

namespace planesdf::detail {
namespace {

/// The box of the finite points among points[b, e) (empty when there is none).
Eigen::AlignedBox3f finiteBox(const std::vector<Eigen::Vector3f>& points, std::size_t b,
                              std::size_t e) {
  Eigen::AlignedBox3f box;
#if defined(__SSE2__)
  // A point as 4 lanes (x, y, z and the next point's x, which is ignored); the array's last
  // point, whose fourth lane would lie past its end, is left to the scalar loop below.
  const std::size_t last = std::min(e, points.size() - 1);
  const float inf = std::numeric_limits<float>::infinity();
  __m128 lo = _mm_set1_ps(inf), hi = _mm_set1_ps(-inf);
  bool any = false;
  for (; b < last; ++b) {
    const __m128 p = _mm_loadu_ps(points[b].data());
    // Finite: x - x == 0 in the first three lanes (NaN and infinities give NaN).
    if ((_mm_movemask_ps(_mm_cmpeq_ps(_mm_sub_ps(p, p), _mm_setzero_ps())) & 7) != 7) continue;
    lo = _mm_min_ps(lo, p);
    hi = _mm_max_ps(hi, p);
    any = true;
  }
  if (any) {
    alignas(16) float l[4], h[4];
    _mm_store_ps(l, lo);
    _mm_store_ps(h, hi);
    box.extend(Eigen::Vector3f(l[0], l[1], l[2]));
    box.extend(Eigen::Vector3f(h[0], h[1], h[2]));
  }
#endif
  for (; b < e; ++b)
    if (points[b].allFinite()) box.extend(points[b]);
  return box;
}

}  // namespace

/// The chunk boxes of `points` held by `chunks` (computed on the first call), or nullptr when
/// `chunks` is null, made for other points, or built before points were added (a
/// ChangeDetector keeps the maps of an unchanged plane while the map's points grow).
const std::vector<Eigen::AlignedBox3f>* chunkBoxes(
    const std::shared_ptr<detail::PointChunks>& chunks,
    const std::vector<Eigen::Vector3f>& points) {
  if (!chunks || chunks->source != &points) return nullptr;
  std::call_once(chunks->once, [&] {
    auto& boxes = chunks->boxes;
    boxes.clear();
    for (std::size_t b = 0; b < points.size(); b += detail::kPointChunk)
      boxes.push_back(finiteBox(points, b, std::min(points.size(), b + detail::kPointChunk)));
    chunks->num_points = points.size();
  });
  return chunks->num_points == points.size() ? &chunks->boxes : nullptr;
}

/// The chunk boxes of the points `maps` was computed with, when those are `points`.
const std::vector<Eigen::AlignedBox3f>* chunkBoxes(const PlaneMaps& maps,
                                                   const std::vector<Eigen::Vector3f>& points) {
  return maps.points ? chunkBoxes(maps.points->chunks, points) : nullptr;
}

}  // namespace planesdf::detail
