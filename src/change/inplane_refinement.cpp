// In-plane (u, v, yaw) refinement of a registered plane pair (see registration.hpp,
// refineInPlane): samples of the source height map, a coarse and a fine grid search of the
// window scored against the target height map, and a model selection that keeps the initial
// transform unless the gain is clear.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

#include "../numeric.hpp"
#include "planesdf/error.hpp"
#include "planesdf/registration.hpp"

namespace planesdf {
namespace {

using detail::kPi;

/// A cell index no grid reaches (place's far or non-finite coordinates).
constexpr int kFarCell = -(1 << 30);
/// Samples of the coarse search of refineInPlane.
constexpr std::size_t kCoarseSamples = 6000;
/// Cells around a sample's initial place where sensitiveFirst looks for differing heights.
constexpr int kSensitiveRadius = 3;

struct Sample {
  Eigen::Vector2d uv;       ///< source cell centre mapped by the initial T, target-local
  float h;                  ///< source height
  bool mismatched = false;  ///< differs from the target under the initial T
  int group = 0;            ///< 0 background, else the object it belongs to (see refineInPlane)
  bool ring = false;        ///< background near a changed object, in its group (absorbRings)
};

/// Mismatches a group (one object of either session) may add to a candidate's cost: each object
/// votes with a bounded weight, so that no candidate wins by moving the map onto one moved
/// object's new place against the agreement of the static ones.
struct Groups {
  std::vector<int> cap;  ///< per group; background: its sample count (no cap)
  mutable std::vector<int> count;
  mutable std::vector<int> touched;  ///< groups whose count is not 0 (reset per candidate)
};

/// The groups of `samples` (ids below n_groups): an object's mismatches count up to half its
/// samples (a moved object mismatches wholly at the right T, and a candidate that drags the map
/// onto its new place gains at most that half); the background (group 0) is not capped.
Groups groupsOf(const std::vector<Sample>& samples, std::size_t n_groups) {
  Groups g;
  g.cap.assign(n_groups, 0);
  for (const Sample& smp : samples)
    if (!smp.ring) ++g.cap[static_cast<std::size_t>(smp.group)];
  for (std::size_t i = 1; i < n_groups; ++i) g.cap[i] = (g.cap[i] + 1) / 2;
  g.count.assign(n_groups, 0);
  return g;
}

struct Score {
  int compared = 0;
  int mismatches = 0;  ///< samples that differ
  int cost = 0;        ///< mismatches with each group's share capped (Groups)
  double mean_abs = 0.0;
};

/// Where a yaw `yaw` about `pivot` then a shift `shift` (target frame) puts each sample: its
/// target cell (x, y), unchecked. Far or non-finite coordinates get kFarCell, outside every
/// grid whatever whole-cell offset scorePlaced adds.
struct Placement {
  std::vector<int> x, y;
};

Placement place(const std::vector<Sample>& samples, const HeightMap& tgt,
                const Eigen::Vector2d& pivot, double yaw, const Eigen::Vector2d& shift) {
  const double c = std::cos(yaw);
  const double s = std::sin(yaw);
  const double inv = 1.0 / tgt.cell_size;
  Placement p;
  p.x.resize(samples.size());
  p.y.resize(samples.size());
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const Eigen::Vector2d d = samples[i].uv - pivot;
    const double u = pivot.x() + c * d.x() - s * d.y() + shift.x();
    const double v = pivot.y() + s * d.x() + c * d.y() + shift.y();
    p.x[i] = detail::floorToIntOr(u * inv, kFarCell) - tgt.i0;
    p.y[i] = detail::floorToIntOr(v * inv, kFarCell) - tgt.j0;
  }
  return p;
}

/// The samples as scorePlaced reads them, one array per field (8 at a time with AVX2).
struct SampleArrays {
  std::vector<float> h;
  std::vector<std::int32_t> group;
  std::vector<std::int32_t> mismatched;  ///< -1 (all bits) when Sample::mismatched, else 0
};

SampleArrays arraysOf(const std::vector<Sample>& samples) {
  SampleArrays a;
  for (const Sample& smp : samples) {
    a.h.push_back(smp.h);
    a.group.push_back(smp.group);
    a.mismatched.push_back(smp.mismatched ? -1 : 0);
  }
  return a;
}

/// A running score (see scorePlaced).
struct Scoring {
  const SampleArrays& s;
  const Groups& groups;
  const HeightMap& tgt;
  double delta_h, cap;
  int slack, max_cost;
  Score sc;
  double sum = 0.0;

  /// A mismatch of sample i: false when the cost passed max_cost (stop). The background's
  /// share is not capped.
  bool mismatch(std::size_t i) {
    ++sc.mismatches;
    const std::int32_t g = s.group[i];
    if (g == 0) {
      ++sc.cost;
    } else {
      const auto gi = static_cast<std::size_t>(g);
      if (groups.count[gi] == 0) groups.touched.push_back(g);
      if (++groups.count[gi] <= groups.cap[gi]) ++sc.cost;
    }
    return sc.cost <= max_cost;
  }

