// detectChanges and ChangeDetector against analytic tabletop scenes rendered here: a table with
// objects seen from rings of depth frames, one session before and one after a change.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <sstream>
#include <thread>

#include "analytic_scene.hpp"
#include "change/change_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/events.hpp"
#include "planesdf/io/ply.hpp"
#include "test_support.hpp"

namespace {
using namespace planesdf;
using test::AnalyticScene;
using test::Primitive;

constexpr double kTable = test::kTableTop;

// Objects on the table (z = 0.75): a 10 x 6 x 8 cm box, a cylinder r 4 cm h 12 cm, a sphere
// r 5 cm, and the cylinder moved by 20 cm.
Primitive box() {
  return Primitive::box({0.05, 0.02, kTable}, {0.15, 0.08, kTable + 0.08});
}
Primitive cylinderAt(double x, double y) {
  return Primitive::cylinder({x, y, kTable}, 0.04, 0.12);
}
Primitive sphere() {
  return Primitive::sphere({-0.12, 0.15, kTable + 0.05}, 0.05);
}

/// A session: `n` views on a ring around the table, poses displaced by `drift` (applied to the
/// reported poses, as a localisation error between sessions).
Map session(const AnalyticScene& scene, int n = 8, const Pose& drift = Pose::Identity()) {
  Map m{Config{}};
  const Intrinsics k;
  for (const Pose& T : test::ringPoses({0, 0, kTable}, 0.9, 0.55, n))
    m.integrate(test::renderDepth(scene, k, T), drift * T);
  return m;
}

const ChangeEvent* findType(const ChangeSet& s, ChangeType t) {
  for (const auto& e : s.events)
    if (e.type == t) return &e;
  return nullptr;
}

/// Largest distance (m) of a region's points to the surface of `p`.
double maxSurfaceDistance(const ChangeRegion& r, const Primitive& p) {
  double worst = 0.0;
  for (const auto& q : r.points) worst = std::max(worst, std::abs(p.sdf(q.cast<double>())));
  return worst;
}

const Map& beforeMap() {
  static const Map m = session(test::tableWith({box(), cylinderAt(-0.15, -0.10)}));
  return m;
}
// After: the box is gone, a sphere is new, the cylinder moved 20 cm along +x.
const AnalyticScene& afterScene() {
  static const AnalyticScene s = test::tableWith({sphere(), cylinderAt(0.05, -0.10)});
  return s;
}
const Map& afterMap() {
  static const Map m = session(afterScene());
  return m;
}

TEST(DetectChanges, ASceneAgainstItselfHasNoChange) {
  const ChangeSet s = detectChanges(beforeMap(), beforeMap(), Config{});
  EXPECT_TRUE(s.events.empty()) << s.events.size() << " events";
}

TEST(DetectChanges, ASecondSessionWithLocalisationDriftHasNoChange) {
  // 2 cm and 1.5 degrees of drift of the whole session (poses reported in a displaced frame).
  Pose drift = Pose::Identity();
  drift.linear() = Eigen::AngleAxisd(1.5 * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  drift.translation() = Eigen::Vector3d(0.02, -0.01, 0.0);
  const Map drifted = session(test::tableWith({box(), cylinderAt(-0.15, -0.10)}), 8, drift);
  const ChangeSet s = detectChanges(beforeMap(), drifted, Config{});
  EXPECT_TRUE(s.events.empty()) << s.events.size() << " events, first: "
                                << (s.events.empty() ? "" : toString(s.events[0].type));
}

TEST(DetectChanges, RemovedAddedAndMovedObjectsAreTypedAndLocated) {
  DetectOptions opt;
  opt.keep_stages = true;
  const ChangeSet s = detectChanges(beforeMap(), afterMap(), Config{}, opt);
  ASSERT_EQ(s.events.size(), 3u) << changesToJson(s.events);

  const ChangeEvent* removed = findType(s, ChangeType::Removed);
  ASSERT_NE(removed, nullptr);
  // Centroid of the box's voxels: within 2 cm of its centre in the plane (the voxels span the
  // box's height range, so only u, v are compared).
  EXPECT_LT((removed->reference.centroid.head<2>() - Eigen::Vector2d(0.10, 0.05)).norm(), 0.02);
  EXPECT_GT(removed->reference.points.size(), 100u);
  // Every reported point lies on the box (one voxel of tolerance: points are kept on a 3.5 mm
  // grid).
  EXPECT_LT(maxSurfaceDistance(removed->reference, box()), 0.007);

  const ChangeEvent* added = findType(s, ChangeType::Added);
  ASSERT_NE(added, nullptr);
  EXPECT_LT((added->current.centroid.head<2>() - Eigen::Vector2d(-0.12, 0.15)).norm(), 0.02);
  EXPECT_LT(maxSurfaceDistance(added->current, sphere()), 0.007);

  const ChangeEvent* moved = findType(s, ChangeType::Moved);
  ASSERT_NE(moved, nullptr);
  EXPECT_LT((moved->reference.centroid.head<2>() - Eigen::Vector2d(-0.15, -0.10)).norm(), 0.02);
  EXPECT_LT((moved->current.centroid.head<2>() - Eigen::Vector2d(0.05, -0.10)).norm(), 0.02);
  EXPECT_LT(maxSurfaceDistance(moved->current, cylinderAt(0.05, -0.10)), 0.007);
  EXPECT_LT(maxSurfaceDistance(moved->reference, cylinderAt(-0.15, -0.10)), 0.007);
  for (const auto& e : s.events) {
    EXPECT_GE(e.confidence, 0.5);
    EXPECT_LE(e.confidence, 1.0);
  }
  // Ids are 1..N.
  for (std::size_t i = 0; i < s.events.size(); ++i) EXPECT_EQ(s.events[i].id, int(i) + 1);
  // The phase times: disjoint parts of the call, the maps and both directions' pairs take time.
  EXPECT_GT(s.maps_ms, 0.0);
  EXPECT_GE(s.correction_ms, 0.0);
  EXPECT_GT(s.forward_ms, 0.0);
  EXPECT_GT(s.backward_ms, 0.0);
  EXPECT_LE(s.maps_ms + s.correction_ms + s.forward_ms + s.backward_ms, s.milliseconds);
}

TEST(DetectChanges, SameResultOnOneAndTwoThreads) {
  // Plane maps, the session correction and the pairs of each direction run in parallel; the
  // result is merged in pair order, so it equals the single-threaded one exactly.
  Config one, two;
  one.threads = 1;
  two.threads = 2;
  const ChangeSet a = detectChanges(beforeMap(), afterMap(), one);
  const ChangeSet b = detectChanges(beforeMap(), afterMap(), two);
  ASSERT_EQ(a.events.size(), 3u);
  EXPECT_EQ(changesToJson(a.events), changesToJson(b.events));
  ASSERT_EQ(a.pairs.size(), b.pairs.size());
  for (std::size_t i = 0; i < a.pairs.size(); ++i) {
    EXPECT_EQ(a.pairs[i].reference_to_current, b.pairs[i].reference_to_current);
    EXPECT_EQ(a.pairs[i].match.source_id, b.pairs[i].match.source_id);
    EXPECT_TRUE(a.pairs[i].match.T_target_source_local.isApprox(
        b.pairs[i].match.T_target_source_local, 1e-15));
  }
}

TEST(DetectChanges, OutputsFollowTheDesignContract) {
  DetectOptions opt;
  opt.keep_stages = true;
  const ChangeSet s = detectChanges(beforeMap(), afterMap(), Config{}, opt);
  test::TempDir dir;
  writeChangeOutputs(dir.path(), s);
  std::ifstream in(dir.path() + "/changes.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  ASSERT_TRUE(j.is_array());
  ASSERT_EQ(j.size(), s.events.size());
  for (const auto& e : j) {
    for (const char* k : {"id", "type", "plane_id", "bbox_min", "bbox_max", "centroid",
                          "num_voxels", "num_points", "confidence"})
      EXPECT_TRUE(e.contains(k)) << k;
    const auto mn = e["bbox_min"].get<std::vector<double>>();
    const auto mx = e["bbox_max"].get<std::vector<double>>();
    for (int a = 0; a < 3; ++a) EXPECT_LE(mn[a], mx[a]);
  }
  const PointCloud removed = io::readPly(dir.path() + "/removed_points.ply");
  const PointCloud added = io::readPly(dir.path() + "/added_points.ply");
  ASSERT_NE(removed.field("change_id"), nullptr);
  ASSERT_NE(added.field("change_id"), nullptr);
  std::size_t n_removed = 0, n_added = 0;
  for (const auto& e : s.events) {
    n_removed += e.reference.points.size();
    n_added += e.current.points.size();
  }
  EXPECT_EQ(removed.size(), n_removed);
  EXPECT_EQ(added.size(), n_added);
  // One picture per stage and plane pair and direction.
  EXPECT_TRUE(std::filesystem::exists(dir.path() + "/planes"));
  std::size_t pngs = 0;
  for (const auto& f : std::filesystem::directory_iterator(dir.path() + "/planes"))
    pngs += f.path().extension() == ".png";
  EXPECT_EQ(pngs, s.pairs.size() * 10);
}

TEST(DetectChanges, OutputsReplaceTheFolderWholeAndRefuseForeignFiles) {
  // A second run into the same folder leaves only its own outputs: no picture of the first.
  DetectOptions opt;
  opt.keep_stages = true;
  const ChangeSet staged = detectChanges(beforeMap(), afterMap(), Config{}, opt);
  const ChangeSet plain = detectChanges(afterMap(), beforeMap(), Config{});
  test::TempDir tmp;
  const std::string out = tmp.file("out");
  writeChangeOutputs(out, staged);
  ASSERT_TRUE(std::filesystem::exists(out + "/planes"));
  writeChangeOutputs(out, plain);
  EXPECT_FALSE(std::filesystem::exists(out + "/planes"));
  std::ifstream in(out + "/changes.json");
  EXPECT_EQ(nlohmann::json::parse(in).dump(2), changesToJson(plain.events));
  std::size_t siblings = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator(tmp.path())) ++siblings;
  EXPECT_EQ(siblings, 1u);
  // A folder with anything else in it is not replaced.
  test::writeBytes(out + "/notes.txt", "mine");
  try {
    writeChangeOutputs(out, staged);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), out);
  }
  EXPECT_TRUE(std::filesystem::exists(out + "/notes.txt"));
  EXPECT_FALSE(std::filesystem::exists(out + "/planes"));
}

TEST(DetectChanges, OutputsReadBackIntoTheirEvents) {
  const ChangeSet s = detectChanges(beforeMap(), afterMap(), Config{});
  ASSERT_GE(s.events.size(), 2u);
  test::TempDir dir;
  writeChangeOutputs(dir.path(), s);
  const std::vector<ChangeEvent> back = readChangeOutputs(dir.path());
  ASSERT_EQ(back.size(), s.events.size());
  for (std::size_t k = 0; k < back.size(); ++k) {
    const ChangeEvent& a = s.events[k];
    const ChangeEvent& b = back[k];
    EXPECT_EQ(b.id, a.id);
    EXPECT_EQ(b.type, a.type);
    EXPECT_EQ(b.status, a.status);
    EXPECT_DOUBLE_EQ(b.confidence, a.confidence);
    for (const auto side : {&ChangeEvent::reference, &ChangeEvent::current}) {
      const ChangeRegion& ra = a.*side;
      const ChangeRegion& rb = b.*side;
      ASSERT_EQ(rb.plane_id, ra.plane_id);
      EXPECT_EQ(rb.points, ra.points);  // PLY floats, written and read as float32
      EXPECT_TRUE(rb.centroid.isApprox(ra.centroid, 1e-12) || ra.centroid.isZero());
      EXPECT_EQ(rb.bbox.isEmpty(), ra.bbox.isEmpty());
      if (!ra.bbox.isEmpty()) {
        EXPECT_TRUE(rb.bbox.min().isApprox(ra.bbox.min(), 1e-12));
      }
      EXPECT_EQ(rb.key_voxels, ra.key_voxels);
      EXPECT_EQ(rb.scored, ra.scored);
      EXPECT_EQ(rb.verdict, ra.verdict);
      EXPECT_TRUE(rb.columns.empty());  // not in the files
    }
  }
  // Points of a change changes.json does not hold: an error naming the PLY.
  test::writeBytes(dir.path() + "/changes.json", "[]");
  try {
    readChangeOutputs(dir.path());
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), dir.path() + "/removed_points.ply");
  }
}

