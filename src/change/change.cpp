// The comparison of one registered plane pair: paper eq. 2 on the height maps, blobs, 3D
// validation, and the candidates with their points (see change.hpp, comparePlanePair).

#include "change_internal.hpp"

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <tuple>
#include <utility>

#include "../map/map_internal.hpp"
#include "../numeric.hpp"
#include "../parallel.hpp"
#include "band_filter.hpp"
#include "planesdf/error.hpp"

namespace planesdf {

namespace {

using detail::BandFilter;
using detail::maxHeight;
using detail::parallelFor;

constexpr double kNoReachLimit = std::numeric_limits<double>::infinity();
constexpr float kAbove = std::numeric_limits<float>::infinity();

double relDiff(double a, double b, double floor_value) {
  const double m = std::max({std::abs(a), std::abs(b), floor_value});
  return std::abs(a - b) / m;
}

/// Signature of a set of cells of a height map (heights > 0 count toward the volume).
ShapeSignature signatureOf(const HeightMap& hm, const std::vector<Eigen::Vector2i>& cells) {
  ShapeSignature s;
  s.cells = static_cast<int>(cells.size());
  if (cells.empty()) return s;
  const double a = hm.cell_size * hm.cell_size;
  std::vector<double> heights;
  heights.reserve(cells.size());
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& c : cells) {
    const double h = std::max(0.0, static_cast<double>(hm.at(c.x(), c.y())));
    heights.push_back(h);
    s.volume += a * h;
    mean += hm.cellCenter(c.x(), c.y());
  }
  mean /= static_cast<double>(cells.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& c : cells) {
    const Eigen::Vector2d d = hm.cellCenter(c.x(), c.y()) - mean;
    cov += d * d.transpose();
  }
  cov /= static_cast<double>(cells.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
  s.minor = std::sqrt(std::max(0.0, es.eigenvalues()(0)));
  s.major = std::sqrt(std::max(0.0, es.eigenvalues()(1)));
  s.area = a * static_cast<double>(cells.size());
  std::sort(heights.begin(), heights.end());
  s.max_height = heights.back();
  for (int q = 1; q <= 10; ++q) {
    const auto i = std::min(heights.size() - 1,
                            static_cast<std::size_t>(std::ceil(q / 10.0 * heights.size())) - 1);
    s.deciles.push_back(heights[i]);
  }
  return s;
}

void finishRegion(ChangeRegion& r, const TsdfVolume& vol, const Plane& plane) {
  r.bbox.setEmpty();
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const auto& v : r.voxels) {
    const Eigen::Vector3d w = plane.toWorld(vol.voxelCenter(v));
    r.bbox.extend(w);
    sum += w;
  }
  if (!r.voxels.empty()) r.centroid = sum / static_cast<double>(r.voxels.size());
}

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

/// How many measurements a surface rests on: the mean TSDF weight of the voxels at the height
/// map's surface (the largest of the three around it per column), over `cells` above the
/// object threshold (`blob`) and over the other observed cells of their box grown by `ring`
/// (`around`). A splat adds one to each voxel it reaches, so the weight counts the points within
/// a splat radius (design.md, "Thin support"). Both 0 when either set of cells is empty.
struct SurfaceSupport {
  double blob = 0.0, around = 0.0;
};

SurfaceSupport surfaceSupport(const TsdfVolume& vol, const HeightMap& hm, const Config& cfg,
                              const std::vector<Eigen::Vector2i>& cells, int ring) {
  Eigen::AlignedBox2i box;
  for (const Eigen::Vector2i& c : cells) box.extend(c);
  if (box.isEmpty()) return {};
  box.min() = (box.min().array() - ring).max(0);
  box.max() = (box.max().array() + ring).min(Eigen::Array2i(hm.width - 1, hm.height - 1));
  const int bw = box.sizes().x() + 1;
  const auto local = [&](int x, int y) {
    return static_cast<std::size_t>((y - box.min().y()) * bw + (x - box.min().x()));
  };
  std::vector<std::uint8_t> in_blob(static_cast<std::size_t>(bw) * (box.sizes().y() + 1), 0);
  for (const Eigen::Vector2i& c : cells) in_blob[local(c.x(), c.y())] = 1;
  const double vs = vol.voxelSize();
  const auto surfaceWeight = [&](int x, int y) {
    const int k = static_cast<int>(std::floor(hm.at(x, y) / vs));
    float w = 0.0f;
    for (int dk = -1; dk <= 1; ++dk)
      if (const TsdfVoxel* v = vol.voxel(Eigen::Vector3i(hm.i0 + x, hm.j0 + y, k + dk)))
        w = std::max(w, v->weight);
    return static_cast<double>(w);
  };
  double sum[2] = {0.0, 0.0};
  int count[2] = {0, 0};
  for (int y = box.min().y(); y <= box.max().y(); ++y)
    for (int x = box.min().x(); x <= box.max().x(); ++x) {
      const float h = hm.at(x, y);
      if (h == kUnobserved) continue;
      const int side = in_blob[local(x, y)] ? 0 : 1;
      if (side == 0 && !(h > cfg.h_obj)) continue;  // a grown cell on the support
      sum[side] += surfaceWeight(x, y);
      ++count[side];
    }
  if (count[0] == 0 || count[1] == 0) return {};
  return {sum[0] / count[0], sum[1] / count[1]};
}

/// Observed voxels of column (i, j) with centre height in [lo, hi].
void columnVoxels(const TsdfVolume& vol, int i, int j, double lo, double hi, float w_min,
                  std::vector<Eigen::Vector3i>& out) {
  const double vs = vol.voxelSize();
  const int k0 = static_cast<int>(std::ceil(lo / vs - 0.5));
  const int k1 = static_cast<int>(std::floor(hi / vs - 0.5));
  for (int k = k0; k <= k1; ++k) {
    const Eigen::Vector3i v(i, j, k);
    const TsdfVoxel* vox = vol.voxel(v);
    if (vox != nullptr && vox->weight > 0.0f && vox->weight >= w_min) out.push_back(v);
  }
}

/// A blob of `cells` cells, `top_cells` of them at the band's top and `top_on_top` of those
/// landing on or next to target cells at the top, is a structure passing through the band in both
/// maps (cfg.through_band_top, cfg.through_band_fraction).
bool throughBand(int top_cells, int top_on_top, int cells, const Config& cfg) {
  return top_cells > 0 && top_cells >= cfg.through_band_top * cells &&
         top_on_top >= cfg.through_band_fraction * top_cells;
}

/// Of the cells of the objects `labels` (label -> anything; cells per label in `label_cells`) of
/// `hm`, the fraction at or above `top`; 0 without objects.
double topFraction(const HeightMap& hm, const std::map<int, int>& labels,
                   const std::vector<std::vector<std::size_t>>& label_cells, float top) {
  std::size_t cells = 0, at_top = 0;
  for (const auto& entry : labels)
    for (const std::size_t c : label_cells[static_cast<std::size_t>(entry.first)]) {
      ++cells;
      if (hm.heights[c] >= top) ++at_top;
    }
  return cells > 0 ? static_cast<double>(at_top) / static_cast<double>(cells) : 0.0;
}

/// True when a cell of `hm` within `reach` cells (square) of `c` is at or above `top`.
bool topNear(const HeightMap& hm, const Eigen::Vector2i& c, int reach, float top) {
  for (int y = c.y() - reach; y <= c.y() + reach; ++y)
    for (int x = c.x() - reach; x <= c.x() + reach; ++x)
      if (hm.inBounds(x, y) && hm.at(x, y) != kUnobserved && hm.at(x, y) >= top) return true;
  return false;
}

/// Target height at the source cell centre mapped by T (nearest target cell); kUnobserved when
/// outside or unobserved. `cell` receives the target cell.
float targetHeight(const HeightMap& tgt, const Pose& T, const Eigen::Vector2d& uv, double h,
                   Eigen::Vector2i* cell) {
  const Eigen::Vector3d p = T * Eigen::Vector3d(uv.x(), uv.y(), h);
  const Eigen::Vector2i c = tgt.cellOf(p.head<2>());
  if (cell != nullptr) *cell = c;
  if (!tgt.inBounds(c.x(), c.y())) return kUnobserved;
  return tgt.at(c.x(), c.y());
}

/// The voxels of `vol` in [lo, hi] (global indices) as a new volume, where an unobserved voxel
/// above the surface of an observed height-map column gets its vertical distance to that surface
/// (capped at the truncation) with weight w_min: fusion allocates blocks only around surfaces and
/// a single view leaves voxels near silhouettes unobserved, but the height map knows the space
/// above an observed surface is empty (its 2.5D premise), and the 3D validation needs that free
/// space to tell "gone" from "unobserved".
/// Only the columns (i, j) of the box flagged in `need` (row-major over the box's x-y extent)
/// are filled: the validation reads the voxels near the blob only, and a thin blob's box can
/// span metres.
TsdfVolume completedRegion(const TsdfVolume& vol, const HeightMap& hm, const Eigen::Vector3i& lo,
                           const Eigen::Vector3i& hi, const std::vector<std::uint8_t>& need,
                           float w_min) {
  TsdfVolume out(vol.voxelSize(), vol.truncation());
  const double vs = vol.voxelSize();
  const double trunc = vol.truncation();
  const float w_fill = std::max(w_min, 1.0f);
  const int nx = hi.x() - lo.x() + 1;
  // Block by block: one lookup of the source block and, on the first voxel written, one
  // allocation of the output block; voxels in storage order (x fastest, then y, then z).
  const Eigen::Vector3i blo = TsdfVolume::blockOfVoxel(lo), bhi = TsdfVolume::blockOfVoxel(hi);
  // At most the blocks of the block columns holding a needed column, reserved at once.
  std::size_t columns_needed = 0;
  for (int by = blo.y(); by <= bhi.y(); ++by)
    for (int bx = blo.x(); bx <= bhi.x(); ++bx) {
      bool any = false;
      for (int j = std::max(lo.y(), by * kTsdfBlockSide);
           !any && j <= std::min(hi.y(), (by + 1) * kTsdfBlockSide - 1); ++j)
        for (int i = std::max(lo.x(), bx * kTsdfBlockSide);
             !any && i <= std::min(hi.x(), (bx + 1) * kTsdfBlockSide - 1); ++i)
          any = need[static_cast<std::size_t>(j - lo.y()) * nx + (i - lo.x())] != 0;
      columns_needed += any ? 1 : 0;
    }
  out.reserveBlocks(columns_needed * static_cast<std::size_t>(bhi.z() - blo.z() + 1));
  for (int bz = blo.z(); bz <= bhi.z(); ++bz)
    for (int by = blo.y(); by <= bhi.y(); ++by)
      for (int bx = blo.x(); bx <= bhi.x(); ++bx) {
        const Eigen::Vector3i b(bx, by, bz);
        const TsdfBlock* src_block = vol.findBlock(b);
        TsdfBlock* out_block = nullptr;
        const Eigen::Vector3i v0 = b * kTsdfBlockSide;
        for (int k = std::max(lo.z(), v0.z()); k <= std::min(hi.z(), v0.z() + kTsdfBlockSide - 1);
             ++k)
          for (int j = std::max(lo.y(), v0.y()); j <= std::min(hi.y(), v0.y() + kTsdfBlockSide - 1);
               ++j)
            for (int i = std::max(lo.x(), v0.x());
                 i <= std::min(hi.x(), v0.x() + kTsdfBlockSide - 1); ++i) {
              if (!need[static_cast<std::size_t>(j - lo.y()) * nx + (i - lo.x())]) continue;
              const Eigen::Vector3i v(i, j, k);
              const auto li = static_cast<std::size_t>(TsdfVolume::linearIndexInBlock(v));
              TsdfVoxel val = src_block != nullptr ? src_block->voxels[li] : TsdfVoxel{};
              if (!(val.weight > 0.0f && val.weight >= w_min)) {
                const int x = i - hm.i0, y = j - hm.j0;
                const bool col_known = hm.inBounds(x, y) && hm.observed(x, y);
                const double above =
                    (k + 0.5) * vs - (col_known ? static_cast<double>(hm.at(x, y)) : 0.0);
                if (col_known && above > 0.0) {
                  val = TsdfVoxel{static_cast<float>(std::min(above, trunc)), w_fill};
                } else if (val.weight <= 0.0f) {
                  continue;
                }
              }
              if (out_block == nullptr) out_block = &out.allocateBlock(b);
              out_block->voxels[li] = val;
            }
      }
  return out;
}

/// Flags the columns of the box [lo, hi] (row-major over its x-y extent) within `margin`
/// (Chebyshev) of one of `columns`.
std::vector<std::uint8_t> columnsNear(std::vector<Eigen::Vector2i> columns,
                                      const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                                      int margin) {
  const int nx = hi.x() - lo.x() + 1, ny = hi.y() - lo.y() + 1;
  std::vector<std::uint8_t> need(static_cast<std::size_t>(nx) * ny, 0);
  std::sort(columns.begin(), columns.end(), [](const Eigen::Vector2i& a, const Eigen::Vector2i& b) {
    return a.x() != b.x() ? a.x() < b.x() : a.y() < b.y();
  });
  columns.erase(std::unique(columns.begin(), columns.end()), columns.end());
  for (const Eigen::Vector2i& c : columns)
    for (int y = std::max(0, c.y() - lo.y() - margin);
         y <= std::min(ny - 1, c.y() - lo.y() + margin); ++y)
      for (int x = std::max(0, c.x() - lo.x() - margin);
           x <= std::min(nx - 1, c.x() - lo.x() + margin); ++x)
        need[static_cast<std::size_t>(y) * nx + x] = 1;
  return need;
}

/// Voxel bounding box of `voxels` grown by `margin`.
std::pair<Eigen::Vector3i, Eigen::Vector3i> voxelBox(const std::vector<Eigen::Vector3i>& voxels,
                                                     int margin) {
  Eigen::Vector3i lo = voxels.front(), hi = voxels.front();
  for (const auto& v : voxels) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  return {lo.array() - margin, hi.array() + margin};
}

/// The target voxel box covering the source box [lo, hi] mapped by T, grown by `margin`.
std::pair<Eigen::Vector3i, Eigen::Vector3i> mappedBox(const Eigen::Vector3i& lo,
                                                      const Eigen::Vector3i& hi, const Pose& T,
                                                      double vs, int margin) {
  Eigen::Vector3d mn = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d mx = -mn;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3d corner(((c & 1) ? hi.x() + 1 : lo.x()) * vs,
                                 ((c & 2) ? hi.y() + 1 : lo.y()) * vs,
                                 ((c & 4) ? hi.z() + 1 : lo.z()) * vs);
    const Eigen::Vector3d q = T * corner;
    mn = mn.cwiseMin(q);
    mx = mx.cwiseMax(q);
  }
  const Eigen::Vector3i a((mn / vs).array().floor().cast<int>() - margin);
  const Eigen::Vector3i b((mx / vs).array().floor().cast<int>() + margin);
  return {a, b};
}

}  // namespace

