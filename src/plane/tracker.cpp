// PlaneTracker: merges per-frame RANSAC planes into global planes with stable ids.

#include <algorithm>
#include <cmath>
#include <limits>

#include "../numeric.hpp"
#include "plane_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/plane.hpp"
#include "ransac.hpp"

namespace planesdf {
namespace {

using detail::kPi;
constexpr std::size_t kMatchSample = 1000;  // inliers projected to test extent overlap
/// Cell size (m) of a plane's occupancy (Track::cells); neighbouring cells are connected, so
/// patches up to one to two cells apart are one region.
constexpr double kOccupancyCell = 0.10;
constexpr std::size_t kOccupancySample = 2000;  // inliers per observation marking cells

std::uint64_t occupancyKey(const Eigen::Vector3f& p, int dx = 0, int dy = 0, int dz = 0) {
  const auto axis = [](float v, int d) {
    return static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor(v / kOccupancyCell)) +
                                      d + (1 << 20)) &
           0x1fffff;
  };
  return axis(p.x(), dx) | axis(p.y(), dy) << 21 | axis(p.z(), dz) << 42;
}

/// A plane is refined again once it gained this fraction of the inliers it had seen at its
/// last refinement (and cfg.refine_min_new_inliers): O(log n) refinements over n inliers.
constexpr double kRefineGrowth = 0.5;

// Euclidean gap between two boxes (0 when they overlap); +inf when either is empty.
double boxGap(const Eigen::AlignedBox2d& a, const Eigen::AlignedBox2d& b) {
  if (a.isEmpty() || b.isEmpty()) return std::numeric_limits<double>::infinity();
  const Eigen::Vector2d gap =
      (a.min() - b.max()).cwiseMax(b.min() - a.max()).cwiseMax(Eigen::Vector2d::Zero());
  return gap.norm();
}

}  // namespace

PlaneTracker::PlaneTracker(const Config& cfg) : cfg_(cfg) {
  validatePlaneConfig(cfg_);
  if (!cfg_.up_auto) up_ = cfg_.up.normalized();
}

const Plane* PlaneTracker::plane(int id) const {
  if (id < 0 || static_cast<std::size_t>(id) >= planes_.size()) return nullptr;
  return &planes_[static_cast<std::size_t>(id)];
}

std::size_t PlaneTracker::reservoirSize(int id) const {
  return plane(id) ? tracks_[static_cast<std::size_t>(id)].reservoir.size() : 0;
}

int PlaneTracker::refinementCount(int id) const {
  return plane(id) ? tracks_[static_cast<std::size_t>(id)].refinements : 0;
}

std::vector<int> PlaneTracker::integrate(const std::vector<Eigen::Vector3f>& points_world,
                                         const Eigen::Vector3d& sensor_origin) {
  std::vector<PlaneObservation> all =
      detail::ransacFramePlanes(points_world, sensor_origin, cfg_, up_ ? &*up_ : nullptr);
  if (!up_) {
    if (all.empty()) return {};
    up_ = all.front().plane.normal;  // largest plane, normal toward the sensor
  }
  return merge(detail::finishObservations(std::move(all), points_world, *up_, cfg_), points_world,
               cfg_.plane_min_extent, cfg_.plane_min_width);
}

std::vector<int> PlaneTracker::merge(const std::vector<PlaneObservation>& observations,
                                     const std::vector<Eigen::Vector3f>& points_world,
                                     double min_extent, double min_width) {
  std::vector<int> ids;
  for (const PlaneObservation& obs : observations) {
    if (obs.inliers.empty()) {
      ids.push_back(-1);
      continue;
    }
    // cfg.up_auto and nothing integrated yet: like detectPlanesRansac, the largest (first)
    // observation's normal is up.
    if (!up_) up_ = obs.plane.normal.normalized();
    Eigen::AlignedBox2d obs_extent;
    const int match = findMatch(obs, points_world, obs_extent);
    if (match >= 0) {
      absorb(match, obs, points_world, obs_extent);
      ids.push_back(match);
    } else if (obs.plane.extent.isEmpty() || (obs.plane.extent.sizes().maxCoeff() >= min_extent &&
                                              obs.plane.extent.sizes().minCoeff() >= min_width)) {
      ids.push_back(addPlane(obs, points_world));
    } else {
      ids.push_back(-1);  // an object's face, not a support
    }
  }
  return ids;
}

int PlaneTracker::findMatch(const PlaneObservation& obs, const std::vector<Eigen::Vector3f>& points,
                            Eigen::AlignedBox2d& obs_extent) const {
  const double min_cos = std::cos(cfg_.plane_merge_angle_deg * kPi / 180.0);
  const std::vector<std::uint32_t> sample = detail::evenSubsample(obs.inliers, kMatchSample);
  const Eigen::Vector3d centre = detail::centroidOf(points, obs.inliers);
  const bool over_plane = standsOnAnotherPlane(obs, centre, min_cos);
  int best = -1;
  double best_dist = std::numeric_limits<double>::infinity();
  for (const Plane& g : planes_) {
    if (g.normal.dot(obs.plane.normal) < min_cos) continue;
    const double dist = std::abs(g.signedDistance(centre));
    if (dist > cfg_.plane_merge_offset || dist >= best_dist) continue;
    if (boxGap(detail::extentOf(g, points, sample), g.extent) > cfg_.plane_merge_extent_gap) {
      continue;
    }
    // Apart from a few cm, or over another horizontal plane (the floor under a desk and a shelf
    // board at the same height), only connected patches are one surface.
    if ((dist > cfg_.plane_merge_coplanar || over_plane) &&
        !touches(tracks_[static_cast<std::size_t>(g.id)], g, points, sample))
      continue;
    best = g.id;
    best_dist = dist;
  }
  if (best >= 0) obs_extent = detail::extentOf(planes_[best], points, obs.inliers);
  return best;
}