TEST(DetectChanges, ChangesJsonItCouldNotHaveWrittenIsAnErrorNamingTheEventAndField) {
  const auto errorOf = [](const std::string& text) {
    try {
      changesFromJson(text, "x/changes.json");
    } catch (const Error& e) {
      EXPECT_EQ(e.path(), "x/changes.json");
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string side =
      R"({"plane_id": 2, "bbox_min": [0, 0, 0], "bbox_max": [1, 1, 1], "centroid": [0.5, 0.5, )"
      R"(0.5], "num_voxels": 3, "num_points": 4, "key_voxels": 2, "scored": 1, )"
      R"("mean_similarity": 0.4, "verdict": "changed"})";
  const auto event = [&](const std::string& fields, const std::string& sides) {
    return "[{" + fields + sides + "}]";
  };
  const std::string ok_fields = R"("id": 1, "type": "removed", "status": "new", "confidence": 0.8)";
  const std::vector<ChangeEvent> ok =
      changesFromJson(event(ok_fields, R"(, "reference": )" + side), "x");
  ASSERT_EQ(ok.size(), 1u);
  EXPECT_EQ(ok[0].type, ChangeType::Removed);
  EXPECT_EQ(ok[0].reference.plane_id, 2);
  EXPECT_EQ(ok[0].reference.verdict, BlobValidation::Verdict::Changed);
  EXPECT_NE(errorOf("{}").find("is not a JSON array"), std::string::npos);
  EXPECT_NE(errorOf("[1]").find("event 1: is not an object"), std::string::npos);
  EXPECT_NE(errorOf(event(R"("id": 1, "type": "gone", "status": "new", "confidence": 0.8)",
                          R"(, "reference": )" + side))
                .find("event 1: type must be one of added, removed, moved, replaced"),
            std::string::npos);
  EXPECT_NE(errorOf(event(ok_fields, "")).find("a removed change needs only a reference side"),
            std::string::npos);
  std::string twice = event(ok_fields, R"(, "reference": )" + side);
  twice = "[" + twice.substr(1, twice.size() - 2) + ", " + twice.substr(1, twice.size() - 2) + "]";
  EXPECT_NE(errorOf(twice).find("event 2: id 1 appears twice"), std::string::npos);
  std::string bad_box = side;
  bad_box.replace(bad_box.find("[1, 1, 1]"), 9, "[-1, 1, 1]");
  EXPECT_NE(errorOf(event(ok_fields, R"(, "reference": )" + bad_box))
                .find("event 1: reference bbox_min lies above bbox_max"),
            std::string::npos);
}

TEST(DetectChanges, DifferentVoxelSizesAreAnError) {
  Config c;
  c.voxel_size = 0.01;
  const Map other(c);
  EXPECT_THROW(detectChanges(beforeMap(), other, Config{}), Error);
}

TEST(ShapeDistance, SameObjectIsCloseAndDifferentObjectsAreFar) {
  ShapeSignature a;
  a.cells = 100;
  a.area = 0.0049;
  a.max_height = 0.12;
  a.volume = 0.0005;
  a.major = 0.02;
  a.minor = 0.02;
  a.deciles.assign(10, 0.12);
  ShapeSignature b = a;
  b.area *= 1.1;
  b.volume *= 1.1;
  EXPECT_LT(shapeDistance(a, b), Config{}.moved_shape_distance);
  ShapeSignature c = a;
  c.max_height = 0.05;
  c.deciles.assign(10, 0.05);
  EXPECT_GT(shapeDistance(a, c), Config{}.moved_shape_distance);
  EXPECT_TRUE(std::isinf(shapeDistance(a, ShapeSignature{})));
}

// ---- sameInPlace, on hand-made floor height maps (7 mm cells): a 9 x 9 cell table leg cut at
// the top of the band (0.30 m), as two sessions see it --------------------------------------------

constexpr int kGrid = 60;
constexpr double kCell = 0.007;
constexpr float kLegTop = 0.30f;
const Pose kId = Pose::Identity();

HeightMap floorMap() {
  HeightMap hm;
  hm.width = hm.height = kGrid;
  hm.cell_size = kCell;
  hm.heights.assign(hm.numCells(), 0.0f);
  return hm;
}
/// Cells [x0, x0 + w) x [y0, y0 + h) set to `height`.
void fill(HeightMap& hm, int x0, int y0, int w, int h, float height) {
  for (int y = y0; y < y0 + h; ++y)
    for (int x = x0; x < x0 + w; ++x) hm.at(x, y) = height;
}
/// The object cells of `hm` (heights above h_obj).
std::vector<Eigen::Vector2i> objectCells(const HeightMap& hm) {
  std::vector<Eigen::Vector2i> out;
  for (int y = 0; y < hm.height; ++y)
    for (int x = 0; x < hm.width; ++x)
      if (hm.at(x, y) > Config{}.h_obj) out.emplace_back(x, y);
  return out;
}
/// The leg at cells [25, 34)^2 with, on its +x side, a 2-cell streak of mixed pixels between its
/// edge and the floor (heights 0.26 and 0.24 m over 6 rows): the outline one orbit sees.
HeightMap legWithStreak() {
  HeightMap hm = floorMap();
  fill(hm, 25, 25, 9, 9, kLegTop);
  fill(hm, 34, 27, 1, 6, 0.26f);
  fill(hm, 35, 27, 1, 6, 0.24f);
  return hm;
}

TEST(SameInPlace, ALegWhoseOutlineDiffersIsTheSameObject) {
  const Config cfg;
  HeightMap other = floorMap();
  fill(other, 25, 25, 9, 9, kLegTop);  // the other orbit: the leg's outline only
  const HeightMap src = legWithStreak();
  const InPlaceMatch m =
      sameInPlace(src, objectCells(src), other, computeObjectMap(other, cfg), kId, cfg);
  EXPECT_EQ(m.target_cells, 81);
  EXPECT_NEAR(m.overlap, 81.0 / 93.0, 1e-9);  // the 12 streak cells land on the floor
  EXPECT_LT(m.shift, 0.006);                  // < 1 cell: the streak pulls the centroid
  EXPECT_LT(m.shift, Config{}.in_place_shift_fraction * m.size);
  EXPECT_LT(m.shape_distance, Config{}.moved_shape_distance);
  EXPECT_TRUE(m.same(cfg));
  // And the other way round (the leg without its streak against the streaked one).
  const InPlaceMatch r =
      sameInPlace(other, objectCells(other), src, computeObjectMap(src, cfg), kId, cfg);
  EXPECT_EQ(r.target_cells, 93);
  EXPECT_TRUE(r.same(cfg));
}

TEST(SameInPlace, AMovedReplacedOrNewObjectIsNot) {
  const Config cfg;
  const HeightMap src = legWithStreak();
  const std::vector<Eigen::Vector2i> cells = objectCells(src);
  // Moved 4.2 cm (6 cells) along x: footprints still overlap, the centroid shift gives it away.
  HeightMap moved = floorMap();
  fill(moved, 31, 25, 9, 9, kLegTop);
  const InPlaceMatch mv = sameInPlace(src, cells, moved, computeObjectMap(moved, cfg), kId, cfg);
  EXPECT_GT(mv.shift, 0.03);
  EXPECT_FALSE(mv.same(cfg));
  // The same registration error carried by T instead: in place again.
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(6 * kCell, 0.0, 0.0);
  EXPECT_TRUE(sameInPlace(src, cells, moved, computeObjectMap(moved, cfg), T, cfg).same(cfg));
  // Replaced in place by a lower object (12 cm) of the same footprint: the shape differs.
  HeightMap lower = floorMap();
  fill(lower, 25, 25, 9, 9, 0.12f);
  const InPlaceMatch lo = sameInPlace(src, cells, lower, computeObjectMap(lower, cfg), kId, cfg);
  EXPECT_GT(lo.overlap, 0.5);
  EXPECT_GT(lo.shape_distance, Config{}.moved_shape_distance);
  EXPECT_FALSE(lo.same(cfg));
  // Replaced by a much larger object (the leg stood on its footprint): overlap and shape differ.
  HeightMap large = floorMap();
  fill(large, 15, 15, 30, 30, kLegTop);
  const InPlaceMatch lg = sameInPlace(src, cells, large, computeObjectMap(large, cfg), kId, cfg);
  EXPECT_LT(lg.overlap, 0.5);
  EXPECT_FALSE(lg.same(cfg));
  // Free floor in the other map (a new object): no target object at all.
  const HeightMap empty = floorMap();
  const InPlaceMatch no = sameInPlace(src, cells, empty, computeObjectMap(empty, cfg), kId, cfg);
  EXPECT_EQ(no.target_cells, 0);
  EXPECT_FALSE(no.same(cfg));
}

TEST(SameInPlace, AnObjectJoinedToAPanelIsComparedWithItsPartAboveThePanel) {
  // A wall's band: a back panel 1.5 cm in front of the wall (55 x 50 cells, 0.135 m², larger
  // than blob_large_area) with a 20 cm object standing in it, one object in the target map; the
  // source sees the object alone.
  const Config cfg;
  constexpr float kPanel = 0.015f;
  constexpr float kObject = 0.20f;
  HeightMap src = floorMap();
  fill(src, 25, 25, 9, 9, kObject);
  HeightMap panel = floorMap();
  fill(panel, 2, 5, 55, 50, kPanel);
  HeightMap joined = panel;
  fill(joined, 25, 25, 9, 9, kObject);
  const ObjectMap joined_objects = computeObjectMap(joined, cfg);
  ASSERT_EQ(joined_objects.numObjects(), 1);
  ASSERT_GE(joined_objects.object(1).area, largeObjectCells(cfg, kCell));
  const std::vector<Eigen::Vector2i> cells = objectCells(src);
  const InPlaceMatch m = sameInPlace(src, cells, joined, joined_objects, kId, cfg);
  EXPECT_EQ(m.target_cells, 81);  // the object's part above the panel, not the 2,750 cells
  EXPECT_NEAR(m.overlap, 1.0, 1e-9);
  EXPECT_TRUE(m.same(cfg));
  // The object gone, the panel left: it lands on structure only, compared with the whole panel.
  const InPlaceMatch gone = sameInPlace(src, cells, panel, computeObjectMap(panel, cfg), kId, cfg);
  EXPECT_EQ(gone.target_cells, 55 * 50);
  EXPECT_FALSE(gone.same(cfg));
  // A lower object (12 cm) in its place on the panel: its part differs in shape.
  HeightMap lower = panel;
  fill(lower, 25, 25, 9, 9, 0.12f);
  const InPlaceMatch lo = sameInPlace(src, cells, lower, computeObjectMap(lower, cfg), kId, cfg);
  EXPECT_EQ(lo.target_cells, 81);
  EXPECT_FALSE(lo.same(cfg));
}

/// A table on four 5 x 5 cm legs, seen by the views of a 16-view ring around it on the +x side
/// (`plus_x`) or on the -x side.
Map legsSession(bool plus_x, const Pose& drift = Pose::Identity()) {
  std::vector<Primitive> legs;
  for (const double x : {-0.55, 0.55})
    for (const double y : {-0.35, 0.35})
      legs.push_back(Primitive::box({x - 0.025, y - 0.025, 0.0}, {x + 0.025, y + 0.025, kTable}));
  const AnalyticScene scene = test::tableWith(legs);
  Map m{Config{}};
  const Intrinsics k;
  for (const Pose& T : test::ringPoses({0, 0, 0.1}, 1.7, 0.6, 16))
    if ((T.translation().x() > 0.1) == plus_x && std::abs(T.translation().x()) > 0.1)
      m.integrate(test::renderDepth(scene, k, T), drift * T);
  return m;
}

TEST(DetectChanges, TableLegsSeenFromOppositeSidesAreNoChange) {
  // Each leg passes through the floor's band; one session sees its +x faces, the other its -x
  // faces and carries a 1.4 cm localisation error, so their height maps differ around every
  // leg. The simulated rooms' noisier legs need the through-band rule besides (Demo.Room*).
  Pose drift = Pose::Identity();
  drift.translation() = Eigen::Vector3d(0.012, -0.008, 0.0);
  const ChangeSet s = detectChanges(legsSession(true), legsSession(false, drift), Config{});
  EXPECT_TRUE(s.events.empty()) << s.events.size() << " events";
}

/// A candidate on plane 0 of its map, compared with plane 0 of the other, on column (1, 1).
CandidateChange candidate(BlobValidation::Verdict verdict, bool same_in_place) {
  CandidateChange c;
  c.region.plane_id = 0;
  c.region.columns = {Eigen::Vector2i(1, 1)};
  c.region.verdict = verdict;
  c.target_plane_id = 0;
  c.target_columns = {Eigen::Vector2i(1, 1)};
  c.same_in_place = same_in_place;
  return c;
}

TEST(AssembleEvents, TheSameObjectInPlaceIsNoEventUnlessTheOtherSideHas3DEvidence) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // Unknown and the other map has it in place: static, on either side.
  EXPECT_TRUE(assembleEvents({candidate(V::Unknown, true)}, {}, cfg).empty());
  EXPECT_TRUE(assembleEvents({}, {candidate(V::Unknown, true)}, cfg).empty());
  // With 3D evidence, or not in place: an event.
  EXPECT_EQ(assembleEvents({candidate(V::Changed, true)}, {}, cfg).size(), 1u);
  EXPECT_EQ(assembleEvents({}, {candidate(V::Unknown, false)}, cfg).size(), 1u);
  // The other direction found a change with 3D evidence on its footprint: both sides stay, as
  // one replaced event.
  const auto e = assembleEvents({candidate(V::Unknown, true)}, {candidate(V::Changed, false)}, cfg);
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].type, ChangeType::Replaced);
  EXPECT_FALSE(e[0].reference.empty());
  EXPECT_FALSE(e[0].current.empty());
}