double shapeDistance(const ShapeSignature& a, const ShapeSignature& b) {
  if (a.cells == 0 || b.cells == 0) return std::numeric_limits<double>::infinity();
  const double cell = 0.007;  // floors keep tiny objects from dividing by ~0
  double d = relDiff(a.max_height, b.max_height, 0.02);
  d = std::max(d, relDiff(a.area, b.area, 4 * cell * cell));
  d = std::max(d, relDiff(a.volume, b.volume, 1e-6));
  d = std::max(d, relDiff(a.major, b.major, 2 * cell));
  d = std::max(d, relDiff(a.minor, b.minor, 2 * cell));
  const double hmax = std::max({a.max_height, b.max_height, 0.02});
  for (std::size_t i = 0; i < std::min(a.deciles.size(), b.deciles.size()); ++i)
    d = std::max(d, std::abs(a.deciles[i] - b.deciles[i]) / hmax);
  return d;
}

bool InPlaceMatch::same(const Config& cfg) const {
  return target_cells > 0 && overlap >= cfg.in_place_min_overlap &&
         shift <= cfg.in_place_shift_fraction * size && shape_distance < cfg.moved_shape_distance;
}

namespace {

/// The part of target object `label` that stands where a blob lands on a sliver of it (design.md,
/// "In place on structure"): its cells higher than delta_h above the structure (its median
/// height: most of a large object a blob covers a sliver of is the structure), 8-connected to
/// such cells under the footprint. Empty when the footprint holds none: it landed on structure.
std::vector<std::size_t> partStandingIn(const HeightMap& tgt, const ObjectMap& objects, int label,
                                        const std::vector<char>& mapped, double delta_h) {
  std::vector<float> heights;
  std::vector<std::size_t> seeds;
  for (std::size_t i = 0; i < objects.labels.size(); ++i) {
    if (objects.labels[i] != label) continue;
    heights.push_back(tgt.heights[i]);
    if (mapped[i] != 0) seeds.push_back(i);
  }
  if (heights.empty()) return {};
  const auto mid = heights.begin() + static_cast<std::ptrdiff_t>(heights.size() / 2);
  std::nth_element(heights.begin(), mid, heights.end());
  const float level = *mid + static_cast<float>(delta_h);
  Mask2D above = Mask2D::zeros(tgt);
  for (std::size_t i = 0; i < objects.labels.size(); ++i)
    above.cells[i] = objects.labels[i] == label && tgt.heights[i] > level ? 1 : 0;
  const Components cc = connectedComponents(above, 1, 8);
  std::vector<char> keep(cc.areas.size() + 1, 0);
  for (const std::size_t i : seeds) keep[static_cast<std::size_t>(cc.labels[i])] = 1;
  keep[0] = 0;  // seeds at or below the level
  std::vector<std::size_t> part;
  for (std::size_t i = 0; i < cc.labels.size(); ++i)
    if (keep[static_cast<std::size_t>(cc.labels[i])] != 0) part.push_back(i);
  return part;
}

}  // namespace

