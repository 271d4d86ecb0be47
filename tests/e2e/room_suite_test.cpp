// Pairs of the room suite (`planesdf bench --suite`, one change per room) and one of its tabletop
// pairs, rendered again from the scenes the suite wrote (tests/data/scenes/): the TUM streams
// and the reconstruction clouds through `detect`, scored by `eval`.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "test_support.hpp"

namespace {
using planesdf::test::runCli;
using planesdf::test::TempDir;

std::string sceneFile(const std::string& name) {
  return std::string(PLANESDF_TEST_DATA_DIR) + "/scenes/" + name + ".json";
}

// `detect REF CUR` then `eval` against the simulation's ground truth `sim/gt/*{gt}.ply`; null
// (with a failure recorded) when a step fails.
nlohmann::json detectAndScore(const TempDir& tmp, const std::string& ref, const std::string& cur,
                              const std::string& gt, const std::string& out) {
  const auto d = runCli("detect '" + tmp.file(ref) + "' '" + tmp.file(cur) + "' --out '" +
                        tmp.file(out) + "'");
  EXPECT_EQ(d.exit_code, 0) << d.out;
  if (d.exit_code != 0) return nullptr;
  const auto e = runCli("eval '" + tmp.file(out) + "' --gt-reference '" +
                        tmp.file("sim/gt/reference" + gt + ".ply") + "' --gt-current '" +
                        tmp.file("sim/gt/current" + gt + ".ply") + "' --json");
  EXPECT_EQ(e.exit_code, 0) << e.out;
  if (e.exit_code != 0) return nullptr;
  return nlohmann::json::parse(e.out.substr(e.out.find('{')));
}

struct PairExpectation {
  const char* scene;
  double recon_min_f1;  ///< the reconstruction clouds' least F1
};

TEST(RoomSuite, ShelfBoardsNearEyeHeightAndTableLegsAreNoChange) {
  // room04: a sphere moved 3 cm on a desk, a shelf of 5 boards whose upper two are seen only
  // foreshortened (design.md, "Boards near eye height are foreshortened"). room06: an object
  // replaced on a desk; a table leg's top seen a cell apart by the two sessions (design.md,
  // "Structure through the band"). In the reconstructions the sphere's 3 cm move is narrower
  // than a rim; it is found where the sphere fits the other map shifted, and reported whole
  // (design.md, "Small moves"). The replaced object is lower than the new one: both are reported
  // whole, not only where one stands above the other (design.md, "Changed objects whole").
  for (const PairExpectation& p :
       {PairExpectation{"room04_small_move", 0.9}, PairExpectation{"room06_replace", 0.95}}) {
    SCOPED_TRACE(p.scene);
    TempDir tmp;
    const auto sim =
        runCli("simulate --scene '" + sceneFile(p.scene) + "' --out '" + tmp.file("sim") + "'");
    ASSERT_EQ(sim.exit_code, 0) << sim.out;
    const nlohmann::json s = detectAndScore(tmp, "sim/reference", "sim/current", "", "streams");
    ASSERT_FALSE(s.is_null());
    EXPECT_EQ(s["wrong"].get<int>(), 0);
    EXPECT_EQ(s["missed"].get<int>(), 0);
    EXPECT_GE(s["f1"].get<double>(), 0.9);
    const nlohmann::json r =
        detectAndScore(tmp, "sim/reference_recon.ply", "sim/current_recon.ply", "_recon", "recon");
    ASSERT_FALSE(r.is_null());
    EXPECT_EQ(r["wrong"].get<int>(), 0);
    EXPECT_GE(r["f1"].get<double>(), p.recon_min_f1);
  }
}

// Two objects of different sizes swap places on a desk: of the smaller one only the ring the
// larger one leaves uncovered changes height, but the larger one's moves land on it whole, and
// both moves are reported whole (design.md, "Swaps").
TEST(RoomSuite, ASwapOfObjectsOfDifferentSizesIsTwoWholeMoves) {
  TempDir tmp;
  const auto sim =
      runCli("simulate --scene '" + sceneFile("room05_swap") + "' --out '" + tmp.file("sim") + "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.out;
  for (const bool recon : {false, true}) {
    SCOPED_TRACE(recon ? "reconstruction clouds" : "streams");
    const nlohmann::json r =
        recon ? detectAndScore(tmp, "sim/reference_recon.ply", "sim/current_recon.ply", "_recon",
                               "recon")
              : detectAndScore(tmp, "sim/reference", "sim/current", "", "streams");
    ASSERT_FALSE(r.is_null());
    EXPECT_EQ(r["wrong"].get<int>(), 0);
    EXPECT_EQ(r["missed"].get<int>(), 0);
    // Recall: the smaller object's ring alone leaves out most of its points.
    EXPECT_GE(r["recall"].get<double>(), 0.9);
    EXPECT_GE(r["f1"].get<double>(), 0.9);
  }
}

/// Scores room pair `scene` as raw accumulated clouds: every frame's points of a session, noise
/// included, without viewpoints.
nlohmann::json scoreRawPair(const TempDir& tmp, const std::string& scene) {
  const auto sim =
      runCli("simulate --scene '" + sceneFile(scene) + "' --out '" + tmp.file("sim") + "'");
  EXPECT_EQ(sim.exit_code, 0) << sim.out;
  if (sim.exit_code != 0) return nullptr;
  return detectAndScore(tmp, "sim/reference.ply", "sim/current.ply", "", "raw");
}

/// Expects `dir`/changes.json to hold one event, of type `type`.
void expectOneEvent(const TempDir& tmp, const std::string& dir, const std::string& type) {
  std::ifstream in(tmp.file(dir + "/changes.json"));
  ASSERT_TRUE(in) << "no changes.json";
  const nlohmann::json events = nlohmann::json::parse(in);
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0]["type"].get<std::string>(), type);
}