TEST(AssembleEvents, AnObjectInTheBandsOfTwoPlanesIsOneEvent) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // A 10 cm cube's surface points (2 mm grid on its top), found on plane 0 (Changed) and on
  // plane 3 (Unknown, with a 3 cm margin of another surface); and a cube 20 cm away on plane 3.
  const auto cube = [](float x0, float margin) {
    std::vector<Eigen::Vector3f> pts;
    for (int j = 0; j < 50; ++j)
      for (int i = 0; i < 50 + static_cast<int>(margin / 0.002f); ++i)
        pts.emplace_back(x0 + 0.002f * i, 0.002f * j, 0.1f);
    return pts;
  };
  const auto on = [](int plane, V verdict, std::vector<Eigen::Vector3f> pts) {
    CandidateChange c;
    c.region.plane_id = c.target_plane_id = plane;
    c.region.verdict = verdict;
    c.region.points = std::move(pts);
    c.region.columns = {Eigen::Vector2i(plane, 0)};
    c.target_columns = c.region.columns;
    return c;
  };
  const auto e =
      assembleEvents({},
                     {on(3, V::Unknown, cube(0.0f, 0.03f)), on(0, V::Changed, cube(0.0f, 0.0f)),
                      on(3, V::Changed, cube(0.3f, 0.0f))},
                     cfg);
  ASSERT_EQ(e.size(), 2u);
  EXPECT_EQ(e[0].current.plane_id, 0);  // the one with 3D evidence, with the other's points
  EXPECT_EQ(e[0].current.points.size(), cube(0.0f, 0.03f).size());
  EXPECT_EQ(e[1].current.plane_id, 3);
  EXPECT_GT(e[1].current.points.front().x(), 0.25f);
  // On one plane, two candidates stay two events (blobs of one plane are disjoint objects).
  EXPECT_EQ(
      assembleEvents(
          {}, {on(3, V::Changed, cube(0.0f, 0.0f)), on(3, V::Changed, cube(0.0f, 0.03f))}, cfg)
          .size(),
      2u);
}

TEST(AssembleEvents, ANewObjectWiderThanTheOldOneIsTheReplacementNotAnotherEvent) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // The old object's blob lands on columns 0-1 of a new, wider object (columns 0-3); the new
  // one's added blob is only the ring around the old footprint (columns 2-3).
  CandidateChange old_one = candidate(V::Changed, false);
  old_one.target_columns = {Eigen::Vector2i(0, 0), Eigen::Vector2i(1, 0)};
  old_one.target_object_overlap = 1.0;
  old_one.target_object.plane_id = 0;
  for (int x = 0; x < 4; ++x) old_one.target_object.columns.emplace_back(x, 0);
  old_one.target_object.points = {Eigen::Vector3f(0.0f, 0.0f, 0.1f)};
  CandidateChange ring = candidate(V::Changed, false);
  ring.region.columns = {Eigen::Vector2i(2, 0), Eigen::Vector2i(3, 0)};
  ring.region.points = {Eigen::Vector3f(0.0f, 0.0f, 0.1f), Eigen::Vector3f(0.03f, 0.0f, 0.1f)};
  const auto e = assembleEvents({old_one}, {ring}, cfg);
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].type, ChangeType::Replaced);
  EXPECT_EQ(e[0].current.points.size(), 2u);  // the object's, and the ring's it did not hold
}

TEST(AssembleEvents, AReplacementReportsBothObjectsWholeWhereTheyOverlap) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // An old box (reference columns 0-5) replaced by a lower ring (current columns 3-9): each blob
  // is only the part of its object above the other (old 0-2, new 6-9), each lands on the other
  // object in part only (overlap 0.3). Both objects are reported whole, no point twice.
  const auto points = [](int x0, int x1, float z, ChangeRegion& r) {
    r.plane_id = 0;
    for (int x = x0; x <= x1; ++x) {
      r.columns.emplace_back(x, 0);
      r.points.emplace_back(0.01f * static_cast<float>(x), 0.0f, z);
    }
  };
  CandidateChange old_box = candidate(V::Changed, false);
  old_box.region.columns.clear();
  points(0, 2, 0.08f, old_box.region);
  old_box.target_columns = {Eigen::Vector2i(0, 0), Eigen::Vector2i(1, 0), Eigen::Vector2i(2, 0),
                            Eigen::Vector2i(6, 0)};  // the grown blob reaches the ring
  old_box.target_object_overlap = 0.3;
  points(3, 9, 0.04f, old_box.target_object);
  CandidateChange ring = candidate(V::Unknown, false);
  ring.region.columns.clear();
  points(6, 9, 0.04f, ring.region);
  ring.target_object_overlap = 0.3;
  points(0, 5, 0.08f, ring.target_object);
  const auto e = assembleEvents({old_box}, {ring}, cfg);
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].type, ChangeType::Replaced);
  EXPECT_EQ(e[0].reference.points.size(), 6u);
  EXPECT_EQ(e[0].current.points.size(), 7u);
  // A new object beside the old one, whose target objects do not meet the old blob, adds none.
  CandidateChange beside = ring;
  beside.target_object = ChangeRegion{};
  points(20, 25, 0.08f, beside.target_object);
  const auto b = assembleEvents({old_box}, {beside}, cfg);
  ASSERT_EQ(b.size(), 1u);
  EXPECT_EQ(b[0].reference.points.size(), 3u);
}

TEST(AssembleEvents, PointsUnderTheOtherObjectJoinOnlyWhenThatObjectChanged) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // A removed object whose columns (0-1) hold points under the height of a current object
  // (columns 0-3): a wider, lower object that replaced it (an added blob on columns 2-3), or a
  // static box it lay on (no blob).
  CandidateChange top = candidate(V::Changed, false);
  top.region.columns = {Eigen::Vector2i(0, 0), Eigen::Vector2i(1, 0)};
  top.region.points = {Eigen::Vector3f(0.0f, 0.0f, 0.2f), Eigen::Vector3f(0.01f, 0.0f, 0.2f)};
  top.target_columns = top.region.columns;
  top.target_object_overlap = 1.0;
  top.target_object.plane_id = 0;
  for (int x = 0; x < 4; ++x) {
    top.target_object.columns.emplace_back(x, 0);
    top.target_object.points.emplace_back(0.01f * static_cast<float>(x), 0.0f, 0.05f);
  }
  top.covered_points = {Eigen::Vector3f(0.0f, 0.0f, 0.03f), Eigen::Vector3f(0.01f, 0.0f, 0.03f)};
  CandidateChange ring = candidate(V::Changed, false);
  ring.region.columns = {Eigen::Vector2i(2, 0), Eigen::Vector2i(3, 0)};
  ring.region.points = {Eigen::Vector3f(0.02f, 0.0f, 0.05f)};
  const auto replaced = assembleEvents({top}, {ring}, cfg);
  ASSERT_EQ(replaced.size(), 1u);
  EXPECT_EQ(replaced[0].type, ChangeType::Replaced);
  EXPECT_EQ(replaced[0].reference.points.size(), 4u);
  // On a static box the points under it are the box's.
  CandidateChange on_box = top;
  on_box.target_object_overlap = 0.0;
  const auto removed = assembleEvents({on_box}, {}, cfg);
  ASSERT_EQ(removed.size(), 1u);
  EXPECT_EQ(removed[0].type, ChangeType::Removed);
  EXPECT_EQ(removed[0].reference.points.size(), 2u);
}

TEST(AssembleEvents, ASupportingSliverJoinsAnotherCandidatesEventButMakesNone) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // The part of a new ring outside the old box's footprint (columns 6-9), with too little 3D
  // evidence to stand alone, and the box's removal (columns 0-5) whose blob reaches it.
  CandidateChange ring = candidate(V::Unknown, false);
  ring.supporting = true;
  ring.region.columns = {Eigen::Vector2i(6, 0), Eigen::Vector2i(9, 0)};
  ring.region.points = {Eigen::Vector3f(0.06f, 0.0f, 0.04f)};
  EXPECT_TRUE(assembleEvents({}, {ring}, cfg).empty());
  EXPECT_TRUE(assembleEvents({ring}, {}, cfg).empty());
  CandidateChange box = candidate(V::Changed, false);
  box.region.columns = {Eigen::Vector2i(0, 0), Eigen::Vector2i(5, 0)};
  box.region.points = {Eigen::Vector3f(0.0f, 0.0f, 0.08f)};
  box.target_columns = {Eigen::Vector2i(5, 0), Eigen::Vector2i(6, 0)};
  const auto e = assembleEvents({box}, {ring}, cfg);
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].type, ChangeType::Replaced);
  EXPECT_EQ(e[0].current.points.size(), 1u);
  // Two supporting slivers on each other's columns make no event either, even of matching shape.
  CandidateChange old_part = ring;
  old_part.target_columns = ring.region.columns;
  EXPECT_TRUE(assembleEvents({old_part}, {ring}, cfg).empty());
}

TEST(AssembleEvents, ASmallMoveFoundFromEitherSideIsOneMovedEvent) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // An object moved by a few cm: the whole old object (columns 0-3) with the objects on its
  // footprint now (columns 1-4) as target_object, and the other direction's crescent (column 4).
  const auto moved = [](int first) {
    CandidateChange c = candidate(V::Changed, false);
    c.small_move = true;
    c.region.columns.clear();
    for (int x = first; x < first + 4; ++x) c.region.columns.emplace_back(x, 0);
    c.target_columns = c.region.columns;
    c.target_object_overlap = 1.0;
    c.target_object.plane_id = 0;
    for (int x = first + 1; x < first + 5; ++x) c.target_object.columns.emplace_back(x, 0);
    c.target_object.points = {Eigen::Vector3f(0.01f * static_cast<float>(first + 1), 0.0f, 0.1f)};
    return c;
  };
  CandidateChange crescent = candidate(V::Unknown, false);
  crescent.region.columns = {Eigen::Vector2i(4, 0)};
  crescent.region.points = {Eigen::Vector3f(0.04f, 0.0f, 0.1f)};
  for (const bool from_reference : {true, false}) {
    SCOPED_TRACE(from_reference);
    const auto e = from_reference ? assembleEvents({moved(0)}, {crescent}, cfg)
                                  : assembleEvents({crescent}, {moved(0)}, cfg);
    ASSERT_EQ(e.size(), 1u);
    EXPECT_EQ(e[0].type, ChangeType::Moved);
    // The side it was found from is its region; the other its target objects with the crescent.
    const ChangeRegion& found = from_reference ? e[0].reference : e[0].current;
    const ChangeRegion& other = from_reference ? e[0].current : e[0].reference;
    EXPECT_EQ(found.columns.size(), 4u);
    EXPECT_EQ(other.columns.size(), 4u);
    EXPECT_EQ(other.points.size(), 2u);
  }
  // The same sliver without the move is a replacement.
  CandidateChange replaced = moved(0);
  replaced.small_move = false;
  const auto r = assembleEvents({replaced}, {crescent}, cfg);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].type, ChangeType::Replaced);
}

