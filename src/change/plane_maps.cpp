// The maps of one plane for the comparison: height and object maps of its band, what the other
// planes of the map claim of that band, roughness, and its band points by cell (see change.hpp,
// computePlaneMaps).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <mutex>
#include <utility>
#include <vector>

#include "../numeric.hpp"
#include "band_filter.hpp"
#include "change_internal.hpp"

namespace planesdf {
namespace {

using detail::BandFilter;
using detail::maxHeight;

}  // namespace

CellPoints bucketBandPoints(const Plane& plane, const HeightMap& heights,
                            const std::vector<Eigen::Vector3f>& points, const Config& cfg) {
  CellPoints cp;
  cp.num_points = points.size();
  cp.start.assign(heights.numCells() + 1, 0);
  if (heights.empty()) return cp;
  const BandFilter in_band(plane, 0.5 * cfg.h_obj, maxHeight(heights) + heights.cell_size);
  // (point, cell) in input order; a buffer per thread, reused: maps hold millions of points.
  thread_local std::vector<std::pair<std::uint32_t, std::uint32_t>> scratch;
  auto& hits = scratch;
  hits.clear();
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!in_band(points[i])) continue;
    const Eigen::Vector3d l = plane.toLocal(points[i].cast<double>());
    const Eigen::Vector2i c = heights.cellOf(l.head<2>());
    if (heights.inBounds(c.x(), c.y()))
      hits.emplace_back(static_cast<std::uint32_t>(i),
                        static_cast<std::uint32_t>(heights.index(c.x(), c.y())));
  }
  // Counting sort by cell (stable: input order within a cell).
  for (const auto& h : hits) ++cp.start[h.second + 1];
  for (std::size_t c = 1; c < cp.start.size(); ++c) cp.start[c] += cp.start[c - 1];
  cp.index.resize(hits.size());
  std::vector<std::uint32_t> next(cp.start.begin(), cp.start.end() - 1);
  for (const auto& h : hits) cp.index[next[h.second]++] = h.first;
  if (hits.capacity() > (std::size_t{64} << 20)) hits = {};  // keep at most 512 MiB
  return cp;
}

