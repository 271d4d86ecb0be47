// `planesdf bench --stream`: the incremental ChangeDetector as a SLAM loop runs it (issue 26).
// Per simulated preset: the reference session fused, then the current session frame by frame
// with ChangeDetector::update() after every --update-every frames and finish() at the end; the
// notifications are counted against the final events and the offline detectChanges, and each
// ground-truth change's alert latency is measured from the first frame that sees its place.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <map>
#include <set>
#include <sstream>

#include "bench_render.hpp"
#include "commands.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"
#include "planesdf/events.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/map.hpp"
#include "planesdf/sim.hpp"
#include "timing.hpp"

namespace planesdf::cli {
namespace {

using nlohmann::json;

/// A changed object's place: its centre and a radius that covers it.
struct Place {
  Eigen::Vector3d centre;
  double radius = 0.0;
};

/// The ground-truth changes (scene.changes) as the places of their objects in either session.
std::vector<std::vector<Place>> changePlaces(const sim::Scene& scene) {
  const auto placesOf = [](const sim::Session& s, const std::vector<int>& ids,
                           std::vector<Place>& out) {
    for (const sim::Object& o : s.objects)
      if (std::find(ids.begin(), ids.end(), o.id) != ids.end())
        out.push_back(
            {sim::objectPose(o) * Eigen::Vector3d(0, 0, 0.5 * o.size.z()), 0.5 * o.size.norm()});
  };
  std::vector<std::vector<Place>> out;
  for (const sim::Change& c : scene.changes) {
    std::vector<Place> p;
    placesOf(scene.reference, c.reference_ids, p);
    placesOf(scene.current, c.current_ids, p);
    if (!p.empty()) out.push_back(std::move(p));
  }
  return out;
}

/// True when `frame`, taken from `camera_to_world`, sees `place`: its centre projects into the
/// image in range and the depth there reaches it (nothing in front by more than its radius).
bool sees(const DepthFrame& frame, const Pose& camera_to_world, const Place& place) {
  const Eigen::Vector3d p = camera_to_world.inverse() * place.centre;
  if (p.z() <= 0.1) return false;
  const Intrinsics& k = frame.intrinsics;
  const int u = static_cast<int>(std::lround(k.fx * p.x() / p.z() + k.cx));
  const int v = static_cast<int>(std::lround(k.fy * p.y() / p.z() + k.cy));
  if (u < 0 || v < 0 || u >= k.width || v >= k.height) return false;
  const float d = frame.at(u, v);
  return DepthFrame::isValidDepth(d) && d >= p.z() - place.radius;
}

bool near(const ChangeEvent& e, const std::vector<Place>& places) {
  for (const ChangeRegion* r : {&e.reference, &e.current})
    if (!r->empty())
      for (const Place& p : places)
        if ((r->centroid - p.centre).norm() <= p.radius + 0.1) return true;
  return false;
}

/// The same events, compared by type, plane and points (ids and statuses aside).
bool sameEvents(std::vector<ChangeEvent> a, std::vector<ChangeEvent> b) {
  if (a.size() != b.size()) return false;
  const auto key = [](const ChangeEvent& e) {
    return std::make_tuple(static_cast<int>(e.type), e.planeId(), e.numPoints(), e.numVoxels());
  };
  const auto byKey = [&](const ChangeEvent& x, const ChangeEvent& y) { return key(x) < key(y); };
  std::sort(a.begin(), a.end(), byKey);
  std::sort(b.begin(), b.end(), byKey);
  for (std::size_t i = 0; i < a.size(); ++i)
    if (key(a[i]) != key(b[i])) return false;
  return true;
}

json streamRun(const std::string& preset, unsigned seed, const BenchArgs& args) {
  const sim::Scene scene = sim::makePreset(preset, seed);
  std::cerr << "bench --stream: " << preset << " seed " << seed << "\n";
  const Sequence ref = renderSession(scene, scene.reference, 0, args.frames, "reference");
  const Sequence cur = renderSession(scene, scene.current, 1, args.frames, "current");
  Config cfg;
  if (args.settle_frames >= 0) cfg.event_settle_frames = args.settle_frames;
  auto reference = std::make_shared<Map>(cfg);
  for (std::size_t i = 0; i < ref.frames.size(); ++i)
    reference->integrate(ref.frames[i], ref.poses[i]);
  ChangeDetector detector(std::shared_ptr<const Map>(reference), cfg);
  std::map<int, std::uint64_t> announced;  // id -> frame of its New
  int notifications = 0, retracted = 0, type_updates = 0;
  std::map<int, ChangeType> last_type;
  detector.onEvent([&](const ChangeEvent& e) {
    ++notifications;
    if (e.status == ChangeStatus::New) announced.emplace(e.id, e.frame);
    if (e.status == ChangeStatus::Retracted) ++retracted;
    if (e.status == ChangeStatus::Updated && last_type[e.id] != e.type) ++type_updates;
    last_type[e.id] = e.type;
    const Eigen::Vector3d c = e.primary().centroid;
    std::cerr << "bench --stream: frame " << e.frame << " change #" << e.id << " "
              << toString(e.status) << " " << toString(e.type) << " at (" << c.x() << " " << c.y()
              << " " << c.z() << "), " << e.numPoints() << " points\n";
  });
  const std::vector<std::vector<Place>> places = changePlaces(scene);
  std::vector<long> first_seen(places.size(), -1);
  Map current(cfg);
  std::vector<double> integrate_ms, update_ms;
  for (std::size_t i = 0; i < cur.frames.size(); ++i) {
    auto t0 = Clock::now();
    current.integrate(cur.frames[i], cur.poses[i]);
    integrate_ms.push_back(msSince(t0));
    for (std::size_t c = 0; c < places.size(); ++c)
      for (const Place& p : places[c])
        if (first_seen[c] < 0 && sees(cur.frames[i], cur.true_poses[i], p))
          first_seen[c] = static_cast<long>(i) + 1;  // frames() after this frame
    const bool last = i + 1 == cur.frames.size();
    if (!last && (i + 1) % static_cast<std::size_t>(args.update_every) != 0) continue;
    t0 = Clock::now();
    if (last)
      detector.finish(current);
    else
      detector.update(current);
    update_ms.push_back(msSince(t0));
    std::cerr << "bench --stream: frame " << (i + 1) << "/" << cur.frames.size() << ", "
              << notifications << " notifications\n";
  }
  const std::vector<ChangeEvent> final_events = detector.events();
  const ChangeSet offline = detectChanges(*reference, current, cfg);
  std::vector<double> latency;
  int alerted = 0;
  for (std::size_t c = 0; c < places.size(); ++c) {
    std::uint64_t first = 0;
    for (const ChangeEvent& e : final_events)
      if (near(e, places[c]) && (first == 0 || announced[e.id] < first)) first = announced[e.id];
    if (first == 0) continue;
    ++alerted;
    if (first_seen[c] > 0)
      latency.push_back(static_cast<double>(first) - static_cast<double>(first_seen[c]));
  }
  const auto finalCount = static_cast<double>(std::max<std::size_t>(final_events.size(), 1));
  json j;
  j["scene"] = preset;
  j["seed"] = seed;
  j["frames"] = cur.frames.size();
  j["update_every"] = args.update_every;
  j["event_settle_frames"] = cfg.event_settle_frames;
  j["event_unscored_settle_frames"] = cfg.event_unscored_settle_frames;
  j["integrate_ms_median"] = quantile(integrate_ms, 0.5);
  j["update_ms_median"] = quantile(update_ms, 0.5);
  j["update_ms_p95"] = quantile(update_ms, 0.95);
  j["notifications"] = notifications;
  j["announced"] = announced.size();
  j["retracted"] = retracted;
  j["type_updates"] = type_updates;
  j["final_events"] = final_events.size();
  j["notifications_per_final_event"] = notifications / finalCount;
  j["retracted_fraction"] =
      announced.empty() ? 0.0 : static_cast<double>(retracted) / announced.size();
  j["final_events_match_offline"] = sameEvents(final_events, offline.events);
  j["gt_changes"] = places.size();
  j["gt_changes_alerted"] = alerted;
  const double lat = quantile(latency, 0.5);
  j["alert_latency_frames_median"] = std::isfinite(lat) ? json(lat) : json(nullptr);
  return j;
}

}  // namespace

int runStreamBench(const BenchArgs& args) {
  if (args.update_every < 1) throw Error("--update-every", "must be at least 1");
  json runs = json::array();
  for (const std::string& spec : args.stream_runs) {
    const auto colon = spec.find(':');
    if (colon == std::string::npos)
      throw Error("--stream-runs", "expected PRESET:SEED, got '" + spec + "'");
    unsigned seed = 0;
    try {
      seed = static_cast<unsigned>(std::stoul(spec.substr(colon + 1)));
    } catch (const std::exception&) {
      throw Error("--stream-runs", "bad seed in '" + spec + "'");
    }
    runs.push_back(streamRun(spec.substr(0, colon), seed, args));
  }
  std::printf("%-10s %5s %7s %9s %9s %6s %6s %6s %7s %8s %8s %6s\n", "scene", "seed", "frames",
              "integ ms", "update ms", "notif", "final", "retr", "n/final", "latency", "alerted",
              "match");
  for (const json& r : runs)
    std::printf("%-10s %5u %7zu %9.1f %9.1f %6d %6zu %6d %7.2f %8s %5d/%-2zu %6s\n",
                r["scene"].get<std::string>().c_str(), r["seed"].get<unsigned>(),
                r["frames"].get<std::size_t>(), r["integrate_ms_median"].get<double>(),
                r["update_ms_median"].get<double>(), r["notifications"].get<int>(),
                r["final_events"].get<std::size_t>(), r["retracted"].get<int>(),
                r["notifications_per_final_event"].get<double>(),
                r["alert_latency_frames_median"].is_null()
                    ? std::string("n/a").c_str()
                    : std::to_string(r["alert_latency_frames_median"].get<int>()).c_str(),
                r["gt_changes_alerted"].get<int>(), r["gt_changes"].get<std::size_t>(),
                r["final_events_match_offline"].get<bool>() ? "yes" : "NO");
  if (!args.json.empty()) {
    io::writeFileAtomic(args.json, [&](std::ostream& out) { out << runs.dump(2) << "\n"; });
    std::printf("-> %s\n", args.json.c_str());
  }
  return kExitOk;
}

}  // namespace planesdf::cli
