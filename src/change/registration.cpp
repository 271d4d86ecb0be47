// PlaneSDF registration (paper §III-B) and in-plane (u, v, yaw) refinement; see registration.hpp.

#include "planesdf/registration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

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

// --- in-plane refinement ---------------------------------------------------------------------

namespace {

/// A cell index no grid reaches (place's far or non-finite coordinates).
constexpr int kFarCell = -(1 << 30);
/// Smallest improvement refineInPlane accepts (see there).
constexpr int kMinGainCells = 20;
/// Samples of the coarse search of refineInPlane.
constexpr std::size_t kCoarseSamples = 6000;
/// Cells around a sample's initial place where sensitiveFirst looks for differing heights.
constexpr int kSensitiveRadius = 3;
constexpr double kMinGainFraction = 0.2;
/// ... or at least this many standard deviations of the initial mismatch count (a Poisson
/// count), or with InPlaneSearch::session_drift of the paired (McNemar) test on the cells the
/// candidate flips: changed objects that mismatch at every T add no noise to that one.
constexpr double kMinGainSigmas = 3.0;

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

  // Observed source cells, evenly subsampled to at most max_cells.
  std::size_t observed = src.numObserved();
  if (observed == 0) return out;
  const std::size_t cap = static_cast<std::size_t>(std::max(1, search.max_cells));
  const std::size_t stride = (observed + cap - 1) / cap;
  // Per source cell under the initial T: -1 not compared, 0 agrees, 1 differs. A difference
  // with no differing 8-neighbour is sensor noise (the comparison's component filter drops it
  // too): it is not a sample, so noise cannot dilute the evidence of a real misalignment.
  // Computed on first use: only the samples and the neighbours of differing ones need it.
  constexpr std::int8_t kNotYet = -2;
  std::vector<std::int8_t> state(src.numCells(), kNotYet);
  const auto stateAt = [&](int x, int y) {
    std::int8_t& st = state[src.index(x, y)];
    if (st != kNotYet) return st;
    st = -1;
    const float h = src.at(x, y);
    if (h == kUnobserved) return st;
    const Eigen::Vector2d c = src.cellCenter(x, y);
    const Eigen::Vector2i tc = tgt.cellOf((T * Eigen::Vector3d(c.x(), c.y(), 0.0)).head<2>());
    if (!tgt.inBounds(tc.x(), tc.y()) || !tgt.observed(tc.x(), tc.y())) return st;
    st =
        std::abs(static_cast<double>(tgt.at(tc.x(), tc.y())) - static_cast<double>(h)) > cfg.delta_h
            ? 1
            : 0;
    return st;
  };
  const auto isolated = [&](int x, int y) {
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        if ((dx == 0 && dy == 0) || x + dx < 0 || y + dy < 0 || x + dx >= src.width ||
            y + dy >= src.height)
          continue;
        if (stateAt(x + dx, y + dy) == 1) return false;
      }
    return true;
  };
  // Groups: a sample on an object of the source map belongs to it; else one whose target cell
  // (initial T) is on an object of the target map belongs to that one; else the background.
  const int n_src_objects = src_objects.numObjects();
  const auto n_groups = static_cast<std::size_t>(1 + n_src_objects + tgt_objects.numObjects());
  std::vector<Sample> samples;
  std::vector<std::size_t> cells;  // each sample's source cell
  samples.reserve(std::min(observed, cap) + 1);
  std::size_t k = 0;
  Eigen::Vector2d lo(std::numeric_limits<double>::infinity(),
                     std::numeric_limits<double>::infinity());
  Eigen::Vector2d hi = -lo;
  for (int y = 0; y < src.height; ++y) {
    for (int x = 0; x < src.width; ++x) {
      const float h = src.at(x, y);
      if (h == kUnobserved) continue;
      if (k++ % stride != 0) continue;
      const std::int8_t st = stateAt(x, y);
      if (st < 0 || (st == 1 && isolated(x, y))) continue;
      const Eigen::Vector2d c = src.cellCenter(x, y);
      const Eigen::Vector2d uv = (T * Eigen::Vector3d(c.x(), c.y(), 0.0)).head<2>();
      const int group = groupOfCell(x, y, src, src_objects, tgt, tgt_objects, T);
      samples.push_back({uv, h, st == 1, group});
      cells.push_back(src.index(x, y));
      lo = lo.cwiseMin(uv);
      hi = hi.cwiseMax(uv);
    }
  }
  const Eigen::Vector2d pivot = 0.5 * (lo + hi);
  out.pivot = pivot;
  if (search.session_drift)
    absorbRings(samples, cells, n_groups, src, src_objects, tgt, tgt_objects, T,
                static_cast<int>(std::ceil(search.max_shift / src.cell_size - 1e-9)));
  const Groups groups = groupsOf(samples, n_groups);

  const Score initial = scorePlaced(arraysOf(samples), groups, tgt,
                                    place(samples, tgt, pivot, 0.0, Eigen::Vector2d::Zero()), 0, 0,
                                    cfg.delta_h, cfg.simd);
  out.compared_before = out.compared_after = initial.compared;
  out.mismatches_before = out.mismatches_after = initial.mismatches;
  out.mean_abs_before = out.mean_abs_after = initial.mean_abs;
  if (initial.compared < std::max(1, search.min_compared)) return out;

  const double step = search.shift_step > 0.0 ? search.shift_step : tgt.cell_size;
  const double ystep = search.yaw_step_deg > 0.0 ? search.yaw_step_deg : 0.5;

  struct Cand {
    double du = 0.0, dv = 0.0, yaw_deg = 0.0;
    double motion() const { return std::hypot(du, dv) + 0.01 * std::abs(yaw_deg); }
  };
  // Whole cells in `d` metres, or INT_MIN when d is no whole number of target cells.
  const auto wholeCells = [&](double d) {
    const double c = d / tgt.cell_size;
    const double r = std::round(c);
    return std::abs(c - r) < 1e-6 && std::abs(r) < 1e6 ? static_cast<int>(r)
                                                       : std::numeric_limits<int>::min();
  };
  // A sample set as scored (in its final order), with its placements per yaw (shift 0): a
  // candidate whose shift is whole cells only adds an offset to them, so each sample is rotated
  // once per yaw, not once per candidate.
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
  // Scores every candidate of a grid centred on `c` (ties keep the smaller motion).
  const auto gridSearch = [&](YawPlacements& placed, const Groups& grp, const Cand& c, int ns,
                              double st, int ny, double yst, int slack, Cand* best_c,
                              Score* best_s) {
    std::vector<Cand> cands;
    for (int iy = -ny; iy <= ny; ++iy)
      for (int iv = -ns; iv <= ns; ++iv)
        for (int iu = -ns; iu <= ns; ++iu) {
          Cand k{c.du + iu * st, c.dv + iv * st, c.yaw_deg + iy * yst};
          if (std::abs(k.du) > search.max_shift + 1e-9 ||
              std::abs(k.dv) > search.max_shift + 1e-9 ||
              std::abs(k.yaw_deg) > search.max_yaw_deg + 1e-9)
            continue;
          cands.push_back(k);
        }
    std::stable_sort(cands.begin(), cands.end(),
                     [](const Cand& x, const Cand& y) { return x.motion() < y.motion(); });
    bool any = false;
    for (const Cand& k : cands) {
      const int max_cost = any ? best_s->cost : std::numeric_limits<int>::max();
      const int ox = wholeCells(k.du), oy = wholeCells(k.dv);
      const bool whole =
          ox != std::numeric_limits<int>::min() && oy != std::numeric_limits<int>::min();
      const Score sc = whole
                           ? scorePlaced(placed.arrays, grp, tgt, placed.at(tgt, pivot, k.yaw_deg),
                                         ox, oy, cfg.delta_h, cfg.simd, slack, max_cost)
                           : scorePlaced(placed.arrays, grp, tgt,
                                         place(*placed.samples, tgt, pivot, k.yaw_deg * kPi / 180.0,
                                               Eigen::Vector2d(k.du, k.dv)),
                                         0, 0, cfg.delta_h, cfg.simd, slack, max_cost);
      if (!any || better(sc, *best_s)) {
        *best_s = sc;
        *best_c = k;
        any = true;
      }
    }
  };

  // Coarse: 2-cell and 1-degree steps over the whole window on at most kCoarseSamples samples;
  // fine: 1-cell and yaw_step steps within 2 coarse steps of the coarse best, on all samples.
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
  Cand coarse;
  Score coarse_score;
  gridSearch(coarse_placed, groupsOf(coarse_samples, n_groups), Cand{},
             static_cast<int>(std::floor(search.max_shift / cstep + 1e-9)), cstep,
             static_cast<int>(std::floor(search.max_yaw_deg / cystep + 1e-9)), cystep, 1, &coarse,
             &coarse_score);
  // Fine search around the coarse best and, when that lies elsewhere, around the initial T too:
  // the coarse costs (one-cell slack) are shallow where a table holds few static objects, and
  // drift is small; the capped fine cost decides between the two.
  const int fine_yaw_steps = static_cast<int>(std::ceil(cystep / ystep));
  Cand fine;
  Score best;
  gridSearch(placed, groups, coarse, 2, step, fine_yaw_steps, ystep, 0, &fine, &best);
  if (coarse.du != 0.0 || coarse.dv != 0.0 || coarse.yaw_deg != 0.0) {
    Cand near;
    Score near_score;
    gridSearch(placed, groups, Cand{}, 2, step, fine_yaw_steps, ystep, 0, &near, &near_score);
    if (better(near_score, best) || (!better(best, near_score) && near.motion() < fine.motion())) {
      fine = near;
      best = near_score;
    }
  }
  const Cand* best_cand = better(best, initial) ? &fine : nullptr;
  if (best_cand == nullptr) return out;
  // A best candidate on the border of the window (one more fine step would leave it) is no
  // optimum of the drift: the cost may still fall outward, which is what dragging the map onto
  // a moved object's new place does. Not evidence of drift.
  const auto onBorder = [](double x, double st, double limit) {
    return std::abs(x) + st > limit + 1e-9;
  };
  if (onBorder(fine.du, step, search.max_shift) || onBorder(fine.dv, step, search.max_shift) ||
      onBorder(fine.yaw_deg, ystep, search.max_yaw_deg))
    return out;
  // Model selection: keep the initial T unless the evidence is clear: the best candidate must
  // remove kMinGainCells cells, and kMinGainFraction of the initial mismatches or kMinGainSigmas
  // of their count or of the paired test (design.md, "In-plane refinement", "The session's
  // drift passes a paired test").
  const Flips f = flips(samples, tgt, pivot, fine.yaw_deg * kPi / 180.0,
                        Eigen::Vector2d(fine.du, fine.dv), cfg.delta_h);
  out.fixed = f.fixed;
  out.broken = f.broken;
  const int gain = initial.mismatches - best.mismatches;
  const bool paired = search.session_drift && pairedSigmas(f) >= kMinGainSigmas;
  if (gain < kMinGainCells || (gain < kMinGainFraction * initial.mismatches &&
                               gain < kMinGainSigmas * std::sqrt(initial.mismatches) && !paired))
    return out;

  out.applied = true;
  out.du = best_cand->du;
  out.dv = best_cand->dv;
  out.dyaw = best_cand->yaw_deg * kPi / 180.0;
  out.compared_after = best.compared;
  out.mismatches_after = best.mismatches;
  out.mean_abs_after = best.mean_abs;
  // Δ = Translate(pivot + shift) * RotZ(dyaw) * Translate(-pivot), in the target frame.
  const Eigen::Vector3d p3(pivot.x(), pivot.y(), 0.0);
  Pose delta = Pose::Identity();
  delta.linear() = Eigen::AngleAxisd(out.dyaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  delta.translation() = p3 + Eigen::Vector3d(out.du, out.dv, 0.0) - delta.linear() * p3;
  T_target_source_local = delta * T_target_source_local;
  return out;
}

}  // namespace planesdf
