// Change-detection scoring (`planesdf eval`): point matching within a tolerance on a
// hashed uniform grid, then point-level precision / recall / F1 and object-level M / W.

#include "planesdf/eval.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <unordered_map>
#include <utility>
#include <vector>

#include "../parallel.hpp"
#include "planesdf/error.hpp"

namespace planesdf {
namespace {

// Cell coordinates are packed into one 64-bit key, 21 bits per axis.
constexpr int kAxisBits = 21;
constexpr std::int64_t kAxisCells = std::int64_t{1} << kAxisBits;

std::uint64_t packKey(const Eigen::Vector3i& c) {
  return static_cast<std::uint64_t>(c.x()) | (static_cast<std::uint64_t>(c.y()) << kAxisBits) |
         (static_cast<std::uint64_t>(c.z()) << (2 * kAxisBits));
}

// splitmix64 finaliser: spreads neighbouring keys over the table.
std::uint64_t mixKey(std::uint64_t k) {
  k ^= k >> 30;
  k *= 0xbf58476d1ce4e5b9ULL;
  k ^= k >> 27;
  k *= 0x94d049bb133111ebULL;
  k ^= k >> 31;
  return k;
}

// The cell lattice shared by the two grids of one side: cubic cells of edge `cell` from `origin`.
// The edge is a hair larger than the tolerance, so two points within tol are always in the same or
// adjacent cells despite rounding; it grows further when the scene would need more than 2^21
// cells along an axis (only the speed changes then, never the result).
struct Lattice {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  double inv_cell = 1.0;

  Eigen::Vector3i coordOf(const Eigen::Vector3f& p) const {
    Eigen::Vector3i c;
    for (int a = 0; a < 3; ++a) {
      const double q = std::floor((static_cast<double>(p[a]) - origin[a]) * inv_cell);
      c[a] = static_cast<int>(std::clamp(q, 0.0, static_cast<double>(kAxisCells - 1)));
    }
    return c;
  }
};

Lattice makeLattice(const std::vector<Eigen::Vector3f>& a, const std::vector<std::uint32_t>& ia,
                    const std::vector<Eigen::Vector3f>& b, const std::vector<std::uint32_t>& ib,
                    double tol) {
  Eigen::AlignedBox3d box;
  for (std::uint32_t i : ia) box.extend(a[i].cast<double>());
  for (std::uint32_t i : ib) box.extend(b[i].cast<double>());
  Lattice lat;
  if (box.isEmpty()) return lat;
  const double extent = (box.max() - box.min()).maxCoeff();
  const double cell = std::max(tol * (1.0 + 1e-6), extent / static_cast<double>(kAxisCells - 4));
  lat.origin = box.min();
  lat.inv_cell = 1.0 / cell;
  return lat;
}

// Points of one cloud bucketed by cell: an open-addressing hash table (load <= 1/2, grown as
// cells appear) from cell key to a range of a cell-sorted copy of the points.
class CellGrid {
 public:
  CellGrid(const std::vector<Eigen::Vector3f>& points, const std::vector<std::uint32_t>& indices,
           const Lattice& lattice) {
    const std::size_t n = indices.size();
    std::size_t capacity = 1024;  // grown on demand; start near a few points per cell
    while (capacity < n / 4) capacity *= 2;
    rehash(capacity);
    std::vector<std::uint32_t> cell_of(n);
    std::vector<std::uint32_t> count;
    // Recently seen cells, direct-mapped: point order is usually spatially coherent (scan rows),
    // so most points find their cell here without touching the (larger) table.
    constexpr std::size_t kRecent = 1024;
    std::vector<std::pair<std::uint64_t, std::uint32_t>> recent(kRecent, {~std::uint64_t{0}, 0});
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::Vector3i c = lattice.coordOf(points[indices[i]]);
      const std::uint64_t key = packKey(c);
      const std::uint64_t hash = mixKey(key);
      auto& hit = recent[hash & (kRecent - 1)];
      if (hit.first != key) {
        std::size_t s = slotOf(key, hash);
        if (slots_[s].cell_plus1 == 0) {
          if (2 * (cells_.size() + 1) > slots_.size()) {
            rehash(2 * slots_.size());
            s = slotOf(key, hash);
          }
          slots_[s].key = key;
          slots_[s].cell_plus1 = static_cast<std::uint32_t>(cells_.size() + 1);
          cells_.push_back({c, key, 0, 0});
          count.push_back(0);
          lo_ = cells_.size() == 1 ? c : lo_.cwiseMin(c);
          hi_ = cells_.size() == 1 ? c : hi_.cwiseMax(c);
        }
        hit = {key, slots_[s].cell_plus1 - 1};
      }
      cell_of[i] = hit.second;
      ++count[hit.second];
    }
    std::uint32_t offset = 0;
    for (std::size_t c = 0; c < cells_.size(); ++c) {
      cells_[c].begin = cells_[c].end = offset;
      offset += count[c];
    }
    sorted_.resize(n);
    original_.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t at = cells_[cell_of[i]].end++;
      sorted_[at] = points[indices[i]];
      original_[at] = indices[i];
    }
  }

