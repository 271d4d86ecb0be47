// The incremental ChangeDetector (see events.hpp).

#include <algorithm>
#include <chrono>
#include <sstream>
#include <string>
#include <utility>

#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"
#include "planesdf/events.hpp"

namespace planesdf {
namespace {

bool sideOverlap(const ChangeRegion& a, const ChangeRegion& b) {
  return !a.empty() && !b.empty() && a.plane_id == b.plane_id &&
         columnsOverlap(a.columns, b.columns);
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
    : ChangeDetector(std::make_shared<const Map>(reference), cfg) {}

ChangeDetector::ChangeDetector(Map&& reference, const Config& cfg)
    : ChangeDetector(std::make_shared<const Map>(std::move(reference)), cfg) {}

namespace {

/// Throws planesdf::Error(`what`, ...) when `map` was built with another voxel size, truncation
/// or band than `cfg` says.
void requireGeometry(const Config& cfg, const Map& map, const std::string& what,
                     const std::string& map_name) {
  const Config& m = map.config();
  const auto check = [&](const char* key, double config_value, double map_value) {
    if (config_value == map_value) return;
    std::ostringstream msg;
    msg << map_name << " was built with " << key << " " << map_value << ", the detector's config "
        << "says " << config_value << ": build both maps and the detector with one geometry";
    throw Error(what, msg.str());
  };
  check("voxel_size", cfg.voxel_size, m.voxel_size);
  check("truncation_voxels", cfg.truncation_voxels, m.truncation_voxels);
  check("fuse_band", cfg.fuse_band, m.fuse_band);
  check("below_band", cfg.below_band, m.below_band);
}

}  // namespace

ChangeDetector::ChangeDetector(std::shared_ptr<const Map> reference, const Config& cfg)
    : reference_(std::move(reference)), cfg_(cfg) {
  if (!reference_) throw Error("reference map", "null");
  validateConfig(cfg_, "config");
  const Map& ref = *reference_;
  requireGeometry(cfg_, ref, "config", "the reference map");
  for (const PlaneSdf& p : ref.planes())
    reference_maps_.push_back(
        computePlaneMaps(p, ref.planes(), cfg_, &ref.points(), surfaceRimCells(ref)));
}

void ChangeDetector::onEvent(Callback callback) {
  callbacks_.push_back(std::move(callback));
}

std::vector<ChangeEvent> ChangeDetector::events() const {
  std::vector<ChangeEvent> out;
  for (const auto& [id, t] : active_) out.push_back(t.shown);
  return out;
}

UpdateStats ChangeDetector::update(const Map& current) {
  return run(current, cfg_.event_settle_frames);
}

UpdateStats ChangeDetector::finish(const Map& current) {
  return run(current, 0);
}

UpdateStats ChangeDetector::run(const Map& current, int settle_frames) {
  const auto t0 = std::chrono::steady_clock::now();
  UpdateStats stats;
  requireGeometry(cfg_, current, "current map", "the current map");
  settle(compare(current, stats), current.frames(), settle_frames, stats);
  std::stable_sort(stats.notifications.begin(), stats.notifications.end(),
                   [](const ChangeEvent& a, const ChangeEvent& b) { return a.id < b.id; });
  for (const ChangeEvent& e : stats.notifications)
    for (const Callback& cb : callbacks_) cb(e);
  stats.milliseconds =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

std::vector<ChangeEvent> ChangeDetector::compare(const Map& current, UpdateStats& stats) {
  const Map& reference = *reference_;
  const auto& cp = current.planes();

  // Current plane maps, recomputed when the plane's volume (or the plane set) changed.
  const auto currentMaps = [&](int id) -> const PlaneMaps& {
    const PlaneSdf& p = cp[static_cast<std::size_t>(id)];
    auto it = current_maps_.find(id);
    if (it == current_maps_.end() || it->second.maps.revision != p.volume.revision() ||
        it->second.num_planes != cp.size()) {
      CurrentMaps m{computePlaneMaps(p, cp, cfg_, &current.points(), surfaceRimCells(current)),
                    cp.size()};
      it = current_maps_.insert_or_assign(id, std::move(m)).first;
    }
    return it->second.maps;
  };

  // The session-wide localisation correction (see sessionCorrection), re-estimated only when a
  // current plane it depends on changed.
  const std::vector<PlaneMatch> forward_matches =
      uniqueMatches(registerPlanes(reference, current, cfg_));
  if (cfg_.refine_inplane) {
    std::vector<std::pair<int, std::uint64_t>> key;
    for (const PlaneMatch& m : forward_matches) {
      const PlaneSdf& p = cp[static_cast<std::size_t>(m.target_id)];
      key.emplace_back(m.target_id, p.volume.revision());
    }
    key.emplace_back(-1, cp.size());
    if (key != correction_key_) {
      correction_ = sessionCorrection(
          reference, current, forward_matches,
          [&](bool ref, int id) -> const PlaneMaps& {
            return ref ? reference_maps_[static_cast<std::size_t>(id)] : currentMaps(id);
          },
          cfg_);
      correction_key_ = std::move(key);
    }
  }

  std::map<std::tuple<bool, int, int>, PairCache> next;
  RefinedTransforms refined;
  for (bool forward : {true, false}) {  // forward first: its transforms are reused backwards
    const Map& src = forward ? reference : current;
    const Map& tgt = forward ? current : reference;
    for (PlaneMatch m : forward ? forward_matches : uniqueMatches(registerPlanes(src, tgt, cfg_))) {
      if (forward) m = corrected(m, reference, current, correction_);
      const int ref_id = forward ? m.source_id : m.target_id;
      const int cur_id = forward ? m.target_id : m.source_id;
      const std::uint64_t rev = cp[static_cast<std::size_t>(cur_id)].volume.revision();
      const auto key = std::make_tuple(forward, m.source_id, m.target_id);
      const auto it = pairs_.find(key);
      const auto maps_it = current_maps_.find(cur_id);
      if (it != pairs_.end() && it->second.current_revision == rev &&
          it->second.correction == correction_ && maps_it != current_maps_.end() &&
          maps_it->second.num_planes == cp.size()) {
        ++stats.pairs_reused;
        next[key] = it->second;
        if (forward) refined[{ref_id, cur_id}] = it->second.T_target_source;
        continue;
      }
      ++stats.pairs_checked;
      const PlaneMaps& ref_maps = reference_maps_[static_cast<std::size_t>(ref_id)];
      const PlaneMaps& cur_maps = currentMaps(cur_id);
      PlanePairResult res;
      PairCache pc;
      pc.current_revision = rev;
      pc.correction = correction_;
      pc.candidates =
          compareMatchedPair(reference, current, forward, m, forward ? ref_maps : cur_maps,
                             forward ? cur_maps : ref_maps, refined, cfg_, options_, &res);
      pc.T_target_source = res.match.T_target_source_local;
      next[key] = std::move(pc);
    }
  }
  pairs_ = std::move(next);

  std::vector<CandidateChange> removed, added;
  for (const auto& [key, pc] : pairs_)
    for (const CandidateChange& c : pc.candidates)
      (std::get<0>(key) ? removed : added).push_back(c);
  return assembleEvents(std::move(removed), std::move(added), cfg_);
}

void ChangeDetector::settle(std::vector<ChangeEvent> fresh, std::uint64_t now, int settle_frames,
                            UpdateStats& stats) {
  const auto held = [&](const Track& t) { return now - t.since >= std::uint64_t(settle_frames); };
  const auto notify = [&](ChangeEvent e, ChangeStatus status) {
    e.status = status;
    e.frame = now;
    stats.notifications.push_back(e);
    return e;
  };
  std::vector<bool> kept(fresh.size(), false);
  const auto take = [&](const Track& t) {
    for (std::size_t i = 0; i < fresh.size(); ++i)
      if (!kept[i] && (sameChange(t.latest, fresh[i]) || sameChange(t.shown, fresh[i]))) {
        kept[i] = true;
        return i;
      }
    return fresh.size();
  };
  // Announced changes: a difference from what was announced, or their absence, must hold.
  for (auto it = active_.begin(); it != active_.end();) {
    Track& t = it->second;
    const std::size_t i = take(t);
    if (i == fresh.size()) {
      if (!t.absent) t.since = now;
      t.absent = true;
      t.differs = false;
      if (held(t)) {
        notify(t.shown, ChangeStatus::Retracted);
        it = active_.erase(it);
      } else {
        ++it;
      }
      continue;
    }
    ChangeEvent e = std::move(fresh[i]);
    e.id = it->first;
    if (!materiallyDifferent(t.shown, e)) {  // kept silently, as announced
      e.status = t.shown.status;
      e.frame = t.shown.frame;
      t = Track{e, e};
    } else {
      if (t.absent || !t.differs || t.latest.type != e.type) t.since = now;
      t.absent = false;
      t.differs = true;
      t.latest = e;
      if (held(t)) t = Track{notify(std::move(e), ChangeStatus::Updated), t.latest};
    }
    ++it;
  }
  // Pending results: announced once their type has held; dropped when not found again.
  std::vector<Track> pending;
  for (Track& t : pending_) {
    const std::size_t i = take(t);
    if (i == fresh.size()) continue;
    if (t.latest.type != fresh[i].type) t.since = now;
    t.latest = std::move(fresh[i]);
    pending.push_back(std::move(t));
  }
  for (std::size_t i = 0; i < fresh.size(); ++i)
    if (!kept[i]) pending.push_back(Track{ChangeEvent{}, std::move(fresh[i]), now});
  pending_.clear();
  for (Track& t : pending) {
    if (!held(t)) {
      pending_.push_back(std::move(t));
      continue;
    }
    ChangeEvent e = std::move(t.latest);
    e.id = next_id_++;
    e = notify(std::move(e), ChangeStatus::New);
    active_.emplace(e.id, Track{e, e});
  }
}

}  // namespace planesdf
