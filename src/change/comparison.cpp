// Height-map comparison (paper eq. 2), mask cleaning and changed blobs; see comparison.hpp.

#include "planesdf/comparison.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "../numeric.hpp"
#include "planesdf/error.hpp"

namespace planesdf {
namespace {

constexpr double kCentreTieEps = 1e-6;  ///< cells

void checkHeights(const HeightMap& hm) {
  if (hm.width < 0 || hm.height < 0 || hm.heights.size() != hm.numCells()) {
    throw Error("height map", "cell array does not match the grid size");
  }
}

}  // namespace

Mask2D compareHeightMaps(const HeightMap& src, const HeightMap& tgt,
                         const Pose& T_target_source_local, const Config& cfg, Mask2D* unknown,
                         const HeightTolerance& tol) {
  if (!(cfg.delta_h > 0.0) || !std::isfinite(cfg.delta_h)) {
    throw Error("config",
                "delta_h must be positive and finite, got " + std::to_string(cfg.delta_h));
  }
  checkHeights(src);
  checkHeights(tgt);
  Mask2D changed = Mask2D::zeros(src.geometry());
  Mask2D unk = Mask2D::zeros(src.geometry());
  const double thr = cfg.delta_h + kHeightCompareTolerance;
  const double k_rough = cfg.roughness_factor;
  const int slack = std::max(0, tol.slack_cells);
  const bool tgt_ok = !tgt.empty() && tgt.cell_size > 0.0;
  const double inv = tgt_ok ? 1.0 / tgt.cell_size : 0.0;
  for (int y = 0; y < src.height; ++y) {
    for (int x = 0; x < src.width; ++x) {
      const float h = src.at(x, y);
      if (h == kUnobserved || !tgt_ok) {
        unk.set(x, y);
        continue;
      }
      const Eigen::Vector2d c = src.cellCenter(x, y);
      const Eigen::Vector3d p = T_target_source_local * Eigen::Vector3d(c.x(), c.y(), h);
      // Continuous target cell coordinates: cell k has its centre at k + 0.5.
      const double fx = p.x() * inv - tgt.i0 - 0.5;
      const double fy = p.y() * inv - tgt.j0 - 0.5;
      if (!(std::isfinite(fx) && std::isfinite(fy)) || fx < -1.0 || fy < -1.0 || fx >= tgt.width ||
          fy >= tgt.height) {
        unk.set(x, y);
        continue;
      }
      int x0 = detail::floorToInt(fx);
      int y0 = detail::floorToInt(fy);
      // A point exactly on a cell centre is equally near both neighbour columns / rows: take
      // the pair inside the grid (the last column / row stays comparable with identity T).
      if (x0 + 1 >= tgt.width && fx - x0 < kCentreTieEps) --x0;
      if (y0 + 1 >= tgt.height && fy - y0 < kCentreTieEps) --y0;
      // The 2x2 cells around the mapped centre must be observed, and a height within their
      // range lies on an edge between them. With `slack`, the observed cells of the ring around
      // them widen the range: a surface placed to within that many cells.
      bool any_unknown = false;
      bool open_above = false;  // a core cell's surface was never seen from above
      float lo = std::numeric_limits<float>::infinity();
      float hi = -lo;
      for (int j = -slack; j < 2 + slack && !any_unknown; ++j) {
        for (int i = -slack; i < 2 + slack; ++i) {
          const int tx = x0 + i;
          const int ty = y0 + j;
          if (!tgt.inBounds(tx, ty) || tgt.at(tx, ty) == kUnobserved) {
            if (i < 0 || i > 1 || j < 0 || j > 1) continue;  // ring cell
            any_unknown = true;
            break;
          }
          if (i >= 0 && i <= 1 && j >= 0 && j <= 1) open_above |= tgt.unseenAbove(tx, ty);
          lo = std::min(lo, tgt.at(tx, ty));
          hi = std::max(hi, tgt.at(tx, ty));
        }
      }
      if (any_unknown) {
        unk.set(x, y);
        continue;
      }
      if (h <= hi + thr && h >= lo - thr) continue;  // within delta_h: rough or not, unchanged
      // Rough surfaces raise the threshold: the largest roughness of the source cell and of the
      // target cells read above.
      double r = tol.source != nullptr ? tol.source->atCell(x, y) : 0.0;
      if (tol.target != nullptr)
        for (int j = -slack; j < 2 + slack; ++j)
          for (int i = -slack; i < 2 + slack; ++i)
            if (tgt.inBounds(x0 + i, y0 + j) && tgt.at(x0 + i, y0 + j) != kUnobserved)
              r = std::max(r, static_cast<double>(tol.target->atCell(x0 + i, y0 + j)));
      const double t = std::max(thr, k_rough * r);
      // Splatted target maps observe free space only in front of their points (tol.free_reach):
      // higher than a target surface whose free side was never observed, or higher than that
      // reach on a source cell whose own top was never seen, is unknown, not a removal
      // (design.md, "Unseen above").
      const bool splat_target = std::isfinite(tol.free_reach);
      const bool capped_source = src.unseenAbove(x, y) && h < tol.band_top - 2.0 * src.cell_size;
      if (h > hi + t && splat_target && (open_above || (capped_source && h > hi + tol.free_reach)))
        unk.set(x, y);
      else if (h > hi + t || h < lo - t)
        changed.set(x, y);
    }
  }
  if (unknown != nullptr) *unknown = std::move(unk);
  return changed;
}

namespace {

void checkCleaningParams(const Config& cfg) {
  if (cfg.min_change_cells < 0) {
    throw Error("config",
                "min_change_cells must be >= 0, got " + std::to_string(cfg.min_change_cells));
  }
  if (cfg.dilation_cells < 0) {
    throw Error("config", "dilation_cells must be >= 0, got " + std::to_string(cfg.dilation_cells));
  }
}

}  // namespace

Mask2D cleanChangeMask(const Mask2D& mask, const Config& cfg) {
  checkCleaningParams(cfg);
  return dilate(removeSmallComponents(mask, cfg.min_change_cells), cfg.dilation_cells);
}

bool sliverOf(int changed_cells, int object_cells, double min_overlap, int large_cells) {
  return object_cells >= large_cells && changed_cells < min_overlap * object_cells;
}

int largeObjectCells(const Config& cfg, double cell_size) {
  const double cells = cfg.blob_large_area / (cell_size * cell_size);
  return cells >= 2e9 ? std::numeric_limits<int>::max() : static_cast<int>(std::ceil(cells));
}

std::vector<Blob> changedBlobs(const Mask2D& cleaned, const ObjectMap& src_objects,
                               double min_overlap, int large_cells, int join_below) {
  if (!cleaned.sameGeometry(src_objects.geometry()) || cleaned.cells.size() != cleaned.numCells() ||
      src_objects.labels.size() != src_objects.numCells()) {
    throw Error("change", "change mask and object map have different grids");
  }
  const int n_obj = src_objects.numObjects();
  // Components of (mask ∩ object cells); each lies on one object (distinct objects are never
  // 8-adjacent).
  Mask2D inter = Mask2D::zeros(cleaned.geometry());
  for (std::size_t i = 0; i < inter.cells.size(); ++i) {
    const int l = src_objects.labels[i];
    inter.cells[i] = (cleaned.cells[i] != 0 && l > 0 && l <= n_obj) ? 1 : 0;
  }
  const Components comps = connectedComponents(inter, 1, 8);
  std::vector<int> comp_object(static_cast<std::size_t>(comps.count()) + 1, 0);
  for (std::size_t i = 0; i < inter.cells.size(); ++i)
    if (comps.labels[i] > 0)
      comp_object[static_cast<std::size_t>(comps.labels[i])] = src_objects.labels[i];
  // An object grows whole into one blob, which takes every component on it, unless each of them
  // touches only a sliver of it: then each such component is a blob of its own cells.
  std::vector<char> whole(static_cast<std::size_t>(n_obj) + 1, 0);
  for (int c = 1; c <= comps.count(); ++c) {
    const int l = comp_object[static_cast<std::size_t>(c)];
    if (!sliverOf(comps.areas[static_cast<std::size_t>(c - 1)], src_objects.object(l).area,
                  min_overlap, large_cells))
      whole[static_cast<std::size_t>(l)] = 1;
  }
  // The slivers of an object smaller than `join_below` are one blob, keyed by the first of them
  // (design.md, "Slivers"): the rims of a small object's sides belong to one object.
  std::vector<int> first_on(static_cast<std::size_t>(n_obj) + 1, 0);
  std::vector<int> rep(static_cast<std::size_t>(comps.count()) + 1, 0);
  for (int c = 1; c <= comps.count(); ++c) {
    const int l = comp_object[static_cast<std::size_t>(c)];
    rep[static_cast<std::size_t>(c)] = c;
    if (whole[static_cast<std::size_t>(l)] || src_objects.object(l).area >= join_below) continue;
    int& first = first_on[static_cast<std::size_t>(l)];
    if (first == 0) first = c;
    rep[static_cast<std::size_t>(c)] = first;
  }
  // Blob keys: whole objects 1..n_obj by label, then sliver components n_obj + c by component.
  std::vector<int> blob_of(static_cast<std::size_t>(n_obj + comps.count()) + 1, -1);
  int n_blobs = 0;
  for (int l = 1; l <= n_obj; ++l)
    if (whole[static_cast<std::size_t>(l)]) blob_of[static_cast<std::size_t>(l)] = n_blobs++;
  for (int c = 1; c <= comps.count(); ++c)
    if (!whole[static_cast<std::size_t>(comp_object[static_cast<std::size_t>(c)])] &&
        rep[static_cast<std::size_t>(c)] == c)
      blob_of[static_cast<std::size_t>(n_obj + c)] = n_blobs++;
  std::vector<Blob> blobs(static_cast<std::size_t>(n_blobs));
  for (std::size_t k = 0; k < blob_of.size(); ++k) {
    if (blob_of[k] < 0) continue;
    Blob& b = blobs[static_cast<std::size_t>(blob_of[k])];
    b.bbox_min = Eigen::Vector2i(cleaned.width, cleaned.height);
    b.bbox_max = Eigen::Vector2i(-1, -1);
    b.partial = static_cast<int>(k) > n_obj;
    b.object_labels = {b.partial ? comp_object[k - static_cast<std::size_t>(n_obj)]
                                 : static_cast<int>(k)};
  }
  for (int y = 0; y < cleaned.height; ++y) {
    for (int x = 0; x < cleaned.width; ++x) {
      const std::size_t i = cleaned.index(x, y);
      const int l = src_objects.labels[i];
      if (l <= 0 || l > n_obj) continue;
      const int key = whole[static_cast<std::size_t>(l)] ? l
                      : comps.labels[i] > 0 ? n_obj + rep[static_cast<std::size_t>(comps.labels[i])]
                                            : 0;
      if (key == 0) continue;
      Blob& b = blobs[static_cast<std::size_t>(blob_of[static_cast<std::size_t>(key)])];
      b.cells.emplace_back(x, y);
      ++b.area;
      b.bbox_min = b.bbox_min.cwiseMin(Eigen::Vector2i(x, y));
      b.bbox_max = b.bbox_max.cwiseMax(Eigen::Vector2i(x, y));
    }
  }
  return blobs;
}

Mask2D freeSpaceEvidence(const HeightMap& src, const Mask2D& unknown,
                         const TsdfVolume& target_volume, const Pose& T_target_source_local,
                         const Config& cfg) {
  Mask2D out = Mask2D::zeros(src.geometry());
  if (src.empty() || !unknown.sameGeometry(src)) return out;
  const double vs = src.cell_size;
  const float free_sdf =
      static_cast<float>(0.5 * std::min(cfg.delta_h, target_volume.truncation()));
  for (int y = 0; y < src.height; ++y)
    for (int x = 0; x < src.width; ++x) {
      if (!unknown.at(x, y)) continue;
      const float h = src.at(x, y);
      if (!(h > cfg.h_obj)) continue;
      const Eigen::Vector2d uv = src.cellCenter(x, y);
      int free = 0, occupied = 0;
      for (int m = 1; m <= 3; ++m) {
        const Eigen::Vector3d p =
            T_target_source_local * Eigen::Vector3d(uv.x(), uv.y(), h - m * vs);
        const TsdfVoxel* v = target_volume.voxel(target_volume.voxelIndexAt(p));
        if (v == nullptr || !(v->weight > 0.0f && v->weight >= cfg.w_min)) continue;
        if (v->sdf >= free_sdf) ++free;
        if (v->sdf <= 0.0f) ++occupied;
      }
      if (free >= 2 && occupied == 0) out.set(x, y);
    }
  return out;
}

HeightChange detectHeightChange(const HeightMap& src, const HeightMap& tgt,
                                const ObjectMap& src_objects, const Pose& T_target_source_local,
                                const Config& cfg, const TsdfVolume* target_volume,
                                const HeightTolerance& tol) {
  HeightChange out;
  out.raw = compareHeightMaps(src, tgt, T_target_source_local, cfg, &out.unknown, tol);
  if (target_volume != nullptr) {
    out.vacated = freeSpaceEvidence(src, out.unknown, *target_volume, T_target_source_local, cfg);
    for (std::size_t i = 0; i < out.raw.cells.size(); ++i)
      if (out.vacated.cells[i]) out.raw.cells[i] = 1;
  }
  // cleanChangeMask(raw), with its first step kept as `filtered`.
  checkCleaningParams(cfg);
  out.filtered = removeSmallComponents(out.raw, cfg.min_change_cells);
  out.cleaned = dilate(out.filtered, cfg.dilation_cells);
  const int large_cells = largeObjectCells(cfg, src.cell_size);
  out.blobs =
      changedBlobs(out.cleaned, src_objects, cfg.blob_min_overlap,
                   tol.any_size_slivers ? 1 : large_cells, tol.any_size_slivers ? large_cells : 0);
  out.blob_mask = Mask2D::zeros(src.geometry());
  for (const Blob& b : out.blobs) {
    for (const Eigen::Vector2i& c : b.cells) out.blob_mask.set(c.x(), c.y());
  }
  return out;
}

}  // namespace planesdf