  /// Scores sample i at target cell (x, y); false when the cost passed max_cost (stop).
  bool sample(std::size_t i, int x, int y) {
    const bool inside = tgt.inBounds(x, y);
    const float ht = inside ? tgt.at(x, y) : kUnobserved;
    if (ht == kUnobserved) {
      // The samples are the cells compared at the initial T. One that mismatched there and that
      // a candidate moves off the observed target still counts as a mismatch, so no candidate
      // wins by hiding differences in unobserved areas (the shadows beside objects in single
      // views); agreeing samples lost at the borders of the observed area do not count.
      if (s.mismatched[i] == 0) return true;
      ++sc.compared;
      if (!mismatch(i)) return false;
      sum += cap;
      return true;
    }
    const double h = static_cast<double>(s.h[i]);
    double diff = std::abs(static_cast<double>(ht) - h);
    for (int dy = -slack; dy <= slack && diff > delta_h; ++dy)
      for (int dx = -slack; dx <= slack; ++dx) {
        if (!tgt.inBounds(x + dx, y + dy)) continue;
        const float hn = tgt.at(x + dx, y + dy);
        if (hn == kUnobserved) continue;
        diff = std::min(diff, std::abs(static_cast<double>(hn) - h));
      }
    ++sc.compared;
    if (diff > delta_h && !mismatch(i)) return false;
    sum += std::min(diff, cap);
    return true;
  }
};

#if defined(__x86_64__) && defined(__GNUC__)
/// The samples [0, n8) of scorePlaced 8 at a time: lanes observed in the target that agree, or
/// (no slack) background lanes that differ, are scored in the vector registers; the others
/// (unobserved cells, objects' mismatches, the slack's neighbourhoods) by Scoring::sample.
/// Checks the cost after each 8; false when it passed max_cost.
__attribute__((target("avx2"))) bool scoreEightsAvx2(Scoring& r, const int* px, const int* py,
                                                     int ox, int oy, std::size_t n8) {
  const HeightMap& tgt = r.tgt;
  const __m256i vox = _mm256_set1_epi32(ox), voy = _mm256_set1_epi32(oy);
  const __m256i minus1 = _mm256_set1_epi32(-1), zero = _mm256_setzero_si256();
  const __m256i vw = _mm256_set1_epi32(tgt.width), vh = _mm256_set1_epi32(tgt.height);
  const __m256 unobserved = _mm256_set1_ps(kUnobserved);
  const __m256d delta = _mm256_set1_pd(r.delta_h), cap = _mm256_set1_pd(r.cap);
  const __m256d sign = _mm256_set1_pd(-0.0);
  __m256d sum0 = _mm256_setzero_pd(), sum1 = _mm256_setzero_pd();
  const float* heights = tgt.heights.data();
  for (std::size_t i = 0; i < n8; i += 8) {
    const __m256i x =
        _mm256_add_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(px + i)), vox);
    const __m256i y =
        _mm256_add_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(py + i)), voy);
    const __m256i inside = _mm256_and_si256(
        _mm256_and_si256(_mm256_cmpgt_epi32(x, minus1), _mm256_cmpgt_epi32(vw, x)),
        _mm256_and_si256(_mm256_cmpgt_epi32(y, minus1), _mm256_cmpgt_epi32(vh, y)));
    const __m256i lin = _mm256_and_si256(inside, _mm256_add_epi32(_mm256_mullo_epi32(y, vw), x));
    const __m256 ht =
        _mm256_mask_i32gather_ps(unobserved, heights, lin, _mm256_castsi256_ps(inside), 4);
    const __m256 observed = _mm256_cmp_ps(ht, unobserved, _CMP_NEQ_UQ);
    const __m256 h = _mm256_loadu_ps(r.s.h.data() + i);
    const __m256d d0 =
        _mm256_andnot_pd(sign, _mm256_sub_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(ht)),
                                             _mm256_cvtps_pd(_mm256_castps256_ps128(h))));
    const __m256d d1 =
        _mm256_andnot_pd(sign, _mm256_sub_pd(_mm256_cvtps_pd(_mm256_extractf128_ps(ht, 1)),
                                             _mm256_cvtps_pd(_mm256_extractf128_ps(h, 1))));
    const int differs = _mm256_movemask_pd(_mm256_cmp_pd(d0, delta, _CMP_GT_OQ)) |
                        _mm256_movemask_pd(_mm256_cmp_pd(d1, delta, _CMP_GT_OQ)) << 4;
    const int obs = _mm256_movemask_ps(observed);
    const int background = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
        _mm256_loadu_si256(reinterpret_cast<const __m256i*>(r.s.group.data() + i)), zero)));
    const int flagged = _mm256_movemask_ps(_mm256_castsi256_ps(
        _mm256_loadu_si256(reinterpret_cast<const __m256i*>(r.s.mismatched.data() + i))));
    // Lanes scored here, and those left to Scoring::sample.
    const int mism = obs & differs & (r.slack == 0 ? background : 0);
    const int here = (obs & ~differs) | mism;
    const int rest = (obs & ~here) | (~obs & flagged & 0xff);
    r.sc.compared += __builtin_popcount(static_cast<unsigned>(here));
    r.sc.mismatches += __builtin_popcount(static_cast<unsigned>(mism));
    r.sc.cost += __builtin_popcount(static_cast<unsigned>(mism));
    const __m256i lanes = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    const __m256i here_m =
        _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(here), lanes), lanes);
    sum0 = _mm256_add_pd(
        sum0,
        _mm256_and_pd(_mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_castsi256_si128(here_m))),
                      _mm256_min_pd(cap, d0)));
    sum1 = _mm256_add_pd(
        sum1, _mm256_and_pd(
                  _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_extracti128_si256(here_m, 1))),
                  _mm256_min_pd(cap, d1)));
    for (int m = rest; m != 0; m &= m - 1) {
      const int j = __builtin_ctz(static_cast<unsigned>(m));
      if (!r.sample(i + static_cast<std::size_t>(j), px[i + j] + ox, py[i + j] + oy)) return false;
    }
    if (r.sc.cost > r.max_cost) return false;
  }
  alignas(32) double parts[8];
  _mm256_store_pd(parts, sum0);
  _mm256_store_pd(parts + 4, sum1);
  for (const double v : parts) r.sum += v;
  return true;
}
#endif

