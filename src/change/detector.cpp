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
    : ChangeDetector(Map(reference), cfg) {}

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

ChangeDetector::ChangeDetector(Map&& reference, const Config& cfg)
    : reference_(std::move(reference)), cfg_(cfg) {
  validateConfig(cfg_, "config");
  requireGeometry(cfg_, reference_, "config", "the reference map");
  for (const PlaneSdf& p : reference_.planes())
    reference_maps_.push_back(computePlaneMaps(p, reference_.planes(), cfg_, &reference_.points(),
                                               surfaceRimCells(reference_)));
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
  requireGeometry(cfg_, current, "current map", "the current map");
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
      uniqueMatches(registerPlanes(reference_, current, cfg_));
  if (cfg_.refine_inplane) {
    std::vector<std::pair<int, std::uint64_t>> key;
    for (const PlaneMatch& m : forward_matches) {
      const PlaneSdf& p = cp[static_cast<std::size_t>(m.target_id)];
      key.emplace_back(m.target_id, p.volume.revision());
    }
    key.emplace_back(-1, cp.size());
    if (key != correction_key_) {
      correction_ = sessionCorrection(
          reference_, current, forward_matches,
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
    const Map& src = forward ? static_cast<const Map&>(reference_) : current;
    const Map& tgt = forward ? current : static_cast<const Map&>(reference_);
    for (PlaneMatch m : forward ? forward_matches : uniqueMatches(registerPlanes(src, tgt, cfg_))) {
      if (forward) m = corrected(m, reference_, current, correction_);
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
          compareMatchedPair(reference_, current, forward, m, forward ? ref_maps : cur_maps,
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
