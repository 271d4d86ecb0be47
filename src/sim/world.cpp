#include "world.hpp"

#include <algorithm>
#include <map>
#include <utility>

namespace planesdf::sim::detail {

World::World(std::vector<Primitive> primitives) : primitives_(std::move(primitives)) {
  std::map<int, std::size_t> index;  // owner -> group, groups in order of first appearance
  for (std::size_t i = 0; i < primitives_.size(); ++i) {
    const int owner = primitives_[i].owner;
    auto it = index.find(owner);
    if (it == index.end()) {
      it = index.emplace(owner, groups_.size()).first;
      Group g;
      g.owner = owner;
      g.box = worldBox(primitives_[i]);
      groups_.push_back(std::move(g));
    } else {
      groups_[it->second].box.extend(worldBox(primitives_[i]));
    }
    groups_[it->second].members.push_back(static_cast<int>(i));
  }
}

Hit World::raycast(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double t_max,
                   const std::vector<std::pair<float, int>>& candidates, int& primitive) const {
  Hit best;
  best.t = t_max;
  primitive = -1;
  for (const auto& [near, m] : candidates) {
    if (static_cast<double>(near) >= best.t) break;  // sorted: no later primitive can be nearer
    const Hit h = raycastWithNormal(primitives_[static_cast<std::size_t>(m)], origin, direction);
    if (h.t < best.t) {
      best = h;
      primitive = m;
    }
  }
  if (primitive < 0) best.t = kInf;
  return best;
}

double World::nearest(const Eigen::Vector3d& p, int& owner) const {
  double best = kInf;
  owner = 0;
  for (const Group& g : groups_) {
    if (g.box.exteriorDistance(p) >= best) continue;
    for (const int m : g.members) {
      const double d = std::abs(signedDistance(primitives_[static_cast<std::size_t>(m)], p));
      if (d < best) {
        best = d;
        owner = g.owner;
      }
    }
  }
  return best;
}

}  // namespace planesdf::sim::detail