/// Scores the samples placed by `placement` and then moved by (ox, oy) whole cells.
/// With `slack` > 0 a sample agrees when any target cell within `slack` cells (Chebyshev) agrees
/// (the coarse search: its steps are 2 cells, so the right answer is at most 1 cell away).
/// Stops early, returning a partial score, once the capped cost passes `max_cost` (it only
/// grows, so such a candidate cannot beat one with that cost). With `simd` (and an AVX2 CPU)
/// 8 samples at a time: the same counts, the mean |diff| summed in another order.
Score scorePlaced(const SampleArrays& samples, const Groups& groups, const HeightMap& tgt,
                  const Placement& placement, int ox, int oy, double delta_h, bool simd,
                  int slack = 0, int max_cost = std::numeric_limits<int>::max()) {
  // Maps hold thousands of small objects: only the counts the last candidate raised are reset.
  for (const int g : groups.touched) groups.count[static_cast<std::size_t>(g)] = 0;
  groups.touched.clear();
  Scoring r{samples, groups, tgt, delta_h, 4.0 * delta_h, slack, max_cost, Score{}};
  const int* px = placement.x.data();
  const int* py = placement.y.data();
  const std::size_t n = samples.h.size();
  std::size_t i = 0;
#if defined(__x86_64__) && defined(__GNUC__)
  if (simd && detail::cpuHasAvx2()) {
    i = n - n % 8;
    if (!scoreEightsAvx2(r, px, py, ox, oy, i)) return r.sc;
  }
#endif
  static_cast<void>(simd);
  for (; i < n; ++i)
    if (!r.sample(i, px[i] + ox, py[i] + oy)) return r.sc;
  r.sc.mean_abs = r.sc.compared > 0 ? r.sum / r.sc.compared : 0.0;
  return r.sc;
}

/// Puts first the samples whose score can depend on the candidate: those that differ from some
/// observed target cell within `radius` cells of where the initial T puts them (object edges,
/// changes); after them those that agree with the whole neighbourhood (flat, static). A
/// candidate that cannot beat the best so far then passes the best cost, and stops, after few
/// samples. Stable: each part keeps the raster order.
void sensitiveFirst(std::vector<Sample>& samples, const HeightMap& tgt, double delta_h,
                    int radius) {
  const auto sensitive = [&](const Sample& smp) {
    const Eigen::Vector2i c = tgt.cellOf(smp.uv);
    for (int y = c.y() - radius; y <= c.y() + radius; ++y)
      for (int x = c.x() - radius; x <= c.x() + radius; ++x) {
        if (!tgt.inBounds(x, y)) continue;
        const float h = tgt.at(x, y);
        if (h != kUnobserved &&
            std::abs(static_cast<double>(h) - static_cast<double>(smp.h)) > delta_h)
          return true;
      }
    return false;
  };
  std::stable_partition(samples.begin(), samples.end(), sensitive);
}

/// What a candidate flips against the initial T (placed as scorePlaced would, no slack):
/// `fixed` samples mismatched there and agree here, `broken` agreed there and mismatch here;
/// `run` is the mean distance the candidate moves a sample, in target cells.
struct Flips {
  int fixed = 0, broken = 0;
  double run = 0.0;
};

