// The session comparison: plane pairs matched one-to-one, the session's drift corrected, both
// directions compared pair by pair, and the candidates assembled into events (see change.hpp,
// detectChanges).

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <set>
#include <utility>

#include "../numeric.hpp"
#include "../parallel.hpp"
#include "change_internal.hpp"
#include "planesdf/error.hpp"
#include "session_comparison.hpp"

namespace planesdf {

using detail::parallelFor;

std::vector<PlaneMatch> uniqueMatches(std::vector<PlaneMatch> ms) {
  std::stable_sort(ms.begin(), ms.end(), [](const PlaneMatch& a, const PlaneMatch& b) {
    return std::abs(a.offset_gap) < std::abs(b.offset_gap);
  });
  std::vector<PlaneMatch> out;
  std::set<int> taken;
  for (const PlaneMatch& m : ms)
    if (taken.insert(m.target_id).second) out.push_back(m);
  std::sort(out.begin(), out.end(),
            [](const PlaneMatch& a, const PlaneMatch& b) { return a.source_id < b.source_id; });
  return out;
}

std::vector<CandidateChange> compareMatchedPair(
    const Map& reference, const Map& current, bool reference_to_current, PlaneMatch match,
    const PlaneMaps& source_maps, const PlaneMaps& target_maps, RefinedTransforms& refined,
    const Config& cfg, const DetectOptions& options, PlanePairResult* result) {
  const Map& src = reference_to_current ? reference : current;
  const Map& tgt = reference_to_current ? current : reference;
  bool refine = cfg.refine_inplane;
  if (!reference_to_current) {
    const auto it = refined.find({match.target_id, match.source_id});
    if (it != refined.end()) {
      match.T_target_source_local = it->second.inverse();
      refine = false;
    }
  }
  PlanePairResult local;
  PlanePairResult& res = result != nullptr ? *result : local;
  res.reference_to_current = reference_to_current;
  auto out = comparePlanePair(src.planes()[static_cast<std::size_t>(match.source_id)], source_maps,
                              tgt.planes()[static_cast<std::size_t>(match.target_id)], target_maps,
                              match, refine, src.points(), tgt.points(), cfg, options, &res);
  if (reference_to_current)
    refined[{match.source_id, match.target_id}] = res.match.T_target_source_local;
  return out;
}

namespace {

/// The horizontal forward pairs' best in-plane refinement as a world motion applied after the
/// plane alignment (identity when none refines), and the anchor of the plane it came from.
std::pair<Pose, Eigen::Vector3d> horizontalCorrection(
    const Map& reference, const Map& current, const std::vector<PlaneMatch>& forward_matches,
    const std::function<const PlaneMaps&(bool, int)>& maps, const Config& cfg) {
  // The horizontal pairs, refined independently (in parallel; the maps are computed first, in
  // order, since `maps` may compute them lazily), then the first with the largest gain wins.
  std::vector<std::size_t> horizontal;
  for (std::size_t i = 0; i < forward_matches.size(); ++i) {
    const PlaneMatch& m = forward_matches[i];
    if (reference.planes()[static_cast<std::size_t>(m.source_id)].plane.orientation !=
            Plane::Orientation::Horizontal ||
        current.planes()[static_cast<std::size_t>(m.target_id)].plane.orientation !=
            Plane::Orientation::Horizontal)
      continue;
    horizontal.push_back(i);
    maps(true, m.source_id);
    maps(false, m.target_id);
  }
  std::vector<Pose> T(horizontal.size());
  std::vector<InPlaneRefinement> r(horizontal.size());
  InPlaneSearch search;
  search.session_drift = true;
  parallelFor(static_cast<int>(horizontal.size()), cfg.threads, [&](int k) {
    const PlaneMatch& m = forward_matches[horizontal[static_cast<std::size_t>(k)]];
    T[k] = m.T_target_source_local;
    r[k] = refineInPlane(maps(true, m.source_id).heights, maps(true, m.source_id).objects,
                         maps(false, m.target_id).heights, maps(false, m.target_id).objects, T[k],
                         cfg, search);
  });
  Pose correction = Pose::Identity();
  Eigen::Vector3d anchor = Eigen::Vector3d::Zero();
  int best_gain = 0;
  for (std::size_t k = 0; k < horizontal.size(); ++k) {
    const PlaneMatch& m = forward_matches[horizontal[k]];
    const int gain = r[k].mismatches_before - r[k].mismatches_after;
    if (!r[k].applied || gain <= best_gain) continue;
    best_gain = gain;
    // T = D * T0 in target-local coordinates: C = F_t * D * F_t^-1 in the world.
    const Plane& target = current.planes()[static_cast<std::size_t>(m.target_id)].plane;
    const Pose Ft = target.frame();
    correction = Ft * (T[k] * m.T_target_source_local.inverse()) * Ft.inverse();
    anchor = planeAnchor(target);
  }
  return {correction, anchor};
}

/// Signed angle (rad) about `up` from the horizontal part of `a` to that of `b`.
double yawBetween(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& up) {
  const Eigen::Vector3d ha = a - a.dot(up) * up, hb = b - b.dot(up) * up;
  return std::atan2(ha.cross(hb).dot(up), ha.dot(hb));
}

struct WallVote {
  double yaw = 0.0;
  double weight = 0.0;
  const Plane* source = nullptr;
  const Plane* target = nullptr;
};

/// The matched vertical planes large enough to vote on the drift.
std::vector<WallVote> wallVotes(const Map& reference, const Map& current,
                                const std::vector<PlaneMatch>& forward_matches,
                                const Eigen::Vector3d& up) {
  std::vector<WallVote> votes;
  for (const PlaneMatch& m : forward_matches) {
    const Plane& s = reference.planes()[static_cast<std::size_t>(m.source_id)].plane;
    const Plane& t = current.planes()[static_cast<std::size_t>(m.target_id)].plane;
    if (s.orientation != Plane::Orientation::Vertical ||
        t.orientation != Plane::Orientation::Vertical || s.extent.isEmpty() || t.extent.isEmpty())
      continue;
    const double area = std::min(s.extent.volume(), t.extent.volume());
    if (area < kDriftMinWallArea) continue;
    votes.push_back({yawBetween(s.normal, t.normal, up), area, &s, &t});
  }
  return votes;
}

double weightedMedianYaw(std::vector<WallVote> votes) {
  std::sort(votes.begin(), votes.end(),
            [](const WallVote& a, const WallVote& b) { return a.yaw < b.yaw; });
  double total = 0.0;
  for (const WallVote& v : votes) total += v.weight;
  double acc = 0.0;
  for (const WallVote& v : votes) {
    acc += v.weight;
    if (acc >= 0.5 * total) return v.yaw;
  }
  return votes.back().yaw;
}

}  // namespace

SessionCorrection sessionCorrection(const Map& reference, const Map& current,
                                    const std::vector<PlaneMatch>& forward_matches,
                                    const std::function<const PlaneMaps&(bool, int)>& maps,
                                    const Config& cfg) {
  const auto [horizontal, anchor] =
      horizontalCorrection(reference, current, forward_matches, maps, cfg);
  const Eigen::Vector3d up = current.up().normalized();
  const std::vector<WallVote> votes = wallVotes(reference, current, forward_matches, up);
  if (votes.empty()) return {horizontal, false};
  // Rotation: the walls' weighted median; shift: least squares of the agreeing walls' offsets
  // (n_t · (R p_s + t) + d_t = 0 for a point p_s of the source wall), in the horizontal plane.
  const double yaw = weightedMedianYaw(votes);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw, up).toRotationMatrix();
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (const WallVote& v : votes) {
    if (std::abs(v.yaw - yaw) > detail::kDegToRad) continue;  // another wall pairing
    const Eigen::Vector3d n = (v.target->normal - v.target->normal.dot(up) * up).normalized();
    const double d = v.target->offset / v.target->normal.norm();
    const double rhs = -(v.target->normal.normalized().dot(R * planeAnchor(*v.source)) + d);
    A += v.weight * n * n.transpose();
    b += v.weight * rhs * n;
  }
  // Directions the walls constrain (eigenvalues of A) take their shift; the others the shift
  // the horizontal refinement gives at its plane's anchor.
  const Eigen::Vector3d fallback = horizontal * anchor - R * anchor;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(A);
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  const double top = eig.eigenvalues().maxCoeff();
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d e = eig.eigenvectors().col(i);
    const double lambda = eig.eigenvalues()(i);
    t += (lambda > 0.05 * top && lambda > 0.0 ? e.dot(b) / lambda : e.dot(fallback)) * e;
  }
  t -= t.dot(up) * up;  // heights come from each pair's own plane alignment
  Pose motion = Pose::Identity();
  motion.linear() = R;
  motion.translation() = t;
  return {motion, true};
}