namespace {

/// True when the extents of two parallel planes overlap, seen along the normal of `a`.
bool extentsOverlap(const Plane& a, const Plane& b) {
  Eigen::AlignedBox2d carried;
  for (int k = 0; k < 4; ++k) {
    const Eigen::Vector2d c = b.extent.corner(static_cast<Eigen::AlignedBox2d::CornerType>(k));
    carried.extend(a.toLocal(b.toWorld(Eigen::Vector3d(c.x(), c.y(), 0.0))).head<2>());
  }
  return !carried.intersection(a.extent).isEmpty();
}

/// A part of a plane's band that another plane of the map claims: points at a height above
/// `owner` in [lo, hi] whose in-plane position (owner's frame) lies in `box`.
struct Claim {
  const Plane* owner = nullptr;
  double lo = 0.0, hi = 0.0;
  Eigen::AlignedBox2d box;
};

Eigen::AlignedBox2d grown(const Eigen::AlignedBox2d& b, double margin) {
  return {b.min().array() - margin, b.max().array() + margin};
}

/// Height over horizontal `q` up to which a wall's band leaves what is above q to q: its band,
/// or, when another horizontal plane over q's extent lies at most twice the band above it, up to
/// that plane's slab (design.md, "A shelf's compartment is its board's"). The strip between the
/// band's top and the next board holds only the tips of q's tall objects and the shelf's back.
double compartmentTop(const Plane& q, const std::vector<PlaneSdf>& map_planes, const Config& cfg) {
  const Eigen::Vector3d origin = q.toWorld(Eigen::Vector3d::Zero());
  double next = std::numeric_limits<double>::infinity();
  for (const PlaneSdf& ps : map_planes) {
    const Plane& r = ps.plane;
    if (r.id == q.id || r.extent.isEmpty() || r.orientation != Plane::Orientation::Horizontal ||
        r.normal.dot(q.normal) < cfg.ownership_parallel_cos)
      continue;
    const double above = -r.signedDistance(origin);
    if (above > cfg.fuse_band && above <= 2.0 * cfg.fuse_band && extentsOverlap(q, r))
      next = std::min(next, above);
  }
  return std::isfinite(next) ? std::max(cfg.fuse_band, next - detail::kMaxSlabThickness)
                             : cfg.fuse_band;
}

/// True when the cameras saw through vertical plane `q`: part of the extent of another vertical
/// plane facing within 45 degrees of it lies more than cfg.structure_behind behind it, and at
/// least as far inside q's extent as it is behind (a shelf's front, the coplanar edges of its
/// boards, with the wall behind the shelf; not a shelf's side, with a wall far behind it seen past
/// its edge). A wall of the room hides what is behind it (design.md, "Walls are opaque").
bool seenThrough(const Plane& q, const std::vector<PlaneSdf>& map_planes, const Config& cfg) {
  constexpr int kSamples = 9;  // per side of another plane's extent
  for (const PlaneSdf& ps : map_planes) {
    const Plane& w = ps.plane;
    if (w.id == q.id || w.extent.isEmpty() || w.orientation != Plane::Orientation::Vertical ||
        std::abs(w.normal.dot(q.normal)) < cfg.ownership_parallel_cos)
      continue;
    for (int i = 0; i < kSamples; ++i)
      for (int j = 0; j < kSamples; ++j) {
        const Eigen::Vector2d t(i / (kSamples - 1.0), j / (kSamples - 1.0));
        const Eigen::Vector2d uv = w.extent.min() + t.cwiseProduct(w.extent.sizes());
        const Eigen::Vector3d x = w.toWorld(Eigen::Vector3d(uv.x(), uv.y(), 0.0));
        const double behind = -q.signedDistance(x);
        if (behind <= cfg.structure_behind) continue;
        // At least `behind` inside q's extent: any ray to it within 45 degrees of q's normal
        // crosses q's extent.
        const Eigen::Vector2d local = q.toLocal(x).head<2>();
        if ((local.array() - q.extent.min().array()).minCoeff() >= behind &&
            (q.extent.max().array() - local.array()).minCoeff() >= behind)
          return true;
      }
  }
  return false;
}

/// What the other planes of the map claim of `plane`'s band (unknown there):
///  * the surface of a non-parallel plane (a wall in a table's band, a table in a wall's band) is
///    structure, within cfg.ownership_surface_distance of it; for room structure (a vertical
///    plane at least cfg.structure_min_extent long, not seenThrough) from cfg.structure_behind
///    behind to cfg.structure_front in front;
///  * what stands on a horizontal plane is that plane's object (design.md, "Ownership"): its
///    whole band, within its extent grown by cfg.support_margin, when `plane` is room structure
///    (a shelf's boards and what stands on them in the band of the wall behind, a box on the
///    floor by a wall), or when `plane` is horizontal and that one is a separate surface above
///    it (a desk a few cm above a lower desk's plane; not a box's top on this table); with
///    that plane's slab, up to detail::kMaxSlabThickness below it (a board's underside); on a
///    wall, up to the next board over it (compartmentTop);
///  * the underside of a horizontal plane over `plane` just above its band (up to
///    detail::kMaxSlabThickness below that plane), within that plane's extent: the next board
///    of a shelf.
std::vector<Claim> claimsOn(const Plane& plane, const std::vector<PlaneSdf>& map_planes,
                            const Config& cfg) {
  const auto isStructure = [&](const Plane& q) {
    return q.orientation == Plane::Orientation::Vertical &&
           q.extent.sizes().maxCoeff() >= cfg.structure_min_extent &&
           !seenThrough(q, map_planes, cfg);
  };
  const bool vertical = plane.orientation == Plane::Orientation::Vertical;
  const bool plane_is_structure = isStructure(plane);
  const Eigen::Vector3d origin = plane.toWorld(Eigen::Vector3d::Zero());
  std::vector<Claim> claims;
  for (const PlaneSdf& ps : map_planes) {
    const Plane& q = ps.plane;
    if (q.id == plane.id || q.extent.isEmpty()) continue;
    if (std::abs(q.normal.dot(plane.normal)) < cfg.ownership_parallel_cos) {
      const bool structure = isStructure(q);
      Eigen::AlignedBox2d box = grown(q.extent, cfg.ownership_extent_margin);
      // A wall goes on up beyond what the streams' planes saw of it (their extents stop near
      // 1.8 m), and along to the room's corners beyond a patch cut off from it (v is up).
      if (structure && q.extent.sizes().x() >= cfg.wall_min_length) {
        box.max().y() = std::numeric_limits<double>::infinity();
        box.min().x() = -std::numeric_limits<double>::infinity();
        box.max().x() = std::numeric_limits<double>::infinity();
      }
      claims.push_back({&q, -(structure ? cfg.structure_behind : cfg.ownership_surface_distance),
                        structure ? cfg.structure_front : cfg.ownership_surface_distance, box});
    }
    if (q.orientation != Plane::Orientation::Horizontal) continue;
    // A slab just above the band (the next shelf board, a table top over a low one): its
    // underside, up to detail::kMaxSlabThickness below it, reaches into the band; that plane
    // compares it.
    const double above = -q.signedDistance(origin);  // q's height over this plane's origin
    if (!vertical && above > cfg.fuse_band && above <= cfg.fuse_band + detail::kMaxSlabThickness &&
        extentsOverlap(plane, q))
      claims.push_back({&q, -detail::kMaxSlabThickness, cfg.ownership_surface_distance,
                        grown(q.extent, cfg.ownership_extent_margin)});
    const bool owns = vertical ? plane_is_structure : above > 0.0 && !extentsOverlap(plane, q);
    if (owns)  // with its slab: a board's underside, up to kMaxSlabThickness below its top
      claims.push_back({&q, -detail::kMaxSlabThickness,
                        vertical ? compartmentTop(q, map_planes, cfg) : cfg.fuse_band,
                        grown(q.extent, cfg.support_margin)});
  }
  return claims;
}

}  // namespace

