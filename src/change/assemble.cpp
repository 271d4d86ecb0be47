// Typed change events from the candidates of both directions: the same object in place, moves,
// swaps, replacements, then what is left as removed or added (see change.hpp, assembleEvents).

#include <algorithm>
#include <cstdint>
#include <limits>
#include <set>
#include <tuple>
#include <unordered_set>
#include <utility>

#include "change_internal.hpp"

namespace planesdf {

namespace {

double confidenceOf(const ChangeRegion& r, const Config& cfg) {
  if (r.empty()) return 0.0;
  if (r.verdict == BlobValidation::Verdict::Changed && cfg.delta_blob > 0.0)
    return std::clamp(0.5 + 0.5 * (cfg.delta_blob - r.mean_similarity) / cfg.delta_blob, 0.5, 1.0);
  return 0.5;
}

void appendRegion(ChangeRegion& into, const ChangeRegion& from) {
  if (into.empty()) {
    into = from;
    return;
  }
  into.columns.insert(into.columns.end(), from.columns.begin(), from.columns.end());
  into.voxels.insert(into.voxels.end(), from.voxels.begin(), from.voxels.end());
  into.points.insert(into.points.end(), from.points.begin(), from.points.end());
  const double n1 = static_cast<double>(into.voxels.size() - from.voxels.size());
  const double n2 = static_cast<double>(from.voxels.size());
  if (n1 + n2 > 0) into.centroid = (into.centroid * n1 + from.centroid * n2) / (n1 + n2);
  into.bbox.extend(from.bbox);
  const int scored = into.scored + from.scored;
  if (scored > 0)
    into.mean_similarity =
        (into.mean_similarity * into.scored + from.mean_similarity * from.scored) / scored;
  into.scored = scored;
  into.key_voxels += from.key_voxels;
  if (from.verdict == BlobValidation::Verdict::Changed) into.verdict = from.verdict;
  into.shape.cells += from.shape.cells;
  into.shape.area += from.shape.area;
  into.shape.volume += from.shape.volume;
  into.shape.max_height = std::max(into.shape.max_height, from.shape.max_height);
}

/// appendRegion of what of `from` `into` does not hold yet: its other columns, voxels and
/// points (the same object's region taken from two candidates).
void uniteRegion(ChangeRegion& into, const ChangeRegion& from) {
  const auto key2 = [](const Eigen::Vector2i& c) { return std::make_pair(c.x(), c.y()); };
  const auto key3 = [](const auto& v) { return std::make_tuple(v.x(), v.y(), v.z()); };
  std::set<std::pair<int, int>> columns;
  std::set<std::tuple<int, int, int>> voxels;
  std::set<std::tuple<float, float, float>> points;
  for (const auto& c : into.columns) columns.insert(key2(c));
  for (const auto& v : into.voxels) voxels.insert(key3(v));
  for (const auto& p : into.points) points.insert(key3(p));
  ChangeRegion rest = from;
  rest.columns.clear();
  rest.voxels.clear();
  rest.points.clear();
  for (const auto& c : from.columns)
    if (columns.count(key2(c)) == 0) rest.columns.push_back(c);
  for (const auto& v : from.voxels)
    if (voxels.count(key3(v)) == 0) rest.voxels.push_back(v);
  for (const auto& p : from.points)
    if (points.count(key3(p)) == 0) rest.points.push_back(p);
  appendRegion(into, rest);
}

/// Greedy pairing by shape, best first: the pairs (i, j) of `a` and `b` (not yet `a_used` /
/// `b_used`) whose shapes (`shape_a(i)`, `shape_b(j)`) lie within `max_distance`
/// (Config::moved_shape_distance), each index used once; marks the paired ones used.
/// `allowed(i, j)` vetoes a pair.
template <typename ShapeA, typename ShapeB, typename Allowed>
std::vector<std::pair<std::size_t, std::size_t>> pairByShape(std::size_t na, std::size_t nb,
                                                             ShapeA shape_a, ShapeB shape_b,
                                                             std::vector<bool>& a_used,
                                                             std::vector<bool>& b_used,
                                                             double max_distance, Allowed allowed) {
  std::vector<std::tuple<double, std::size_t, std::size_t>> near;
  for (std::size_t i = 0; i < na; ++i)
    for (std::size_t j = 0; j < nb; ++j) {
      const double d = shapeDistance(shape_a(i), shape_b(j));
      if (d < max_distance && allowed(i, j)) near.emplace_back(d, i, j);
    }
  std::sort(near.begin(), near.end());
  std::vector<std::pair<std::size_t, std::size_t>> out;
  for (const auto& [d, i, j] : near) {
    if (a_used[i] || b_used[j]) continue;
    a_used[i] = b_used[j] = true;
    out.emplace_back(i, j);
  }
  return out;
}

}  // namespace

bool columnsOverlap(const std::vector<Eigen::Vector2i>& a, const std::vector<Eigen::Vector2i>& b) {
  std::set<std::pair<int, int>> sa;
  for (const auto& c : a) sa.emplace(c.x(), c.y());
  for (const auto& c : b)
    if (sa.count({c.x(), c.y()}) != 0) return true;
  return false;
}

namespace {

int typeOrder(ChangeType t) {
  return static_cast<int>(t);
}

/// 1 cm cells of a region's points (world), as keys.
std::unordered_set<std::uint64_t> pointCells(const ChangeRegion& r) {
  constexpr double kCell = 0.01;
  std::unordered_set<std::uint64_t> cells;
  for (const Eigen::Vector3f& p : r.points) {
    if (!p.allFinite()) continue;
    const Eigen::Vector3i c = (p.cast<double>() / kCell).array().floor().cast<int>();
    cells.insert((static_cast<std::uint64_t>(c.x() & 0x1fffff) << 42) |
                 (static_cast<std::uint64_t>(c.y() & 0x1fffff) << 21) |
                 static_cast<std::uint64_t>(c.z() & 0x1fffff));
  }
  return cells;
}

/// Appends the points of `from` that `into` does not hold.
void mergePoints(std::vector<Eigen::Vector3f>& into, const std::vector<Eigen::Vector3f>& from) {
  const auto less = [](const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
    return std::tie(a.x(), a.y(), a.z()) < std::tie(b.x(), b.y(), b.z());
  };
  std::vector<Eigen::Vector3f> sorted = into;
  std::sort(sorted.begin(), sorted.end(), less);
  for (const Eigen::Vector3f& p : from)
    if (!std::binary_search(sorted.begin(), sorted.end(), p, less)) into.push_back(p);
}

/// The unused candidates of plane `plane_id` on `region`'s columns are part of it: marked used,
/// their points merged into it.
void absorbCandidates(const std::vector<CandidateChange>& candidates, std::vector<bool>& used,
                      int plane_id, ChangeRegion& region) {
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    if (used[k] || candidates[k].region.plane_id != plane_id) continue;
    if (!columnsOverlap(region.columns, candidates[k].region.columns)) continue;
    used[k] = true;
    mergePoints(region.points, candidates[k].region.points);
  }
}

/// The same object in the bands of two planes (design.md, "One object, one event"): of the
/// candidates of one direction on different planes sharing at least half of the smaller one's
/// point cells, the one with the stronger 3D evidence (Changed before Unknown, then more scored
/// key voxels, then more points) stays with the others' points; the others are marked used.
void mergeDuplicates(std::vector<CandidateChange>& c, std::vector<bool>& used) {
  std::vector<std::unordered_set<std::uint64_t>> cells;
  cells.reserve(c.size());
  for (const CandidateChange& x : c) cells.push_back(pointCells(x.region));
  const auto stronger = [&](std::size_t a, std::size_t b) {
    const ChangeRegion &ra = c[a].region, &rb = c[b].region;
    const bool ca = ra.verdict == BlobValidation::Verdict::Changed;
    const bool cb = rb.verdict == BlobValidation::Verdict::Changed;
    return std::make_tuple(!c[a].supporting, ca, ra.scored, ra.points.size()) >
           std::make_tuple(!c[b].supporting, cb, rb.scored, rb.points.size());
  };
  for (std::size_t i = 0; i < c.size(); ++i)
    for (std::size_t j = i + 1; j < c.size(); ++j) {
      if (used[i] || used[j] || c[i].region.plane_id == c[j].region.plane_id) continue;
      const auto& small = cells[i].size() <= cells[j].size() ? cells[i] : cells[j];
      const auto& large = cells[i].size() <= cells[j].size() ? cells[j] : cells[i];
      if (small.empty()) continue;
      std::size_t shared = 0;
      for (const std::uint64_t k : small) shared += large.count(k);
      if (2 * shared < small.size()) continue;
      const std::size_t keep = stronger(i, j) ? i : j, drop = keep == i ? j : i;
      mergePoints(c[keep].region.points, c[drop].region.points);
      used[drop] = true;
    }
}

/// Whether the target objects of `c` are part of the event whose other side is `other` (a region
/// of the target map): `c` landed on them (`min_overlap` of it or more), or they meet `other`.
bool targetsJoin(const CandidateChange& c, const ChangeRegion& other, double min_overlap) {
  const ChangeRegion& t = c.target_object;
  return !t.empty() && t.plane_id == other.plane_id &&
         (c.target_object_overlap >= min_overlap || columnsOverlap(t.columns, other.columns));
}

/// A candidate's points under the target objects it lands on (CandidateChange::covered_points),
/// kept aside while the events are formed.
struct Covered {
  bool removed = true;  ///< a reference-side candidate
  int plane_id = -1, target_plane_id = -1;
  std::vector<Eigen::Vector2i> columns, target_object_columns;
  std::vector<Eigen::Vector3f> points;
};

std::vector<Covered> coveredOf(std::vector<CandidateChange>& candidates, bool removed) {
  std::vector<Covered> out;
  for (CandidateChange& c : candidates) {
    if (c.covered_points.empty() || c.target_object.empty()) continue;
    out.push_back({removed, c.region.plane_id, c.target_object.plane_id, c.region.columns,
                   c.target_object.columns, std::move(c.covered_points)});
  }
  return out;
}

/// The event side holding a region of `plane_id` on `columns`, or null.
ChangeRegion* sideOn(std::vector<ChangeEvent>& events, ChangeRegion ChangeEvent::*side,
                     int plane_id, const std::vector<Eigen::Vector2i>& columns) {
  for (ChangeEvent& e : events) {
    ChangeRegion& r = e.*side;
    if (!r.empty() && r.plane_id == plane_id && columnsOverlap(r.columns, columns)) return &r;
  }
  return nullptr;
}

/// A candidate's covered points join its event when the objects they stood under are in an event
/// too (a swap or a replacement: both objects changed where they overlap).
void addCoveredPoints(std::vector<ChangeEvent>& events, std::vector<Covered> covered) {
  for (Covered& c : covered) {
    const auto own = c.removed ? &ChangeEvent::reference : &ChangeEvent::current;
    const auto other = c.removed ? &ChangeEvent::current : &ChangeEvent::reference;
    ChangeRegion* into = sideOn(events, own, c.plane_id, c.columns);
    if (into == nullptr ||
        sideOn(events, other, c.target_plane_id, c.target_object_columns) == nullptr)
      continue;
    mergePoints(into->points, c.points);
  }
}

}  // namespace