PlaneMatch corrected(PlaneMatch match, const Map& reference, const Map& current,
                     const SessionCorrection& correction) {
  const Pose Ft = current.planes()[static_cast<std::size_t>(match.target_id)].plane.frame();
  if (!correction.rigid) {
    match.T_target_source_local =
        Ft.inverse() * correction.motion * Ft * match.T_target_source_local;
    return match;
  }
  // The motion in the plane frames, kept as a yaw and an in-plane shift (as
  // relativePlaneTransform: heights come from the plane alignment).
  const Pose Fs = reference.planes()[static_cast<std::size_t>(match.source_id)].plane.frame();
  Pose T = Ft.inverse() * correction.motion * Fs;
  const double yaw = std::atan2(T.linear()(1, 0), T.linear()(0, 0));
  T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation().z() = 0.0;
  match.T_target_source_local = T;
  return match;
}

namespace detail {

SessionComparison::SessionComparison(const Map& reference, const Config& cfg,
                                     const DetectOptions& options)
    : reference_(&reference),
      cfg_(cfg),
      options_(options),
      reference_maps_(reference.planes().size()),
      reference_done_(reference.planes().size(), false),
      reference_chunks_(std::make_shared<PointChunks>()) {
  reference_chunks_->source = &reference.points();
}

bool SessionComparison::currentMapsValid(const Map& current, int id) const {
  const auto it = current_maps_.find(id);
  return it != current_maps_.end() &&
         it->second.maps.revision ==
             current.planes()[static_cast<std::size_t>(id)].volume.revision() &&
         it->second.num_planes == current.planes().size();
}

void SessionComparison::computeMaps(const Map& current, std::vector<std::pair<bool, int>> needed) {
  std::sort(needed.begin(), needed.end());
  needed.erase(std::unique(needed.begin(), needed.end()), needed.end());
  needed.erase(std::remove_if(needed.begin(), needed.end(),
                              [&](const std::pair<bool, int>& n) {
                                return n.first ? reference_done_[static_cast<std::size_t>(n.second)]
                                               : currentMapsValid(current, n.second);
                              }),
               needed.end());
  const auto& rp = reference_->planes();
  const auto& cp = current.planes();
  // Largest volumes first (the threads take the next plane as they finish: the long ones start
  // early instead of last).
  const auto blocksOf = [&](const std::pair<bool, int>& n) {
    return (n.first ? rp : cp)[static_cast<std::size_t>(n.second)].volume.numBlocks();
  };
  std::stable_sort(needed.begin(), needed.end(),
                   [&](const auto& a, const auto& b) { return blocksOf(a) > blocksOf(b); });
  std::vector<PlaneMaps> computed(needed.size());
  parallelFor(static_cast<int>(needed.size()), cfg_.threads, [&](int k) {
    const auto [ref, id] = needed[static_cast<std::size_t>(k)];
    const auto i = static_cast<std::size_t>(id);
    const Map& m = ref ? *reference_ : current;
    computed[static_cast<std::size_t>(k)] =
        computePlaneMaps(ref ? rp[i] : cp[i], ref ? rp : cp, cfg_, &m.points(), surfaceRimCells(m));
  });
  for (std::size_t k = 0; k < needed.size(); ++k) {
    const auto [ref, id] = needed[k];
    if (ref) {
      PlaneMaps& m = reference_maps_[static_cast<std::size_t>(id)];
      m = std::move(computed[k]);
      if (m.points) m.points->chunks = reference_chunks_;
      reference_done_[static_cast<std::size_t>(id)] = true;
    } else {
      current_maps_.insert_or_assign(id, CurrentMaps{std::move(computed[k]), cp.size()});
    }
  }
  // One chunk index of the current map's points for all its planes' maps (built on first use).
  auto chunks = std::make_shared<PointChunks>();
  chunks->source = &current.points();
  for (auto& [id, m] : current_maps_)
    if (m.maps.points) m.maps.points->chunks = chunks;
}

const PlaneMaps& SessionComparison::maps(bool reference, int id) const {
  return reference ? reference_maps_[static_cast<std::size_t>(id)] : current_maps_.at(id).maps;
}

namespace {
double msSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}
}  // namespace