// Stray points over far walls and flying pixels at depth edges splat into thin blobs that rest
// on a fraction of the points of the surfaces around them (design.md, "Thin support").
TEST(RoomSuite, RawCloudsOfAnUnchangedRoomShowNoChange) {
  TempDir tmp;
  const nlohmann::json r = scoreRawPair(tmp, "room00_none");
  ASSERT_FALSE(r.is_null());
  EXPECT_EQ(r["wrong"].get<int>(), 0);
  EXPECT_EQ(r["predicted_clusters"].get<int>(), 0);
}

TEST(RoomSuite, RawCloudsShowARemovedObjectAndNothingElse) {
  TempDir tmp;
  const nlohmann::json r = scoreRawPair(tmp, "room02_remove");
  ASSERT_FALSE(r.is_null());
  EXPECT_EQ(r["wrong"].get<int>(), 0);
  EXPECT_EQ(r["missed"].get<int>(), 0);
  EXPECT_GE(r["f1"].get<double>(), 0.9);
}

// A 9 cm sphere moved 3 cm on a desk: two crescents no wider than a splatted rim, slivers of the
// sphere in both maps. Its interior fits the other map shifted by the move: one moved event with
// the whole sphere on both sides (design.md, "Small moves").
TEST(RoomSuite, RawCloudsShowASmallMoveAsOneMovedObject) {
  TempDir tmp;
  const nlohmann::json r = scoreRawPair(tmp, "room04_small_move");
  ASSERT_FALSE(r.is_null());
  EXPECT_EQ(r["wrong"].get<int>(), 0);
  EXPECT_EQ(r["missed"].get<int>(), 0);
  EXPECT_GE(r["f1"].get<double>(), 0.9);
  expectOneEvent(tmp, "raw", "moved");
}

// A box on a wall replaced by a wider, thinner torus: the torus's only blob is its ring outside
// the box, a sliver with little 3D evidence, which joins the box's removal as its replacement
// (design.md, "Supporting slivers"); both objects are reported whole.
TEST(RoomSuite, RawCloudsShowABoxReplacedByAWiderThinnerTorus) {
  TempDir tmp;
  const nlohmann::json r = scoreRawPair(tmp, "room20_replace");
  ASSERT_FALSE(r.is_null());
  EXPECT_EQ(r["wrong"].get<int>(), 0);
  EXPECT_EQ(r["missed"].get<int>(), 0);
  EXPECT_GE(r["f1"].get<double>(), 0.9);
  expectOneEvent(tmp, "raw", "replaced");
}

// Tabletop suite pair 25: 2.2 cm and 0.75 degrees of drift, a wide cone moved 3 cm. A rotation
// of 3.5 degrees about a point near the torus drags the cone's old place onto its new one and fits
// a few cells better than the drift; the drift prefers the smaller motion (design.md, "The
// session's drift prefers the smaller motion"), so no static object is reported.
TEST(TabletopSuite, ASmallMoveUnderDriftDragsNoStaticObject) {
  TempDir tmp;
  const auto sim = runCli("simulate --scene '" + sceneFile("tabletop25_small_move") + "' --out '" +
                          tmp.file("sim") + "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.out;
  const nlohmann::json s = detectAndScore(tmp, "sim/reference", "sim/current", "", "streams");
  ASSERT_FALSE(s.is_null());
  EXPECT_EQ(s["wrong"].get<int>(), 0);
}

}  // namespace