  std::size_t cellCount() const { return cells_.size(); }
  const Eigen::Vector3i& coord(std::size_t c) const { return cells_[c].coord; }
  std::uint32_t begin(std::size_t c) const { return cells_[c].begin; }
  std::uint32_t end(std::size_t c) const { return cells_[c].end; }
  const Eigen::Vector3f& point(std::uint32_t k) const { return sorted_[k]; }
  std::uint32_t original(std::uint32_t k) const { return original_[k]; }
  /// Smallest / largest occupied cell coordinates (meaningless when there is no cell).
  const Eigen::Vector3i& lo() const { return lo_; }
  const Eigen::Vector3i& hi() const { return hi_; }

  /// Index of the cell at `c` (inside the lattice), or -1 when it holds no point.
  long long find(const Eigen::Vector3i& c) const {
    const std::uint32_t cell_plus1 = slots_[slotOf(packKey(c))].cell_plus1;
    return static_cast<long long>(cell_plus1) - 1;
  }

 private:
  struct Slot {
    std::uint64_t key = 0;
    std::uint32_t cell_plus1 = 0;  // 0 = empty
  };
  struct Cell {
    Eigen::Vector3i coord;
    std::uint64_t key;
    std::uint32_t begin;
    std::uint32_t end;
  };

  // The slot holding `key`, or the empty slot where it would go.
  std::size_t slotOf(std::uint64_t key) const { return slotOf(key, mixKey(key)); }
  std::size_t slotOf(std::uint64_t key, std::uint64_t hash) const {
    std::size_t s = hash & mask_;
    while (slots_[s].cell_plus1 != 0 && slots_[s].key != key) s = (s + 1) & mask_;
    return s;
  }

  void rehash(std::size_t capacity) {
    slots_.assign(capacity, Slot{});
    mask_ = capacity - 1;
    for (std::size_t c = 0; c < cells_.size(); ++c) {
      const std::size_t s = slotOf(cells_[c].key);
      slots_[s].key = cells_[c].key;
      slots_[s].cell_plus1 = static_cast<std::uint32_t>(c + 1);
    }
  }

  std::vector<Slot> slots_;
  std::size_t mask_ = 0;
  std::vector<Cell> cells_;
  Eigen::Vector3i lo_ = Eigen::Vector3i::Zero();
  Eigen::Vector3i hi_ = Eigen::Vector3i::Zero();
  std::vector<Eigen::Vector3f> sorted_;
  std::vector<std::uint32_t> original_;
};

// True when a point of target cell `t` lies within sqrt(tol2) of `p`.
bool anyWithin(const CellGrid& target, std::size_t t, const Eigen::Vector3d& p, double tol2) {
  for (std::uint32_t j = target.begin(t); j < target.end(t); ++j)
    if ((target.point(j).cast<double>() - p).squaredNorm() <= tol2) return true;
  return false;
}

// Marks hit[k] = 1 for every point k (cell-sorted index) of query cell `qcell` with a point of
// `target` within sqrt(tol2): the target's own cell first, then the 26 neighbours (clipped to the
// target's occupied box) only for the points that found no match there.
void matchCell(const CellGrid& query, std::size_t qcell, const CellGrid& target, double tol2,
               std::vector<std::uint8_t>& hit, std::vector<std::uint32_t>& pending,
               std::vector<std::uint32_t>& near) {
  const Eigen::Vector3i qc = query.coord(qcell);
  const Eigen::Vector3i from = (qc.array() - 1).max(target.lo().array());
  const Eigen::Vector3i to = (qc.array() + 1).min(target.hi().array());
  if ((from.array() > to.array()).any()) return;  // no target cell around

  pending.clear();
  const long long own = target.find(qc);
  for (std::uint32_t k = query.begin(qcell); k < query.end(qcell); ++k) {
    if (own >= 0 &&
        anyWithin(target, static_cast<std::size_t>(own), query.point(k).cast<double>(), tol2))
      hit[k] = 1;
    else
      pending.push_back(k);
  }
  if (pending.empty()) return;

  near.clear();
  for (int z = from.z(); z <= to.z(); ++z)
    for (int y = from.y(); y <= to.y(); ++y)
      for (int x = from.x(); x <= to.x(); ++x) {
        const Eigen::Vector3i n(x, y, z);
        if (n == qc) continue;
        const long long t = target.find(n);
        if (t >= 0) near.push_back(static_cast<std::uint32_t>(t));
      }
  for (std::uint32_t k : pending) {
    const Eigen::Vector3d p = query.point(k).cast<double>();
    for (std::uint32_t t : near)
      if (anyWithin(target, t, p, tol2)) {
        hit[k] = 1;
        break;
      }
  }
}