namespace {

/// The candidates of both directions while they are turned into events: which are used, and the
/// events so far.
struct Assembly {
  const Config& cfg;
  std::vector<CandidateChange> removed, added;
  std::vector<bool> r_used, a_used;
  std::vector<ChangeEvent> events;

  void addMoved(ChangeRegion&& reference, ChangeRegion&& current) {
    ChangeEvent e;
    e.type = ChangeType::Moved;
    e.reference = std::move(reference);
    e.current = std::move(current);
    events.push_back(std::move(e));
  }
};

bool unknown(const CandidateChange& c) {
  return c.region.verdict == BlobValidation::Verdict::Unknown;
}

/// True when the other direction found a change with 3D evidence (Changed) on c's footprint.
bool evidenceAgainst(const CandidateChange& c, const std::vector<CandidateChange>& others) {
  for (const CandidateChange& o : others)
    if (o.region.verdict == BlobValidation::Verdict::Changed &&
        o.region.plane_id == c.target_plane_id &&
        columnsOverlap(c.target_columns, o.region.columns))
      return true;
  return false;
}

/// The same object in place, seen from other viewpoints, is static: a candidate without 3D
/// evidence (Unknown) that lands on an object of the other map with its shape and position
/// (sameInPlace), unless the other direction found a change with 3D evidence on its footprint;
/// and a removed and an added candidate with matching shapes standing on the same columns,
/// neither with 3D evidence (the validation scored no key voxel). Candidates the validation did
/// score keep their verdict.
void dropStaticInPlace(Assembly& a) {
  std::vector<CandidateChange>& removed = a.removed;
  std::vector<CandidateChange>& added = a.added;
  for (std::size_t i = 0; i < removed.size(); ++i)
    if (unknown(removed[i]) && removed[i].same_in_place && !evidenceAgainst(removed[i], added))
      a.r_used[i] = true;
  for (std::size_t j = 0; j < added.size(); ++j)
    if (unknown(added[j]) && added[j].same_in_place && !evidenceAgainst(added[j], removed))
      a.a_used[j] = true;
  for (std::size_t i = 0; i < removed.size(); ++i) {
    if (!unknown(removed[i]) || removed[i].supporting) continue;
    for (std::size_t j = 0; j < added.size() && !a.r_used[i]; ++j) {
      if (a.a_used[j] || !unknown(added[j]) || added[j].supporting ||
          added[j].region.plane_id != removed[i].target_plane_id)
        continue;
      if (!columnsOverlap(removed[i].target_columns, added[j].region.columns)) continue;
      if (shapeDistance(removed[i].region.shape, added[j].region.shape) >=
          a.cfg.moved_shape_distance)
        continue;
      // Coverage shifts a region's centroid by a fraction of its size; a move by the move.
      const ChangeRegion& rr = removed[i].region;
      const ChangeRegion& ar = added[j].region;
      const double size = std::min(rr.bbox.diagonal().norm(), ar.bbox.diagonal().norm());
      if ((rr.centroid - ar.centroid).norm() > a.cfg.in_place_shift_fraction * size) continue;
      a.r_used[i] = a.a_used[j] = true;
    }
  }
}

/// Objects a moved object stands on in the other session, each with whether the move covers it
/// by half or more (else it is only taken by a move it meets: the lower part of a taller object,
/// under the other one).
using Landed = std::vector<std::pair<ChangeRegion, bool>>;

void landedOn(CandidateChange& c, Landed& into, double min_overlap) {
  if (!c.target_object.empty())
    into.emplace_back(std::move(c.target_object), c.target_object_overlap >= min_overlap);
}

/// Of `regions`, those no Moved event's `side` overlaps and that a move covers by half; the
/// others join the event they overlap.
std::vector<ChangeRegion> takeIntoMoves(Assembly& a, Landed& regions,
                                        ChangeRegion ChangeEvent::*side) {
  std::vector<ChangeRegion> left;
  for (auto& [region, covered] : regions) {
    ChangeRegion& x = region;  // a lambda may not capture a structured binding (C++17)
    const auto e = std::find_if(a.events.begin(), a.events.end(), [&](const ChangeEvent& o) {
      const ChangeRegion& r = o.*side;
      return o.type == ChangeType::Moved && r.plane_id == x.plane_id &&
             columnsOverlap(r.columns, x.columns);
    });
    if (e != a.events.end()) {
      uniteRegion((*e).*side, x);
    } else if (covered) {
      left.push_back(std::move(x));
    }
  }
  return left;
}

/// Whether added candidate j stands where another removed candidate stood while removed candidate
/// i left an empty footprint (it lands on nothing): j is that object's replacement, i a removal,
/// not a move of i onto a spot another object just left (design.md, "Replacement before move").
/// In a swap, i lands on the other object, so swaps still pair.
bool replacesAnother(const Assembly& a, std::size_t i, std::size_t j) {
  if (!a.removed[i].target_object.empty()) return false;
  const CandidateChange& c = a.added[j];
  for (std::size_t k = 0; k < a.removed.size(); ++k) {
    const CandidateChange& r = a.removed[k];
    if (k == i || a.r_used[k] || r.supporting || r.target_plane_id != c.region.plane_id) continue;
    if (columnsOverlap(r.target_columns, c.region.columns)) return true;
  }
  return false;
}

/// Moved: greedy over the pairs with matching shapes, best first (supporting slivers are no
/// object's shape; replacesAnother vetoes a pair). Then swaps (design.md, "Swaps"): each moved
/// object lands on the other one whole, in both places. A move overlapping such a region takes it
/// (the other object's blobs were only the ring the larger one leaves uncovered); regions no move
/// overlaps (the other object's blobs all covered) pair by shape as the other object's move.
void pairMoves(Assembly& a) {
  std::vector<CandidateChange>& removed = a.removed;
  std::vector<CandidateChange>& added = a.added;
  // The objects a moved object stands on in the other session: in a swap, the other object
  // where this one went (reference side) and where it came from (current side).
  Landed under_reference, under_current;
  std::vector<bool> r_skip = a.r_used, a_skip = a.a_used;
  for (std::size_t i = 0; i < removed.size(); ++i) r_skip[i] = r_skip[i] || removed[i].supporting;
  for (std::size_t j = 0; j < added.size(); ++j) a_skip[j] = a_skip[j] || added[j].supporting;
  const auto movedPairs = pairByShape(
      removed.size(), added.size(),
      [&](std::size_t i) -> const ShapeSignature& { return removed[i].region.shape; },
      [&](std::size_t j) -> const ShapeSignature& { return added[j].region.shape; }, r_skip, a_skip,
      a.cfg.moved_shape_distance,
      [&](std::size_t i, std::size_t j) { return !replacesAnother(a, i, j); });
  for (const auto& [i, j] : movedPairs) {
    a.r_used[i] = a.a_used[j] = true;
    landedOn(added[j], under_reference, a.cfg.replaced_min_overlap);
    landedOn(removed[i], under_current, a.cfg.replaced_min_overlap);
    a.addMoved(std::move(removed[i].region), std::move(added[j].region));
  }
  std::vector<ChangeRegion> left_reference =
      takeIntoMoves(a, under_reference, &ChangeEvent::reference);
  std::vector<ChangeRegion> left_current = takeIntoMoves(a, under_current, &ChangeEvent::current);
  std::vector<bool> ref_taken(left_reference.size(), false), cur_taken(left_current.size(), false);
  const auto swapPairs = pairByShape(
      left_reference.size(), left_current.size(),
      [&](std::size_t i) -> const ShapeSignature& { return left_reference[i].shape; },
      [&](std::size_t j) -> const ShapeSignature& { return left_current[j].shape; }, ref_taken,
      cur_taken, a.cfg.moved_shape_distance, [](std::size_t, std::size_t) { return true; });
  for (const auto& [i, j] : swapPairs)
    a.addMoved(std::move(left_reference[i]), std::move(left_current[j]));
}

/// The replacement of removed candidate i: the added candidates on its footprint, or the target
/// objects it landed on; nothing when only supporting slivers are there.
void replace(Assembly& a, std::size_t i) {
  CandidateChange& r = a.removed[i];
  std::vector<std::size_t> on_footprint;
  bool any_strong = !r.supporting;
  for (std::size_t j = 0; j < a.added.size(); ++j) {
    if (a.a_used[j] || a.added[j].region.plane_id != r.target_plane_id) continue;
    if (!columnsOverlap(r.target_columns, a.added[j].region.columns)) continue;
    on_footprint.push_back(j);
    any_strong = any_strong || !a.added[j].supporting;
  }
  if (!any_strong) return;  // supporting slivers only: no event (design.md)
  ChangeEvent e;
  for (const std::size_t j : on_footprint) {
    a.a_used[j] = true;
    appendRegion(e.current, a.added[j].region);
    // The old objects it landed on, whole: where the new object is taller, its blob holds only
    // the part above them (design.md, "Changed objects whole").
    if (targetsJoin(a.added[j], r.region, a.cfg.replaced_min_overlap))
      uniteRegion(r.region, a.added[j].target_object);
  }
  // Likewise the new objects the old one landed on, whole.
  if (!e.current.empty() && targetsJoin(r, e.current, a.cfg.replaced_min_overlap))
    uniteRegion(e.current, r.target_object);
  if (e.current.empty() && r.target_object_overlap >= a.cfg.replaced_min_overlap &&
      !r.target_object.empty()) {
    // Another sliver of the same old object, replaced by the same new one: one event.
    const auto same = std::find_if(a.events.begin(), a.events.end(), [&](const ChangeEvent& o) {
      return o.type == ChangeType::Replaced && o.current.plane_id == r.target_object.plane_id &&
             columnsOverlap(o.current.columns, r.target_object.columns);
    });
    if (same != a.events.end()) {
      a.r_used[i] = true;
      appendRegion(same->reference, r.region);
      return;
    }
    e.current = std::move(r.target_object);
    // An added candidate on those objects (the part of a wider new object around the old
    // footprint) is this replacement, not another event (design.md, "One object, one event").
    absorbCandidates(a.added, a.a_used, r.target_plane_id, e.current);
  }
  if (e.current.empty()) return;
  a.r_used[i] = true;
  e.type = r.small_move ? ChangeType::Moved : ChangeType::Replaced;
  e.reference = std::move(r.region);
  a.events.push_back(std::move(e));
}

/// A small move found only from the current side: the object it was in the reference, with any
/// removed candidate on it.
void currentSideSmallMoves(Assembly& a) {
  for (std::size_t j = 0; j < a.added.size(); ++j) {
    CandidateChange& c = a.added[j];
    if (a.a_used[j] || !c.small_move || c.target_object.empty()) continue;
    a.a_used[j] = true;
    ChangeEvent e;
    e.type = ChangeType::Moved;
    e.reference = std::move(c.target_object);
    absorbCandidates(a.removed, a.r_used, c.target_plane_id, e.reference);
    e.current = std::move(c.region);
    a.events.push_back(std::move(e));
  }
}

/// The candidates left: removed and added objects (supporting slivers are no event).
void addRemovedAndAdded(Assembly& a) {
  for (std::size_t i = 0; i < a.removed.size(); ++i) {
    if (a.r_used[i] || a.removed[i].supporting) continue;
    ChangeEvent e;
    e.type = ChangeType::Removed;
    e.reference = std::move(a.removed[i].region);
    a.events.push_back(std::move(e));
  }
  for (std::size_t j = 0; j < a.added.size(); ++j) {
    if (a.a_used[j] || a.added[j].supporting) continue;
    ChangeEvent e;
    e.type = ChangeType::Added;
    e.current = std::move(a.added[j].region);
    a.events.push_back(std::move(e));
  }
}

/// Events in a stable order (type, plane, centroid), numbered from 1, with their confidence.
void numberEvents(std::vector<ChangeEvent>& events, const Config& cfg) {
  std::stable_sort(events.begin(), events.end(), [](const ChangeEvent& a, const ChangeEvent& b) {
    const auto ka = std::make_tuple(typeOrder(a.type), a.planeId(), a.primary().centroid.x(),
                                    a.primary().centroid.y(), a.primary().centroid.z());
    const auto kb = std::make_tuple(typeOrder(b.type), b.planeId(), b.primary().centroid.x(),
                                    b.primary().centroid.y(), b.primary().centroid.z());
    return ka < kb;
  });
  for (std::size_t k = 0; k < events.size(); ++k) {
    ChangeEvent& e = events[k];
    e.id = static_cast<int>(k) + 1;
    e.confidence = std::max(confidenceOf(e.reference, cfg), confidenceOf(e.current, cfg));
  }
}

}  // namespace

std::vector<ChangeEvent> assembleEvents(std::vector<CandidateChange> removed,
                                        std::vector<CandidateChange> added, const Config& cfg) {
  Assembly a{cfg, {}, {}, {}, {}, {}};
  a.r_used.assign(removed.size(), false);
  a.a_used.assign(added.size(), false);
  a.removed = std::move(removed);
  a.added = std::move(added);
  mergeDuplicates(a.removed, a.r_used);
  mergeDuplicates(a.added, a.a_used);
  std::vector<Covered> covered = coveredOf(a.removed, true);
  for (Covered& c : coveredOf(a.added, false)) covered.push_back(std::move(c));
  dropStaticInPlace(a);
  pairMoves(a);
  // Replaced: a removed object with something else standing on its footprint now.
  for (std::size_t i = 0; i < a.removed.size(); ++i)
    if (!a.r_used[i]) replace(a, i);
  currentSideSmallMoves(a);
  addRemovedAndAdded(a);
  addCoveredPoints(a.events, std::move(covered));
  numberEvents(a.events, cfg);
  return std::move(a.events);
}

}  // namespace planesdf
