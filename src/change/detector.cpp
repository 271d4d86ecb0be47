// The incremental ChangeDetector (see events.hpp).

#include <algorithm>
#include <chrono>
#include <set>
#include <utility>

#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"
#include "planesdf/events.hpp"

namespace planesdf {
namespace {

bool sideOverlap(const ChangeRegion& a, const ChangeRegion& b) {
  if (a.empty() || b.empty() || a.plane_id != b.plane_id) return false;
  std::set<std::pair<int, int>> cols;
  for (const auto& c : a.columns) cols.insert({c.x(), c.y()});
  for (const auto& c : b.columns)
    if (cols.count({c.x(), c.y()}) != 0) return true;
  return false;
}

bool sameChange(const ChangeEvent& a, const ChangeEvent& b) {
  return sideOverlap(a.reference, b.reference) || sideOverlap(a.current, b.current);
}

/// A notification-worthy difference between two states of one change.
bool materiallyDifferent(const ChangeEvent& before, const ChangeEvent& after) {
  if (before.type != after.type) return true;
  if (std::abs(before.confidence - after.confidence) > 0.1) return true;
  const auto grew = [](std::size_t a, std::size_t b) {
    const double m = static_cast<double>(std::max<std::size_t>({a, b, 1}));
    return std::abs(static_cast<double>(a) - static_cast<double>(b)) / m > 0.25;
  };
  return grew(before.reference.columns.size(), after.reference.columns.size()) ||
         grew(before.current.columns.size(), after.current.columns.size());
}

}  // namespace

ChangeDetector::ChangeDetector(const Map& reference, const Config& cfg)
    : ChangeDetector(Map(reference), cfg) {}

ChangeDetector::ChangeDetector(Map&& reference, const Config& cfg)
    : reference_(std::move(reference)), cfg_(cfg) {
  validateConfig(cfg_, "config");
  for (const PlaneSdf& p : reference_.planes())
    reference_maps_.push_back(computePlaneMaps(p, reference_.planes(), cfg_));
}

void ChangeDetector::onEvent(Callback callback) {
  callbacks_.push_back(std::move(callback));
}

std::vector<ChangeEvent> ChangeDetector::events() const {
  std::vector<ChangeEvent> out;
  for (const auto& [id, e] : active_) out.push_back(e);
  return out;
}

UpdateStats ChangeDetector::update(const Map& current) {
  const auto t0 = std::chrono::steady_clock::now();
  UpdateStats stats;
  if (reference_.config().voxel_size != current.config().voxel_size)
    throw Error("map", "the reference and current maps have different voxel sizes");
  const auto& rp = reference_.planes();
  const auto& cp = current.planes();

  // Current plane maps, recomputed when the plane's volume (or the plane set) changed.
  const auto currentMaps = [&](int id) -> const PlaneMaps& {
    const PlaneSdf& p = cp[static_cast<std::size_t>(id)];
    auto it = current_maps_.find(id);
    if (it == current_maps_.end() || it->second.maps.revision != p.volume.revision() ||
        it->second.num_planes != cp.size()) {
      CurrentMaps m{computePlaneMaps(p, cp, cfg_), cp.size()};
      it = current_maps_.insert_or_assign(id, std::move(m)).first;
    }
    return it->second.maps;
  };

  std::map<std::tuple<bool, int, int>, PairCache> next;
  std::map<std::pair<int, int>, Pose> refined;  // (ref id, cur id) -> T_cur_ref
  const auto run = [&](bool forward, PlaneMatch m) {
    const int cur_id = forward ? m.target_id : m.source_id;
    const std::uint64_t rev = cp[static_cast<std::size_t>(cur_id)].volume.revision();
    const auto key = std::make_tuple(forward, m.source_id, m.target_id);
    const auto it = pairs_.find(key);
    if (it != pairs_.end() && it->second.current_revision == rev &&
        current_maps_.count(cur_id) != 0 && current_maps_[cur_id].num_planes == cp.size()) {
      ++stats.pairs_reused;
      next[key] = it->second;
      return;
    }
    ++stats.pairs_checked;
    PlanePairResult res;
    bool refine = cfg_.refine_inplane;
    if (!forward) {
      const auto r = refined.find({m.target_id, m.source_id});
      if (r != refined.end()) {
        m.T_target_source_local = r->second.inverse();
        refine = false;
      }
    }
    PairCache pc;
    pc.current_revision = rev;
    if (forward) {
      pc.candidates =
          comparePlanePair(rp[static_cast<std::size_t>(m.source_id)],
                           reference_maps_[static_cast<std::size_t>(m.source_id)],
                           cp[static_cast<std::size_t>(m.target_id)], currentMaps(m.target_id), m,
                           refine, reference_.points(), current.points(), cfg_, options_, &res);
      refined[{m.source_id, m.target_id}] = res.match.T_target_source_local;
    } else {
      pc.candidates =
          comparePlanePair(cp[static_cast<std::size_t>(m.source_id)], currentMaps(m.source_id),
                           rp[static_cast<std::size_t>(m.target_id)],
                           reference_maps_[static_cast<std::size_t>(m.target_id)], m, refine,
                           current.points(), reference_.points(), cfg_, options_, &res);
    }
    next[key] = std::move(pc);
  };
  for (const PlaneMatch& m : uniqueMatches(registerPlanes(reference_, current, cfg_))) run(true, m);
  for (const PlaneMatch& m : uniqueMatches(registerPlanes(current, reference_, cfg_)))
    run(false, m);
  pairs_ = std::move(next);

  std::vector<CandidateChange> removed, added;
  for (const auto& [key, pc] : pairs_)
    for (const CandidateChange& c : pc.candidates)
      (std::get<0>(key) ? removed : added).push_back(c);
  std::vector<ChangeEvent> fresh = assembleEvents(std::move(removed), std::move(added), cfg_);

  // Match the fresh results with the active changes.
  std::vector<bool> kept(fresh.size(), false);
  std::map<int, ChangeEvent> still;
  for (auto& [id, old] : active_) {
    std::size_t best = fresh.size();
    for (std::size_t i = 0; i < fresh.size(); ++i)
      if (!kept[i] && sameChange(old, fresh[i])) {
        best = i;
        break;
      }
    if (best == fresh.size()) {
      ChangeEvent gone = old;
      gone.status = ChangeStatus::Retracted;
      gone.frame = current.frames();
      stats.notifications.push_back(std::move(gone));
      continue;
    }
    kept[best] = true;
    ChangeEvent now = std::move(fresh[best]);
    now.id = id;
    now.frame = old.frame;
    now.status = old.status;
    if (materiallyDifferent(old, now)) {
      now.status = ChangeStatus::Updated;
      now.frame = current.frames();
      stats.notifications.push_back(now);
    }
    still.emplace(id, std::move(now));
  }
  for (std::size_t i = 0; i < fresh.size(); ++i) {
    if (kept[i]) continue;
    ChangeEvent e = std::move(fresh[i]);
    e.id = next_id_++;
    e.status = ChangeStatus::New;
    e.frame = current.frames();
    stats.notifications.push_back(e);
    still.emplace(e.id, std::move(e));
  }
  active_ = std::move(still);
  std::stable_sort(stats.notifications.begin(), stats.notifications.end(),
                   [](const ChangeEvent& a, const ChangeEvent& b) { return a.id < b.id; });
  for (const ChangeEvent& e : stats.notifications)
    for (const Callback& cb : callbacks_) cb(e);
  stats.milliseconds =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

}  // namespace planesdf