// Below this many query cells the worker threads cost more than they save.
constexpr std::size_t kMinParallelCells = 1024;

// matched_a[i] = 1 for every point i of `a` with a point of `b` within sqrt(tol2), and the same
// for b. One parallel region over the cells of both grids. Threads write hits in cell-sorted
// order (contiguous ranges, no false sharing); they are scattered to the original order after.
void markMatched(const CellGrid& a, const CellGrid& b, double tol2,
                 std::vector<std::uint8_t>& matched_a, std::vector<std::uint8_t>& matched_b) {
  if (a.cellCount() == 0 || b.cellCount() == 0) return;
  std::vector<std::uint8_t> hit_a(a.end(a.cellCount() - 1), 0);
  std::vector<std::uint8_t> hit_b(b.end(b.cellCount() - 1), 0);
  const long long cells_a = static_cast<long long>(a.cellCount());
  const long long cells_b = static_cast<long long>(b.cellCount());
  const int threads = cells_a + cells_b >= static_cast<long long>(kMinParallelCells)
                          ? detail::resolveThreads(0)
                          : 1;
  struct Scratch {  // of matchCell
    std::vector<std::uint32_t> pending, near;
  };
  std::vector<Scratch> scratch(static_cast<std::size_t>(threads));
  // The cells of a, then those of b.
  detail::parallelChunks(
      cells_a + cells_b, threads, 256, [&](int worker, long long begin, long long end) {
        Scratch& s = scratch[static_cast<std::size_t>(worker)];
        for (long long c = begin; c < end; ++c) {
          if (c < cells_a)
            matchCell(a, static_cast<std::size_t>(c), b, tol2, hit_a, s.pending, s.near);
          else
            matchCell(b, static_cast<std::size_t>(c - cells_a), a, tol2, hit_b, s.pending, s.near);
        }
      });
  for (std::size_t k = 0; k < hit_a.size(); ++k)
    if (hit_a[k]) matched_a[a.original(static_cast<std::uint32_t>(k))] = 1;
  for (std::size_t k = 0; k < hit_b.size(); ++k)
    if (hit_b[k]) matched_b[b.original(static_cast<std::uint32_t>(k))] = 1;
}

std::vector<std::uint32_t> validIndices(const PointCloud& cloud, const std::string& what) {
  cloud.validate(what);
  if (cloud.size() > std::numeric_limits<std::uint32_t>::max())
    throw Error(what, "more than 2^32-1 points");
  std::vector<std::uint32_t> idx;
  idx.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (cloud.isValid(i)) idx.push_back(static_cast<std::uint32_t>(i));
  return idx;
}

// Group (object or cluster) number of every valid point, by distinct value of `field_name`;
// all points form group 0 when the cloud lacks the field. Returns the number of groups.
int groupPoints(const PointCloud& cloud, const std::vector<std::uint32_t>& valid,
                const char* field_name, std::vector<int>& group) {
  group.assign(valid.size(), 0);
  const ScalarField* field = cloud.field(field_name);
  if (!field) return valid.empty() ? 0 : 1;
  std::unordered_map<double, int> ids;
  bool has_nan = false;  // NaN never equals itself: all NaN ids form one last group
  for (std::size_t i = 0; i < valid.size(); ++i) {
    const double v = field->values[valid[i]];
    if (std::isnan(v)) {
      has_nan = true;
      group[i] = -1;
    } else if (i > 0 && v == field->values[valid[i - 1]]) {  // runs of one id are common
      group[i] = group[i - 1];
    } else {
      auto it = ids.find(v);
      if (it == ids.end()) it = ids.emplace(v, static_cast<int>(ids.size())).first;
      group[i] = it->second;
    }
  }
  int groups = static_cast<int>(ids.size());
  if (has_nan) {
    for (int& g : group)
      if (g < 0) g = groups;
    ++groups;
  }
  return groups;
}

// Groups with no matched point.
int unmatchedGroups(const std::vector<std::uint32_t>& valid, const std::vector<int>& group,
                    int groups, const std::vector<std::uint8_t>& matched) {
  std::vector<std::uint8_t> hit(static_cast<std::size_t>(groups), 0);
  for (std::size_t i = 0; i < valid.size(); ++i)
    if (matched[valid[i]]) hit[static_cast<std::size_t>(group[i])] = 1;
  return static_cast<int>(std::count(hit.begin(), hit.end(), 0));
}

std::size_t countMatched(const std::vector<std::uint32_t>& valid,
                         const std::vector<std::uint8_t>& matched) {
  std::size_t n = 0;
  for (std::uint32_t i : valid) n += matched[i];
  return n;
}