TEST(AssembleEvents, TwoSliversOfAnObjectReplacedByOneNewObjectAreOneEvent) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // Two slivers of one old object (columns 10-11 and 20-21) each with the new object inside the
  // old footprint (columns 12-19) as their replacement: one replaced event holding both.
  std::vector<CandidateChange> slivers;
  for (const int x0 : {10, 20}) {
    CandidateChange c = candidate(V::Changed, false);
    c.region.columns = {Eigen::Vector2i(x0, 0), Eigen::Vector2i(x0 + 1, 0)};
    c.region.points = {Eigen::Vector3f(0.01f * static_cast<float>(x0), 0.0f, 0.1f)};
    c.target_columns = c.region.columns;
    c.target_object_overlap = 1.0;
    c.target_object.plane_id = 0;
    for (int x = 12; x < 20; ++x) c.target_object.columns.emplace_back(x, 0);
    c.target_object.points = {Eigen::Vector3f(0.15f, 0.0f, 0.1f)};
    slivers.push_back(std::move(c));
  }
  const auto e = assembleEvents(slivers, {}, cfg);
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].type, ChangeType::Replaced);
  EXPECT_EQ(e[0].reference.columns.size(), 4u);
  EXPECT_EQ(e[0].reference.points.size(), 2u);
  EXPECT_EQ(e[0].current.points.size(), 1u);
}

TEST(AssembleEvents, ASwapOfObjectsOfDifferentSizesMovesBothWhole) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // A tall object L (reference columns 0-3, current 10-13) and a low one S (reference 12-14,
  // current 2-4) swap places. L's blobs are whole and land on S; of S only the column that L
  // does not cover changes height (14 removed, 4 added). One point per column at x = column cm.
  const auto shape = [](int cells, double height) {
    ShapeSignature sig;
    sig.cells = cells;
    sig.area = cells * 1e-4;
    sig.max_height = height;
    sig.volume = sig.area * height;
    return sig;
  };
  const auto columns = [](int x0, int x1, ChangeRegion& r) {
    r.plane_id = 0;
    for (int x = x0; x <= x1; ++x) {
      r.columns.emplace_back(x, 0);
      r.points.emplace_back(0.01f * static_cast<float>(x), 0.0f, 0.05f);
    }
  };
  const auto blob = [&](int x0, int x1, const ShapeSignature& sig) {
    CandidateChange c = candidate(V::Changed, false);
    c.region.columns.clear();
    columns(x0, x1, c.region);
    c.region.shape = sig;
    c.target_columns = c.region.columns;
    return c;
  };
  const auto landsOn = [&](CandidateChange c, int x0, int x1) {
    c.target_object_overlap = 1.0;
    columns(x0, x1, c.target_object);
    return c;
  };
  const ShapeSignature large = shape(4, 0.10), small = shape(3, 0.05);
  const CandidateChange l_removed = landsOn(blob(0, 3, large), 2, 4);
  const CandidateChange l_added = landsOn(blob(10, 13, large), 12, 14);
  // The crescents keep S's signature here so that they pair as its move.
  const auto e =
      assembleEvents({l_removed, blob(14, 14, small)}, {l_added, blob(4, 4, small)}, cfg);
  ASSERT_EQ(e.size(), 2u);
  EXPECT_EQ(e[0].type, ChangeType::Moved);
  EXPECT_EQ(e[1].type, ChangeType::Moved);
  const ChangeEvent& s_move = e[0].reference.shape.max_height < 0.07 ? e[0] : e[1];
  // S whole on both sides, the crescent's column and point not repeated.
  EXPECT_EQ(s_move.reference.columns.size(), 3u);
  EXPECT_EQ(s_move.reference.points.size(), 3u);
  EXPECT_EQ(s_move.current.columns.size(), 3u);
  EXPECT_EQ(s_move.current.points.size(), 3u);
  // L covers all of S in both places (no blob of S): what L landed on is S's move.
  CandidateChange l_removed_shaped = l_removed, l_added_shaped = l_added;
  l_removed_shaped.target_object.shape = l_added_shaped.target_object.shape = small;
  const auto covered = assembleEvents({l_removed_shaped}, {l_added_shaped}, cfg);
  ASSERT_EQ(covered.size(), 2u);
  const ChangeEvent& s_whole =
      covered[0].current.columns.front().x() == 2 ? covered[0] : covered[1];
  EXPECT_EQ(s_whole.type, ChangeType::Moved);
  EXPECT_EQ(s_whole.reference.columns.front().x(), 12);
  EXPECT_EQ(s_whole.reference.points.size(), 3u);
  EXPECT_EQ(s_whole.current.points.size(), 3u);
  // Objects of other shapes under the two ends are no move.
  l_added_shaped.target_object.shape = large;
  EXPECT_EQ(assembleEvents({l_removed_shaped}, {l_added_shaped}, cfg).size(), 1u);
}

TEST(AssembleEvents, ANewObjectWhereAnotherWasRemovedReplacesItRatherThanArrivingByAMove) {
  using V = BlobValidation::Verdict;
  const Config cfg;
  // Object A (columns 0-3) is gone, leaving nothing; object B (columns 10-12) is gone and C
  // (columns 10-13) stands where it stood. A and C have matching shapes, B another one.
  const auto blob = [&](int x0, int x1, double height) {
    CandidateChange c = candidate(V::Changed, false);
    c.region.columns.clear();
    for (int x = x0; x <= x1; ++x) {
      c.region.columns.emplace_back(x, 0);
      c.region.points.emplace_back(0.01f * static_cast<float>(x), 0.0f, 0.05f);
    }
    c.region.shape.cells = x1 - x0 + 1;
    c.region.shape.area = c.region.shape.cells * 1e-4;
    c.region.shape.max_height = height;
    c.region.shape.volume = c.region.shape.area * height;
    c.target_columns = c.region.columns;
    return c;
  };
  const CandidateChange a = blob(0, 3, 0.10), b = blob(10, 12, 0.25), c = blob(10, 13, 0.10);
  const auto e = assembleEvents({a, b}, {c}, cfg);
  ASSERT_EQ(e.size(), 2u);
  const ChangeEvent* removed = e[0].type == ChangeType::Removed ? &e[0] : &e[1];
  const ChangeEvent* replaced = removed == &e[0] ? &e[1] : &e[0];
  EXPECT_EQ(removed->type, ChangeType::Removed);
  EXPECT_EQ(removed->reference.columns.front().x(), 0);
  EXPECT_EQ(replaced->type, ChangeType::Replaced);
  EXPECT_EQ(replaced->reference.columns.front().x(), 10);
  EXPECT_EQ(replaced->current.columns.size(), 4u);
  // Where nothing stood before, the same shapes are a move.
  const auto moved = assembleEvents({a}, {c}, cfg);
  ASSERT_EQ(moved.size(), 1u);
  EXPECT_EQ(moved[0].type, ChangeType::Moved);
}

// ---- other planes' surfaces in a plane's maps ------------------------------------------------

/// A floor whose volume holds the height field `h(x, y)` (world = floor frame, 7 mm voxels).
PlaneSdf floorWith(const std::function<double(double, double)>& h) {
  Config cfg;
  Plane floor;
  floor.id = 0;
  floor.extent = Eigen::AlignedBox2d(Eigen::Vector2d(-0.5, -0.5), Eigen::Vector2d(0.5, 0.5));
  PlaneSdf ps(floor, TsdfVolume(cfg));
  const double vs = cfg.voxel_size, trunc = cfg.truncation();
  const int n = static_cast<int>(0.5 / vs);
  for (int j = -n; j < n; ++j)
    for (int i = -n; i < n; ++i) {
      const double top = h((i + 0.5) * vs, (j + 0.5) * vs);
      for (int k = -4; k < static_cast<int>(cfg.fuse_band / vs); ++k) {
        const double sdf = top - (k + 0.5) * vs;  // above the top: free (positive)
        if (sdf > trunc || sdf < -trunc) {
          if (sdf < 0.0) continue;  // deep inside: unobserved
        }
        const Eigen::Vector3i v(i, j, k);
        TsdfBlock& b = ps.volume.allocateBlock(TsdfVolume::blockOfVoxel(v));
        b.voxels[static_cast<std::size_t>(TsdfVolume::linearIndexInBlock(v))] = {
            static_cast<float>(std::min(-sdf, trunc)), 5.0f};
      }
    }
  return ps;
}

/// A vertical plane facing -y at y = y0, `length` m long along x from x0 (default: centred on
/// x = 0) and `height` m high.
PlaneSdf wallAt(double y0, double length, double height, double x0 = std::nan("")) {
  Plane wall;
  wall.id = 1;
  wall.orientation = Plane::Orientation::Vertical;
  wall.normal = -Eigen::Vector3d::UnitY();
  wall.offset = y0;
  wall.frame_origin = Eigen::Vector3d(0.0, y0, 0.0);
  wall.frame_axes.col(0) = Eigen::Vector3d::UnitX();
  wall.frame_axes.col(1) = Eigen::Vector3d::UnitZ();
  wall.frame_axes.col(2) = wall.normal;
  if (std::isnan(x0)) x0 = -0.5 * length;
  wall.extent = Eigen::AlignedBox2d(Eigen::Vector2d(x0, 0.0), Eigen::Vector2d(x0 + length, height));
  return PlaneSdf(wall, TsdfVolume(Config{}));
}

/// Object cells of `maps` whose centre y lies in [y0, y1).
int objectCellsBetween(const PlaneMaps& maps, double y0, double y1) {
  int n = 0;
  const HeightMap& hm = maps.heights;
  for (int y = 0; y < hm.height; ++y)
    for (int x = 0; x < hm.width; ++x) {
      const double cy = hm.cellCenter(x, y).y();
      if (cy >= y0 && cy < y1 && hm.at(x, y) > Config{}.h_obj) ++n;
    }
  return n;
}

TEST(PlaneMaps, AWallsNoisySurfaceAndTheBandBehindItAreStructureNotObjects) {
  // A wall at y = 0.31 m. In the floor's band, its surface spreads 5 cm in front of the plane
  // (far-range noise) and 7 cm behind it (noise and the truncation band); a 6 cm box stands
  // 20 cm in front of it.
  const auto field = [](double, double y) {
    if (y >= 0.26 && y < 0.38) return 0.29;  // the wall's surface, noisy
    if (y >= 0.05 && y < 0.11) return 0.06;  // the box
    return 0.0;
  };
  const PlaneSdf floor = floorWith(field);
  const Config cfg;
  // Without other planes, all of it is objects.
  const PlaneMaps alone = computePlaneMaps(floor, {floor}, cfg);
  EXPECT_GT(objectCellsBetween(alone, 0.26, 0.38), 1000);
  // A wall (room structure): its spread is unknown, the box stays.
  const PlaneMaps with_wall = computePlaneMaps(floor, {floor, wallAt(0.31, 1.2, 2.0)}, cfg);
  EXPECT_EQ(objectCellsBetween(with_wall, 0.26, 0.38), 0);
  EXPECT_EQ(objectCellsBetween(with_wall, 0.05, 0.11), objectCellsBetween(alone, 0.05, 0.11));
  EXPECT_GT(objectCellsBetween(alone, 0.05, 0.11), 500);
  // Config::structure_min_extent above its 2 m: the same wall is only a surface, and its spread
  // beyond ownership_surface_distance stays objects.
  Config short_cfg;
  short_cfg.structure_min_extent = 2.5;
  const PlaneMaps short_wall = computePlaneMaps(floor, {floor, wallAt(0.31, 1.2, 2.0)}, short_cfg);
  EXPECT_EQ(objectCellsBetween(short_wall, 0.34, 0.38), objectCellsBetween(alone, 0.34, 0.38));
  // A box face (a vertical plane 30 x 30 cm) only takes the cells within 2 cm of it.
  const PlaneMaps with_face = computePlaneMaps(floor, {floor, wallAt(0.31, 0.3, 0.3)}, cfg);
  const int near_face =
      objectCellsBetween(alone, 0.29, 0.33) - objectCellsBetween(with_face, 0.29, 0.33);
  EXPECT_GT(near_face, 0);
  EXPECT_EQ(objectCellsBetween(with_face, 0.34, 0.38), objectCellsBetween(alone, 0.34, 0.38));
  EXPECT_EQ(objectCellsBetween(with_face, 0.26, 0.28), objectCellsBetween(alone, 0.26, 0.28));
}