InPlaceMatch sameInPlace(const HeightMap& src, const std::vector<Eigen::Vector2i>& cells,
                         const HeightMap& tgt, const ObjectMap& tgt_objects, const Pose& T,
                         const Config& cfg) {
  InPlaceMatch m;
  if (cells.empty() || tgt.empty() || !tgt_objects.sameGeometry(tgt)) return m;
  // The blob's footprint in the target grid (distinct cells) and the objects it lands on, with
  // how many of their cells it lands on.
  std::vector<char> mapped(tgt.numCells(), 0);
  std::map<int, int> landed;
  for (const Eigen::Vector2i& c : cells) {
    const float h = src.at(c.x(), c.y());
    Eigen::Vector2i tc;
    targetHeight(tgt, T, src.cellCenter(c.x(), c.y()), std::max(0.0f, h), &tc);
    if (!tgt.inBounds(tc.x(), tc.y())) continue;
    const std::size_t i = tgt.index(tc.x(), tc.y());
    if (mapped[i] != 0) continue;
    mapped[i] = 1;
    const int label = tgt_objects.labels[i];
    if (label > 0) ++landed[label];
  }
  if (landed.empty()) return m;
  // Whole objects, but of a large one it lands on a sliver of, only the part standing there.
  std::vector<char> target(tgt.numCells(), 0);
  std::vector<char> is_label(static_cast<std::size_t>(tgt_objects.numObjects()) + 1, 0);
  const int large_cells = largeObjectCells(cfg, tgt.cell_size);
  for (const auto& [label, n] : landed) {
    if (!sliverOf(n, tgt_objects.object(label).area, cfg.blob_min_overlap, large_cells)) {
      is_label[static_cast<std::size_t>(label)] = 1;
      continue;
    }
    const std::vector<std::size_t> part =
        partStandingIn(tgt, tgt_objects, label, mapped, cfg.delta_h);
    if (part.empty()) is_label[static_cast<std::size_t>(label)] = 1;
    for (const std::size_t i : part) target[i] = 1;
  }
  std::vector<Eigen::Vector2i> obj_cells;
  Eigen::Vector2d c_obj = Eigen::Vector2d::Zero(), c_blob = Eigen::Vector2d::Zero();
  Eigen::AlignedBox2d box_obj, box_blob;
  int n_mapped = 0, common = 0;
  for (int y = 0; y < tgt.height; ++y)
    for (int x = 0; x < tgt.width; ++x) {
      const Eigen::Vector2d uv = tgt.cellCenter(x, y);
      const int label = tgt_objects.at(x, y);
      const bool in_obj = (label > 0 && is_label[static_cast<std::size_t>(label)] != 0) ||
                          target[tgt.index(x, y)] != 0;
      const bool in_blob = mapped[tgt.index(x, y)] != 0;
      if (in_obj) {
        obj_cells.emplace_back(x, y);
        c_obj += uv;
        box_obj.extend(uv);
      }
      if (in_blob) {
        ++n_mapped;
        c_blob += uv;
        box_blob.extend(uv);
      }
      if (in_obj && in_blob) ++common;
    }
  m.target_cells = static_cast<int>(obj_cells.size());
  const int n_union = n_mapped + m.target_cells - common;
  m.overlap = n_union > 0 ? static_cast<double>(common) / n_union : 0.0;
  m.shift = (c_blob / n_mapped - c_obj / m.target_cells).norm();
  // Box diagonals over cell centres, plus one cell (the cells' own extent).
  const Eigen::Vector2d one = Eigen::Vector2d::Constant(tgt.cell_size);
  m.size = std::min((box_blob.sizes() + one).norm(), (box_obj.sizes() + one).norm());
  m.shape_distance = shapeDistance(signatureOf(src, cells), signatureOf(tgt, obj_cells));
  return m;
}