void SessionComparison::computeMatchedMaps(const Map& current,
                                           const std::vector<PlaneMatch>& forward_matches,
                                           const std::vector<PlaneMatch>& backward_matches) {
  std::vector<std::pair<bool, int>> needed;
  for (const PlaneMatch& m : forward_matches) {
    needed.emplace_back(true, m.source_id);
    needed.emplace_back(false, m.target_id);
  }
  for (const PlaneMatch& m : backward_matches) {
    needed.emplace_back(false, m.source_id);
    needed.emplace_back(true, m.target_id);
  }
  computeMaps(current, std::move(needed));
}

void SessionComparison::updateCorrection(const Map& current,
                                         const std::vector<PlaneMatch>& forward_matches) {
  const auto& cp = current.planes();
  std::vector<std::pair<int, std::uint64_t>> key;
  for (const PlaneMatch& m : forward_matches)
    key.emplace_back(m.target_id, cp[static_cast<std::size_t>(m.target_id)].volume.revision());
  key.emplace_back(-1, cp.size());
  if (key == correction_key_) return;  // never equal before the first estimate: key is not empty
  correction_ = sessionCorrection(
      *reference_, current, forward_matches,
      [&](bool ref, int id) -> const PlaneMaps& { return maps(ref, id); }, cfg_);
  correction_key_ = std::move(key);
}