TEST(PlaneMaps, ARoomWallGoesOnAlongItsLineBeyondTheEndsOfItsExtent) {
  // The floor's band holds a wall's surface at y = 0.31 m across the floor (x in [-0.5, 0.5]),
  // but the wall's plane only has the extent from x = 0.3 on: the patch at x < 0.3 was cut off
  // from the rest by what hid the wall between. A 6 cm box stands 20 cm in front of it.
  const auto field = [](double, double y) {
    if (y >= 0.26 && y < 0.38) return 0.29;
    if (y >= 0.05 && y < 0.11) return 0.06;
    return 0.0;
  };
  const PlaneSdf floor = floorWith(field);
  const Config cfg;
  const PlaneMaps alone = computePlaneMaps(floor, {floor}, cfg);
  // A wall (at least Config::wall_min_length long): the whole line is structure, the box stays.
  const PlaneMaps wall = computePlaneMaps(floor, {floor, wallAt(0.31, 2.4, 2.0, 0.3)}, cfg);
  EXPECT_EQ(objectCellsBetween(wall, 0.26, 0.38), 0);
  EXPECT_EQ(objectCellsBetween(wall, 0.05, 0.11), objectCellsBetween(alone, 0.05, 0.11));
  // Shorter room structure (a shelf's side) claims only its extent: the patch stays objects,
  // 0.8 m of the floor's 1 m less the extent margin.
  const PlaneMaps side = computePlaneMaps(floor, {floor, wallAt(0.31, 1.5, 2.0, 0.3)}, cfg);
  const double patch = (0.8 - cfg.ownership_extent_margin) / 1.0;
  EXPECT_NEAR(objectCellsBetween(side, 0.26, 0.38), patch * objectCellsBetween(alone, 0.26, 0.38),
              0.03 * objectCellsBetween(alone, 0.26, 0.38));
}

TEST(PlaneMaps, AShelfFrontSeenThroughToTheWallIsNotStructure) {
  // A board's band: a 6 cm box stands 2-8 cm behind a vertical plane at y = 0.2 (1.2 x 2 m, long
  // enough for room structure), the coplanar front edges of the shelf's boards.
  const auto field = [](double, double y) { return y >= 0.22 && y < 0.28 ? 0.06 : 0.0; };
  const PlaneSdf board = floorWith(field);
  const Config cfg;
  PlaneSdf front = wallAt(0.2, 1.2, 2.0);
  front.plane.id = 1;
  const PlaneMaps alone = computePlaneMaps(board, {board}, cfg);
  EXPECT_GT(objectCellsBetween(alone, 0.225, 0.28), 500);
  // As a wall it claims 10 cm behind itself: the box is unknown.
  EXPECT_EQ(objectCellsBetween(computePlaneMaps(board, {board, front}, cfg), 0.225, 0.28), 0);
  // With the room's wall 35 cm behind it, inside its extent, the cameras saw through it: it
  // claims only its own 2 cm, and the box behind that is the board's again.
  PlaneSdf wall = wallAt(0.55, 1.2, 2.0);
  wall.plane.id = 2;
  const PlaneMaps seen = computePlaneMaps(board, {board, front, wall}, cfg);
  EXPECT_EQ(objectCellsBetween(seen, 0.225, 0.28), objectCellsBetween(alone, 0.225, 0.28));
  // A wall 1.4 m behind a plane 1.2 m wide is seen past its edges, not through it.
  PlaneSdf far = wallAt(1.6, 1.2, 2.0);
  far.plane.id = 2;
  EXPECT_EQ(objectCellsBetween(computePlaneMaps(board, {board, front, far}, cfg), 0.225, 0.28), 0);
}

/// A shelf board in the x-y plane (normal +y) whose top is at v = `top`, 0.8 x 0.3 m.
Plane boardAt(int id, double top) {
  Plane board;
  board.id = id;
  board.normal = Eigen::Vector3d::UnitY();
  board.offset = -top;
  board.frame_origin = Eigen::Vector3d(0.0, top, 0.0);
  board.frame_axes.col(0) = Eigen::Vector3d::UnitX();
  board.frame_axes.col(1) = Eigen::Vector3d::UnitZ();
  board.frame_axes.col(2) = board.normal;
  board.extent = Eigen::AlignedBox2d(Eigen::Vector2d(-0.4, 0.0), Eigen::Vector2d(0.4, 0.3));
  return board;
}

TEST(PlaneMaps, AShelfBoardsSlabInAWallsBandIsTheBoards) {
  // A wall (here in the x-y plane, its band along +z) with a board sticking out of it: the
  // board's top at v = 0.20, its 2 cm slab and the splat below reaching down to v = 0.155. A 6 cm
  // box hangs on the wall 45 cm lower.
  const auto field = [](double, double v) {
    if (v >= 0.155 && v < 0.20) return 0.29;
    if (v >= -0.30 && v < -0.24) return 0.06;
    return 0.0;
  };
  PlaneSdf wall = floorWith(field);
  wall.plane.orientation = Plane::Orientation::Vertical;  // 1 m long: room structure
  const Plane board = boardAt(2, 0.20);
  const Config cfg;
  const PlaneMaps alone = computePlaneMaps(wall, {wall}, cfg);
  EXPECT_GT(objectCellsBetween(alone, 0.155, 0.20), 500);
  const PlaneMaps with_board =
      computePlaneMaps(wall, {wall, PlaneSdf(board, TsdfVolume(cfg))}, cfg);
  EXPECT_EQ(objectCellsBetween(with_board, 0.155, 0.20), 0);
  EXPECT_EQ(objectCellsBetween(with_board, -0.30, -0.24), objectCellsBetween(alone, -0.30, -0.24));
  EXPECT_GT(objectCellsBetween(alone, -0.30, -0.24), 500);
}

TEST(PlaneMaps, AShelfCompartmentAboveABoardsBandIsTheBoards) {
  // A wall (its band along +z, v up) behind a board at v = -0.2 and the next one 42 cm higher.
  // Between the lower board's band (to v = 0.1) and the upper one's slab (from 0.17) the wall's
  // band sees the shelf's back panel, 1.5 cm thick, and the tip of a bottle on the lower board.
  const auto field = [](double x, double v) {
    if (v >= 0.10 && v < 0.14 && x >= 0.0 && x < 0.06) return 0.10;  // the bottle's tip
    if (v >= 0.10 && v < 0.17) return 0.015;                         // the back panel
    return 0.0;
  };
  PlaneSdf wall = floorWith(field);
  wall.plane.orientation = Plane::Orientation::Vertical;
  const Config cfg;
  const auto strip = [](const PlaneMaps& m) { return objectCellsBetween(m, 0.105, 0.165); };
  const PlaneSdf lower(boardAt(2, -0.2), TsdfVolume(cfg));
  const PlaneMaps alone = computePlaneMaps(wall, {wall, lower}, cfg);
  EXPECT_GT(strip(alone), 1000);
  // With the board above, the compartment up to its slab is the lower board's.
  const PlaneMaps shelf =
      computePlaneMaps(wall, {wall, lower, PlaneSdf(boardAt(3, 0.22), TsdfVolume(cfg))}, cfg);
  EXPECT_EQ(strip(shelf), 0);
  // A plane more than twice the band higher bounds no compartment (a shelf over a desk).
  const PlaneSdf low(boardAt(2, -0.45), TsdfVolume(cfg));
  const PlaneMaps far =
      computePlaneMaps(wall, {wall, low, PlaneSdf(boardAt(3, 0.22), TsdfVolume(cfg))}, cfg);
  EXPECT_EQ(strip(far), strip(alone));
}

TEST(PlaneMaps, WhatStandsBeyondThePlaneExtentIsUnknown) {
  // The plane's inliers end at y = 0.2. A box stands on it, one within the support margin
  // (0.1 m) beyond its edge, and one 15 cm beyond (a shelf or a wall in its unbounded band).
  const auto field = [](double, double y) {
    if (y >= 0.00 && y < 0.06) return 0.06;
    if (y >= 0.22 && y < 0.28) return 0.08;
    if (y >= 0.35 && y < 0.41) return 0.10;
    return 0.0;
  };
  PlaneSdf floor = floorWith(field);
  floor.plane.extent = Eigen::AlignedBox2d(Eigen::Vector2d(-0.5, -0.5), Eigen::Vector2d(0.5, 0.2));
  Config cfg;
  const PlaneMaps maps = computePlaneMaps(floor, {floor}, cfg);
  EXPECT_GT(objectCellsBetween(maps, 0.00, 0.06), 500);
  EXPECT_GT(objectCellsBetween(maps, 0.22, 0.28), 500);
  EXPECT_EQ(objectCellsBetween(maps, 0.30, 0.50), 0);
  EXPECT_EQ(maps.objects.numObjects(), 2);
  cfg.support_margin = 1000.0;  // no limit: the far box is an object again
  const PlaneMaps all = computePlaneMaps(floor, {floor}, cfg);
  EXPECT_EQ(objectCellsBetween(all, 0.35, 0.41), objectCellsBetween(maps, 0.00, 0.06));
  EXPECT_EQ(all.objects.numObjects(), 3);
}

TEST(ComparePlanePair, ABoxTakenOffALargeComponentIsTheBoxNotTheComponent) {
  // A 60 x 60 cm platform 3 cm high (one object-map component of 86 x 86 cells: a shelf's back
  // panel in a wall's band is such a component) with a 10 x 10 x 8 cm box on it, then without
  // the box. The box's change covers 4 % of the component: the removed region is the box's
  // footprint (14 x 14 cells, dilated by one: at most 16 x 16), not the whole platform, which
  // the brief's plain growth (blob_min_overlap 0) reports.
  const auto platform = [](double u, double v) {
    return std::abs(u) < 0.3 && std::abs(v) < 0.3 ? 0.03 : 0.0;
  };
  const auto with_box = [&](double u, double v) {
    return u > 0.05 && u < 0.15 && v > 0.05 && v < 0.15 ? 0.11 : platform(u, v);
  };
  const PlaneSdf before = floorWith(with_box), after = floorWith(platform);
  PlaneMatch match;
  match.source_id = match.target_id = 0;
  for (const double min_overlap : {Config{}.blob_min_overlap, 0.0}) {
    SCOPED_TRACE(min_overlap);
    Config cfg;
    cfg.blob_min_overlap = min_overlap;
    const PlaneMaps src = computePlaneMaps(before, {before}, cfg);
    const PlaneMaps tgt = computePlaneMaps(after, {after}, cfg);
    ASSERT_EQ(src.objects.numObjects(), 1);
    ASSERT_GE(src.objects.object(1).area, largeObjectCells(cfg, cfg.voxel_size));
    PlanePairResult res;
    DetectOptions opt;
    opt.keep_stages = true;
    const std::vector<CandidateChange> out =
        comparePlanePair(before, src, after, tgt, match, false, {}, {}, cfg, opt, &res);
    ASSERT_EQ(out.size(), 1u);
    const ChangeRegion& r = out[0].region;
    EXPECT_EQ(r.verdict, BlobValidation::Verdict::Changed);
    if (min_overlap > 0.0) {
      ASSERT_EQ(res.change.blobs.size(), 1u);
      EXPECT_TRUE(res.change.blobs[0].partial);
      EXPECT_GE(r.columns.size(), 14u * 14u);
      EXPECT_LE(r.columns.size(), 16u * 16u);
      EXPECT_LT((r.centroid.head<2>() - Eigen::Vector2d(0.10, 0.10)).norm(), 0.01);
    } else {
      EXPECT_EQ(r.columns.size(), static_cast<std::size_t>(src.objects.object(1).area));
    }
  }
}