namespace {

/// True when `blob`'s cells eroded by `cells` (square element) keep at least one cell.
bool hasCore(const Blob& blob, int cells) {
  GridGeometry g;
  g.width = blob.bbox_max.x() - blob.bbox_min.x() + 1;
  g.height = blob.bbox_max.y() - blob.bbox_min.y() + 1;
  g.cell_size = 1.0;
  if (g.width <= 2 * cells || g.height <= 2 * cells) return false;
  Mask2D m = Mask2D::zeros(g);
  for (const Eigen::Vector2i& c : blob.cells)
    m.set(c.x() - blob.bbox_min.x(), c.y() - blob.bbox_min.y());
  return erode(m, cells).count() > 0;
}

/// The cells of the source objects `labels` (`src`) and the target cells their centres map to
/// under T (`tgt`, unchecked), in the same order.
void mappedObjectCells(const HeightMap& hs, const ObjectMap& os, const std::vector<int>& labels,
                       const HeightMap& ht, const Pose& T, std::vector<Eigen::Vector2i>& src,
                       std::vector<Eigen::Vector2i>& tgt) {
  for (const int label : labels) {
    const ObjectInfo& o = os.object(label);
    for (int y = o.bbox_min.y(); y <= o.bbox_max.y(); ++y)
      for (int x = o.bbox_min.x(); x <= o.bbox_max.x(); ++x) {
        if (os.at(x, y) != label) continue;
        Eigen::Vector2i tc;
        targetHeight(ht, T, hs.cellCenter(x, y), std::max(0.0f, hs.at(x, y)), &tc);
        src.emplace_back(x, y);
        tgt.push_back(tc);
      }
  }
}

/// The cells of the objects `labels` of `os` that are not in `cells`, raster order per object.
std::vector<Eigen::Vector2i> objectCellsOutside(const ObjectMap& os, const std::vector<int>& labels,
                                                const std::vector<Eigen::Vector2i>& cells) {
  std::set<std::pair<int, int>> taken;
  for (const Eigen::Vector2i& c : cells) taken.emplace(c.x(), c.y());
  std::vector<Eigen::Vector2i> out;
  for (const int label : labels) {
    const ObjectInfo& o = os.object(label);
    for (int y = o.bbox_min.y(); y <= o.bbox_max.y(); ++y)
      for (int x = o.bbox_min.x(); x <= o.bbox_max.x(); ++x)
        if (os.at(x, y) == label && taken.count({x, y}) == 0) out.emplace_back(x, y);
  }
  return out;
}

/// How the source objects `labels` fit the target heights, in place and at the best shift up
/// to `max_shift` cells (design.md, "Small moves"). "Off" is the 90th percentile of the height
/// mismatch (capped at 5 cm) of the objects' interior cells (all four neighbours on them).
/// Cells the target did not observe at a shift are not compared; a shift comparing fewer than
/// 80 % of the cells is infinitely off. Empty (both infinite) for objects of `large_cells` or
/// more; the shifts are searched only when in place is more than `search_above` off.
struct ObjectFit {
  double in_place = std::numeric_limits<double>::infinity();
  double best = std::numeric_limits<double>::infinity();  ///< least off over the shifts
  int best_d2 = 0;                                        ///< squared shift of `best`, cells
};

ObjectFit fitObject(const HeightMap& hs, const ObjectMap& os, const std::vector<int>& labels,
                    const HeightMap& ht, const Pose& T, int large_cells, int max_shift,
                    double search_above) {
  ObjectFit fit;
  std::vector<Eigen::Vector2i> src, tgt;
  mappedObjectCells(hs, os, labels, ht, T, src, tgt);
  if (src.empty() || static_cast<int>(src.size()) >= large_cells) return fit;
  // Interior cells only: speckle and the outer ring of rim attached to an object do not move
  // with it.
  const auto onObjects = [&](int x, int y) {
    return hs.inBounds(x, y) &&
           std::find(labels.begin(), labels.end(), os.at(x, y)) != labels.end();
  };
  std::size_t n = 0;
  for (std::size_t i = 0; i < src.size(); ++i) {
    const int x = src[i].x(), y = src[i].y();
    if (!onObjects(x - 1, y) || !onObjects(x + 1, y) || !onObjects(x, y - 1) ||
        !onObjects(x, y + 1))
      continue;
    src[n] = src[i];
    tgt[n++] = tgt[i];
  }
  src.resize(n);
  tgt.resize(n);
  if (src.empty()) return fit;
  // A move by part of an object's size leaves most of its footprint on itself: the mismatch
  // that a tenth of the cells exceed.
  constexpr float kCap = 0.05f;
  std::vector<float> err;
  const auto misfit = [&](int dx, int dy) {
    err.clear();
    for (std::size_t i = 0; i < src.size(); ++i) {
      const int x = tgt[i].x() + dx, y = tgt[i].y() + dy;
      if (!ht.inBounds(x, y) || ht.at(x, y) == kUnobserved) continue;
      err.push_back(std::min(kCap, std::fabs(std::max(0.0f, hs.at(src[i].x(), src[i].y())) -
                                             std::max(0.0f, ht.at(x, y)))));
    }
    if (10 * err.size() < 8 * src.size()) return std::numeric_limits<double>::infinity();
    const auto q = err.begin() + static_cast<std::ptrdiff_t>(err.size() * 9 / 10);
    std::nth_element(err.begin(), q, err.end());
    return static_cast<double>(*q);
  };
  fit.in_place = fit.best = misfit(0, 0);
  if (!std::isfinite(fit.in_place) || fit.in_place <= search_above) return fit;
  for (int dy = -max_shift; dy <= max_shift; ++dy)
    for (int dx = -max_shift; dx <= max_shift; ++dx) {
      const double m = misfit(dx, dy);
      if (m < fit.best) {
        fit.best = m;
        fit.best_d2 = dx * dx + dy * dy;
      }
    }
  return fit;
}

/// True when `fit` is a small move: in place more than `h_obj` off (and comparable), best at a
/// shift of at least `min_shift` cells and there at most half as far off as in place.
bool isSmallMove(const ObjectFit& fit, int min_shift, double h_obj) {
  return std::isfinite(fit.in_place) && fit.in_place > h_obj &&
         fit.best_d2 >= min_shift * min_shift && fit.best <= 0.5 * fit.in_place;
}

/// The target objects standing inside the footprint of the source objects `labels` (together
/// smaller than `large_cells`): per target label, its cells the footprint covers, for those
/// covered at least half (design.md, "Replaced inside the footprint"). `covered` receives the
/// footprint's cells landing on them.
std::map<int, int> objectsInFootprint(const HeightMap& hs, const ObjectMap& os,
                                      const std::vector<int>& labels, const HeightMap& ht,
                                      const ObjectMap& ot, const Pose& T, int large_cells,
                                      std::vector<std::size_t>* covered) {
  std::vector<Eigen::Vector2i> src, tgt;
  mappedObjectCells(hs, os, labels, ht, T, src, tgt);
  if (src.empty() || static_cast<int>(src.size()) >= large_cells) return {};
  std::map<int, int> landed;
  std::vector<std::size_t> cells;
  for (const Eigen::Vector2i& tc : tgt) {
    if (!ht.inBounds(tc.x(), tc.y())) continue;
    const int t = ot.at(tc.x(), tc.y());
    if (t == 0) continue;
    ++landed[t];
    cells.push_back(ht.index(tc.x(), tc.y()));
  }
  for (auto it = landed.begin(); it != landed.end();)
    it = 2 * it->second >= ot.object(it->first).area ? std::next(it) : landed.erase(it);
  if (covered != nullptr)
    for (const std::size_t c : cells)
      if (landed.count(ot.labels[c]) > 0) covered->push_back(c);
  return landed;
}

/// What the blobs of one comparePlanePair call share: the two planes and their maps, the pair's
/// transform and the derived sizes.
struct PairScope {
  PairScope(const PlaneSdf& src_, const PlaneMaps& src_maps_, const PlaneSdf& tgt_,
            const PlaneMaps& tgt_maps_, const Pose& T_, const Config& cfg_)
      : src(src_),
        src_maps(src_maps_),
        tgt(tgt_),
        tgt_maps(tgt_maps_),
        T(T_),
        cfg(cfg_),
        validation(validationParams(cfg_)) {
    // Splatted maps need more scored key voxels (design.md, "3D verdicts").
    if (rim_cells > 0) validation.min_scored = validation.min_scored_splatted;
  }