void SessionComparison::compareDirection(const Map& current, bool forward,
                                         std::vector<PlaneMatch> matches, Direction& d, Run& out) {
  const Map& reference = *reference_;
  const auto& cp = current.planes();
  if (forward)
    for (PlaneMatch& m : matches) m = corrected(m, reference, current, correction_);
  // A pair whose current volume and correction are as when it was compared keeps its result.
  const auto keyOf = [&](const PlaneMatch& m) {
    return std::make_tuple(forward, m.source_id, m.target_id);
  };
  const auto revisionOf = [&](const PlaneMatch& m) {
    return cp[static_cast<std::size_t>(forward ? m.target_id : m.source_id)].volume.revision();
  };
  std::vector<PairCache*> kept(matches.size(), nullptr);
  std::vector<std::size_t> order;
  for (std::size_t i = 0; i < matches.size(); ++i) {
    const auto it = pairs_.find(keyOf(matches[i]));
    if (it != pairs_.end() && it->second.current_revision == revisionOf(matches[i]) &&
        it->second.correction == correction_ && it->second.num_planes == cp.size())
      kept[i] = &it->second;
    else
      order.push_back(i);
  }
  // The pairs to compare are independent: in parallel, each with its own share of the refined
  // transforms, merged in pair order; largest source maps first (results stay in pair order).
  const auto cellsOf = [&](std::size_t i) {
    return maps(forward, matches[i].source_id).heights.numCells();
  };
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return cellsOf(a) > cellsOf(b); });
  std::vector<PlanePairResult> results(matches.size());
  std::vector<std::vector<CandidateChange>> found(matches.size());
  std::vector<RefinedTransforms> own(matches.size());
  parallelFor(static_cast<int>(order.size()), cfg_.threads, [&](int k) {
    const std::size_t i = order[static_cast<std::size_t>(k)];
    const PlaneMatch& m = matches[i];
    if (!forward) own[i] = d.refined;  // read only backwards
    found[i] = compareMatchedPair(reference, current, forward, m, maps(forward, m.source_id),
                                  maps(!forward, m.target_id), own[i], cfg_, options_, &results[i]);
  });
  for (std::size_t i = 0; i < matches.size(); ++i) {
    const PlaneMatch& m = matches[i];
    PairCache pc;
    if (kept[i] != nullptr) {
      pc = std::move(*kept[i]);  // pairs_ is replaced by d.next after both directions
      ++out.pairs_reused;
      if (forward) d.refined[{m.source_id, m.target_id}] = pc.T_target_source;
    } else {
      ++out.pairs_checked;
      if (forward) d.refined.insert(own[i].begin(), own[i].end());
      pc = PairCache{revisionOf(m), std::move(found[i]), results[i].match.T_target_source_local,
                     correction_, cp.size()};
      out.set.pairs.push_back(std::move(results[i]));
    }
    for (const CandidateChange& c : pc.candidates) (forward ? d.removed : d.added).push_back(c);
    d.next[keyOf(m)] = std::move(pc);
  }
}