void checkTol(double tol) {
  if (!(std::isfinite(tol) && tol > 0.0)) {
    std::ostringstream s;
    s << "tol must be a positive finite distance in metres, got " << tol;
    throw Error("", s.str());
  }
}

SideScore scoreSideNamed(const PointCloud& predicted, const PointCloud& gt, double tol,
                         const std::string& predicted_name, const std::string& gt_name) {
  checkTol(tol);
  const std::vector<std::uint32_t> pv = validIndices(predicted, predicted_name);
  const std::vector<std::uint32_t> gv = validIndices(gt, gt_name);

  std::vector<std::uint8_t> pred_matched(predicted.size(), 0);
  std::vector<std::uint8_t> gt_matched(gt.size(), 0);
  if (!pv.empty() && !gv.empty()) {
    const Lattice lat = makeLattice(predicted.points, pv, gt.points, gv, tol);
    const CellGrid pred_grid(predicted.points, pv, lat);
    const CellGrid gt_grid(gt.points, gv, lat);
    const double tol2 = tol * tol;
    markMatched(pred_grid, gt_grid, tol2, pred_matched, gt_matched);
  }

  SideScore s;
  s.predicted_points = pv.size();
  s.gt_points = gv.size();
  s.matched_predicted = countMatched(pv, pred_matched);
  s.matched_gt = countMatched(gv, gt_matched);

  std::vector<int> group;
  s.predicted_clusters = groupPoints(predicted, pv, kChangeIdField, group);
  s.wrong = unmatchedGroups(pv, group, s.predicted_clusters, pred_matched);
  s.gt_objects = groupPoints(gt, gv, kObjectIdField, group);
  s.missed = unmatchedGroups(gv, group, s.gt_objects, gt_matched);
  computeRates(s);
  return s;
}

nlohmann::ordered_json sideToJson(const SideScore& s) {
  nlohmann::ordered_json j;
  j["precision"] = s.precision;
  j["recall"] = s.recall;
  j["f1"] = s.f1;
  j["missed"] = s.missed;
  j["wrong"] = s.wrong;
  j["predicted_points"] = s.predicted_points;
  j["gt_points"] = s.gt_points;
  j["matched_predicted"] = s.matched_predicted;
  j["matched_gt"] = s.matched_gt;
  j["gt_objects"] = s.gt_objects;
  j["predicted_clusters"] = s.predicted_clusters;
  return j;
}

}  // namespace

void computeRates(SideScore& s) {
  if (s.predicted_points == 0 && s.gt_points == 0) {
    s.precision = s.recall = s.f1 = 1.0;
    return;
  }
  s.precision = s.predicted_points == 0 ? 0.0
                                        : static_cast<double>(s.matched_predicted) /
                                              static_cast<double>(s.predicted_points);
  s.recall =
      s.gt_points == 0 ? 0.0 : static_cast<double>(s.matched_gt) / static_cast<double>(s.gt_points);
  const double sum = s.precision + s.recall;
  s.f1 = sum > 0.0 ? 2.0 * s.precision * s.recall / sum : 0.0;
}

SideScore scoreSide(const PointCloud& predicted, const PointCloud& gt, double tol) {
  return scoreSideNamed(predicted, gt, tol, "prediction", "ground truth");
}

SideScore poolScores(const SideScore& a, const SideScore& b) {
  SideScore s;
  s.predicted_points = a.predicted_points + b.predicted_points;
  s.gt_points = a.gt_points + b.gt_points;
  s.matched_predicted = a.matched_predicted + b.matched_predicted;
  s.matched_gt = a.matched_gt + b.matched_gt;
  s.gt_objects = a.gt_objects + b.gt_objects;
  s.predicted_clusters = a.predicted_clusters + b.predicted_clusters;
  s.missed = a.missed + b.missed;
  s.wrong = a.wrong + b.wrong;
  computeRates(s);
  return s;
}

EvalResult evaluateChanges(const PointCloud& removed_pred, const PointCloud& added_pred,
                           const PointCloud& gt_reference, const PointCloud& gt_current,
                           double tol) {
  EvalResult r;
  r.tol = tol;
  r.removed =
      scoreSideNamed(removed_pred, gt_reference, tol, "removed points", "reference ground truth");
  r.added = scoreSideNamed(added_pred, gt_current, tol, "added points", "current ground truth");
  r.pooled = poolScores(r.removed, r.added);
  return r;
}

std::string evalToJson(const EvalResult& result, int indent) {
  nlohmann::ordered_json j = sideToJson(result.pooled);
  j["tol"] = result.tol;
  j["removed"] = sideToJson(result.removed);
  j["added"] = sideToJson(result.added);
  return j.dump(indent < 0 ? -1 : indent);
}

}  // namespace planesdf