  const PlaneSdf& src;
  const PlaneMaps& src_maps;
  const PlaneSdf& tgt;
  const PlaneMaps& tgt_maps;
  const HeightMap& hs = src_maps.heights;
  const HeightMap& ht = tgt_maps.heights;
  const ObjectMap& os = src_maps.objects;
  const ObjectMap& ot = tgt_maps.objects;
  const Pose T;
  const Config& cfg;
  ValidationParams validation;
  /// Nonzero when either map was splatted (surfaceRimCells).
  const int rim_cells = std::max(src_maps.rim_cells, tgt_maps.rim_cells);
  const double vs = src.volume.voxelSize();
  const double trunc = src.volume.truncation();
  const double lo_flat = 0.5 * cfg.h_obj;
  /// Heights are capped at the fused band; a cell within two voxels of it reaches the top.
  const float band_top = static_cast<float>(cfg.fuse_band - 2.0 * vs);
  /// Shifts searched for a small move (design.md, "Small moves"): up to 6 cm.
  const int small_move_cells = static_cast<int>(std::ceil(0.06 / hs.cell_size));
  const int large_cells = largeObjectCells(cfg, ht.cell_size);
  /// The surfaces a blob's support is compared with: those within 10 cm of it.
  const int support_ring = static_cast<int>(std::ceil(0.10 / hs.cell_size));
  /// How wide the rim of a static object can come out in a change mask of splatted maps: the
  /// surface's placement (rim_cells) plus the mask's dilation.
  const int rim_width = rim_cells > 0 ? rim_cells + cfg.dilation_cells : 0;

  /// Per target object label, its cells (row-major indices, raster order), once needed.
  const std::vector<std::vector<std::size_t>>& targetLabelCells() const {
    if (!label_cells_.empty()) return label_cells_;
    label_cells_.resize(static_cast<std::size_t>(ot.numObjects()) + 1);
    for (std::size_t c = 0; c < ot.labels.size(); ++c)
      if (ot.labels[c] > 0) label_cells_[static_cast<std::size_t>(ot.labels[c])].push_back(c);
    return label_cells_;
  }

  /// Where the other map is flat, a column's points are a change only above that flat surface's
  /// own height: a shelf's back panel a centimetre in front of the wall is in both (design.md,
  /// "Event points").
  double pointFloor(const Eigen::Vector2i& c) const {
    const float h = targetHeight(ht, T, hs.cellCenter(c.x(), c.y()), 0.0, nullptr);
    return h == kUnobserved || h > cfg.h_obj ? lo_flat
                                             : std::max(lo_flat, static_cast<double>(h) + lo_flat);
  }