int PlaneTracker::addPlane(const PlaneObservation& obs,
                           const std::vector<Eigen::Vector3f>& points) {
  const int id = static_cast<int>(planes_.size());
  Plane plane =
      detail::planeFromInliers(obs.plane.normal, obs.plane.offset, points, obs.inliers, *up_);
  plane.id = id;
  plane.orientation = obs.plane.orientation;
  planes_.push_back(plane);
  Track track;
  track.rng_state = 0x7a3c5eedULL + static_cast<std::uint64_t>(id);
  tracks_.push_back(std::move(track));
  Track& t = tracks_.back();
  if (!obs.fitted) offerToReservoir(t, points, obs.inliers);
  occupy(t, points, obs.inliers);
  t.since_refine = obs.inliers.size();
  maybeRefine(id);
  return id;
}

void PlaneTracker::absorb(int id, const PlaneObservation& obs,
                          const std::vector<Eigen::Vector3f>& points,
                          const Eigen::AlignedBox2d& obs_extent) {
  Plane& plane = planes_[static_cast<std::size_t>(id)];
  Track& track = tracks_[static_cast<std::size_t>(id)];
  plane.support += obs.inliers.size();
  plane.extent.extend(obs_extent);
  if (!obs.fitted) offerToReservoir(track, points, obs.inliers);
  occupy(track, points, obs.inliers);
  track.since_refine += obs.inliers.size();
  maybeRefine(id);
}

bool PlaneTracker::standsOnAnotherPlane(const PlaneObservation& obs, const Eigen::Vector3d& centre,
                                        double min_cos) const {
  if (obs.plane.orientation != Plane::Orientation::Horizontal) return false;
  for (const Plane& low : planes_) {
    if (low.normal.dot(obs.plane.normal) < min_cos) continue;
    if (low.signedDistance(centre) <= cfg_.plane_merge_offset) continue;
    if (low.extent.isEmpty() || low.extent.contains(low.toLocal(centre).head<2>())) return true;
  }
  return false;
}

bool PlaneTracker::touches(const Track& track, const Plane& plane,
                           const std::vector<Eigen::Vector3f>& points,
                           const std::vector<std::uint32_t>& sample) const {
  if (track.cells.empty())
    return boxGap(detail::extentOf(plane, points, sample), plane.extent) <= kOccupancyCell;
  for (const std::uint32_t i : sample) {
    const Eigen::Vector3f& p = points[i];
    if (!p.allFinite()) continue;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx)
          if (track.cells.count(occupancyKey(p, dx, dy, dz))) return true;
  }
  return false;
}

void PlaneTracker::occupy(Track& track, const std::vector<Eigen::Vector3f>& points,
                          const std::vector<std::uint32_t>& inliers) const {
  for (const std::uint32_t i : detail::evenSubsample(inliers, kOccupancySample))
    if (points[i].allFinite()) track.cells.insert(occupancyKey(points[i]));
}

void PlaneTracker::offerToReservoir(Track& track, const std::vector<Eigen::Vector3f>& points,
                                    const std::vector<std::uint32_t>& indices) const {
  const auto cap = static_cast<std::size_t>(cfg_.plane_reservoir_size);
  detail::SplitMix64 rng(track.rng_state);
  for (std::uint32_t i : indices) {
    ++track.seen;
    if (track.reservoir.size() < cap) {
      track.reservoir.push_back(points[i]);
    } else {
      const std::uint64_t j = rng.below(track.seen);
      if (j < cap) track.reservoir[j] = points[i];
    }
  }
  track.rng_state = rng.state;
}

void PlaneTracker::maybeRefine(int id) {
  Track& track = tracks_[static_cast<std::size_t>(id)];
  if (track.since_refine < static_cast<std::size_t>(cfg_.refine_min_new_inliers)) return;
  const std::size_t before = track.seen - track.since_refine;
  if (static_cast<double>(track.since_refine) < kRefineGrowth * static_cast<double>(before)) return;
  Plane& plane = planes_[static_cast<std::size_t>(id)];
  if (refinePlane(track.reservoir, plane, cfg_)) {
    ++track.refinements;
    // Keep the class in step with the refined normal (it stays within the merge tolerance).
    if (const auto cls = classifyOrientation(plane.normal, *up_, cfg_.orientation_tolerance_deg)) {
      plane.orientation = *cls;
    }
  }
  track.since_refine = 0;
}

void PlaneTracker::restore(std::vector<Plane> planes, std::optional<Eigen::Vector3d> up) {
  for (std::size_t i = 0; i < planes.size(); ++i)
    if (planes[i].id != static_cast<int>(i))
      throw Error("planes", "plane ids must be 0..n-1 (plane " + std::to_string(i) + " has id " +
                                std::to_string(planes[i].id) + ")");
  planes_ = std::move(planes);
  tracks_.clear();
  for (std::size_t i = 0; i < planes_.size(); ++i) {
    Track track;
    track.rng_state = 0x7a3c5eedULL + static_cast<std::uint64_t>(i);
    tracks_.push_back(std::move(track));
  }
  if (up) up_ = up->normalized();
}

}  // namespace planesdf