int surfaceRimCells(const Map& map) {
  return map.splatted() ? static_cast<int>(std::ceil(map.config().splat_radius_voxels)) : 0;
}

PlaneMaps computePlaneMaps(const PlaneSdf& plane, const std::vector<PlaneSdf>& map_planes,
                           const Config& cfg, const std::vector<Eigen::Vector3f>* points,
                           int rim_cells) {
  PlaneMaps m;
  m.rim_cells = rim_cells;
  // Support: the band is unbounded, but only what stands on the plane is its object; beyond its
  // extent (a table's band reaching the walls, a shelf across the room) it is unknown. The grid
  // reaches support_margin further, so the other session's cells placed within its drift of
  // this one's land in it (design.md, "Support limit").
  Eigen::AlignedBox2d support, window;
  if (!plane.plane.extent.isEmpty()) {
    support = grown(plane.plane.extent, cfg.support_margin);
    window = grown(support, cfg.support_margin);
  }
  m.heights = computeHeightMap(plane.volume, cfg, window);
  HeightMap& hm = m.heights;
  if (!support.isEmpty()) {
    for (int y = 0; y < hm.height; ++y)
      for (int x = 0; x < hm.width; ++x)
        if (!support.contains(hm.cellCenter(x, y))) hm.at(x, y) = kUnobserved;
  }
  // What other planes of the map claim of this band is unknown here (claimsOn).
  const std::vector<Claim> claims = claimsOn(plane.plane, map_planes, cfg);
  if (!claims.empty())
    for (int y = 0; y < hm.height; ++y)
      for (int x = 0; x < hm.width; ++x) {
        const float h = hm.at(x, y);
        if (!(h > cfg.h_obj)) continue;
        const Eigen::Vector2d uv = hm.cellCenter(x, y);
        const Eigen::Vector3d p = plane.plane.toWorld(Eigen::Vector3d(uv.x(), uv.y(), h));
        for (const Claim& c : claims) {
          const double sd = c.owner->signedDistance(p);
          if (sd >= c.lo && sd <= c.hi && c.box.contains(c.owner->toLocal(p).head<2>())) {
            hm.at(x, y) = kUnobserved;
            break;
          }
        }
      }
  m.objects = computeObjectMap(m.heights, cfg);
  m.roughness = computeRoughness(m.heights, cfg);
  m.revision = plane.volume.revision();
  if (points != nullptr) {
    m.points = std::make_shared<detail::LazyCellPoints>();
    m.points->source = points;
    m.points->chunks = std::make_shared<detail::PointChunks>();
    m.points->chunks->source = points;
  }
  return m;
}

const CellPoints* bandPoints(const PlaneMaps& maps, const Plane& plane,
                             const std::vector<Eigen::Vector3f>& points, const Config& cfg) {
  if (!maps.points || maps.points->source != &points) return nullptr;
  detail::LazyCellPoints& lazy = *maps.points;
  std::call_once(lazy.once,
                 [&] { lazy.cells = bucketBandPoints(plane, maps.heights, points, cfg); });
  return lazy.cells.builtFor(points.size()) ? &lazy.cells : nullptr;
}

}  // namespace planesdf
