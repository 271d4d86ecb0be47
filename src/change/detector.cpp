// The incremental ChangeDetector (see events.hpp).

#include <algorithm>
#include <chrono>
#include <map>
#include <sstream>
#include <string>
#include <utility>

#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"
#include "planesdf/events.hpp"
#include "session_comparison.hpp"

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

/// True when the 3D validation could check a side of `e` (enough key voxels scored against an
/// observed counterpart): both sessions saw the object's surfaces, not only its heights.
bool shapeChecked(const ChangeEvent& e) {
  const auto checked = [](const ChangeRegion& r) {
    return !r.empty() && r.verdict != BlobValidation::Verdict::Unknown;
  };
  return checked(e.reference) || checked(e.current);
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
  requireGeometry(cfg_, *reference_, "config", "the reference map");
  comparison_ = std::make_unique<detail::SessionComparison>(*reference_, cfg_, DetectOptions{});
}

ChangeDetector::ChangeDetector(const ChangeDetector& other)
    : reference_(other.reference_),
      cfg_(other.cfg_),
      callbacks_(other.callbacks_),
      comparison_(std::make_unique<detail::SessionComparison>(*other.comparison_)),
      active_(other.active_),
      pending_(other.pending_),
      next_id_(other.next_id_) {}

ChangeDetector::ChangeDetector(ChangeDetector&& other) noexcept = default;
ChangeDetector& ChangeDetector::operator=(ChangeDetector&& other) noexcept = default;
ChangeDetector::~ChangeDetector() = default;

ChangeDetector& ChangeDetector::operator=(const ChangeDetector& other) {
  if (this != &other) *this = ChangeDetector(other);
  return *this;
}

void ChangeDetector::onEvent(Callback callback) {
  callbacks_.push_back(std::move(callback));
}

std::vector<ChangeEvent> ChangeDetector::events() const {
  std::vector<ChangeEvent> out;
  for (const auto& [id, t] : active_) out.push_back(t.shown);
  return out;
}

void ChangeDetector::restore(const std::vector<ChangeEvent>& events, int next_id) {
  std::map<int, Track> active;
  for (const ChangeEvent& e : events) {
    if (e.id < 1 || e.id >= next_id)
      throw Error("events", "change id " + std::to_string(e.id) + " is not in [1, next id " +
                                std::to_string(next_id) + ")");
    if (!active.emplace(e.id, Track{e, e}).second)
      throw Error("events", "change id " + std::to_string(e.id) + " appears twice");
  }
  active_ = std::move(active);
  pending_.clear();
  next_id_ = next_id;
}

UpdateStats ChangeDetector::update(const Map& current) {
  return run(current, false);
}

UpdateStats ChangeDetector::finish(const Map& current) {
  return run(current, true);
}

UpdateStats ChangeDetector::run(const Map& current, bool finishing) {
  const auto t0 = std::chrono::steady_clock::now();
  UpdateStats stats;
  requireGeometry(cfg_, current, "current map", "the current map");
  detail::SessionComparison::Run r = comparison_->run(current);
  stats.pairs_checked = r.pairs_checked;
  stats.pairs_reused = r.pairs_reused;
  settle(std::move(r.set.events), current.frames(), finishing, stats);
  std::stable_sort(stats.notifications.begin(), stats.notifications.end(),
                   [](const ChangeEvent& a, const ChangeEvent& b) { return a.id < b.id; });
  for (const ChangeEvent& e : stats.notifications)
    for (const Callback& cb : callbacks_) cb(e);
  stats.milliseconds =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

void ChangeDetector::settle(std::vector<ChangeEvent> fresh, std::uint64_t now, bool finishing,
                            UpdateStats& stats) {
  // A verdict the 3D validation checked settles sooner than one resting on heights alone; an
  // absence settles as soon as a checked verdict (design.md, "Stable events").
  const auto held = [&](const Track& t) {
    if (finishing) return true;
    const int frames = t.absent || shapeChecked(t.latest) ? cfg_.event_settle_frames
                                                          : cfg_.event_unscored_settle_frames;
    return now - t.since >= static_cast<std::uint64_t>(frames);
  };
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
