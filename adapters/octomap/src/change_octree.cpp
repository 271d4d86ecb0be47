#include "planesdf/octomap/change_octree.hpp"

#include <algorithm>
#include <cmath>

#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"

namespace planesdf::octomap_adapter {
namespace {

bool isRemovedSide(const ChangeEvent& e) {
  return e.type != ChangeType::Added;
}
bool isAddedSide(const ChangeEvent& e) {
  return e.type != ChangeType::Removed;
}

/// Keys of `region` in any tree (OcTree or ColorOcTree share the key grid of their resolution).
template <class Tree>
octomap::KeySet keysOf(const ChangeRegion& region, const Tree& tree, bool removed,
                       const OctreeChangeOptions& options) {
  octomap::KeySet keys;
  if (region.points.empty()) return keys;
  const Eigen::Vector3d up = options.up.normalized();
  const double res = tree.getResolution();
  double base = std::numeric_limits<double>::infinity();
  for (const auto& p : region.points) base = std::min(base, up.dot(p.cast<double>()));
  // A removed side keeps the layer it shares with the support surface (see the header).
  const double lowest = removed ? base + res : base;
  const auto insert = [&](const Eigen::Vector3d& q) {
    octomap::OcTreeKey key;
    if (tree.coordToKeyChecked(
            octomap::point3d(static_cast<float>(q.x()), static_cast<float>(q.y()),
                             static_cast<float>(q.z())),
            key))
      keys.insert(key);
  };
  for (const auto& pf : region.points) {
    const Eigen::Vector3d p = pf.cast<double>();
    const double h = up.dot(p);
    if (h < lowest) continue;
    insert(p);
    if (!options.solid) continue;
    for (double t = h - 0.5 * res; t >= lowest; t -= 0.5 * res) insert(p - (h - t) * up);
    insert(p - (h - lowest) * up);
  }
  return keys;
}

template <class Tree>
float fullSwing(const Tree& tree) {
  return tree.getClampingThresMaxLog() - tree.getClampingThresMinLog();
}

}  // namespace

octomap::KeySet changeKeys(const ChangeRegion& region, const octomap::OcTree& tree, bool removed,
                           const OctreeChangeOptions& options) {
  return keysOf(region, tree, removed, options);
}

OctreeChangeStats applyChanges(const std::vector<ChangeEvent>& events, octomap::OcTree& tree,
                               const OctreeChangeOptions& options) {
  const float free_update =
      std::isnan(options.free_log_odds) ? -fullSwing(tree) : options.free_log_odds;
  const float occupied_update =
      std::isnan(options.occupied_log_odds) ? fullSwing(tree) : options.occupied_log_odds;
  octomap::KeySet freed, occupied;
  for (const ChangeEvent& e : events) {
    if (e.status == ChangeStatus::Retracted) continue;
    if (isRemovedSide(e)) {
      const octomap::KeySet k = keysOf(e.reference, tree, true, options);
      freed.insert(k.begin(), k.end());
    }
    if (isAddedSide(e)) {
      const octomap::KeySet k = keysOf(e.current, tree, false, options);
      occupied.insert(k.begin(), k.end());
    }
  }
  for (const auto& key : freed) tree.updateNode(key, free_update, true);
  for (const auto& key : occupied) tree.updateNode(key, occupied_update, true);
  tree.updateInnerOccupancy();
  return {freed.size(), occupied.size()};
}

OctreeChangeStats applyChanges(const ChangeSet& set, octomap::OcTree& tree,
                               const OctreeChangeOptions& options) {
  return applyChanges(set.events, tree, options);
}

std::size_t paintChanges(const std::vector<ChangeEvent>& events, octomap::ColorOcTree& tree,
                         const OctreeChangeOptions& options) {
  octomap::KeySet painted;
  for (const ChangeEvent& e : events) {
    if (e.status == ChangeStatus::Retracted) continue;
    const auto c = changeColor(e.type);
    const auto paint = [&](const octomap::KeySet& keys) {
      for (const auto& key : keys) {
        tree.updateNode(key, fullSwing(tree), true);
        tree.setNodeColor(key, c[0], c[1], c[2]);
        painted.insert(key);
      }
    };
    if (isRemovedSide(e)) paint(keysOf(e.reference, tree, true, options));
    if (isAddedSide(e)) paint(keysOf(e.current, tree, false, options));
  }
  tree.updateInnerOccupancy();
  return painted.size();
}

void writeOcTree(const std::string& path, const octomap::AbstractOcTree& tree) {
  io::writeFileAtomic(path, [&](std::ostream& os) {
    if (!tree.write(os)) throw Error(path, "OctoMap could not write the tree");
  });
}

}  // namespace planesdf::octomap_adapter
