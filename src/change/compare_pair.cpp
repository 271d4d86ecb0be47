// The comparison of one registered plane pair: paper eq. 2 on the height maps, blobs, 3D
// validation, and the candidates with their points (see change.hpp, comparePlanePair).

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <tuple>
#include <utility>

#include "band_points.hpp"
#include "change_internal.hpp"
#include "object_fit.hpp"
#include "voxel_region.hpp"

namespace planesdf {

namespace {

using detail::chunkBoxes;
using detail::columnsNear;
using detail::columnVoxels;
using detail::completedRegion;
using detail::fitObject;
using detail::forBandPointsIn;
using detail::hasCore;
using detail::isSmallMove;
using detail::mappedBox;
using detail::objectCellsOutside;
using detail::objectsInFootprint;
using detail::SurfaceSupport;
using detail::surfaceSupport;
using detail::targetHeight;
using detail::voxelBox;

constexpr double kNoReachLimit = std::numeric_limits<double>::infinity();
constexpr float kAbove = std::numeric_limits<float>::infinity();

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