Flips flips(const std::vector<Sample>& samples, const HeightMap& tgt, const Eigen::Vector2d& pivot,
            double yaw, const Eigen::Vector2d& shift, double delta_h) {
  const Placement placement = place(samples, tgt, pivot, yaw, shift);
  const Eigen::Rotation2Dd R(yaw);
  Flips f;
  double moved = 0.0;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const Eigen::Vector2d d = samples[i].uv - pivot;
    moved += (R * d + shift - d).norm();
    const int x = placement.x[i], y = placement.y[i];
    const float ht = tgt.inBounds(x, y) ? tgt.at(x, y) : kUnobserved;
    if (ht == kUnobserved) continue;  // a mismatch stays one; an agreeing sample is not compared
    const bool differs =
        std::abs(static_cast<double>(ht) - static_cast<double>(samples[i].h)) > delta_h;
    f.fixed += samples[i].mismatched && !differs;
    f.broken += !samples[i].mismatched && differs;
  }
  f.run = samples.empty() ? 0.0 : moved / static_cast<double>(samples.size()) / tgt.cell_size;
  return f;
}

/// The paired (McNemar) test of a candidate's flips: (fixed - broken) / sqrt(fixed + broken) in
/// independent events. A candidate that moves the map by s cells moves every height edge by s
/// cells, flipping runs of about s cells along it: one event per run, at least one cell.
double pairedSigmas(const Flips& f) {
  if (f.fixed + f.broken == 0) return 0.0;
  const double run = std::max(1.0, f.run);
  return (f.fixed - f.broken) / run / std::sqrt((f.fixed + f.broken) / run);
}

/// True when `a` is a strictly better cost than `b` (capped mismatches, then mean |diff|).
bool better(const Score& a, const Score& b) {
  if (a.cost != b.cost) return a.cost < b.cost;
  return a.mean_abs < b.mean_abs - 1e-9;
}

/// The group of source cell (x, y) as refineInPlane assigns it: the source object it lies on,
/// else the target object the initial T puts it on (after the n_src source objects), else 0.
int groupOfCell(int x, int y, const HeightMap& src, const ObjectMap& src_objects,
                const HeightMap& tgt, const ObjectMap& tgt_objects, const Pose& T) {
  const int g = src_objects.at(x, y);
  if (g > 0) return g;
  const Eigen::Vector2d c = src.cellCenter(x, y);
  const Eigen::Vector2i tc = tgt.cellOf((T * Eigen::Vector3d(c.x(), c.y(), 0.0)).head<2>());
  if (!tgt.inBounds(tc.x(), tc.y())) return 0;
  const int t = tgt_objects.at(tc.x(), tc.y());
  return t > 0 ? src_objects.numObjects() + t : 0;
}

/// Background samples within `radius` cells of a changed object (one that mismatches in more
/// than half its samples under the initial T) join its group as its ring. Such an object
/// mismatches wherever a candidate puts the map; the background a shift sweeps onto or off it is
/// part of that change, not evidence against the shift, and its group is already over its cap.
/// Without rings every candidate but the initial T pays the crescent each changed object sweeps
/// (design.md, "Rings of changed objects"). `cells` holds each sample's source cell index.
void absorbRings(std::vector<Sample>& samples, const std::vector<std::size_t>& cells,
                 std::size_t n_groups, const HeightMap& src, const ObjectMap& src_objects,
                 const HeightMap& tgt, const ObjectMap& tgt_objects, const Pose& T, int radius) {
  const Groups core = groupsOf(samples, n_groups);  // no rings yet: each object's own cap
  std::vector<int> mismatched(n_groups, 0);
  for (const Sample& smp : samples)
    if (smp.mismatched) ++mismatched[static_cast<std::size_t>(smp.group)];
  std::vector<char> changed(n_groups, 0);
  bool any = false;
  for (std::size_t g = 1; g < n_groups; ++g) {
    changed[g] = mismatched[g] > core.cap[g];
    any = any || changed[g];
  }
  if (!any) return;
  // Breadth-first from the changed objects' cells through the background; other objects' cells
  // are neither entered nor reassigned.
  std::vector<int> owner(src.numCells(), 0), dist(src.numCells(), -1);
  std::vector<std::size_t> queue;
  for (int y = 0; y < src.height; ++y)
    for (int x = 0; x < src.width; ++x) {
      const int g = groupOfCell(x, y, src, src_objects, tgt, tgt_objects, T);
      if (g == 0) continue;
      const std::size_t i = src.index(x, y);
      owner[i] = g;
      dist[i] = 0;
      if (changed[static_cast<std::size_t>(g)]) queue.push_back(i);
    }
  for (std::size_t q = 0; q < queue.size(); ++q) {
    const std::size_t i = queue[q];
    if (dist[i] >= radius) continue;
    const int x = static_cast<int>(i % static_cast<std::size_t>(src.width));
    const int y = static_cast<int>(i / static_cast<std::size_t>(src.width));
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        if (!src.inBounds(x + dx, y + dy)) continue;
        const std::size_t n = src.index(x + dx, y + dy);
        if (dist[n] >= 0) continue;
        dist[n] = dist[i] + 1;
        owner[n] = owner[i];
        queue.push_back(n);
      }
  }
  for (std::size_t k = 0; k < samples.size(); ++k)
    if (samples[k].group == 0 && owner[cells[k]] > 0) {
      samples[k].group = owner[cells[k]];
      samples[k].ring = true;
    }
}