SessionComparison::Run SessionComparison::run(const Map& current) {
  const auto t0 = std::chrono::steady_clock::now();
  Run out;
  ChangeSet& set = out.set;
  const std::vector<PlaneMatch> forward_matches =
      uniqueMatches(registerPlanes(*reference_, current, cfg_));
  const std::vector<PlaneMatch> backward_matches =
      uniqueMatches(registerPlanes(current, *reference_, cfg_));
  // The maps of every matched plane (read-only from here on).
  auto tp = std::chrono::steady_clock::now();
  computeMatchedMaps(current, forward_matches, backward_matches);
  set.maps_ms = msSince(tp);
  // The session-wide correction, estimated again only when a current plane it rests on changed.
  tp = std::chrono::steady_clock::now();
  if (cfg_.refine_inplane) updateCorrection(current, forward_matches);
  set.correction_ms = msSince(tp);
  Direction d;
  tp = std::chrono::steady_clock::now();  // forward first: its transforms are reused backwards
  compareDirection(current, true, forward_matches, d, out);
  set.forward_ms = msSince(tp);
  tp = std::chrono::steady_clock::now();
  compareDirection(current, false, backward_matches, d, out);
  set.backward_ms = msSince(tp);
  pairs_ = std::move(d.next);
  set.events = assembleEvents(std::move(d.removed), std::move(d.added), cfg_);
  set.milliseconds = msSince(t0);
  return out;
}

}  // namespace detail

ChangeSet detectChanges(const Map& reference, const Map& current, const Config& cfg,
                        const DetectOptions& options) {
  if (reference.config().voxel_size != current.config().voxel_size)
    throw Error("", "the reference and current maps have different voxel sizes (" +
                        std::to_string(reference.config().voxel_size) + " vs " +
                        std::to_string(current.config().voxel_size) + " m)");
  return detail::SessionComparison(reference, cfg, options).run(current).set;
}

}  // namespace planesdf