 private:
  mutable std::vector<std::vector<std::size_t>> label_cells_;
};

/// A cell of a candidate's columns with the index of its candidate and its height range (a few
/// cells of a large map: not arrays over the whole map). Blobs are disjoint, so no cell is
/// listed twice.
struct OwnedCell {
  int x, y;
  int owner;
  float lo, hi;
  float covered_lo;  ///< points from here to lo (hi when lo is kAbove) are covered points
};

/// What the candidates of one pair share as they are made.
struct PairState {
  std::vector<OwnedCell> owned;
  std::set<int> moved_labels;  ///< source objects a small move already reported whole
  std::set<int> whole_labels;  ///< source objects a candidate already took whole
  /// (target cell, candidate) of each candidate's target region, for its points.
  std::vector<std::pair<std::size_t, std::size_t>> target_region_cells;
};

/// A blob's columns: its voxels in the differing height range and what its cells land on.
struct BlobColumns {
  std::vector<Eigen::Vector3i> voxels;
  std::vector<OwnedCell> ranges;          ///< its columns' height ranges (owner set once accepted)
  std::map<int, int> target_labels;       ///< target object label -> blob cells landing on it
  std::vector<std::size_t> landed_cells;  ///< target cells (row-major) on an object it lands on
  int top_cells = 0;                      ///< cells at the band's top
  int top_on_top = 0;                     ///< of those, landing near target cells at the band's top
};

/// Walks the blob's cells: fills cand's columns and target columns, and returns the voxels and
/// height ranges of the columns the other map is lower in, and what the cells land on.
BlobColumns blobColumns(const PairScope& s, const Blob& blob, CandidateChange& cand) {
  // A column's top lands on, or next to, the other map's top column (design.md, "Structure
  // through the band").
  constexpr int top_reach = 1;
  const Config& cfg = s.cfg;
  BlobColumns out;
  for (const Eigen::Vector2i& c : blob.cells) {
    const float h_src = s.hs.at(c.x(), c.y());
    const Eigen::Vector2d uv = s.hs.cellCenter(c.x(), c.y());
    Eigen::Vector2i tc;
    const float h_tgt = targetHeight(s.ht, s.T, uv, std::max(0.0f, h_src), &tc);
    if (h_src >= s.band_top) {
      ++out.top_cells;
      if (topNear(s.ht, tc, top_reach, s.band_top)) ++out.top_on_top;
    }
    if (s.ht.inBounds(tc.x(), tc.y())) {
      cand.target_columns.emplace_back(s.ht.i0 + tc.x(), s.ht.j0 + tc.y());
      const int label = s.ot.at(tc.x(), tc.y());
      if (label > 0) {
        ++out.target_labels[label];
        out.landed_cells.push_back(s.ht.index(tc.x(), tc.y()));
      }
    }
    cand.region.columns.emplace_back(s.hs.i0 + c.x(), s.hs.j0 + c.y());
    if (!(h_src > cfg.h_obj)) continue;  // grown cell without an object height
    const double lo = (h_tgt != kUnobserved && h_tgt > cfg.h_obj)
                          ? static_cast<double>(h_tgt) + 0.5 * cfg.delta_h
                          : s.lo_flat;
    if (lo >= h_src) continue;  // the other map is as high here: this column did not change
    const double hi = static_cast<double>(h_src) + s.trunc;
    columnVoxels(s.src.volume, s.hs.i0 + c.x(), s.hs.j0 + c.y(), lo - s.vs, hi, cfg.w_min,
                 out.voxels);
    const double floor_c = s.pointFloor(c);
    out.ranges.push_back({c.x(), c.y(), -1, static_cast<float>(std::max(lo, floor_c)),
                          h_src + static_cast<float>(s.vs), static_cast<float>(floor_c)});
  }
  return out;
}

/// Fraction of the blob's cells landing on target objects it is not a sliver of: landing on a
/// sliver of a larger object (a panel the old object hid) is landing on structure, not on an
/// object that took its place (design.md, "Landing on structure").
double wholeObjectOverlap(const PairScope& s, const Blob& blob,
                          const std::map<int, int>& target_labels) {
  int on_whole_objects = 0;
  for (const auto& [label, landed] : target_labels)
    if (!sliverOf(landed, s.ot.object(label).area, s.cfg.blob_min_overlap, s.large_cells))
      on_whole_objects += landed;
  return blob.cells.empty() ? 0.0 : static_cast<double>(on_whole_objects) / blob.cells.size();
}

/// The 3D validation of a blob's voxels against the target (Unknown without voxels).
BlobValidation validateVoxels(const PairScope& s, const std::vector<Eigen::Vector3i>& voxels) {
  if (voxels.empty()) return BlobValidation{};
  // Key voxels need 3 voxels of observed neighbourhood (Hessians of their 3x3x3 neighbourhood,
  // 5x5x5 Sobel each); one more for the local-extremum test.
  constexpr int kMargin = 4;
  const auto [slo, shi] = voxelBox(voxels, kMargin);
  const auto [tlo, thi] = mappedBox(slo, shi, s.T, s.vs, kMargin);
  // The columns the validation reads: near the blob's voxels in the source, near where they map
  // to in the target.
  std::vector<Eigen::Vector2i> src_cols, tgt_cols;
  src_cols.reserve(voxels.size());
  tgt_cols.reserve(voxels.size());
  for (const Eigen::Vector3i& v : voxels) {
    src_cols.emplace_back(v.x(), v.y());
    const Eigen::Vector3i t = s.tgt.volume.voxelIndexAt(s.T * s.src.volume.voxelCenter(v));
    tgt_cols.emplace_back(t.x(), t.y());
  }
  const TsdfVolume sv =
      completedRegion(s.src.volume, s.hs, slo, shi,
                      columnsNear(std::move(src_cols), slo, shi, kMargin), s.cfg.w_min);
  const TsdfVolume tv =
      completedRegion(s.tgt.volume, s.ht, tlo, thi,
                      columnsNear(std::move(tgt_cols), tlo, thi, kMargin), s.cfg.w_min);
  return validateBlob(sv, tv, s.T, voxels, s.cfg, s.validation);
}

/// How an accepted blob is reported.
struct Acceptance {
  bool small_move = false;
  bool supporting = false;
};

/// Whether a validated blob is a candidate, by the rules after the 3D validation; nullopt when
/// it is not.
std::optional<Acceptance> accept(const PairScope& s, const Blob& blob, const BlobValidation& val,
                                 const BlobColumns& cols, const std::set<int>& moved_labels) {
  using Verdict = BlobValidation::Verdict;
  const Config& cfg = s.cfg;
  if (val.verdict == Verdict::Unchanged || cols.voxels.empty()) return std::nullopt;
  // Structure passing through the band in both maps (design.md, "Structure through the band").
  if (val.verdict != Verdict::Changed &&
      throughBand(cols.top_cells, cols.top_on_top, static_cast<int>(blob.cells.size()), cfg) &&
      topFraction(s.ht, cols.target_labels, s.targetLabelCells(), s.band_top) >=
          cfg.through_band_top)
    return std::nullopt;
  // In a splatted map, a sliver whose whole object fits the other map shifted by more than a rim
  // is a small move of that object (design.md, "Small moves"). A move's crescents are narrow
  // and score few key voxels: it needs the depth-fused count of them (verdict_min_scored, not
  // the splatted one), dissimilar.
  const bool some_3d = val.scored >= cfg.verdict_min_scored && val.mean_similarity < cfg.delta_blob;
  const bool shifted = blob.partial && s.rim_width > 0 && some_3d &&
                       isSmallMove(fitObject(s.hs, s.os, blob.object_labels, s.ht, s.T,
                                             s.large_cells, s.small_move_cells, cfg.h_obj),
                                   s.rim_width + 1, cfg.h_obj);
  // A sliver of a larger object (Blob::partial), or a blob smaller than the smallest change
  // cluster, is a change only on 3D evidence (verdict Changed) or as a small move: without it,
  // its height differences are edges and rims seen from other viewpoints.
  // A sliver with some 3D evidence and a core wider than a rim may be the part of an object
  // that another object does not cover: it supports an event another candidate makes on its
  // columns, never one of its own (design.md, "Supporting slivers").
  const bool supporting = blob.partial && s.rim_width > 0 && some_3d && !shifted &&
                          val.verdict != Verdict::Changed && hasCore(blob, s.rim_width);
  if ((blob.partial || blob.area < cfg.min_change_cells) && val.verdict != Verdict::Changed &&
      !shifted && !supporting)
    return std::nullopt;
  Acceptance a;
  a.supporting = supporting;
  // Otherwise a sliver no wider than a rim is a rim (design.md, "Slivers").
  if (blob.partial && s.rim_width > 0) {
    if (shifted) {
      // Another crescent of an object already reported whole.
      if (std::any_of(blob.object_labels.begin(), blob.object_labels.end(),
                      [&](int l) { return moved_labels.count(l) > 0; }))
        return std::nullopt;
      a.small_move = true;
    } else if (!hasCore(blob, s.rim_width)) {
      return std::nullopt;
    }
  }
  // In a splatted map, a blob must be a surface about as well supported by points as the
  // surfaces around it (design.md, "Thin support").
  if (s.rim_cells > 0 && cfg.thin_support_ratio > 0.0) {
    const SurfaceSupport d = surfaceSupport(s.src.volume, s.hs, cfg, blob.cells, s.support_ring);
    if (d.around > 0.0 && d.blob < cfg.thin_support_ratio * d.around) return std::nullopt;
  }
  return a;
}

/// Adds the blob's whole objects' columns, from the plane up, once per object (another sliver of
/// it joins the event that took it): to the region, or `as_covered` as covered points only,
/// which join when the objects it lands on are in an event too (design.md, "Changed objects
/// whole").
void takeWholeObject(const PairScope& s, const Blob& blob, bool as_covered, PairState& st,
                     ChangeRegion& reg, BlobColumns& cols, Mask2D& validated) {
  if (std::any_of(blob.object_labels.begin(), blob.object_labels.end(),
                  [&](int l) { return st.whole_labels.count(l) > 0; }))
    return;
  st.whole_labels.insert(blob.object_labels.begin(), blob.object_labels.end());
  for (const Eigen::Vector2i& c : objectCellsOutside(s.os, blob.object_labels, blob.cells)) {
    const float h = s.hs.at(c.x(), c.y());
    if (!(h > s.cfg.h_obj)) continue;
    const auto floor_c = static_cast<float>(s.pointFloor(c));
    const float top = h + static_cast<float>(s.vs);
    if (as_covered) {  // no region range: every point up to the top is covered
      cols.ranges.push_back({c.x(), c.y(), -1, kAbove, top, floor_c});
      continue;
    }
    reg.columns.emplace_back(s.hs.i0 + c.x(), s.hs.j0 + c.y());
    columnVoxels(s.src.volume, s.hs.i0 + c.x(), s.hs.j0 + c.y(), s.lo_flat - s.vs,
                 static_cast<double>(h) + s.trunc, s.cfg.w_min, cols.voxels);
    cols.ranges.push_back({c.x(), c.y(), -1, floor_c, top, floor_c});
    validated.set(c.x(), c.y());
  }
}

/// The target objects a candidate lands on, as a region of the target map, with their cells
/// (row-major, for their points): whole objects, but of an object it lands on a sliver of
/// (sliverOf: a shelf in a wall's band), only the cells it lands on.
std::vector<std::size_t> targetObjectRegion(const PairScope& s, const BlobColumns& cols,
                                            ChangeRegion& to) {
  const ObjectMap& ot = s.ot;
  to.plane_id = s.tgt.plane.id;
  std::vector<std::size_t> flat, partial;
  std::set<int> whole;
  for (const auto& [label, landed] : cols.target_labels) {
    if (!sliverOf(landed, ot.object(label).area, s.cfg.blob_min_overlap, s.large_cells)) {
      whole.insert(label);
      const auto& lc = s.targetLabelCells()[static_cast<std::size_t>(label)];
      flat.insert(flat.end(), lc.begin(), lc.end());
    }
  }
  for (const std::size_t c : cols.landed_cells)
    if (whole.count(ot.labels[c]) == 0) partial.push_back(c);
  std::sort(partial.begin(), partial.end());
  partial.erase(std::unique(partial.begin(), partial.end()), partial.end());
  flat.insert(flat.end(), partial.begin(), partial.end());
  std::sort(flat.begin(), flat.end());
  std::vector<Eigen::Vector2i> cells;
  cells.reserve(flat.size());
  for (const std::size_t i : flat)
    cells.emplace_back(static_cast<int>(i % static_cast<std::size_t>(ot.width)),
                       static_cast<int>(i / static_cast<std::size_t>(ot.width)));
  for (const auto& c : cells) {
    to.columns.emplace_back(ot.i0 + c.x(), ot.j0 + c.y());
    const float h = s.ht.at(c.x(), c.y());
    columnVoxels(s.tgt.volume, ot.i0 + c.x(), ot.j0 + c.y(), s.lo_flat - s.vs,
                 static_cast<double>(h) + s.trunc, s.cfg.w_min, to.voxels);
  }
  to.shape = signatureOf(s.ht, cells);
  finishRegion(to, s.tgt.volume, s.tgt.plane);
  return flat;
}

/// The candidate of one blob (index `idx` among the pair's), or nullopt when the rules reject
/// it; records its validation, in-place match and validated cells in `r`.
std::optional<CandidateChange> candidateOf(const PairScope& s, const Blob& blob, std::size_t idx,
                                           PairState& st, PlanePairResult& r) {
  CandidateChange cand;
  ChangeRegion& reg = cand.region;
  reg.plane_id = s.src.plane.id;
  cand.target_plane_id = s.tgt.plane.id;
  BlobColumns cols = blobColumns(s, blob, cand);
  cand.target_object_overlap = wholeObjectOverlap(s, blob, cols.target_labels);
  const BlobValidation val = validateVoxels(s, cols.voxels);
  r.validations.push_back(val);
  r.in_place.push_back(sameInPlace(s.hs, blob.cells, s.ht, s.ot, s.T, s.cfg));
  cand.same_in_place = r.in_place.back().same(s.cfg);
  const std::optional<Acceptance> a = accept(s, blob, val, cols, st.moved_labels);
  if (!a) return std::nullopt;
  cand.supporting = a->supporting;
  cand.small_move = a->small_move;
  // A small move reports its whole object, from where it stood to where it stands now.
  if (cand.small_move) {
    st.moved_labels.insert(blob.object_labels.begin(), blob.object_labels.end());
    takeWholeObject(s, blob, false, st, reg, cols, r.validated);
    cols.target_labels.clear();
    cols.landed_cells.clear();
  }
  // A sliver of an object that moved a little or whose loss has 3D evidence, with objects
  // standing inside the old footprint now: they replaced it, beside whatever the sliver's own
  // cells land on, and the whole old object is gone (design.md, "Replaced inside the
  // footprint").
  if (blob.partial && (cand.small_move || val.verdict == BlobValidation::Verdict::Changed)) {
    std::vector<std::size_t> covered;
    const std::map<int, int> inside = objectsInFootprint(s.hs, s.os, blob.object_labels, s.ht, s.ot,
                                                         s.T, s.large_cells, &covered);
    for (const auto& [label, cells] : inside)
      cols.target_labels[label] = std::max(cols.target_labels[label], cells);
    cols.landed_cells.insert(cols.landed_cells.end(), covered.begin(), covered.end());
    // Each of those objects stands at least half inside the object this sliver is part of: the
    // replacement is on the object's footprint, whatever of it the sliver's own cells hit.
    if (!inside.empty()) {
      cand.target_object_overlap = 1.0;
      takeWholeObject(s, blob, !cand.small_move, st, reg, cols, r.validated);
    }
  }

  for (const auto& c : blob.cells) r.validated.set(c.x(), c.y());
  reg.voxels = std::move(cols.voxels);
  reg.key_voxels = val.key_voxels;
  reg.scored = val.scored;
  reg.mean_similarity = val.mean_similarity;
  reg.verdict = val.verdict;
  reg.shape = signatureOf(s.hs, blob.cells);
  finishRegion(reg, s.src.volume, s.src.plane);
  for (OwnedCell rg : cols.ranges) {
    rg.owner = static_cast<int>(idx);
    st.owned.push_back(rg);
  }
  if (!cols.target_labels.empty())  // its points after the pair's blobs (addTargetRegionPoints)
    for (const std::size_t c : targetObjectRegion(s, cols, cand.target_object))
      st.target_region_cells.emplace_back(c, idx);
  return cand;
}

/// The target regions' points: those standing on a region's cell, from lo_flat to the cell's
/// height + one voxel, in input order (one pass over the target points for all candidates; a
/// cell of two candidates' regions gives its points to both).
void addTargetRegionPoints(const PairScope& s, const std::vector<Eigen::Vector3f>& target_points,
                           std::vector<std::pair<std::size_t, std::size_t>> region_cells,
                           std::vector<CandidateChange>& out) {
  if (region_cells.empty()) return;
  const HeightMap& ht = s.ht;
  std::sort(region_cells.begin(), region_cells.end());
  std::vector<std::uint8_t> in_region(ht.numCells(), 0);
  Eigen::AlignedBox2i box;
  for (const auto& [c, k] : region_cells) {
    in_region[c] = 1;
    box.extend(Eigen::Vector2i(static_cast<int>(c % static_cast<std::size_t>(ht.width)),
                               static_cast<int>(c / static_cast<std::size_t>(ht.width))));
  }
  forBandPointsIn(
      s.tgt.plane, ht, target_points, chunkBoxes(s.tgt_maps, target_points), s.cfg, box,
      [&](std::size_t c) { return in_region[c] != 0; },
      [&](std::size_t i, std::size_t c, double z) {
        if (!(z >= s.lo_flat && z <= static_cast<double>(ht.heights[c]) + s.vs)) return;
        auto it = std::lower_bound(region_cells.begin(), region_cells.end(),
                                   std::make_pair(c, std::size_t{0}));
        for (; it != region_cells.end() && it->first == c; ++it)
          out[it->second].target_object.points.push_back(target_points[i]);
      });
}

/// Per cell of the owned cells' box grown by a ring: the candidate whose points it holds (-1:
/// none) and their height ranges.
struct PointOwners {
  int bx0 = 0, by0 = 0, bx1 = -1, by1 = -1;
  std::size_t bw = 0;
  std::vector<int> owner;
  std::vector<float> lo, hi, covered_lo;
  std::size_t local(int x, int y) const {
    return static_cast<std::size_t>(y - by0) * bw + static_cast<std::size_t>(x - bx0);
  }
};

/// The owned cells and their rings of `ring` cells: each owned cell, in raster order, offers
/// itself to the unowned cells of its ring; a cell takes the first owner offered (the first
/// owned cell of its own ring in raster order) and the highest upper bound among that owner's
/// cells. A ring cell only covered-only cells (lo kAbove) offered themselves to is covered-only
/// too.
PointOwners pointOwners(const PairScope& s, std::vector<OwnedCell> owned, int ring) {
  std::sort(owned.begin(), owned.end(), [](const OwnedCell& a, const OwnedCell& b) {
    return std::tie(a.y, a.x) < std::tie(b.y, b.x);  // raster order
  });
  Eigen::AlignedBox2i box;
  for (const OwnedCell& o : owned) box.extend(Eigen::Vector2i(o.x, o.y));
  PointOwners p;
  p.bx0 = std::max(0, box.min().x() - ring);
  p.by0 = std::max(0, box.min().y() - ring);
  p.bx1 = std::min(s.hs.width - 1, box.max().x() + ring);
  p.by1 = std::min(s.hs.height - 1, box.max().y() + ring);
  p.bw = static_cast<std::size_t>(p.bx1 - p.bx0 + 1);
  const std::size_t box_cells = p.bw * static_cast<std::size_t>(p.by1 - p.by0 + 1);
  p.owner.assign(box_cells, -1);
  p.lo.assign(box_cells, 0.0f);
  p.hi.assign(box_cells, 0.0f);
  p.covered_lo.assign(box_cells, 0.0f);
  std::vector<std::uint8_t> is_owned(box_cells, 0);
  for (const OwnedCell& o : owned) {
    const std::size_t l = p.local(o.x, o.y);
    p.owner[l] = o.owner;
    p.lo[l] = o.lo;
    p.hi[l] = o.hi;
    p.covered_lo[l] = o.covered_lo;
    is_owned[l] = 1;
  }
  std::vector<std::uint8_t> ring_region(box_cells, 0);
  for (const OwnedCell& o : owned) {
    const int x0 = std::max(p.bx0, o.x - ring), x1 = std::min(p.bx1, o.x + ring);
    const int y0 = std::max(p.by0, o.y - ring), y1 = std::min(p.by1, o.y + ring);
    for (int ny = y0; ny <= y1; ++ny)
      for (int nx = x0; nx <= x1; ++nx) {
        const std::size_t l = p.local(nx, ny);
        if (is_owned[l]) continue;
        if (p.owner[l] < 0) {
          p.owner[l] = o.owner;
          p.lo[l] = p.covered_lo[l] = static_cast<float>(s.pointFloor(Eigen::Vector2i(nx, ny)));
          p.hi[l] = o.hi;
        } else if (p.owner[l] == o.owner) {
          p.hi[l] = std::max(p.hi[l], o.hi);
        } else {
          continue;
        }
        if (o.lo != kAbove) ring_region[l] = 1;
      }
  }
  for (std::size_t l = 0; l < box_cells; ++l)
    if (p.owner[l] >= 0 && !is_owned[l] && ring_region[l] == 0) p.lo[l] = kAbove;
  return p;
}

/// Points: the brief's "input points that fused into" the blobs' voxels. A point updates the voxels
/// within the truncation of its surface, so the points within truncation_voxels cells of a
/// blob's columns (with the neighbouring blob cell's upper bound, from the plane up: vertical
/// faces seen from the side) count too; a cell between two blobs goes to the first (in raster
/// order) of the owned cells within its ring. Appended in input order.
void addSourcePoints(const PairScope& s, const std::vector<Eigen::Vector3f>& source_points,
                     std::vector<OwnedCell> owned, std::vector<CandidateChange>& out) {
  if (owned.empty()) return;
  const PointOwners p = pointOwners(s, std::move(owned), std::max(0, s.cfg.truncation_voxels));
  const auto W = static_cast<std::size_t>(s.hs.width);
  const auto localOf = [&](std::size_t c) {  // a row-major cell of the map
    return p.local(static_cast<int>(c % W), static_cast<int>(c / W));
  };
  forBandPointsIn(
      s.src.plane, s.hs, source_points, chunkBoxes(s.src_maps, source_points), s.cfg,
      Eigen::AlignedBox2i(Eigen::Vector2i(p.bx0, p.by0), Eigen::Vector2i(p.bx1, p.by1)),
      [&](std::size_t c) { return p.owner[localOf(c)] >= 0; },
      [&](std::size_t i, std::size_t c, double z) {
        const std::size_t l = localOf(c);
        CandidateChange& to = out[static_cast<std::size_t>(p.owner[l])];
        if (z >= p.lo[l] && z <= p.hi[l]) {
          to.region.points.push_back(source_points[i]);
        } else if (z >= p.covered_lo[l] && z <= p.hi[l]) {  // below lo
          to.covered_points.push_back(source_points[i]);
        }
      });
}

}  // namespace