/// Per source cell under the initial T: -1 not compared, 0 agrees, 1 differs. A difference with
/// no differing 8-neighbour is sensor noise (the comparison's component filter drops it too):
/// it is not a sample, so noise cannot dilute the evidence of a real misalignment. Computed on
/// first use: only the samples and the neighbours of differing ones need it.
class CellStates {
 public:
  CellStates(const HeightMap& src, const HeightMap& tgt, const Pose& T, double delta_h)
      : src_(src), tgt_(tgt), T_(T), delta_h_(delta_h), state_(src.numCells(), kNotYet) {}

  std::int8_t at(int x, int y) {
    std::int8_t& st = state_[src_.index(x, y)];
    if (st != kNotYet) return st;
    st = -1;
    const float h = src_.at(x, y);
    if (h == kUnobserved) return st;
    const Eigen::Vector2d c = src_.cellCenter(x, y);
    const Eigen::Vector2i tc = tgt_.cellOf((T_ * Eigen::Vector3d(c.x(), c.y(), 0.0)).head<2>());
    if (!tgt_.inBounds(tc.x(), tc.y()) || !tgt_.observed(tc.x(), tc.y())) return st;
    st = std::abs(static_cast<double>(tgt_.at(tc.x(), tc.y())) - static_cast<double>(h)) > delta_h_
             ? 1
             : 0;
    return st;
  }

  /// True when no 8-neighbour of (x, y) differs.
  bool isolated(int x, int y) {
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        if ((dx == 0 && dy == 0) || x + dx < 0 || y + dy < 0 || x + dx >= src_.width ||
            y + dy >= src_.height)
          continue;
        if (at(x + dx, y + dy) == 1) return false;
      }
    return true;
  }

 private:
  static constexpr std::int8_t kNotYet = -2;
  const HeightMap& src_;
  const HeightMap& tgt_;
  const Pose& T_;
  double delta_h_;
  std::vector<std::int8_t> state_;
};

/// The samples of a refinement, their source cells and groups, and the pivot of its yaw.
struct SampleSet {
  std::vector<Sample> samples;
  std::vector<std::size_t> cells;  ///< each sample's source cell
  std::size_t n_groups = 0;
  Eigen::Vector2d pivot = Eigen::Vector2d::Zero();  ///< centre of the samples' box
};

/// Observed source cells, evenly subsampled to at most `cap`, that compare under T and are no
/// isolated difference. Groups: a sample on an object of the source map belongs to it; else one
/// whose target cell (initial T) is on an object of the target map belongs to that one; else the
/// background.
SampleSet sampleCells(const HeightMap& src, const ObjectMap& src_objects, const HeightMap& tgt,
                      const ObjectMap& tgt_objects, const Pose& T, double delta_h,
                      std::size_t observed, std::size_t cap) {
  const std::size_t stride = (observed + cap - 1) / cap;
  CellStates states(src, tgt, T, delta_h);
  SampleSet set;
  set.n_groups = static_cast<std::size_t>(1 + src_objects.numObjects() + tgt_objects.numObjects());
  set.samples.reserve(std::min(observed, cap) + 1);
  std::size_t k = 0;
  Eigen::Vector2d lo(std::numeric_limits<double>::infinity(),
                     std::numeric_limits<double>::infinity());
  Eigen::Vector2d hi = -lo;
  for (int y = 0; y < src.height; ++y) {
    for (int x = 0; x < src.width; ++x) {
      const float h = src.at(x, y);
      if (h == kUnobserved) continue;
      if (k++ % stride != 0) continue;
      const std::int8_t st = states.at(x, y);
      if (st < 0 || (st == 1 && states.isolated(x, y))) continue;
      const Eigen::Vector2d c = src.cellCenter(x, y);
      const Eigen::Vector2d uv = (T * Eigen::Vector3d(c.x(), c.y(), 0.0)).head<2>();
      const int group = groupOfCell(x, y, src, src_objects, tgt, tgt_objects, T);
      set.samples.push_back({uv, h, st == 1, group});
      set.cells.push_back(src.index(x, y));
      lo = lo.cwiseMin(uv);
      hi = hi.cwiseMax(uv);
    }
  }
  set.pivot = 0.5 * (lo + hi);
  return set;
}

