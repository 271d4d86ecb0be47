// applyChanges / paintChanges on an analytic tabletop: the box removed, a sphere added, the
// cylinder moved. The user's OcTree is built from the reference session's frames; after
// applying the ChangeSet the removed box is free, the added sphere occupied, the table under
// the box still occupied; the ColorOcTree is painted with the change colours and written as .ot.
#include <gtest/gtest.h>
#include <octomap/ColorOcTree.h>
#include <octomap/OcTree.h>

#include <filesystem>
#include <memory>

#include "analytic_scene.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"
#include "planesdf/octomap/change_octree.hpp"
#include "planesdf/octomap/octomap_conversion.hpp"

namespace {
using namespace planesdf;
namespace oa = planesdf::octomap_adapter;
using test::AnalyticScene;
using test::Primitive;

constexpr double kTable = test::kTableTop;
constexpr double kRes = 0.02;

const Eigen::Vector3d kBoxCentre(0.10, 0.05, kTable + 0.04);
const Eigen::Vector3d kSphereCentre(-0.12, 0.15, kTable + 0.05);
AnalyticScene before() {
  return test::tableWith({Primitive::box({0.05, 0.02, kTable}, {0.15, 0.08, kTable + 0.08}),
                          Primitive::cylinder({-0.15, -0.10, kTable}, 0.04, 0.12)});
}
AnalyticScene after() {
  return test::tableWith({Primitive::sphere(kSphereCentre, 0.05),
                          Primitive::cylinder({0.05, -0.10, kTable}, 0.04, 0.12)});
}

struct Fixture {
  ChangeSet changes;
  std::unique_ptr<octomap::OcTree> tree;  ///< the user's map of the reference session
};
const Fixture& fixture() {
  static const Fixture f = [] {
    Fixture out;
    const auto poses = test::ringPoses({0, 0, kTable}, 0.9, 0.55, 8);
    Map ref{Config{}}, cur{Config{}};
    out.tree = std::make_unique<octomap::OcTree>(kRes);
    const AnalyticScene b = before(), a = after();
    for (const Pose& T : poses) {
      const DepthFrame f = test::renderDepth(b, Intrinsics{}, T);
      ref.integrate(f, T);
      // The same frame as a cloud for OctoMap (every 4th pixel, world frame).
      PointCloud c;
      for (int v = 0; v < f.intrinsics.height; v += 4)
        for (int u = 0; u < f.intrinsics.width; u += 4) {
          const float d = f.at(u, v);
          if (!DepthFrame::isValidDepth(d)) continue;
          c.points.emplace_back((u - f.intrinsics.cx) * d / f.intrinsics.fx,
                                (v - f.intrinsics.cy) * d / f.intrinsics.fy, d);
        }
      c.width = static_cast<std::uint32_t>(c.points.size());
      const Eigen::Vector3d o = T.translation();
      out.tree->insertPointCloud(oa::toOctomap(c, T), octomap::point3d(o.x(), o.y(), o.z()), 3.0);
      cur.integrate(test::renderDepth(a, Intrinsics{}, T), T);
    }
    out.changes = detectChanges(ref, cur, Config{});
    return out;
  }();
  return f;
}

const ChangeEvent* findType(const ChangeSet& s, ChangeType t) {
  for (const auto& e : s.events)
    if (e.type == t) return &e;
  return nullptr;
}
bool occupied(const octomap::OcTree& tree, const Eigen::Vector3d& p) {
  const octomap::OcTreeNode* n = tree.search(p.x(), p.y(), p.z());
  return n != nullptr && tree.isNodeOccupied(n);
}
bool knownFree(const octomap::OcTree& tree, const Eigen::Vector3d& p) {
  const octomap::OcTreeNode* n = tree.search(p.x(), p.y(), p.z());
  return n != nullptr && !tree.isNodeOccupied(n);
}

TEST(OctomapChanges, RemovedObjectBecomesFreeAndAddedOccupied) {
  const Fixture& f = fixture();
  const ChangeEvent* removed = findType(f.changes, ChangeType::Removed);
  const ChangeEvent* added = findType(f.changes, ChangeType::Added);
  ASSERT_NE(removed, nullptr) << changesToJson(f.changes.events);
  ASSERT_NE(added, nullptr) << changesToJson(f.changes.events);
  octomap::OcTree tree(*f.tree);
  // Before: the box's top surface is occupied, the sphere's centre is not.
  const Eigen::Vector3d box_top(0.10, 0.05, kTable + 0.08 - 0.005);
  ASSERT_TRUE(occupied(tree, box_top));
  ASSERT_FALSE(occupied(tree, kSphereCentre));

  const oa::OctreeChangeStats stats = oa::applyChanges(f.changes, tree);
  EXPECT_GT(stats.freed_voxels, 10u);
  EXPECT_GT(stats.occupied_voxels, 10u);
  // At the centroids planesdf reports and at the true object centres.
  EXPECT_TRUE(knownFree(tree, removed->reference.centroid));
  EXPECT_TRUE(knownFree(tree, kBoxCentre));
  EXPECT_TRUE(knownFree(tree, box_top));
  EXPECT_TRUE(occupied(tree, added->current.centroid));
  EXPECT_TRUE(occupied(tree, kSphereCentre));
  // The table top under the removed box (never seen: unknown before) is not carved free.
  const Eigen::Vector3d under_box(0.10, 0.05, kTable - 0.005);
  EXPECT_FALSE(knownFree(tree, under_box));
  // The seen table top beside it stays occupied.
  const Eigen::Vector3d beside_box(0.10, -0.01, kTable - 0.005);
  ASSERT_TRUE(occupied(*f.tree, beside_box));
  EXPECT_TRUE(occupied(tree, beside_box));
  // The moved cylinder: old place free, new place occupied.
  EXPECT_TRUE(knownFree(tree, Eigen::Vector3d(-0.15, -0.10, kTable + 0.06)));
  EXPECT_TRUE(occupied(tree, Eigen::Vector3d(0.05, -0.10, kTable + 0.06)));
}

/// A region of points filling a 6 x 6 x 6 cm box on the table around (x, y).
ChangeRegion blockAt(double x, double y) {
  ChangeRegion r;
  for (double dx = -0.03; dx <= 0.03; dx += 0.01)
    for (double dy = -0.03; dy <= 0.03; dy += 0.01)
      for (double z = kTable + 0.005; z <= kTable + 0.06; z += 0.01)
        r.points.emplace_back(static_cast<float>(x + dx), static_cast<float>(y + dy),
                              static_cast<float>(z));
  r.centroid = Eigen::Vector3d(x, y, kTable + 0.03);
  return r;
}

ChangeEvent event(int id, ChangeType type, ChangeStatus status, const ChangeRegion& ref,
                  const ChangeRegion& cur) {
  ChangeEvent e;
  e.id = id;
  e.type = type;
  e.status = status;
  e.reference = ref;
  e.current = cur;
  return e;
}

/// Every voxel `events` cover (either side, either way) has the same value in both trees, and
/// so has every leaf of `original`.
void expectSameTrees(const octomap::OcTree& got, const octomap::OcTree& want,
                     const octomap::OcTree& original, const std::vector<ChangeEvent>& events) {
  octomap::KeySet keys;
  for (const ChangeEvent& e : events)
    for (const ChangeRegion* r : {&e.reference, &e.current})
      for (const bool removed : {true, false}) {
        const octomap::KeySet k = oa::changeKeys(*r, original, removed);
        keys.insert(k.begin(), k.end());
      }
  for (auto it = original.begin_leafs(); it != original.end_leafs(); ++it)
    if (it.getDepth() == original.getTreeDepth()) keys.insert(it.getKey());
  ASSERT_GT(keys.size(), 1000u);
  std::size_t differ = 0;
  for (const auto& key : keys) {
    const octomap::OcTreeNode* a = got.search(key);
    const octomap::OcTreeNode* b = want.search(key);
    if ((a == nullptr) != (b == nullptr) ||
        (a != nullptr && std::abs(a->getLogOdds() - b->getLogOdds()) > 1e-5f))
      ++differ;
  }
  EXPECT_EQ(differ, 0u) << "of " << keys.size() << " voxels";
}

TEST(OctomapChanges, ALayerFollowsNotificationsToTheFinalSet) {
  // New, Updated and Retracted in turn, with overlapping changes: the tree ends as the final
  // set applied to the original.
  const octomap::OcTree& original = *fixture().tree;
  const ChangeRegion none;
  const ChangeRegion box = blockAt(kBoxCentre.x(), kBoxCentre.y());
  const std::vector<ChangeEvent> notes = {
      event(1, ChangeType::Added, ChangeStatus::New, none, blockAt(-0.12, 0.15)),
      event(2, ChangeType::Removed, ChangeStatus::New, box, none),
      event(3, ChangeType::Added, ChangeStatus::New, none, blockAt(-0.09, 0.15)),
      event(1, ChangeType::Moved, ChangeStatus::Updated, blockAt(-0.15, -0.10),
            blockAt(-0.13, 0.15)),
      event(2, ChangeType::Removed, ChangeStatus::Retracted, box, none),
      event(3, ChangeType::Replaced, ChangeStatus::Updated, blockAt(0.12, 0.05),
            blockAt(-0.09, 0.15)),
  };
  octomap::OcTree tree(original);
  oa::OctreeChangeLayer layer(tree);
  for (const ChangeEvent& e : notes) layer.apply(e);
  ASSERT_EQ(layer.active().size(), 2u);
  octomap::OcTree want(original);
  oa::applyChanges(std::vector<ChangeEvent>{notes[3], notes[5]}, want);
  expectSameTrees(tree, want, original, notes);
  // The retracted removal left the box occupied; the replaced place overlapping it is free.
  EXPECT_TRUE(occupied(tree, Eigen::Vector3d(0.07, 0.05, kTable + 0.075)));
  EXPECT_TRUE(knownFree(tree, Eigen::Vector3d(0.13, 0.05, kTable + 0.05)));

  // Retracting everything gives the original back.
  layer.apply(event(1, ChangeType::Moved, ChangeStatus::Retracted, none, none));
  layer.apply(event(3, ChangeType::Replaced, ChangeStatus::Retracted, none, none));
  EXPECT_TRUE(layer.active().empty());
  expectSameTrees(tree, original, original, notes);
}

TEST(OctomapChanges, ColorTreeIsPaintedByTypeAndWritten) {
  const Fixture& f = fixture();
  octomap::ColorOcTree tree(kRes);
  const std::size_t n = oa::paintChanges(f.changes.events, tree);
  EXPECT_GT(n, 30u);
  const auto colourAt = [&](const Eigen::Vector3d& p) {
    const octomap::ColorOcTreeNode* node = tree.search(p.x(), p.y(), p.z());
    EXPECT_NE(node, nullptr) << p.transpose();
    EXPECT_TRUE(node != nullptr && tree.isNodeOccupied(node));
    return node ? node->getColor() : octomap::ColorOcTreeNode::Color();
  };
  const auto expectColour = [&](const Eigen::Vector3d& p, ChangeType t) {
    const auto c = changeColor(t);
    const auto got = colourAt(p);
    EXPECT_EQ(got, octomap::ColorOcTreeNode::Color(c[0], c[1], c[2]))
        << toString(t) << " at " << p.transpose() << ": got " << int(got.r) << "," << int(got.g)
        << "," << int(got.b);
  };
  expectColour(kBoxCentre, ChangeType::Removed);                                  // blue
  expectColour(kSphereCentre, ChangeType::Added);                                 // red
  expectColour(Eigen::Vector3d(-0.15, -0.10, kTable + 0.06), ChangeType::Moved);  // yellow, old
  expectColour(Eigen::Vector3d(0.05, -0.10, kTable + 0.06), ChangeType::Moved);   // and new
  // Unchanged space is not in the tree.
  EXPECT_EQ(tree.search(0.4, 0.3, kTable + 0.05), nullptr);

  const auto path = std::filesystem::temp_directory_path() / "planesdf_octomap_changes_test.ot";
  oa::writeOcTree(path.string(), tree);
  std::unique_ptr<octomap::AbstractOcTree> back(octomap::AbstractOcTree::read(path.string()));
  auto* color_back = dynamic_cast<octomap::ColorOcTree*>(back.get());
  ASSERT_NE(color_back, nullptr);
  EXPECT_EQ(color_back->size(), tree.size());
  const octomap::ColorOcTreeNode* node =
      color_back->search(kSphereCentre.x(), kSphereCentre.y(), kSphereCentre.z());
  ASSERT_NE(node, nullptr);
  EXPECT_EQ(node->getColor(),
            tree.search(kSphereCentre.x(), kSphereCentre.y(), kSphereCentre.z())->getColor());
  std::filesystem::remove(path);
}

TEST(OctomapChanges, WriteErrorNamesTheFile) {
  octomap::OcTree tree(kRes);
  const std::string bad = "/nonexistent_planesdf_dir/changes.ot";
  try {
    oa::writeOcTree(bad, tree);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), bad);
  }
}

}  // namespace
