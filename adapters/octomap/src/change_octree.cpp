#include "planesdf/octomap/change_octree.hpp"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

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

/// octomap 1.9's deleteNode frees an inner node it left without children by plain `delete`,
/// which needs the node's child array freed first (liboctomap asserts; without asserts the array
/// leaks). The array is a protected member, reached through a pointer to member formed here.
struct ChildArray : octomap::OcTreeNode {
  static void release(octomap::OcTreeNode& node) {
    constexpr auto member = &ChildArray::children;
    delete[](node.*member);
    node.*member = nullptr;
  }
};

/// Removes the voxel at `key` from `tree`, and the inner nodes that leaves without children.
void eraseVoxel(octomap::OcTree& tree, const octomap::OcTreeKey& key) {
  std::vector<std::pair<octomap::OcTreeNode*, unsigned>> path;  // node, child taken
  octomap::OcTreeNode* node = tree.getRoot();
  const unsigned depth = tree.getTreeDepth();
  for (unsigned d = 0; node != nullptr && d < depth; ++d) {
    const unsigned pos = octomap::computeChildIdx(key, static_cast<int>(depth - 1 - d));
    if (!tree.nodeChildExists(node, pos)) return;  // not in the tree
    path.emplace_back(node, pos);
    node = tree.getNodeChild(node, pos);
  }
  if (node == nullptr || tree.nodeHasChildren(node)) return;
  for (auto it = path.rbegin(); it != path.rend(); ++it) {
    tree.deleteNodeChild(it->first, it->second);
    if (it->first == tree.getRoot() || tree.nodeHasChildren(it->first)) break;
    ChildArray::release(*it->first);  // now a childless inner node: its parent deletes it next
  }
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

OctreeChangeLayer::OctreeChangeLayer(octomap::OcTree& tree, const OctreeChangeOptions& options)
    : tree_(tree),
      options_(options),
      free_update_(std::isnan(options.free_log_odds) ? -fullSwing(tree) : options.free_log_odds),
      occupied_update_(std::isnan(options.occupied_log_odds) ? fullSwing(tree)
                                                             : options.occupied_log_odds) {}

void OctreeChangeLayer::restore(const octomap::OcTreeKey& key) {
  const auto it = original_.find(key);
  if (it == original_.end()) return;
  if (it->second)
    tree_.setNodeValue(key, *it->second, true);
  else
    eraseVoxel(tree_, key);
}

void OctreeChangeLayer::apply(const ChangeEvent& e) {
  // The voxels the change covered and covers now: back to their original values, then every
  // active change's updates on them again, frees first (as applyChanges).
  octomap::KeySet touched;
  if (const auto it = keys_.find(e.id); it != keys_.end()) {
    touched.insert(it->second.freed.begin(), it->second.freed.end());
    touched.insert(it->second.occupied.begin(), it->second.occupied.end());
    keys_.erase(it);
    active_.erase(e.id);
  }
  if (e.status != ChangeStatus::Retracted) {
    Keys k;
    if (isRemovedSide(e)) k.freed = keysOf(e.reference, tree_, true, options_);
    if (isAddedSide(e)) k.occupied = keysOf(e.current, tree_, false, options_);
    for (const octomap::KeySet* s : {&k.freed, &k.occupied})
      for (const auto& key : *s) {
        touched.insert(key);
        if (original_.count(key) == 0) {
          const octomap::OcTreeNode* n = tree_.search(key);
          original_.emplace(
              key, n != nullptr ? std::optional<float>(n->getLogOdds()) : std::optional<float>());
        }
      }
    keys_.emplace(e.id, std::move(k));
    active_[e.id] = e;
  }
  for (const auto& key : touched) {
    restore(key);
    bool freed = false, occupied = false;
    for (const auto& [id, k] : keys_) {
      freed = freed || k.freed.count(key) > 0;
      occupied = occupied || k.occupied.count(key) > 0;
    }
    if (freed) tree_.updateNode(key, free_update_, true);
    if (occupied) tree_.updateNode(key, occupied_update_, true);
    if (!freed && !occupied) original_.erase(key);  // no change covers it any more
  }
  tree_.updateInnerOccupancy();
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