/// A candidate in-plane motion: shift (m) and yaw (degrees) about the pivot.
struct Cand {
  double du = 0.0, dv = 0.0, yaw_deg = 0.0;
  double motion() const { return std::hypot(du, dv) + 0.01 * std::abs(yaw_deg); }
};

/// A sample set as scored (in its final order), with its placements per yaw (shift 0): a
/// candidate whose shift is whole cells only adds an offset to them, so each sample is rotated
/// once per yaw, not once per candidate.
struct YawPlacements {
  const std::vector<Sample>* samples = nullptr;
  SampleArrays arrays;
  std::vector<std::pair<double, Placement>> by_yaw;
  const Placement& at(const HeightMap& t, const Eigen::Vector2d& pv, double yaw_deg) {
    for (const auto& [y, p] : by_yaw)
      if (y == yaw_deg) return p;
    by_yaw.emplace_back(yaw_deg,
                        place(*samples, t, pv, yaw_deg * kPi / 180.0, Eigen::Vector2d::Zero()));
    return by_yaw.back().second;
  }
};

/// A grid of candidates: `shifts` steps of `step` (m) each way in u and v, `yaws` steps of
/// `yaw_step` (degrees) each way, scored with `slack` cells of tolerance.
struct Grid {
  int shifts = 0;
  double step = 0.0;
  int yaws = 0;
  double yaw_step = 0.0;
  int slack = 0;
};

/// Scores the candidates of grids within the search window against `tgt`.
class GridSearch {
 public:
  GridSearch(const HeightMap& tgt, const Eigen::Vector2d& pivot, const Config& cfg)
      : tgt_(tgt), pivot_(pivot), cfg_(cfg) {}

  /// The best candidate of the grid centred on `c` (ties keep the smaller motion) and its score.
  std::pair<Cand, Score> best(YawPlacements& placed, const Groups& groups, const Cand& c,
                              const Grid& g) const {
    std::pair<Cand, Score> out;
    bool any = false;
    for (const Cand& k : candidates(c, g)) {
      const int max_cost = any ? out.second.cost : std::numeric_limits<int>::max();
      const Score sc = score(placed, groups, k, g.slack, max_cost);
      if (!any || better(sc, out.second)) {
        out = {k, sc};
        any = true;
      }
    }
    return out;
  }

 private:
  /// The grid's candidates inside the window, by increasing motion.
  std::vector<Cand> candidates(const Cand& c, const Grid& g) const {
    std::vector<Cand> cands;
    for (int iy = -g.yaws; iy <= g.yaws; ++iy)
      for (int iv = -g.shifts; iv <= g.shifts; ++iv)
        for (int iu = -g.shifts; iu <= g.shifts; ++iu) {
          Cand k{c.du + iu * g.step, c.dv + iv * g.step, c.yaw_deg + iy * g.yaw_step};
          if (std::abs(k.du) > cfg_.inplane_max_shift + 1e-9 ||
              std::abs(k.dv) > cfg_.inplane_max_shift + 1e-9 ||
              std::abs(k.yaw_deg) > cfg_.inplane_max_yaw_deg + 1e-9)
            continue;
          cands.push_back(k);
        }
    std::stable_sort(cands.begin(), cands.end(),
                     [](const Cand& x, const Cand& y) { return x.motion() < y.motion(); });
    return cands;
  }

  /// Whole cells in `d` metres, or INT_MIN when d is no whole number of target cells.
  int wholeCells(double d) const {
    const double c = d / tgt_.cell_size;
    const double r = std::round(c);
    return std::abs(c - r) < 1e-6 && std::abs(r) < 1e6 ? static_cast<int>(r)
                                                       : std::numeric_limits<int>::min();
  }

  Score score(YawPlacements& placed, const Groups& groups, const Cand& k, int slack,
              int max_cost) const {
    const int ox = wholeCells(k.du), oy = wholeCells(k.dv);
    if (ox != std::numeric_limits<int>::min() && oy != std::numeric_limits<int>::min())
      return scorePlaced(placed.arrays, groups, tgt_, placed.at(tgt_, pivot_, k.yaw_deg), ox, oy,
                         cfg_.delta_h, cfg_.simd, slack, max_cost);
    return scorePlaced(
        placed.arrays, groups, tgt_,
        place(*placed.samples, tgt_, pivot_, k.yaw_deg * kPi / 180.0, Eigen::Vector2d(k.du, k.dv)),
        0, 0, cfg_.delta_h, cfg_.simd, slack, max_cost);
  }

  const HeightMap& tgt_;
  Eigen::Vector2d pivot_;
  const Config& cfg_;
};