TEST(ComparePlanePair, AChangesPointsComeFromTheChunksItsRegionMeets) {
  // An 8 cm box replaced by a 4 cm one on a floor. Each map's points: far points (floor and
  // above the band, 3 chunks of detail::kPointChunk that the region's box does not meet), the
  // box tops across a chunk boundary, more far points. The removed region holds exactly the
  // points on the old box's top and the replaced object exactly those on the new one's, in
  // input order, whether the maps carry chunk boxes (detectChanges) or not (a full scan).
  const auto tall = [](double u, double v) {
    return std::abs(u - 0.1) < 0.04 && std::abs(v - 0.1) < 0.04 ? 0.08 : 0.0;
  };
  const auto low = [](double u, double v) {
    return std::abs(u - 0.1) < 0.04 && std::abs(v - 0.1) < 0.04 ? 0.04 : 0.0;
  };
  const PlaneSdf before = floorWith(tall), after = floorWith(low);
  const auto pointsWith = [](float top) {
    std::vector<Eigen::Vector3f> pts;
    for (int i = 0; i < 3 * static_cast<int>(detail::kPointChunk); ++i)
      pts.emplace_back(-0.4f + 1e-4f * (i % 2000), -0.4f, i % 2 ? 0.0f : 0.9f);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const float inf = std::numeric_limits<float>::infinity();
    for (int i = 0; i < 5000; ++i) {  // on the top, inside its edges
      pts.emplace_back(0.07f + 0.06f * (i % 71) / 70.0f, 0.07f + 0.06f * (i / 71) / 70.0f, top);
      if (i == 1000) pts.emplace_back(nan, nan, nan);  // invalid points: in no chunk's box
      if (i == 2000) pts.emplace_back(0.1f, 0.1f, inf);
    }
    for (int i = 0; i < 6000; ++i) pts.emplace_back(0.4f, -0.4f + 1e-4f * i, 0.0f);
    // The array's last point on the top: its chunk's box (far points otherwise) holds it.
    pts.emplace_back(0.1f, 0.1f, top);
    return pts;
  };
  std::vector<Eigen::Vector3f> src_pts = pointsWith(0.08f);
  const std::vector<Eigen::Vector3f> tgt_pts = pointsWith(0.04f);
  const Config cfg;
  PlaneMatch match;
  match.source_id = match.target_id = 0;
  std::vector<CandidateChange> out[2];
  for (int chunked = 0; chunked < 2; ++chunked) {
    const PlaneMaps src = computePlaneMaps(before, {before}, cfg, chunked ? &src_pts : nullptr);
    const PlaneMaps tgt = computePlaneMaps(after, {after}, cfg, chunked ? &tgt_pts : nullptr);
    out[chunked] =
        comparePlanePair(before, src, after, tgt, match, false, src_pts, tgt_pts, cfg, {}, nullptr);
    ASSERT_EQ(out[chunked].size(), 1u);
  }
  const auto onTop = [](const std::vector<Eigen::Vector3f>& pts, float top) {
    std::vector<Eigen::Vector3f> r;
    for (const auto& p : pts)
      if (p.z() == top && p.x() > 0.06f) r.push_back(p);
    return r;
  };
  EXPECT_EQ(out[1][0].region.points, onTop(src_pts, 0.08f));
  EXPECT_EQ(out[1][0].target_object.points, onTop(tgt_pts, 0.04f));
  EXPECT_EQ(out[0][0].region.points, out[1][0].region.points);
  EXPECT_EQ(out[0][0].target_object.points, out[1][0].target_object.points);

  // Points added after the chunk boxes were built (a ChangeDetector keeps an unchanged plane's
  // maps while the map grows): one more on the old top, in the last chunk, whose box holds only
  // far points and the top point before it (built for one point less, it does not hold the new
  // one). It is found (the stale boxes are not used).
  const PlaneMaps src = computePlaneMaps(before, {before}, cfg, &src_pts);
  const PlaneMaps tgt = computePlaneMaps(after, {after}, cfg, &tgt_pts);
  comparePlanePair(before, src, after, tgt, match, false, src_pts, tgt_pts, cfg, {}, nullptr);
  src_pts.emplace_back(0.12f, 0.12f, 0.08f);
  const auto grown =
      comparePlanePair(before, src, after, tgt, match, false, src_pts, tgt_pts, cfg, {}, nullptr);
  ASSERT_EQ(grown.size(), 1u);
  EXPECT_EQ(grown[0].region.points, onTop(src_pts, 0.08f));
  EXPECT_EQ(grown[0].region.points.back(), Eigen::Vector3f(0.12f, 0.12f, 0.08f));
}

TEST(ComparePlanePair, StructureThroughTheBandIsThroughItInBothMaps) {
  // A bottle (body r 5 cm, 20 cm high, neck r 2.5 cm through the band's top) without 3D
  // evidence either way (min_scored unreachable: Unknown). Replaced by a cone (r 5.5 cm, cut by
  // the band) whose tip alone reaches the top, it is a change; against a narrower column through
  // the band (a leg whose outline differs between sessions) it is structure and dropped.
  const auto radius = [](double u, double v) { return std::hypot(u - 0.1, v - 0.1); };
  const auto bottle = [&](double u, double v) {
    const double r = radius(u, v);
    return r < 0.025 ? 0.4 : r < 0.05 ? 0.2 : 0.0;
  };
  const auto cone = [&](double u, double v) {
    return std::max(0.0, 0.35 * (1.0 - radius(u, v) / 0.055));
  };
  const auto column = [&](double u, double v) { return radius(u, v) < 0.035 ? 0.4 : 0.0; };
  const PlaneSdf before = floorWith(bottle);
  Config cfg;
  cfg.verdict_min_scored = 1 << 20;
  DetectOptions opt;
  opt.keep_stages = true;
  PlaneMatch match;
  match.source_id = match.target_id = 0;
  const PlaneMaps src = computePlaneMaps(before, {before}, cfg);
  for (const bool replaced : {true, false}) {
    SCOPED_TRACE(replaced);
    const PlaneSdf after = floorWith(replaced ? std::function<double(double, double)>(cone)
                                              : std::function<double(double, double)>(column));
    const PlaneMaps tgt = computePlaneMaps(after, {after}, cfg);
    PlanePairResult res;
    const std::vector<CandidateChange> out =
        comparePlanePair(before, src, after, tgt, match, false, {}, {}, cfg, opt, &res);
    ASSERT_EQ(res.change.blobs.size(), 1u);
    ASSERT_EQ(res.validations.size(), 1u);
    EXPECT_EQ(res.validations[0].verdict, BlobValidation::Verdict::Unknown);
    EXPECT_EQ(out.size(), replaced ? 1u : 0u);
  }
}

TEST(ComparePlanePair, AnEventsPointsStartAboveTheOtherMapsFlatSurface) {
  // A platform 8 mm high (flat: below h_obj; a shelf's back panel in front of its wall) in both
  // maps, and on it a box that is new. The added region holds the box's points, not the
  // platform's around it, which both maps have.
  const auto platform = [](double u, double v) {
    return std::abs(u) < 0.3 && std::abs(v) < 0.3 ? 0.008 : 0.0;
  };
  const auto with_box = [&](double u, double v) {
    return std::abs(u - 0.1) < 0.04 && std::abs(v - 0.1) < 0.04 ? 0.08 : platform(u, v);
  };
  const PlaneSdf before = floorWith(platform), after = floorWith(with_box);
  std::vector<Eigen::Vector3f> pts;  // the platform on a 2 mm grid around the box, its top
  for (int j = 0; j <= 100; ++j)
    for (int i = 0; i <= 100; ++i) {
      const float u = 0.1f + 0.002f * (i - 50), v = 0.1f + 0.002f * (j - 50);
      const bool on_box = std::abs(u - 0.1f) < 0.04f && std::abs(v - 0.1f) < 0.04f;
      pts.emplace_back(u, v, on_box ? 0.08f : 0.008f);
    }
  const Config cfg;
  PlaneMatch match;
  match.source_id = match.target_id = 0;
  const PlaneMaps src = computePlaneMaps(after, {after}, cfg);
  const PlaneMaps tgt = computePlaneMaps(before, {before}, cfg);
  const std::vector<CandidateChange> out =
      comparePlanePair(after, src, before, tgt, match, false, pts, {}, cfg, {}, nullptr);
  ASSERT_EQ(out.size(), 1u);
  const auto& region_pts = out[0].region.points;
  EXPECT_GT(region_pts.size(), 1000u);
  const auto on_platform = std::count_if(region_pts.begin(), region_pts.end(),
                                         [](const Eigen::Vector3f& p) { return p.z() < 0.05f; });
  EXPECT_EQ(on_platform, 0) << "of " << region_pts.size();
}

TEST(ComparePlanePair, AnObjectStandingInsideAChangedSliversOldFootprintReplacedIt) {
  // Splatted maps (rim of one cell): a 4.5 cm disc of radius 11 cm, then a 4 cm box of 12 x 15
  // cm in its place. Only the disc's ring around the box differs (3.5-5 cm wide, wider than a
  // rim), as slivers of the disc; the box inside the old footprint is the replacement, one
  // event. A disc simply taken away is removed, with nothing replacing it.
  const auto disc = [](double u, double v) { return std::hypot(u, v) < 0.11 ? 0.045 : 0.0; };
  const auto box = [](double u, double v) {
    return std::abs(u) < 0.06 && std::abs(v) < 0.075 ? 0.04 : 0.0;
  };
  const PlaneSdf before = floorWith(disc);
  Config cfg;
  cfg.verdict_min_scored_splatted = cfg.verdict_min_scored;
  DetectOptions opt;
  opt.keep_stages = true;
  PlaneMatch match;
  match.source_id = match.target_id = 0;
  const PlaneMaps src = computePlaneMaps(before, {before}, cfg, nullptr, 1);
  for (const bool replaced : {true, false}) {
    SCOPED_TRACE(replaced);
    const PlaneSdf after = floorWith(replaced ? std::function<double(double, double)>(box)
                                              : [](double, double) { return 0.0; });
    const PlaneMaps tgt = computePlaneMaps(after, {after}, cfg, nullptr, 1);
    PlanePairResult res;
    const std::vector<CandidateChange> out =
        comparePlanePair(before, src, after, tgt, match, false, {}, {}, cfg, opt, &res);
    ASSERT_FALSE(out.empty());
    const std::vector<ChangeEvent> events = assembleEvents(out, {}, cfg);
    ASSERT_EQ(events.size(), 1u);
    if (!replaced) {
      EXPECT_EQ(events[0].type, ChangeType::Removed);
      continue;
    }
    ASSERT_FALSE(res.change.blobs.empty());
    EXPECT_TRUE(res.change.blobs[0].partial);
    EXPECT_EQ(events[0].type, ChangeType::Replaced);
    // The box's columns (17 x 21 cells).
    const auto n = static_cast<int>(events[0].current.columns.size());
    EXPECT_GE(n, 17 * 21 * 9 / 10);
    EXPECT_LE(n, 18 * 22);
  }
}

TEST(ComparePlanePair, AnObjectGoneFromALargePanelLandsOnStructureNotOnAReplacement) {
  // A shelf's back panel 1.5 cm in front of its wall (an object: above h_obj, 60 x 60 cm, larger
  // than blob_large_area) with a 10 cm box on it, then the panel alone: the box's footprint
  // lands on a sliver of the panel, which the box hid; the event is a removal. Without the
  // panel, a 2 cm book of 12 x 12 cm left in the box's place stands on its footprint: a
  // replacement.
  const auto panel = [](double u, double v) {
    return std::abs(u) < 0.3 && std::abs(v) < 0.3 ? 0.015 : 0.0;
  };
  const auto box = [](double u, double v) {
    return std::abs(u - 0.1) < 0.05 && std::abs(v - 0.1) < 0.05 ? 0.10 : 0.0;
  };
  const auto book = [](double u, double v) {
    return std::abs(u - 0.1) < 0.06 && std::abs(v - 0.1) < 0.06 ? 0.02 : 0.0;
  };
  const Config cfg;
  ASSERT_GT(0.6 * 0.6, cfg.blob_large_area);
  PlaneMatch match;
  match.source_id = match.target_id = 0;
  for (const bool on_panel : {true, false}) {
    SCOPED_TRACE(on_panel);
    const PlaneSdf before = floorWith([&](double u, double v) {
      return on_panel ? std::max(box(u, v), panel(u, v)) : box(u, v);
    });
    const PlaneSdf after = on_panel ? floorWith(panel) : floorWith(book);
    const PlaneMaps src = computePlaneMaps(before, {before}, cfg);
    const PlaneMaps tgt = computePlaneMaps(after, {after}, cfg);
    const std::vector<CandidateChange> out =
        comparePlanePair(before, src, after, tgt, match, false, {}, {}, cfg, {}, nullptr);
    ASSERT_EQ(out.size(), 1u);
    EXPECT_EQ(out[0].target_object_overlap, on_panel ? 0.0 : 1.0);
    const std::vector<ChangeEvent> events = assembleEvents(out, {}, cfg);
    ASSERT_EQ(events.size(), 1u);
    EXPECT_EQ(events[0].type, on_panel ? ChangeType::Removed : ChangeType::Replaced);
  }
}

