#pragma once
/// \file change_octree.hpp
/// planesdf change events applied to a user's OctoMap, at the tree's own resolution.
///
/// What an event covers. A ChangeRegion's `points` are the session's input points on the
/// changed object (world frame): its seen surface. Objects rest on (or hang from) a plane, so
/// the object is taken as a height field along `up`: the voxels of the segment from each point
/// down to the object's lowest point (`solid`, the default), or only the voxels holding its
/// points. A removed side (Removed, the old place of Moved, the object Replaced) is the
/// reference region; an added side (Added, the new place of Moved, the replacing object) is the
/// current region. applyChanges skips Retracted notifications: it applies a final set of
/// events. To follow a ChangeDetector's notifications as they come, use an OctreeChangeLayer.
///
/// Writing: writeOcTree writes `.ot` (AbstractOcTree::write: full node data, so a ColorOcTree
/// keeps its colours). OctoMap's `.bt` format (OcTree::writeBinaryConst) keeps occupancy only:
/// use it for an OcTree, never for the painted ColorOcTree.

#include <octomap/ColorOcTree.h>
#include <octomap/OcTree.h>

#include <Eigen/Core>

#include <cstddef>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "planesdf/change.hpp"

namespace planesdf::octomap_adapter {

struct OctreeChangeOptions {
  /// World up: objects are filled as height fields along it (see the file comment).
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  /// Fill each object down to its lowest point (true) or mark only the voxels of its points.
  bool solid = true;
  /// Log-odds added to each voxel of an added / removed side. NaN (default): the full clamping
  /// range, so the voxel ends occupied / free whatever it was before.
  float occupied_log_odds = std::numeric_limits<float>::quiet_NaN();
  float free_log_odds = std::numeric_limits<float>::quiet_NaN();
};

struct OctreeChangeStats {
  std::size_t freed_voxels = 0;     ///< voxels of removed sides updated toward free
  std::size_t occupied_voxels = 0;  ///< voxels of added sides updated toward occupied
};

/// The voxel keys of `tree` covered by `region` (see the file comment). A removed side
/// (`removed`) leaves out the voxel layer at the object's base, which it shares with the
/// support surface, so the table under a removed object stays occupied.
octomap::KeySet changeKeys(const ChangeRegion& region, const octomap::OcTree& tree, bool removed,
                           const OctreeChangeOptions& options = {});

/// Applies the events to `tree` by log-odds updates (updateNode): the voxels of removed sides
/// become free, then those of added sides occupied (so a replacing object wins over the one it
/// replaced), and inner nodes are updated.
OctreeChangeStats applyChanges(const std::vector<ChangeEvent>& events, octomap::OcTree& tree,
                               const OctreeChangeOptions& options = {});
OctreeChangeStats applyChanges(const ChangeSet& set, octomap::OcTree& tree,
                               const OctreeChangeOptions& options = {});

/// A user's OcTree kept equal to the tree it started as with the active changes applied, as
/// applyChanges would apply them, while a ChangeDetector's notifications arrive: New applies a
/// change, Updated replaces its earlier state, Retracted undoes it. The layer remembers the value
/// each voxel had before a change first touched it. The tree must outlive the layer, and only
/// the layer may write the voxels the active changes cover.
class OctreeChangeLayer {
 public:
  explicit OctreeChangeLayer(octomap::OcTree& tree, const OctreeChangeOptions& options = {});

  /// Applies one notification (see the class comment) and updates the inner nodes.
  void apply(const ChangeEvent& notification);
  /// The changes applied now (latest state of each, by id).
  const std::map<int, ChangeEvent>& active() const { return active_; }

 private:
  struct Keys {
    octomap::KeySet freed, occupied;
  };
  void restore(const octomap::OcTreeKey& key);

  octomap::OcTree& tree_;
  OctreeChangeOptions options_;
  float free_update_ = 0.0f, occupied_update_ = 0.0f;
  std::map<int, ChangeEvent> active_;
  std::map<int, Keys> keys_;  ///< the voxels of each active change
  /// Per voxel some change touched: its log-odds before, or none when it was not in the tree.
  std::unordered_map<octomap::OcTreeKey, std::optional<float>, octomap::OcTreeKey::KeyHash>
      original_;
};

/// Marks the voxels of both sides of every event occupied in `tree` and colours them with
/// planesdf::changeColor (added red, removed blue, moved yellow, replaced magenta; a moved
/// object is yellow at both places). Returns the number of voxels painted.
std::size_t paintChanges(const std::vector<ChangeEvent>& events, octomap::ColorOcTree& tree,
                         const OctreeChangeOptions& options = {});

/// Writes `tree` as an `.ot` file (any OcTree type, with its node data), atomically. Throws
/// planesdf::Error naming `path` on failure.
void writeOcTree(const std::string& path, const octomap::AbstractOcTree& tree);

}  // namespace planesdf::octomap_adapter