/// The best candidate near the initial T against the best elsewhere: near wins when it is no
/// worse, and for the session's drift also when it is not clearly worse (the far one's capped
/// cost lower by less than inplane_min_gain_sigmas standard deviations of near's, a Poisson
/// count). A rotation about a far point can drag one moved object onto its new place while the
/// objects near that point stay put; on a table of small objects that fits a few cells better
/// than the drift (design.md, "The session's drift prefers the smaller motion").
bool nearWins(const std::pair<Cand, Score>& near, const std::pair<Cand, Score>& far,
              bool session_drift, const Config& cfg) {
  if (better(near.second, far.second) ||
      (!better(far.second, near.second) && near.first.motion() < far.first.motion()))
    return true;
  return session_drift && near.second.cost - far.second.cost <
                              cfg.inplane_min_gain_sigmas * std::sqrt(near.second.cost);
}

/// Coarse: 2-cell and 1-degree steps over the whole window on at most kCoarseSamples samples;
/// fine: 1-cell and yaw_step steps within 2 coarse steps of the coarse best, on all samples.
/// Returns the fine best and its score. Reorders `set.samples` (sensitiveFirst).
std::pair<Cand, Score> searchWindow(SampleSet& set, const Groups& groups, const HeightMap& tgt,
                                    const Config& cfg, bool session_drift, double step,
                                    double ystep) {
  std::vector<Sample>& samples = set.samples;
  std::vector<Sample> coarse_samples;
  const std::size_t cstride = (samples.size() + kCoarseSamples - 1) / kCoarseSamples;
  for (std::size_t i = 0; i < samples.size(); i += std::max<std::size_t>(1, cstride))
    coarse_samples.push_back(samples[i]);
  // Scores do not depend on the sample order, except the last bits of mean |diff|; the order
  // only decides how soon a losing candidate stops.
  sensitiveFirst(coarse_samples, tgt, cfg.delta_h, kSensitiveRadius);
  sensitiveFirst(samples, tgt, cfg.delta_h, kSensitiveRadius);
  const double cstep = 2.0 * step, cystep = std::max(1.0, ystep);
  YawPlacements coarse_placed{&coarse_samples, arraysOf(coarse_samples), {}};
  YawPlacements placed{&samples, arraysOf(samples), {}};
  const GridSearch grids(tgt, set.pivot, cfg);
  const Cand coarse =
      grids
          .best(coarse_placed, groupsOf(coarse_samples, set.n_groups), Cand{},
                Grid{static_cast<int>(std::floor(cfg.inplane_max_shift / cstep + 1e-9)), cstep,
                     static_cast<int>(std::floor(cfg.inplane_max_yaw_deg / cystep + 1e-9)), cystep,
                     1})
          .first;
  // Fine search around the coarse best and, when that lies elsewhere, around the initial T too:
  // the coarse costs (one-cell slack) are shallow where a table holds few static objects, and
  // drift is small; the capped fine cost decides between the two.
  const Grid fine_grid{2, step, static_cast<int>(std::ceil(cystep / ystep)), ystep, 0};
  std::pair<Cand, Score> fine = grids.best(placed, groups, coarse, fine_grid);
  if (coarse.du != 0.0 || coarse.dv != 0.0 || coarse.yaw_deg != 0.0) {
    const std::pair<Cand, Score> near = grids.best(placed, groups, Cand{}, fine_grid);
    if (nearWins(near, fine, session_drift, cfg)) fine = near;
  }
  return fine;
}

/// A best candidate on the border of the window (one more step would leave it) is no optimum of
/// the drift: the cost may still fall outward, which is what dragging the map onto a moved
/// object's new place does.
bool onWindowBorder(const Cand& c, const Config& cfg, double step, double ystep) {
  const auto onBorder = [](double x, double st, double limit) {
    return std::abs(x) + st > limit + 1e-9;
  };
  return onBorder(c.du, step, cfg.inplane_max_shift) ||
         onBorder(c.dv, step, cfg.inplane_max_shift) ||
         onBorder(c.yaw_deg, ystep, cfg.inplane_max_yaw_deg);
}

/// Model selection: keep the initial T unless the evidence is clear. The best candidate must
/// remove inplane_min_gain_cells cells, and inplane_min_gain_fraction of the initial mismatches
/// or inplane_min_gain_sigmas of their count (a Poisson count) or, for the session's drift, of
/// the paired (McNemar) test on the cells it flips: changed objects that mismatch at every T add
/// no noise to that one (design.md, "In-plane refinement", "The session's drift passes a paired
/// test").
bool clearGain(const Flips& f, int initial_mismatches, int best_mismatches, bool session_drift,
               const Config& cfg) {
  const int gain = initial_mismatches - best_mismatches;
  const double sigmas = cfg.inplane_min_gain_sigmas;
  const bool paired = session_drift && pairedSigmas(f) >= sigmas;
  return gain >= cfg.inplane_min_gain_cells &&
         (gain >= cfg.inplane_min_gain_fraction * initial_mismatches ||
          gain >= sigmas * std::sqrt(initial_mismatches) || paired);
}