TEST(PlaneMaps, BandPointsAreBucketedOnceOnFirstUse) {
  // A floor with a 10 cm box; points on the box top, on the floor and far above the band.
  const PlaneSdf floor = floorWith([](double u, double v) {
    return std::abs(u - 0.1) < 0.05 && std::abs(v) < 0.05 ? 0.10 : 0.0;
  });
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 20; ++i) {
    points.emplace_back(0.08f + 0.002f * i, 0.0f, 0.10f);  // box top: in the band
    points.emplace_back(-0.2f, 0.01f * i, 0.0f);           // floor: below h_obj / 2
    points.emplace_back(0.1f, 0.0f, 0.9f);                 // above the band
  }
  const Config cfg;
  const PlaneMaps maps = computePlaneMaps(floor, {floor}, cfg, &points);
  ASSERT_TRUE(maps.points);
  const CellPoints expected = bucketBandPoints(floor.plane, maps.heights, points, cfg);
  EXPECT_EQ(expected.index.size(), 20u);
  // Built once: two threads asking at the same time get the same buckets, and so does a copy.
  const CellPoints* got[2] = {nullptr, nullptr};
  std::thread t([&] { got[1] = bandPoints(maps, floor.plane, points, cfg); });
  got[0] = bandPoints(maps, floor.plane, points, cfg);
  t.join();
  ASSERT_NE(got[0], nullptr);
  EXPECT_EQ(got[0], got[1]);
  EXPECT_EQ(got[0]->start, expected.start);
  EXPECT_EQ(got[0]->index, expected.index);
  const PlaneMaps copy = maps;
  EXPECT_EQ(bandPoints(copy, floor.plane, points, cfg), got[0]);
  // Other points, or maps computed without points: none.
  const std::vector<Eigen::Vector3f> other = points;
  EXPECT_EQ(bandPoints(maps, floor.plane, other, cfg), nullptr);
  EXPECT_EQ(bandPoints(computePlaneMaps(floor, {floor}, cfg), floor.plane, points, cfg), nullptr);
}

/// A detector that announces every result at once (no settle frames).
Config immediate() {
  Config cfg;
  cfg.event_settle_frames = 0;
  cfg.event_unscored_settle_frames = 0;
  return cfg;
}

TEST(ChangeDetector, EmitsOnceThenOnlyRechecksChangedPlanes) {
  ChangeDetector det(beforeMap(), immediate());
  std::vector<ChangeEvent> heard;
  det.onEvent([&](const ChangeEvent& e) { heard.push_back(e); });
  Map cur{Config{}};
  const Intrinsics k;
  const auto poses = test::ringPoses({0, 0, kTable}, 0.9, 0.55, 8);
  for (const Pose& T : poses) cur.integrate(test::renderDepth(afterScene(), k, T), T);
  const UpdateStats first = det.update(cur);
  EXPECT_GT(first.pairs_checked, 0);
  ASSERT_EQ(heard.size(), 3u);
  for (const auto& e : heard) EXPECT_EQ(e.status, ChangeStatus::New);

  // Nothing integrated since: every pair is reused and nobody hears anything.
  const UpdateStats again = det.update(cur);
  EXPECT_EQ(again.pairs_checked, 0);
  EXPECT_EQ(again.pairs_reused, first.pairs_checked);
  EXPECT_EQ(heard.size(), 3u);
  EXPECT_EQ(det.events().size(), 3u);
}

TEST(ChangeDetector, AConfigOrCurrentMapOfAnotherGeometryIsAnError) {
  Config coarse;
  coarse.voxel_size = 0.01;
  try {
    ChangeDetector det(beforeMap(), coarse);
    ADD_FAILURE() << "a 1 cm config over a 7 mm reference was accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), "config");
    EXPECT_NE(e.message().find("voxel_size 0.007"), std::string::npos) << e.what();
  }
  ChangeDetector det(beforeMap(), Config{});
  Config band = Config{};
  band.fuse_band = 0.4;
  Map cur(band);
  try {
    det.update(cur);
    ADD_FAILURE() << "a current map with a 0.4 m band was accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), "current map");
    EXPECT_NE(e.message().find("fuse_band 0.4"), std::string::npos) << e.what();
  }
}

TEST(ChangeDetector, ARestoredDetectorKeepsItsIdsAndNotifiesNothingNew) {
  const Config cfg = immediate();
  auto reference = std::make_shared<const Map>(beforeMap());
  ChangeDetector first(reference, cfg);
  Map cur{cfg};
  const Intrinsics k;
  for (const Pose& T : test::ringPoses({0, 0, kTable}, 0.9, 0.55, 8))
    cur.integrate(test::renderDepth(afterScene(), k, T), T);
  first.update(cur);
  const std::vector<ChangeEvent> saved =
      deserializeEvents(serializeEvents(first.events()), "saved events");
  ASSERT_EQ(saved.size(), 3u);

  ChangeDetector second(reference, cfg);
  second.restore(saved, first.nextId());
  EXPECT_TRUE(second.update(cur).notifications.empty());
  ASSERT_EQ(second.events().size(), 3u);
  for (std::size_t i = 0; i < saved.size(); ++i) EXPECT_EQ(second.events()[i].id, saved[i].id);
  EXPECT_EQ(second.nextId(), first.nextId());
  // Ids that could come again are refused.
  EXPECT_THROW(second.restore(saved, saved.back().id), Error);
  EXPECT_THROW(second.restore({saved[0], saved[0]}, first.nextId()), Error);
}

TEST(EventIo, SerializedEventsComeBackWholeAndOtherBytesAreRefused) {
  ChangeEvent e;
  e.id = 7;
  e.type = ChangeType::Replaced;
  e.status = ChangeStatus::Updated;
  e.confidence = 0.8125;
  e.frame = 42;
  for (ChangeRegion* r : {&e.reference, &e.current}) {
    r->plane_id = r == &e.reference ? 3 : 5;
    r->columns = {{1, 2}, {-3, 4}};
    r->voxels = {{1, 2, 3}, {-4, 5, -6}};
    r->points = {{0.5f, -0.25f, 1.0f}};
    r->bbox = Eigen::AlignedBox3d(Eigen::Vector3d(-1, -2, -3), Eigen::Vector3d(1, 2, 3));
    r->centroid = Eigen::Vector3d(0.1, 0.2, 0.3);
    r->shape.cells = 12;
    r->shape.area = 0.01;
    r->shape.deciles = {0.1, 0.2};
    r->key_voxels = 9;
    r->scored = 8;
    r->mean_similarity = 0.375;
    r->verdict = BlobValidation::Verdict::Changed;
  }
  ChangeEvent bare;  // an event with no sides: empty boxes stay empty
  const std::string bytes = serializeEvents({e, bare});
  const std::vector<ChangeEvent> back = deserializeEvents(bytes, "events.bin");
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(serializeEvents(back), bytes);
  EXPECT_EQ(back[0].id, 7);
  EXPECT_EQ(back[0].type, ChangeType::Replaced);
  EXPECT_EQ(back[0].status, ChangeStatus::Updated);
  EXPECT_EQ(back[0].frame, 42u);
  EXPECT_EQ(back[0].current.plane_id, 5);
  EXPECT_EQ(back[0].reference.voxels, e.reference.voxels);
  EXPECT_EQ(back[0].current.shape.deciles, e.current.shape.deciles);
  EXPECT_TRUE(back[1].reference.empty());
  EXPECT_TRUE(back[1].reference.bbox.isEmpty());
  for (const std::string& bad :
       {bytes.substr(0, bytes.size() - 1), std::string("PSDFMAP") + bytes.substr(7), bytes + "x"}) {
    try {
      deserializeEvents(bad, "events.bin");
      ADD_FAILURE() << "accepted " << bad.size() << " bytes";
    } catch (const Error& err) {
      EXPECT_EQ(err.path(), "events.bin");
      EXPECT_NE(err.message().find("corrupt change events"), std::string::npos) << err.what();
    }
  }
}

TEST(ChangeDetector, RetractsAChangeLaterFramesContradict) {
  // The current session first sees the table without the box (removed), then the box is back
  // and seen from many more views: the removal is retracted.
  ChangeDetector det(beforeMap(), immediate());
  std::vector<ChangeEvent> heard;
  det.onEvent([&](const ChangeEvent& e) { heard.push_back(e); });
  Map cur{Config{}};
  const Intrinsics k;
  const AnalyticScene without = test::tableWith({cylinderAt(-0.15, -0.10)});
  const AnalyticScene with = test::tableWith({box(), cylinderAt(-0.15, -0.10)});
  for (const Pose& T : test::ringPoses({0, 0, kTable}, 0.9, 0.55, 4))
    cur.integrate(test::renderDepth(without, k, T), T);
  det.update(cur);
  ASSERT_EQ(heard.size(), 1u);
  EXPECT_EQ(heard[0].type, ChangeType::Removed);
  const int id = heard[0].id;
  for (int round = 0; round < 4; ++round)
    for (const Pose& T : test::ringPoses({0, 0, kTable}, 0.85, 0.5, 8))
      cur.integrate(test::renderDepth(with, k, T), T);
  det.update(cur);
  ASSERT_EQ(heard.size(), 2u);
  EXPECT_EQ(heard[1].status, ChangeStatus::Retracted);
  EXPECT_EQ(heard[1].id, id);
  EXPECT_TRUE(det.events().empty());
}

TEST(ChangeDetector, AnnouncesOnlyWhatHeldOverTheSettleFrames) {
  Config cfg;
  cfg.event_settle_frames = 5;
  cfg.event_unscored_settle_frames = 5;
  ChangeDetector det(std::make_shared<const Map>(beforeMap()), cfg);
  std::vector<ChangeEvent> heard;
  det.onEvent([&](const ChangeEvent& e) { heard.push_back(e); });
  Map cur{cfg};
  const Intrinsics k;
  const auto poses = test::ringPoses({0, 0, kTable}, 0.9, 0.55, 8);
  for (std::size_t i = 0; i < 4; ++i)
    cur.integrate(test::renderDepth(afterScene(), k, poses[i]), poses[i]);
  det.update(cur);  // found over 0 frames: pending
  EXPECT_TRUE(heard.empty());
  for (std::size_t i = 4; i < 8; ++i)
    cur.integrate(test::renderDepth(afterScene(), k, poses[i]), poses[i]);
  det.update(cur);  // 4 frames
  EXPECT_TRUE(heard.empty());
  EXPECT_TRUE(det.events().empty());
  cur.integrate(test::renderDepth(afterScene(), k, poses[0]), poses[0]);
  det.update(cur);  // 5 frames: every result that kept its type is announced, once
  const std::size_t settled = heard.size();
  EXPECT_GT(settled, 0u);
  for (const auto& e : heard) {
    EXPECT_EQ(e.status, ChangeStatus::New);
    EXPECT_EQ(e.frame, 9u);
  }
  // The end of the session settles the rest: the events are detectChanges' on the same maps.
  det.finish(cur);
  const ChangeSet offline = detectChanges(det.reference(), cur, cfg);
  ASSERT_EQ(det.events().size(), offline.events.size());
  EXPECT_EQ(offline.events.size(), 3u);
  const std::size_t after_finish = heard.size();
  det.finish(cur);  // nothing left to settle
  EXPECT_EQ(heard.size(), after_finish);
}