std::vector<CandidateChange> comparePlanePair(const PlaneSdf& src, const PlaneMaps& src_maps,
                                              const PlaneSdf& tgt, const PlaneMaps& tgt_maps,
                                              const PlaneMatch& match, bool refine_inplane,
                                              const std::vector<Eigen::Vector3f>& source_points,
                                              const std::vector<Eigen::Vector3f>& target_points,
                                              const Config& cfg, const DetectOptions& options,
                                              PlanePairResult* result) {
  PlanePairResult local;
  PlanePairResult& r = result != nullptr ? *result : local;
  r.match = match;
  if (refine_inplane)
    r.refinement = refineInPlane(src_maps.heights, src_maps.objects, tgt_maps.heights,
                                 tgt_maps.objects, r.match.T_target_source_local, cfg);
  const PairScope s(src, src_maps, tgt, tgt_maps, r.match.T_target_source_local, cfg);
  r.change = detectHeightChange(
      s.hs, s.ht, s.os, s.T, cfg, &tgt.volume,
      HeightTolerance{&src_maps.roughness, &tgt_maps.roughness, s.rim_cells,
                      tgt_maps.rim_cells > 0 ? tgt.volume.truncation() : kNoReachLimit,
                      cfg.fuse_band, s.rim_cells > 0});
  r.validations.clear();
  r.in_place.clear();
  r.validated = Mask2D::zeros(s.hs);
  PairState st;
  std::vector<CandidateChange> out;
  for (const Blob& blob : r.change.blobs)
    if (std::optional<CandidateChange> c = candidateOf(s, blob, out.size(), st, r))
      out.push_back(std::move(*c));
  addTargetRegionPoints(s, target_points, std::move(st.target_region_cells), out);
  addSourcePoints(s, source_points, std::move(st.owned), out);
  if (options.keep_stages) {
    r.source_heights = s.hs;
    r.target_heights = s.ht;
    r.source_objects = s.os;
  } else {
    r.source_heights = HeightMap{};
    r.target_heights = HeightMap{};
    r.source_objects = ObjectMap{};
    r.change = HeightChange{};
    r.validated = Mask2D{};
  }
  return out;
}

}  // namespace planesdf