/// Applies candidate `c` with score `best` to `out` and to T: Δ = Translate(pivot + shift) *
/// RotZ(dyaw) * Translate(-pivot), in the target frame.
void applyCandidate(const Cand& c, const Score& best, const Eigen::Vector2d& pivot,
                    InPlaneRefinement& out, Pose& T_target_source_local) {
  out.applied = true;
  out.du = c.du;
  out.dv = c.dv;
  out.dyaw = c.yaw_deg * kPi / 180.0;
  out.compared_after = best.compared;
  out.mismatches_after = best.mismatches;
  out.mean_abs_after = best.mean_abs;
  const Eigen::Vector3d p3(pivot.x(), pivot.y(), 0.0);
  Pose delta = Pose::Identity();
  delta.linear() = Eigen::AngleAxisd(out.dyaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  delta.translation() = p3 + Eigen::Vector3d(out.du, out.dv, 0.0) - delta.linear() * p3;
  T_target_source_local = delta * T_target_source_local;
}

}  // namespace

InPlaneRefinement refineInPlane(const HeightMap& src, const HeightMap& tgt,
                                Pose& T_target_source_local, const Config& cfg,
                                const InPlaneSearch& search) {
  // Maps it rejects (empty, or with a cell array of the wrong size: it returns or throws before
  // reading the object maps) get none.
  const bool usable = !src.empty() && !tgt.empty() && src.heights.size() == src.numCells() &&
                      tgt.heights.size() == tgt.numCells();
  if (!usable)
    return refineInPlane(src, ObjectMap{}, tgt, ObjectMap{}, T_target_source_local, cfg, search);
  return refineInPlane(src, computeObjectMap(src, cfg), tgt, computeObjectMap(tgt, cfg),
                       T_target_source_local, cfg, search);
}

InPlaneRefinement refineInPlane(const HeightMap& src, const ObjectMap& src_objects,
                                const HeightMap& tgt, const ObjectMap& tgt_objects,
                                Pose& T_target_source_local, const Config& cfg,
                                const InPlaneSearch& search) {
  InPlaneRefinement out;
  if (src.empty() || tgt.empty() || !(tgt.cell_size > 0.0)) return out;
  if (src.heights.size() != src.numCells() || tgt.heights.size() != tgt.numCells()) {
    throw Error("height map", "cell array does not match the grid size");
  }
  if (!src_objects.sameGeometry(src) || !tgt_objects.sameGeometry(tgt) ||
      src_objects.labels.size() != src.numCells() || tgt_objects.labels.size() != tgt.numCells())
    throw Error("object map", "grid does not match its height map");
  const Pose& T = T_target_source_local;
  const std::size_t observed = src.numObserved();
  if (observed == 0) return out;
  SampleSet set = sampleCells(src, src_objects, tgt, tgt_objects, T, cfg.delta_h, observed,
                              static_cast<std::size_t>(std::max(1, cfg.inplane_max_cells)));
  out.pivot = set.pivot;
  if (search.session_drift)
    absorbRings(set.samples, set.cells, set.n_groups, src, src_objects, tgt, tgt_objects, T,
                static_cast<int>(std::ceil(cfg.inplane_max_shift / src.cell_size - 1e-9)));
  const Groups groups = groupsOf(set.samples, set.n_groups);

  const Score initial =
      scorePlaced(arraysOf(set.samples), groups, tgt,
                  place(set.samples, tgt, set.pivot, 0.0, Eigen::Vector2d::Zero()), 0, 0,
                  cfg.delta_h, cfg.simd);
  out.compared_before = out.compared_after = initial.compared;
  out.mismatches_before = out.mismatches_after = initial.mismatches;
  out.mean_abs_before = out.mean_abs_after = initial.mean_abs;
  if (initial.compared < std::max(1, cfg.inplane_min_compared)) return out;
  // No candidate removes more mismatches than there are: clearGain cannot pass.
  if (initial.mismatches < cfg.inplane_min_gain_cells) return out;

  const double step = cfg.inplane_shift_step > 0.0 ? cfg.inplane_shift_step : tgt.cell_size;
  const double ystep = cfg.inplane_yaw_step_deg;
  const auto [fine, best] = searchWindow(set, groups, tgt, cfg, search.session_drift, step, ystep);
  if (!better(best, initial) || onWindowBorder(fine, cfg, step, ystep)) return out;
  const Flips f = flips(set.samples, tgt, set.pivot, fine.yaw_deg * kPi / 180.0,
                        Eigen::Vector2d(fine.du, fine.dv), cfg.delta_h);
  out.fixed = f.fixed;
  out.broken = f.broken;
  if (!clearGain(f, initial.mismatches, best.mismatches, search.session_drift, cfg)) return out;
  applyCandidate(fine, best, set.pivot, out, T_target_source_local);
  return out;
}

}  // namespace planesdf