TEST(ChangeDetector, AVerdictOnHeightsAloneWaitsForItsOwnSettleFrames) {
  Config cfg;
  cfg.event_settle_frames = 5;
  cfg.event_unscored_settle_frames = 8;
  ChangeDetector det(std::make_shared<const Map>(beforeMap()), cfg);
  std::vector<ChangeEvent> heard;
  det.onEvent([&](const ChangeEvent& e) { heard.push_back(e); });
  Map cur{cfg};
  const auto poses = test::ringPoses({0, 0, kTable}, 0.9, 0.55, 8);
  const auto seeUpTo = [&](std::uint64_t frames) {
    while (cur.frames() < frames) {
      const Pose& T = poses[cur.frames() % poses.size()];
      cur.integrate(test::renderDepth(afterScene(), Intrinsics{}, T), T);
    }
    det.update(cur);
  };
  // What the updates find: from frame 4 a move no key voxel of which could be scored; from frame
  // 8 an addition the 3D validation checked and a removal it could not.
  const auto checked = [](const ChangeEvent& e) {
    return e.reference.verdict != BlobValidation::Verdict::Unknown ||
           e.current.verdict != BlobValidation::Verdict::Unknown;
  };
  seeUpTo(4);
  seeUpTo(8);
  const ChangeSet at8 = detectChanges(det.reference(), cur, cfg);
  ASSERT_EQ(at8.events.size(), 3u);
  EXPECT_EQ(std::count_if(at8.events.begin(), at8.events.end(), checked), 1);
  seeUpTo(9);  // the move held over 5 frames on heights alone: not yet
  EXPECT_TRUE(heard.empty());
  seeUpTo(12);  // over 8 frames: announced
  ASSERT_EQ(heard.size(), 1u);
  EXPECT_EQ(heard[0].type, ChangeType::Moved);
  EXPECT_FALSE(checked(heard[0]));
  EXPECT_EQ(heard[0].frame, 12u);
  seeUpTo(13);  // the checked addition held over 5 frames
  ASSERT_EQ(heard.size(), 2u);
  EXPECT_EQ(heard[1].type, ChangeType::Added);
  EXPECT_TRUE(checked(heard[1]));
  seeUpTo(15);  // the removal on heights alone needs 16
  EXPECT_EQ(heard.size(), 2u);
  seeUpTo(16);
  ASSERT_EQ(heard.size(), 3u);
  EXPECT_EQ(heard[2].type, ChangeType::Removed);
}

/// A detector that announces what held over 5 frames, what its callbacks heard, the current
/// map, and the table without the box and with it.
struct Settling {
  Config cfg = [] {
    Config c;
    c.event_settle_frames = 5;
    c.event_unscored_settle_frames = 5;
    return c;
  }();
  ChangeDetector det{beforeMap(), cfg};
  std::vector<ChangeEvent> heard;
  Map cur{cfg};
  AnalyticScene without = test::tableWith({cylinderAt(-0.15, -0.10)});
  AnalyticScene with = test::tableWith({box(), cylinderAt(-0.15, -0.10)});
  Settling() {
    det.onEvent([this](const ChangeEvent& e) { heard.push_back(e); });
  }
  void see(const AnalyticScene& scene, const std::vector<Pose>& poses) {
    for (const Pose& T : poses) cur.integrate(test::renderDepth(scene, Intrinsics{}, T), T);
  }
};

TEST(ChangeDetector, AResultLaterFramesContradictIsNeverAnnounced) {
  // As RetractsAChangeLaterFramesContradict, with settling: the removal found from the first
  // views is dropped when the box is seen again, before anyone heard of it.
  Settling s;
  s.see(s.without, test::ringPoses({0, 0, kTable}, 0.9, 0.55, 4));
  s.det.update(s.cur);
  EXPECT_TRUE(s.heard.empty());
  for (int round = 0; round < 4; ++round)
    s.see(s.with, test::ringPoses({0, 0, kTable}, 0.85, 0.5, 8));
  s.det.update(s.cur);
  s.det.finish(s.cur);
  EXPECT_TRUE(s.heard.empty());
  EXPECT_TRUE(s.det.events().empty());
}

TEST(ChangeDetector, RetractsOnlyOnceTheContradictionHeld) {
  Settling s;
  const auto ring = test::ringPoses({0, 0, kTable}, 0.9, 0.55, 4);
  for (int round = 0; round < 2; ++round) {
    s.see(s.without, ring);
    s.det.update(s.cur);  // frames 4, then 8: the removal held over 4 frames
  }
  EXPECT_TRUE(s.heard.empty());
  s.see(s.without, {ring[0]});
  s.det.update(s.cur);  // 5 frames
  std::vector<ChangeEvent>& heard = s.heard;
  ASSERT_EQ(heard.size(), 1u);
  EXPECT_EQ(heard[0].type, ChangeType::Removed);
  EXPECT_EQ(heard[0].status, ChangeStatus::New);
  for (int round = 0; round < 4; ++round)
    s.see(s.with, test::ringPoses({0, 0, kTable}, 0.85, 0.5, 8));
  s.det.update(s.cur);  // not found any more, over 0 frames: still announced
  EXPECT_EQ(heard.size(), 1u);
  EXPECT_EQ(s.det.events().size(), 1u);
  s.see(s.with, test::ringPoses({0, 0, kTable}, 0.85, 0.5, 5));
  s.det.update(s.cur);  // 5 frames: retracted
  ASSERT_EQ(heard.size(), 2u);
  EXPECT_EQ(heard[1].status, ChangeStatus::Retracted);
  EXPECT_EQ(heard[1].id, heard[0].id);
  EXPECT_TRUE(s.det.events().empty());
}

}  // namespace

namespace {

/// A bare room corner as an unorganised cloud (2 cm grid): a 4 x 4 m floor and the two walls at
/// x = 2 and y = 2, 2 m high.
planesdf::PointCloud roomCorner(const planesdf::Pose& T) {
  planesdf::PointCloud c;
  const auto add = [&](double x, double y, double z) {
    c.points.push_back((T * Eigen::Vector3d(x, y, z)).cast<float>());
  };
  for (double a = -2.0; a < 2.0; a += 0.02) {
    for (double b = -2.0; b < 2.0; b += 0.02) add(a, b, 0.0);
    for (double z = 0.02; z < 2.0; z += 0.02) {
      add(2.0, a, z);
      add(a, 2.0, z);
    }
  }
  c.width = static_cast<std::uint32_t>(c.points.size());
  return c;
}

}  // namespace

TEST(SessionCorrection, WallsGiveTheRotationAndTheShiftOfTheDrift) {
  // The current session sees the same corner through a 2 degree / (2, -1.5) cm localisation
  // error: the walls' normals fix the rotation, their offsets the shift across each wall.
  const Pose E = Eigen::Translation3d(0.02, -0.015, 0.0) *
                 Eigen::AngleAxisd(2.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ());
  Config cfg;
  const Map ref = Map::fromCloud(roomCorner(Pose::Identity()), cfg);
  const Map cur = Map::fromCloud(roomCorner(E), cfg);
  ASSERT_GE(ref.planes().size(), 3u);
  const std::vector<PlaneMatch> matches = uniqueMatches(registerPlanes(ref, cur, cfg));
  std::map<std::pair<bool, int>, PlaneMaps> cache;
  const auto maps = [&](bool is_ref, int id) -> const PlaneMaps& {
    auto it = cache.find({is_ref, id});
    if (it == cache.end()) {
      const Map& m = is_ref ? ref : cur;
      it = cache
               .emplace(std::make_pair(is_ref, id),
                        computePlaneMaps(m.planes()[static_cast<std::size_t>(id)], m.planes(), cfg,
                                         nullptr))
               .first;
    }
    return it->second;
  };
  const SessionCorrection c = sessionCorrection(ref, cur, matches, maps, cfg);
  ASSERT_TRUE(c.rigid);
  const double yaw = std::atan2(c.motion.linear()(1, 0), c.motion.linear()(0, 0));
  EXPECT_NEAR(yaw * 180.0 / M_PI, 2.0, 0.1);
  // A point on each wall lands where the drift puts it, within the walls' fit (a few mm).
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(2.0, 0.5, 1.0), Eigen::Vector3d(-0.5, 2.0, 1.0)})
    EXPECT_LT((c.motion * p - E * p).head<2>().norm(), 0.005) << p.transpose();
  // Every pair's in-plane transform follows from it: a wall point maps onto its drifted place.
  for (const PlaneMatch& m : matches) {
    const PlaneMatch k = corrected(m, ref, cur, c);
    const Plane& s = ref.planes()[static_cast<std::size_t>(m.source_id)].plane;
    const Plane& t = cur.planes()[static_cast<std::size_t>(m.target_id)].plane;
    const Eigen::Vector3d p = s.toWorld({0.3, 0.4, 0.0});
    const Eigen::Vector3d q = t.toWorld(k.T_target_source_local * s.toLocal(p));
    EXPECT_LT((q - E * p).norm(), 0.01) << "pair " << m.source_id << " -> " << m.target_id;
  }
}

namespace {

/// A 1.6 m floor as an unorganised cloud on a 5 mm grid, with `extra` points added.
planesdf::PointCloud floorCloudWith(const std::vector<Eigen::Vector3f>& extra) {
  planesdf::PointCloud c;
  for (double x = -0.8; x < 0.8; x += 0.005)
    for (double y = -0.8; y < 0.8; y += 0.005)
      c.points.emplace_back(static_cast<float>(x), static_cast<float>(y), 0.0f);
  c.points.insert(c.points.end(), extra.begin(), extra.end());
  c.width = static_cast<std::uint32_t>(c.points.size());
  return c;
}

/// The faces of an axis-aligned box on the floor (centre (x, y), half size s, height h) sampled
/// every `step` metres.
std::vector<Eigen::Vector3f> boxPoints(double x, double y, double s, double h, double step) {
  std::vector<Eigen::Vector3f> p;
  for (double a = -s; a <= s + 1e-9; a += step) {
    for (double b = -s; b <= s + 1e-9; b += step) p.emplace_back(x + a, y + b, h);
    for (double z = step; z < h; z += step) {
      p.emplace_back(x + a, y - s, z);
      p.emplace_back(x + a, y + s, z);
      p.emplace_back(x - s, y + a, z);
      p.emplace_back(x + s, y + a, z);
    }
  }
  return p;
}

}  // namespace

TEST(ThinSupport, ASparseClusterOverASplattedFloorIsNoiseAndADenseBoxIsAnObject) {
  // The same 10 x 10 x 6 cm box sampled as densely as the floor (5 mm) and a sixth as densely
  // (12 mm: a few flying pixels in the shape of a box), added in the current session of a
  // splatted floor.
  const double dense_step = 0.005, sparse_step = 0.012;
  Config cfg;
  const Map ref = Map::fromCloud(floorCloudWith({}), cfg);
  std::vector<Eigen::Vector3f> extra = boxPoints(0.35, 0.35, 0.05, 0.06, dense_step);
  const std::vector<Eigen::Vector3f> sparse = boxPoints(-0.35, -0.35, 0.05, 0.06, sparse_step);
  extra.insert(extra.end(), sparse.begin(), sparse.end());
  const Map cur = Map::fromCloud(floorCloudWith(extra), cfg);
  ASSERT_TRUE(ref.splatted() && cur.splatted());
  const auto near = [](const ChangeSet& set, double x, double y) {
    return std::count_if(set.events.begin(), set.events.end(), [&](const ChangeEvent& e) {
      return (e.primary().centroid.head<2>() - Eigen::Vector2d(x, y)).norm() < 0.08;
    });
  };
  const ChangeSet kept = detectChanges(ref, cur, cfg);
  EXPECT_EQ(near(kept, 0.35, 0.35), 1);
  EXPECT_EQ(near(kept, -0.35, -0.35), 0);
  EXPECT_EQ(kept.events.size(), 1u);
  // Without the rule the sparse box is an object too: its surface is as high as the dense box's,
  // and its splats close the gaps between its points.
  cfg.thin_support_ratio = 0.0;
  const ChangeSet all = detectChanges(ref, cur, cfg);
  EXPECT_EQ(near(all, 0.35, 0.35), 1);
  EXPECT_EQ(near(all, -0.35, -0.35), 1);
}
