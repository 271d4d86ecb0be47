// Tests of the height-map comparison (paper eq. 2), mask cleaning, changed blobs and the in-plane
// refinement, on height maps built by hand: a flat 60x60 map (7 mm cells) with 8 cm boxes.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "planesdf/comparison.hpp"
#include "planesdf/config.hpp"
#include "planesdf/error.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/registration.hpp"

namespace planesdf {
namespace {

constexpr double kCell = 0.007;
constexpr int kSize = 60;
constexpr double kDeg = 3.14159265358979323846 / 180.0;

/// A box [x0, x0 + w) x [y0, y0 + h) in cells of the source grid, `height` metres tall.
struct Box {
  int x0, y0, w, h;
  float height;
};

GridGeometry grid() {
  GridGeometry g;
  g.width = kSize;
  g.height = kSize;
  g.cell_size = kCell;
  return g;
}

/// The height map of a scene of boxes (given in source-local metres via their cells) seen by a
/// session whose plane-local frame is `A` * source-local: cell centre c' samples the scene at
/// A^{-1} c'.
HeightMap render(const std::vector<Box>& boxes, const Pose& A = Pose::Identity()) {
  HeightMap hm;
  static_cast<GridGeometry&>(hm) = grid();
  hm.heights.assign(hm.numCells(), 0.0f);
  const Pose inv = A.inverse(Eigen::Isometry);
  for (int y = 0; y < hm.height; ++y) {
    for (int x = 0; x < hm.width; ++x) {
      const Eigen::Vector2d c = hm.cellCenter(x, y);
      const Eigen::Vector3d q = inv * Eigen::Vector3d(c.x(), c.y(), 0.0);
      for (const Box& b : boxes) {
        if (q.x() >= b.x0 * kCell && q.x() < (b.x0 + b.w) * kCell && q.y() >= b.y0 * kCell &&
            q.y() < (b.y0 + b.h) * kCell) {
          hm.at(x, y) = std::max(hm.at(x, y), b.height);
        }
      }
    }
  }
  return hm;
}

Pose yawShift(double yaw_rad, double du, double dv) {
  Pose p = Pose::Identity();
  p.linear() = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(du, dv, 0.0);
  return p;
}

const Box kObject{25, 25, 10, 10, 0.08f};

TEST(HeightCompare, IdenticalMapsGiveEmptyMask) {
  const Config cfg;
  const HeightMap hm = render({kObject});
  Mask2D unknown;
  const Mask2D raw = compareHeightMaps(hm, hm, Pose::Identity(), cfg, &unknown);
  EXPECT_TRUE(raw.sameGeometry(hm.geometry()));
  EXPECT_EQ(raw.count(), 0u);
  EXPECT_EQ(unknown.count(), 0u);  // the last column / row stays comparable (inward tie)
  EXPECT_EQ(cleanChangeMask(raw, cfg).count(), 0u);
}

TEST(HeightCompare, RemovedObjectCellsAreChanged) {
  const Config cfg;
  const HeightMap src = render({kObject});
  const HeightMap tgt = render({});
  const HeightChange hc =
      detectHeightChange(src, tgt, computeObjectMap(src, cfg), Pose::Identity(), cfg);
  EXPECT_EQ(hc.raw.count(), 100u);
  for (int y = 25; y < 35; ++y) {
    for (int x = 25; x < 35; ++x) EXPECT_TRUE(hc.raw.at(x, y));
  }
  EXPECT_EQ(hc.filtered.count(), 100u);
  EXPECT_EQ(hc.cleaned.count(), 144u);  // 10x10 dilated by one cell
  ASSERT_EQ(hc.blobs.size(), 1u);
  EXPECT_EQ(hc.blobs[0].area, 100);
  EXPECT_EQ(hc.blob_mask.count(), 100u);
  EXPECT_EQ(hc.blobs[0].bbox_min, Eigen::Vector2i(25, 25));
  EXPECT_EQ(hc.blobs[0].bbox_max, Eigen::Vector2i(34, 34));
}

TEST(HeightCompare, UnobservedTargetIsUnknownNotChanged) {
  const Config cfg;
  const HeightMap src = render({kObject});
  HeightMap tgt = render({});
  for (int y = 24; y < 36; ++y) {
    for (int x = 24; x < 36; ++x) tgt.at(x, y) = kUnobserved;
  }
  Mask2D unknown;
  const Mask2D raw = compareHeightMaps(src, tgt, Pose::Identity(), cfg, &unknown);
  EXPECT_EQ(raw.count(), 0u);
  for (int y = 25; y < 35; ++y) {
    for (int x = 25; x < 35; ++x) EXPECT_TRUE(unknown.at(x, y));
  }
  // One unobserved neighbour among the four is enough to make a cell unknown.
  HeightMap tgt2 = render({});
  tgt2.at(30, 30) = kUnobserved;
  Mask2D unknown2;
  const Mask2D raw2 =
      compareHeightMaps(src, tgt2, yawShift(0.0, 0.5 * kCell, 0.5 * kCell), cfg, &unknown2);
  // Shifted by half a cell, source cells 29..30 x 29..30 all need target cell (30, 30).
  for (int y = 29; y <= 30; ++y) {
    for (int x = 29; x <= 30; ++x) {
      EXPECT_FALSE(raw2.at(x, y));
      EXPECT_TRUE(unknown2.at(x, y));
    }
  }
  EXPECT_EQ(raw2.count(), 96u);
  // An unobserved source cell is unknown too; cells mapped outside the target are unknown.
  HeightMap src3 = src;
  src3.at(30, 30) = kUnobserved;
  Mask2D unknown3;
  const Mask2D raw3 = compareHeightMaps(src3, tgt, yawShift(0.0, 0.1, 0.0), cfg, &unknown3);
  EXPECT_TRUE(unknown3.at(30, 30));
  EXPECT_TRUE(unknown3.at(kSize - 1, 10));
  EXPECT_FALSE(raw3.at(kSize - 1, 10));
}

TEST(HeightCompare, SmallNoiseIsNoChangeAfterCleaning) {
  const Config cfg;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> noise(-0.005f, 0.005f);
  HeightMap src = render({kObject});
  HeightMap tgt = render({kObject});
  for (float& h : src.heights) h = std::max(0.0f, h + noise(rng));
  for (float& h : tgt.heights) h = std::max(0.0f, h + noise(rng));
  const Mask2D raw = compareHeightMaps(src, tgt, Pose::Identity(), cfg);
  EXPECT_EQ(raw.count(), 0u);
  EXPECT_EQ(cleanChangeMask(raw, cfg).count(), 0u);
}

TEST(HeightCompare, DifferenceOfExactlyDeltaHIsUnchanged) {
  const Config cfg;  // delta_h = 0.02
  HeightMap src = render({});
  HeightMap tgt = render({});
  src.at(10, 10) = 0.08f;
  tgt.at(10, 10) = tgt.at(11, 10) = tgt.at(10, 11) = tgt.at(11, 11) = 0.06f;  // exactly 2 cm
  src.at(40, 40) = 0.0f;
  tgt.at(40, 40) = tgt.at(41, 40) = tgt.at(40, 41) = tgt.at(41, 41) = 0.02f;
  src.at(20, 20) = 0.0f;
  tgt.at(20, 20) = tgt.at(21, 20) = tgt.at(20, 21) = tgt.at(21, 21) = 0.0201f;
  src.at(50, 20) = 0.1f;  // three neighbours differ, one agrees -> unchanged
  tgt.at(51, 20) = tgt.at(50, 21) = tgt.at(51, 21) = 0.05f;
  tgt.at(50, 20) = 0.1f;
  const Mask2D raw = compareHeightMaps(src, tgt, Pose::Identity(), cfg);
  EXPECT_FALSE(raw.at(10, 10));
  EXPECT_FALSE(raw.at(40, 40));
  EXPECT_TRUE(raw.at(20, 20));
  EXPECT_FALSE(raw.at(50, 20));
}

TEST(HeightCompare, UsesTheFourCellsAroundTheProjectedPoint) {
  const Config cfg;
  HeightMap src = render({});
  HeightMap tgt = render({});
  src.at(30, 30) = 0.1f;
  // Shifted by +0.6 cell: the point sits between target cells 30/31 (x) and 30/31 (y).
  const Pose T = yawShift(0.0, 0.6 * kCell, 0.6 * kCell);
  tgt.at(31, 31) = 0.1f;
  EXPECT_FALSE(compareHeightMaps(src, tgt, T, cfg).at(30, 30));
  tgt.at(31, 31) = 0.0f;
  tgt.at(32, 32) = 0.1f;  // outside the 2x2 neighbourhood
  EXPECT_TRUE(compareHeightMaps(src, tgt, T, cfg).at(30, 30));
}

TEST(HeightCompare, AHeightBetweenTheFourTargetCellsLiesOnAnEdge) {
  const Config cfg;
  HeightMap src = render({});
  HeightMap tgt = render({});
  // Shifted by half a cell: source cell 30 maps between target cells 30 and 31, an edge from
  // 0 to 10 cm; 5 cm lies on it. 15 cm is above both.
  const Pose T = yawShift(0.0, 0.5 * kCell, 0.0);
  src.at(30, 30) = 0.05f;
  src.at(30, 40) = 0.15f;
  for (int y : {30, 31, 40, 41}) tgt.at(31, y) = 0.1f;
  const Mask2D raw = compareHeightMaps(src, tgt, T, cfg);
  EXPECT_FALSE(raw.at(30, 30));
  EXPECT_TRUE(raw.at(30, 40));
}

TEST(HeightCompare, SlackCellsExplainASurfaceOneCellOver) {
  const Config cfg;
  // A table leg 30 cm tall, placed further along x in the target (a splatted reconstruction puts
  // its rim within a cell). With T = identity, source cell x sits on target cell x's centre: the
  // 2x2 cells are x and x + 1, and one cell of slack adds x - 1 and x + 2.
  const HeightMap src = render({{20, 20, 6, 6, 0.3f}});
  const HeightMap tgt = render({{22, 20, 6, 6, 0.3f}});
  const Mask2D plain = compareHeightMaps(src, tgt, Pose::Identity(), cfg);
  EXPECT_TRUE(plain.at(20, 22));  // the rim the target lacks
  const Mask2D slack =
      compareHeightMaps(src, tgt, Pose::Identity(), cfg, nullptr, HeightTolerance{{}, {}, 1});
  EXPECT_EQ(slack.count(), 0u);
  // A leg moved by 5 cells stays a change, less the one cell of slack.
  const HeightMap moved = render({{25, 20, 6, 6, 0.3f}});
  const Mask2D far =
      compareHeightMaps(src, moved, Pose::Identity(), cfg, nullptr, HeightTolerance{{}, {}, 1});
  for (int x = 20; x < 23; ++x) EXPECT_TRUE(far.at(x, 22)) << x;
  EXPECT_FALSE(far.at(23, 22));
}

/// `hm` with the cells of `b` marked as never seen from above (HeightMap::unseen_above).
void markUnseenAbove(HeightMap& hm, const Box& b) {
  hm.unseen_above.assign(hm.numCells(), 0);
  for (int y = b.y0; y < b.y0 + b.h; ++y)
    for (int x = b.x0; x < b.x0 + b.w; ++x) hm.unseen_above[hm.index(x, y)] = 1;
}

std::size_t countSet(const Mask2D& m, const Box& b) {
  std::size_t n = 0;
  for (int y = b.y0; y < b.y0 + b.h; ++y)
    for (int x = b.x0; x < b.x0 + b.w; ++x) n += m.at(x, y) ? 1 : 0;
  return n;
}

TEST(HeightCompare, ASplattedTargetNeverSeenFromAboveIsUnknownAboveItsSurface) {
  const Config cfg;
  // The source has an 8 cm box; the target's surface there is the top face of inside voxels
  // (a board seen edge-on from a wall's band): nothing above it was observed.
  const HeightMap src = render({kObject});
  HeightMap tgt = render({});
  markUnseenAbove(tgt, kObject);
  const Box core{kObject.x0 + 1, kObject.y0 + 1, kObject.w - 2, kObject.h - 2, 0.0f};
  HeightTolerance splatted;
  splatted.free_reach = 4 * kCell;  // free voxels only within the truncation
  Mask2D unknown;
  const Mask2D changed = compareHeightMaps(src, tgt, Pose::Identity(), cfg, &unknown, splatted);
  EXPECT_EQ(countSet(changed, core), 0u);
  EXPECT_EQ(countSet(unknown, core), static_cast<std::size_t>(core.w * core.h));
  // Depth fusion carves whole rays: the same maps are a removal.
  const Mask2D fused = compareHeightMaps(src, tgt, Pose::Identity(), cfg);
  EXPECT_EQ(countSet(fused, core), static_cast<std::size_t>(core.w * core.h));
  // The other way round the target is the lower map, whose cells are compared as before.
  EXPECT_EQ(countSet(compareHeightMaps(tgt, src, Pose::Identity(), cfg, nullptr, splatted), core),
            static_cast<std::size_t>(core.w * core.h));
}

TEST(HeightCompare, ASplattedSourceTopNeverSeenNeedsTheTargetsObservedFreeSpace) {
  const Config cfg;  // fuse_band 0.3
  HeightTolerance splatted;
  splatted.free_reach = 0.05;
  splatted.band_top = cfg.fuse_band;
  const HeightMap tgt = render({});
  const auto changedCells = [&](float height) {
    HeightMap src = render({{25, 25, 10, 10, height}});
    markUnseenAbove(src, {25, 25, 10, 10, 0.0f});
    return countSet(compareHeightMaps(src, tgt, Pose::Identity(), cfg, nullptr, splatted),
                    {25, 25, 10, 10, 0.0f});
  };
  // Noise of a far surface 8 cm out, inside voxels only: the target saw free space up to 5 cm.
  EXPECT_EQ(changedCells(0.08f), 0u);
  // Within the target's observed free space: a change.
  EXPECT_EQ(changedCells(0.04f), 100u);
  // At the band's top the object goes on beyond the band (a tall bottle): a change.
  EXPECT_EQ(changedCells(0.3f), 100u);
  // A top seen from above is a change at any height.
  const HeightMap seen = render({{25, 25, 10, 10, 0.08f}});
  EXPECT_EQ(countSet(compareHeightMaps(seen, tgt, Pose::Identity(), cfg, nullptr, splatted),
                     {25, 25, 10, 10, 0.0f}),
            100u);
}

/// `hm` with bumps 3x3 cells wide and up to `max_bump` high at random places over the columns
/// [x0, x1): a far surface fused from noisy depth.
void addBumps(HeightMap& hm, int x0, int x1, float max_bump, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> px(x0, x1 - 3), py(0, hm.height - 3);
  std::uniform_real_distribution<float> height(0.3f * max_bump, max_bump);
  for (int k = 0; k < (x1 - x0) * hm.height / 20; ++k) {
    const int bx = px(rng), by = py(rng);
    const float h = height(rng);
    for (int y = by; y < by + 3; ++y)
      for (int x = bx; x < bx + 3; ++x) hm.at(x, y) = std::max(hm.at(x, y), h);
  }
}

TEST(Roughness, BumpyTilesAreRoughAndObjectsTallerThanTheNoiseAreNot) {
  Config cfg;                                      // roughness_tile 16, cap 2 delta_h = 4 cm
  HeightMap hm = render({{2, 2, 12, 12, 0.08f}});  // a box in the flat half
  addBumps(hm, 32, kSize, 0.03f, 3);
  const RoughnessMap r = computeRoughness(hm, cfg);
  ASSERT_EQ(r.tiles_x, 4);
  ASSERT_EQ(r.tiles_y, 4);
  // Flat tiles, the box's included (its edges are above the cap): no roughness.
  EXPECT_EQ(r.atCell(5, 5), 0.0f);
  EXPECT_EQ(r.atCell(20, 40), 0.0f);
  // Bumpy tiles: a fair part of the 1-3 cm bumps, never more than the largest bump.
  for (int y : {5, 20, 40}) {
    EXPECT_GT(r.atCell(40, y), 0.005f) << y;
    EXPECT_LE(r.atCell(40, y), 0.03f) << y;
  }
  cfg.roughness_tile = 0;
  EXPECT_EQ(computeRoughness(hm, cfg).tile, 0);
  EXPECT_EQ(computeRoughness(hm, cfg).atCell(40, 5), 0.0f);
}

TEST(HeightCompare, BumpsOfNoiseInBothSessionsAreNoChangeButATallObjectIs) {
  const Config cfg;
  HeightMap src = render({});
  HeightMap tgt = render({});
  addBumps(src, 0, kSize, 0.03f, 11);
  addBumps(tgt, 0, kSize, 0.03f, 12);
  // Added in the source: 13 cm on bumps of at most 3 cm differs by more than 3 times any
  // roughness (at most the largest bump) from every target cell.
  for (int y = 20; y < 30; ++y)
    for (int x = 20; x < 30; ++x) src.at(x, y) = 0.13f;
  const RoughnessMap rs = computeRoughness(src, cfg);
  const RoughnessMap rt = computeRoughness(tgt, cfg);
  const Mask2D plain = cleanChangeMask(compareHeightMaps(src, tgt, Pose::Identity(), cfg), cfg);
  const Mask2D aware = cleanChangeMask(
      compareHeightMaps(src, tgt, Pose::Identity(), cfg, nullptr, HeightTolerance{&rs, &rt}), cfg);
  std::size_t plain_off = 0, aware_off = 0;
  for (int y = 0; y < kSize; ++y)
    for (int x = 0; x < kSize; ++x) {
      const bool in_box = x >= 19 && x <= 30 && y >= 19 && y <= 30;  // dilated by one cell
      if (in_box) {
        if (x >= 20 && x < 30 && y >= 20 && y < 30) {
          EXPECT_TRUE(aware.at(x, y)) << x << " " << y;
        }
        continue;
      }
      plain_off += plain.at(x, y) ? 1 : 0;
      aware_off += aware.at(x, y) ? 1 : 0;
    }
  EXPECT_GT(plain_off, 100u);  // the plain 2 cm test reports the noise
  EXPECT_EQ(aware_off, 0u);
}

TEST(HeightCompare, BlobsGrowToWholeObjectComponent) {
  Config cfg;
  HeightMap src = render({{10, 10, 12, 4, 0.08f}, {10, 14, 4, 10, 0.08f}, {40, 40, 6, 6, 0.05f}});
  const ObjectMap objects = computeObjectMap(src, cfg);
  ASSERT_EQ(objects.numObjects(), 2);
  Mask2D mask = Mask2D::zeros(src.geometry());
  for (int y = 20; y < 24; ++y) {
    for (int x = 8; x < 12; ++x) mask.set(x, y);  // touches the L-shaped object's foot only
  }
  const std::vector<Blob> blobs = changedBlobs(mask, objects);
  ASSERT_EQ(blobs.size(), 1u);
  EXPECT_EQ(blobs[0].area, 12 * 4 + 4 * 10);
  EXPECT_EQ(blobs[0].cells.size(), 88u);
  for (const Eigen::Vector2i& c : blobs[0].cells)  // every cell on the object, none twice
    EXPECT_EQ(objects.at(c.x(), c.y()), objects.at(10, 10));
  EXPECT_TRUE(std::adjacent_find(blobs[0].cells.begin(), blobs[0].cells.end()) ==
              blobs[0].cells.end());
  EXPECT_EQ(blobs[0].object_labels, std::vector<int>{objects.at(10, 10)});
  EXPECT_EQ(blobs[0].bbox_min, Eigen::Vector2i(10, 10));
  EXPECT_EQ(blobs[0].bbox_max, Eigen::Vector2i(21, 23));
  // A mask off every object gives no blob; mismatched grids throw.
  Mask2D off = Mask2D::zeros(src.geometry());
  off.set(55, 5);
  EXPECT_TRUE(changedBlobs(off, objects).empty());
  GridGeometry other = src.geometry();
  other.width = 10;
  EXPECT_THROW(changedBlobs(Mask2D::zeros(other), objects), Error);
}

TEST(HeightCompare, BlobsTakeOnlyTheChangedSliverOfALargeComponent) {
  // A 50x30-cell component (a shelf with its back panel in a wall's band, 1500 cells) and a 6x6
  // box. With large_cells 1000, a change on 16 of the shelf's cells (1 %, below min_overlap 5 %)
  // keeps only those cells; the box, touched on 4 of its 36 cells, still grows whole.
  Config cfg;
  HeightMap src = render({{5, 5, 50, 30, 0.05f}, {40, 45, 6, 6, 0.08f}});
  const ObjectMap objects = computeObjectMap(src, cfg);
  ASSERT_EQ(objects.numObjects(), 2);
  const int shelf = objects.at(5, 5), box = objects.at(40, 45);
  Mask2D mask = Mask2D::zeros(src.geometry());
  const auto fill = [&](int x0, int y0, int w, int h) {
    for (int y = y0; y < y0 + h; ++y)
      for (int x = x0; x < x0 + w; ++x) mask.set(x, y);
  };
  fill(10, 10, 4, 4);  // a sliver of the shelf ...
  fill(45, 25, 4, 4);  // ... another one, away from the first
  fill(38, 43, 4, 4);  // 4 cells of the box, 12 off every object
  std::vector<Blob> blobs = changedBlobs(mask, objects, 0.05, 1000);
  ASSERT_EQ(blobs.size(), 3u);
  // Whole objects first, then the slivers by component (raster order of their first cell).
  EXPECT_FALSE(blobs[0].partial);
  EXPECT_EQ(blobs[0].area, 36);
  EXPECT_EQ(blobs[0].object_labels, std::vector<int>{box});
  EXPECT_TRUE(blobs[1].partial);
  EXPECT_EQ(blobs[1].area, 16);
  EXPECT_EQ(blobs[1].bbox_min, Eigen::Vector2i(10, 10));
  EXPECT_EQ(blobs[1].bbox_max, Eigen::Vector2i(13, 13));
  EXPECT_EQ(blobs[1].object_labels, std::vector<int>{shelf});
  EXPECT_TRUE(blobs[2].partial);
  EXPECT_EQ(blobs[2].area, 16);
  EXPECT_EQ(blobs[2].bbox_min, Eigen::Vector2i(45, 25));

  // Two slivers of 40 cells each (5.3 % together, 2.7 % each) stay slivers: the overlap is per
  // change cluster.
  Mask2D two = Mask2D::zeros(src.geometry());
  for (int y = 10; y < 15; ++y)
    for (int x = 10; x < 18; ++x) {
      two.set(x, y);
      two.set(x + 25, y + 10);
    }
  blobs = changedBlobs(two, objects, 0.05, 1000);
  ASSERT_EQ(blobs.size(), 2u);
  EXPECT_TRUE(blobs[0].partial && blobs[1].partial);
  EXPECT_EQ(blobs[0].area + blobs[1].area, 80);
  // A change cluster on 100 of its cells (6.7 %) grows into the whole shelf, and its slivers
  // join it; so does any change when
  // min_overlap is 0 (the brief's blobs) or the shelf is below large_cells.
  fill(20, 20, 10, 10);
  blobs = changedBlobs(mask, objects, 0.05, 1000);
  ASSERT_EQ(blobs.size(), 2u);
  EXPECT_EQ(blobs[0].area, 1500);
  EXPECT_FALSE(blobs[0].partial);
  Mask2D sliver = Mask2D::zeros(src.geometry());
  sliver.set(10, 10);
  for (const auto& [overlap, large] : {std::pair<double, int>{0.0, 1000}, {0.05, 1501}}) {
    blobs = changedBlobs(sliver, objects, overlap, large);
    ASSERT_EQ(blobs.size(), 1u);
    EXPECT_EQ(blobs[0].area, 1500);
  }
  blobs = changedBlobs(sliver, objects, 0.05, 1500);
  ASSERT_EQ(blobs.size(), 1u);
  EXPECT_EQ(blobs[0].area, 1);

  // The rule, and Config::blob_large_area in cells: 0.1 m2 of 7 mm cells is 2041 cells.
  EXPECT_TRUE(sliverOf(74, 1500, 0.05, 1000));
  EXPECT_FALSE(sliverOf(75, 1500, 0.05, 1000));
  EXPECT_FALSE(sliverOf(1, 999, 0.05, 1000));
  EXPECT_EQ(largeObjectCells(cfg, cfg.voxel_size), 2041);
}

TEST(HeightCompare, SplattedMapsKeepOnlyTheChangedSliverOfAnObjectOfAnySize) {
  // A static 14x14-cell box (196 cells, far below blob_large_area) whose rim the target places
  // 3 cells over: 3 columns of it change (42 cells, about a quarter after dilation).
  const Config cfg;
  const HeightMap src = render({{20, 20, 14, 14, 0.08f}});
  const HeightMap tgt = render({{23, 20, 14, 14, 0.08f}});
  const ObjectMap objects = computeObjectMap(src, cfg);
  ASSERT_EQ(objects.numObjects(), 1);
  const HeightChange fused = detectHeightChange(src, tgt, objects, Pose::Identity(), cfg);
  ASSERT_EQ(fused.blobs.size(), 1u);
  EXPECT_FALSE(fused.blobs[0].partial);
  EXPECT_EQ(fused.blobs[0].area, 196);
  HeightTolerance splatted;
  splatted.any_size_slivers = true;
  const HeightChange whole_cloud =
      detectHeightChange(src, tgt, objects, Pose::Identity(), cfg, nullptr, splatted);
  // The rim it lacks in front and the one it has behind: two slivers, less than half of it, of
  // an object smaller than blob_large_area, so one blob.
  ASSERT_EQ(whole_cloud.blobs.size(), 1u);
  EXPECT_TRUE(whole_cloud.blobs[0].partial);
  EXPECT_GE(whole_cloud.blobs[0].area, 42);
  EXPECT_LT(whole_cloud.blobs[0].area, 196 / 2);
  // A box moved by its width is a change of it whole, also in a whole cloud.
  const HeightMap moved = render({{34, 20, 14, 14, 0.08f}});
  const HeightChange far =
      detectHeightChange(src, moved, objects, Pose::Identity(), cfg, nullptr, splatted);
  ASSERT_EQ(far.blobs.size(), 1u);
  EXPECT_FALSE(far.blobs[0].partial);
  EXPECT_EQ(far.blobs[0].area, 196);
}

TEST(HeightCompare, TheSliversOfASmallObjectAreOneBlob) {
  // Two slivers of a 20x20-cell box (4x4 cells at opposite corners, 8 % of it together) and two of
  // a 50x30-cell shelf. Below join_below (1000 cells) the box's slivers are one blob; the shelf's
  // stay apart, and without join_below so do the box's.
  const HeightMap src = render({{5, 5, 50, 30, 0.05f}, {30, 40, 20, 20, 0.08f}});
  const Config cfg;
  const ObjectMap objects = computeObjectMap(src, cfg);
  ASSERT_EQ(objects.numObjects(), 2);
  const int box = objects.at(30, 40);
  Mask2D mask = Mask2D::zeros(src.geometry());
  for (const auto& [x0, y0] :
       std::vector<std::pair<int, int>>{{30, 40}, {46, 56}, {8, 8}, {48, 28}})
    for (int y = y0; y < y0 + 4; ++y)
      for (int x = x0; x < x0 + 4; ++x) mask.set(x, y);
  const std::vector<Blob> joined = changedBlobs(mask, objects, 0.5, 1, 1000);
  ASSERT_EQ(joined.size(), 3u);
  int box_blobs = 0;
  for (const Blob& b : joined) {
    EXPECT_TRUE(b.partial);
    if (b.object_labels == std::vector<int>{box}) {
      ++box_blobs;
      EXPECT_EQ(b.area, 32);
      EXPECT_EQ(b.bbox_min, Eigen::Vector2i(30, 40));
      EXPECT_EQ(b.bbox_max, Eigen::Vector2i(49, 59));
    } else {
      EXPECT_EQ(b.area, 16);
    }
  }
  EXPECT_EQ(box_blobs, 1);
  EXPECT_EQ(changedBlobs(mask, objects, 0.5, 1).size(), 4u);
}

TEST(HeightCompare, RefinementKeepsToTheConfiguredWindow) {
  // A 21 mm drift: found within the default 8 cm window; with a 14 mm window its best lies on
  // the border (the cost may still fall outward), so T stays.
  const std::vector<Box> scene{kObject, {8, 40, 6, 12, 0.05f}};
  const HeightMap src = render(scene);
  const HeightMap tgt = render(scene, yawShift(0.0, 3 * kCell, 3 * kCell));
  Config narrow;
  narrow.inplane_max_shift = 2 * kCell;
  Pose T_wide = Pose::Identity(), T_narrow = Pose::Identity();
  EXPECT_TRUE(refineInPlane(src, tgt, T_wide, Config{}).applied);
  const InPlaneRefinement r = refineInPlane(src, tgt, T_narrow, narrow);
  EXPECT_FALSE(r.applied);
  EXPECT_TRUE(T_narrow.isApprox(Pose::Identity()));
}

TEST(HeightCompare, InPlaneShiftIsRemovedByRefinement) {
  const Config cfg;
  const std::vector<Box> scene{kObject, {8, 40, 6, 12, 0.05f}};
  const HeightMap src = render(scene);
  for (int cells : {2, 3}) {  // 14 mm and 21 mm drift along u and v
    SCOPED_TRACE(cells);
    const double d = cells * kCell;
    const HeightMap tgt = render(scene, yawShift(0.0, d, d));
    Pose T = Pose::Identity();
    const Mask2D before = compareHeightMaps(src, tgt, T, cfg);
    // A ring of false change around both objects (2 cells: 68 cells in 1-cell-wide L shapes,
    // each below min_change_cells; 3 cells: 2-cell-wide L shapes that survive cleaning).
    EXPECT_GE(before.count(), 60u);
    if (cells == 3) {
      EXPECT_GT(cleanChangeMask(before, cfg).count(), 0u);
    }
    const InPlaneRefinement r = refineInPlane(src, tgt, T, cfg);
    EXPECT_TRUE(r.applied);
    EXPECT_EQ(r.mismatches_after, 0);
    EXPECT_LT(r.mismatches_after, r.mismatches_before);
    EXPECT_NEAR(r.du, d, kCell + 1e-9);
    EXPECT_NEAR(r.dv, d, kCell + 1e-9);
    EXPECT_NEAR(r.dyaw, 0.0, 1e-12);
    EXPECT_NEAR(T.translation().x(), d, kCell + 1e-9);
    const Mask2D after = compareHeightMaps(src, tgt, T, cfg);
    EXPECT_EQ(after.count(), 0u);
    EXPECT_EQ(cleanChangeMask(after, cfg).count(), 0u);
  }
}

TEST(HeightCompare, ADriftAmongLargeChangesIsFoundByTheCellsItFlips) {
  // A removed (900 cells) and an added box (576) mismatch wherever the map is put; three static
  // 8x8 boxes drifted by one cell along u and v mismatch in two 15-cell L shapes each (90 cells).
  // The drift removes 6 % of the mismatches, 2.3 sigma of their count, too little for the count
  // tests. It flips those 90 cells and the added box's two 47-cell L shapes, one each way: 6.6
  // sigma of the paired test that the session's drift uses. Without drift nothing is refined.
  const Config cfg;
  const std::vector<Box> statics{
      {6, 40, 8, 8, 0.05f}, {22, 44, 8, 8, 0.06f}, {44, 40, 8, 8, 0.07f}};
  std::vector<Box> src_scene = statics, tgt_scene = statics;
  src_scene.push_back({2, 2, 30, 30, 0.08f});
  tgt_scene.push_back({34, 2, 24, 24, 0.12f});
  const HeightMap src = render(src_scene);
  const HeightMap tgt = render(tgt_scene, yawShift(0.0, kCell, kCell));
  Pose T_count = Pose::Identity();
  const InPlaneRefinement counted = refineInPlane(src, tgt, T_count, cfg);
  EXPECT_FALSE(counted.applied);
  EXPECT_EQ(counted.fixed, 3 * 30 + 47);
  InPlaneSearch drift;
  drift.session_drift = true;
  Pose T = Pose::Identity();
  const InPlaneRefinement r = refineInPlane(src, tgt, T, cfg, drift);
  EXPECT_EQ(r.mismatches_before, 900 + 576 + 3 * 30);
  EXPECT_TRUE(r.applied);
  EXPECT_NEAR(r.du, kCell, 1e-9);
  EXPECT_NEAR(r.dv, kCell, 1e-9);
  EXPECT_EQ(r.fixed, 3 * 30 + 47);
  EXPECT_EQ(r.broken, 47);
  // The change is what it is without drift: the two boxes, no ring around the static ones.
  const HeightChange hc = detectHeightChange(src, tgt, computeObjectMap(src, cfg), T, cfg);
  const HeightChange no_drift =
      detectHeightChange(src, render(tgt_scene), computeObjectMap(src, cfg), Pose::Identity(), cfg);
  EXPECT_GE(no_drift.raw.count(), 900u + 500u);
  EXPECT_EQ(hc.raw.count(), no_drift.raw.count());

  Pose T0 = Pose::Identity();
  const InPlaneRefinement r0 = refineInPlane(src, render(tgt_scene), T0, cfg, drift);
  EXPECT_FALSE(r0.applied);
  EXPECT_TRUE(T0.isApprox(Pose::Identity()));
}

TEST(HeightCompare, ChangedObjectsDoNotHoldTheMapAgainstItsDrift) {
  // Two static 8x8 boxes drifted by one cell along u and v (60 cells fixed by the drift) beside
  // four 12x12 boxes added in the target. An added box mismatches wherever the map is put; a shift
  // moves 23 background cells onto it. Counted as background, those 4 x 23 cells would outweigh
  // the statics and keep the drift; as the added boxes' rings (in their groups, already over their
  // caps) they cost nothing, and the drift is found.
  const Config cfg;
  const std::vector<Box> statics{{6, 40, 8, 8, 0.05f}, {44, 44, 8, 8, 0.07f}};
  std::vector<Box> tgt_scene = statics;
  for (const auto& [x, y] : std::vector<std::pair<int, int>>{{4, 4}, {24, 4}, {44, 4}, {24, 24}})
    tgt_scene.push_back({x, y, 12, 12, 0.1f});
  const HeightMap src = render(statics);
  const HeightMap tgt = render(tgt_scene, yawShift(0.0, kCell, kCell));
  InPlaneSearch drift;
  drift.session_drift = true;
  Pose T = Pose::Identity();
  const InPlaneRefinement r = refineInPlane(src, tgt, T, cfg, drift);
  EXPECT_EQ(r.mismatches_before, 4 * 144 + 2 * 30);
  EXPECT_TRUE(r.applied);
  EXPECT_NEAR(r.du, kCell, 1e-9);
  EXPECT_NEAR(r.dv, kCell, 1e-9);
  EXPECT_EQ(r.fixed - r.broken, 2 * 30);
}

TEST(HeightCompare, YawOfTwoDegreesIsRemovedByRefinement) {
  const Config cfg;
  const std::vector<Box> scene{
      {40, 42, 10, 10, 0.08f}, {44, 8, 8, 14, 0.06f}, {6, 44, 12, 6, 0.1f}};
  const HeightMap src = render(scene);
  const HeightMap tgt = render(scene, yawShift(2.0 * kDeg, 0.0, 0.0));
  Pose T = Pose::Identity();
  const HeightChange before = detectHeightChange(src, tgt, computeObjectMap(src, cfg), T, cfg);
  EXPECT_GE(before.raw.count(), 90u);
  EXPECT_GT(before.cleaned.count(), 0u);  // survives cleaning: a false blob
  EXPECT_FALSE(before.blobs.empty());
  const InPlaneRefinement r = refineInPlane(src, tgt, T, cfg);
  EXPECT_TRUE(r.applied);
  EXPECT_NEAR(r.dyaw, 2.0 * kDeg, 0.5 * kDeg + 1e-9);
  const HeightChange after = detectHeightChange(src, tgt, computeObjectMap(src, cfg), T, cfg);
  EXPECT_EQ(after.raw.count(), 0u);
  EXPECT_TRUE(after.blobs.empty());
}

TEST(HeightCompare, RefinementWithGivenObjectMapsMatchesAndChecksThem) {
  // The detection passes the object maps it has; the result is the same transform and figures.
  const Config cfg;
  const std::vector<Box> scene{kObject, {8, 40, 6, 12, 0.05f}, {40, 42, 10, 10, 0.08f}};
  const HeightMap src = render(scene);
  const HeightMap tgt = render(scene, yawShift(1.0 * kDeg, 2 * kCell, -kCell));
  Pose T1 = Pose::Identity(), T2 = Pose::Identity();
  const InPlaneRefinement a = refineInPlane(src, tgt, T1, cfg);
  const InPlaneRefinement b =
      refineInPlane(src, computeObjectMap(src, cfg), tgt, computeObjectMap(tgt, cfg), T2, cfg);
  EXPECT_TRUE(a.applied);
  EXPECT_EQ(a.applied, b.applied);
  EXPECT_EQ(a.mismatches_after, b.mismatches_after);
  EXPECT_EQ(a.compared_after, b.compared_after);
  EXPECT_EQ(a.du, b.du);
  EXPECT_EQ(a.dv, b.dv);
  EXPECT_EQ(a.dyaw, b.dyaw);
  EXPECT_TRUE(T1.isApprox(T2, 0.0));
  // Object maps of another grid are an error, not a wrong answer.
  HeightMap small = src;
  small.width -= 8;
  small.heights.resize(small.numCells());
  Pose T3 = Pose::Identity();
  EXPECT_THROW(
      refineInPlane(src, computeObjectMap(small, cfg), tgt, computeObjectMap(tgt, cfg), T3, cfg),
      Error);
}

TEST(HeightCompare, RefinementScoresWholeCellShiftsLikeAnyOtherShift) {
  // Shifts of whole cells are scored by offsetting each yaw's placement of the samples; a step
  // that is no whole number of cells places the samples per candidate. Both find the same drift
  // (2 degrees, 2 cells along u, -1 along v) with the same figures.
  const std::vector<Box> scene{
      {40, 42, 10, 10, 0.08f}, {44, 8, 8, 14, 0.06f}, {6, 44, 12, 6, 0.1f}};
  const HeightMap src = render(scene);
  const HeightMap tgt = render(scene, yawShift(2.0 * kDeg, 2 * kCell, -kCell));
  Config whole, general;
  whole.inplane_shift_step = kCell;
  general.inplane_shift_step = kCell * (1.0 + 1e-4);  // 0.7 um more: the same cells, general path
  Pose T1 = Pose::Identity(), T2 = Pose::Identity();
  const InPlaneRefinement a = refineInPlane(src, tgt, T1, whole);
  const InPlaneRefinement b = refineInPlane(src, tgt, T2, general);
  ASSERT_TRUE(a.applied);
  EXPECT_TRUE(b.applied);
  EXPECT_EQ(a.mismatches_before, b.mismatches_before);
  EXPECT_EQ(a.mismatches_after, b.mismatches_after);
  EXPECT_EQ(a.compared_after, b.compared_after);
  // The yaw is about the samples' centre, so the shift differs from the render's.
  EXPECT_NEAR(a.dyaw, 2.0 * kDeg, 0.5 * kDeg + 1e-9);
  EXPECT_LE(a.mismatches_after * 5, a.mismatches_before);
  EXPECT_NEAR(a.du, b.du, 1e-5);
  EXPECT_NEAR(a.dv, b.dv, 1e-5);
  EXPECT_EQ(a.dyaw, b.dyaw);
  EXPECT_TRUE(T1.isApprox(T2, 1e-4));
}

TEST(HeightCompare, RefinementScoresTheSameWithAndWithoutSimd) {
  // The AVX2 scoring (8 samples at a time, its slack row by row) against the scalar code, on
  // maps with what takes each lane's other paths: noise (many differing background samples),
  // objects (capped groups), holes (unobserved cells, flagged mismatches moved onto them), a
  // moved object and drift. The same transform and counts; the mean |diff| sums in another
  // order.
  Config cfg;
  std::vector<Box> scene{{40, 42, 10, 10, 0.08f}, {44, 8, 8, 14, 0.06f}, {6, 44, 12, 6, 0.1f}};
  HeightMap src = render(scene);
  scene.push_back({20, 20, 8, 8, 0.07f});  // added in the target
  scene[2].x0 += 3;                        // moved by 3 cells
  HeightMap tgt = render(scene, yawShift(1.5 * kDeg, 2 * kCell, -kCell));
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.006f);
  for (HeightMap* hm : {&src, &tgt})
    for (std::size_t c = 0; c < hm->heights.size(); ++c) {
      if (c % 23 == 0) {
        hm->heights[c] = kUnobserved;
        continue;
      }
      hm->heights[c] = std::max(0.0f, hm->heights[c] + noise(rng));
    }
  InPlaneRefinement r[2];
  Pose T[2] = {Pose::Identity(), Pose::Identity()};
  for (int simd = 0; simd < 2; ++simd) {
    cfg.simd = simd == 1;
    r[simd] = refineInPlane(src, tgt, T[simd], cfg);
  }
  EXPECT_TRUE(r[0].applied);               // the drift is found through the noise
  EXPECT_GT(r[0].mismatches_before, 150);  // the noise: many differing samples
  EXPECT_EQ(r[0].applied, r[1].applied);
  EXPECT_EQ(r[0].mismatches_before, r[1].mismatches_before);
  EXPECT_EQ(r[0].mismatches_after, r[1].mismatches_after);
  EXPECT_EQ(r[0].compared_before, r[1].compared_before);
  EXPECT_EQ(r[0].compared_after, r[1].compared_after);
  EXPECT_EQ(r[0].du, r[1].du);
  EXPECT_EQ(r[0].dv, r[1].dv);
  EXPECT_EQ(r[0].dyaw, r[1].dyaw);
  EXPECT_NEAR(r[0].mean_abs_before, r[1].mean_abs_before, 1e-12);
  EXPECT_NEAR(r[0].mean_abs_after, r[1].mean_abs_after, 1e-12);
  EXPECT_TRUE(T[0].isApprox(T[1], 0.0));
}

TEST(HeightCompare, ShiftAndYawTogetherButRealRemovalStays) {
  const Config cfg;
  const std::vector<Box> statics{
      {40, 42, 10, 10, 0.08f}, {44, 8, 8, 14, 0.06f}, {6, 44, 12, 6, 0.1f}};
  std::vector<Box> src_scene = statics;
  src_scene.push_back({12, 12, 10, 10, 0.08f});  // removed in the target
  const HeightMap src = render(src_scene);
  const HeightMap tgt = render(statics, yawShift(-2.0 * kDeg, 0.02, -0.015));
  Pose T = Pose::Identity();
  refineInPlane(src, tgt, T, cfg);
  const HeightChange hc = detectHeightChange(src, tgt, computeObjectMap(src, cfg), T, cfg);
  ASSERT_EQ(hc.blobs.size(), 1u);
  EXPECT_EQ(hc.blobs[0].area, 100);
  EXPECT_EQ(hc.blobs[0].bbox_min, Eigen::Vector2i(12, 12));
  EXPECT_EQ(hc.filtered.count(), hc.raw.count());
  EXPECT_EQ(hc.raw.count(), 100u);  // exactly the removed object, no false ring
}

TEST(HeightCompare, AnObjectMovedBeyondTheSearchWindowDoesNotDragTheMap) {
  // One box moved 17 cells (11.9 cm) along u, beyond the 8 cm window: shifting the map by the
  // window's largest step (11 cells) would halve the mismatches, but the cost still falls at the
  // border; that is a moved object, not drift.
  const Config cfg;
  const HeightMap src = render({{10, 25, 10, 10, 0.08f}});
  const HeightMap tgt = render({{27, 25, 10, 10, 0.08f}});
  Pose T = Pose::Identity();
  const InPlaneRefinement r = refineInPlane(src, tgt, T, cfg);
  EXPECT_FALSE(r.applied);
  EXPECT_EQ(r.mismatches_before, 200);
  EXPECT_TRUE(T.isApprox(Pose::Identity()));
  // The same move within the window (5 cells) with a static box beside it: the refinement does
  // not trade the static box for the moved one either (equal areas: no gain).
  const HeightMap src2 = render({{10, 25, 10, 10, 0.08f}, {40, 40, 10, 10, 0.08f}});
  const HeightMap tgt2 = render({{15, 25, 10, 10, 0.08f}, {40, 40, 10, 10, 0.08f}});
  Pose T2 = Pose::Identity();
  EXPECT_FALSE(refineInPlane(src2, tgt2, T2, cfg).applied);
  EXPECT_TRUE(T2.isApprox(Pose::Identity()));
}

TEST(HeightCompare, RefinementKeepsAlignedMapsAndHandlesEmpty) {
  const Config cfg;
  const HeightMap hm = render({kObject});
  Pose T = Pose::Identity();
  const InPlaneRefinement r = refineInPlane(hm, hm, T, cfg);
  EXPECT_FALSE(r.applied);
  EXPECT_EQ(r.mismatches_before, 0);
  EXPECT_TRUE(T.isApprox(Pose::Identity()));
  // Flat maps carry no in-plane information: nothing moves.
  const HeightMap flat = render({});
  EXPECT_FALSE(refineInPlane(flat, flat, T, cfg).applied);
  EXPECT_FALSE(refineInPlane(HeightMap{}, hm, T, cfg).applied);
  EXPECT_TRUE(T.isApprox(Pose::Identity()));
}

TEST(HeightCompare, InvalidConfigThrows) {
  Config cfg;
  const HeightMap hm = render({});
  cfg.delta_h = 0.0;
  EXPECT_THROW(compareHeightMaps(hm, hm, Pose::Identity(), cfg), Error);
  cfg = Config{};
  cfg.min_change_cells = -1;
  EXPECT_THROW(cleanChangeMask(Mask2D::zeros(hm.geometry()), cfg), Error);
  HeightMap bad = hm;
  bad.heights.pop_back();
  EXPECT_THROW(compareHeightMaps(bad, hm, Pose::Identity(), Config{}), Error);
}

TEST(HeightCompare, CleaningDropsSmallComponentsThenDilates) {
  Config cfg;
  Mask2D m = Mask2D::zeros(grid());
  for (int x = 5; x < 24; ++x) m.set(x, 5);   // 19 cells: dropped
  for (int x = 5; x < 25; ++x) m.set(x, 30);  // 20 cells: kept
  const Mask2D c = cleanChangeMask(m, cfg);
  EXPECT_EQ(c.count(), 22u * 3u);
  EXPECT_FALSE(c.at(10, 5));
  cfg.dilation_cells = 0;
  EXPECT_EQ(cleanChangeMask(m, cfg).count(), 20u);
}

}  // namespace
}  // namespace planesdf
