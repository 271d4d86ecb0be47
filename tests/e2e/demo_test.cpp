// `planesdf demo` end to end: the built-in default run (simulated tabletop, fixed seed) writes
// its report and detects every simulated change. Seed 1 today: pooled F1 0.979, M 0, W 0 (the
// issue-5 target). The last wrong cluster was a table leg on the floor whose outline the two orbits
// saw differently; it is now the same object in place (sameInPlace), not a change.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "test_support.hpp"

namespace {
using planesdf::test::runCli;
using planesdf::test::TempDir;

// Runs `planesdf demo ARGS --out TMP` and returns its report.json; null (with a test failure
// recorded) when the run fails or writes no report.
nlohmann::json runDemo(const std::string& args, const TempDir& tmp) {
  const auto r = runCli("demo " + args + " --out '" + tmp.path() + "'");
  EXPECT_EQ(r.exit_code, 0) << r.out;
  std::ifstream in(tmp.file("report.json"));
  EXPECT_TRUE(in.good()) << "no report.json after: demo " << args;
  if (r.exit_code != 0 || !in.good()) return nullptr;
  return nlohmann::json::parse(in);
}

// Runs `planesdf detect` on the demo's clouds sim/reference{suffix}.ply and
// sim/current{suffix}.ply and scores it against sim/gt/*{gt_suffix}.ply; null (with a test
// failure recorded) when either step fails.
nlohmann::json detectClouds(const TempDir& tmp, const std::string& suffix,
                            const std::string& gt_suffix) {
  const std::string out = tmp.file("detect" + suffix);
  const auto d = runCli("detect '" + tmp.file("sim/reference" + suffix + ".ply") + "' '" +
                        tmp.file("sim/current" + suffix + ".ply") + "' --out '" + out + "'");
  EXPECT_EQ(d.exit_code, 0) << d.out;
  if (d.exit_code != 0) return nullptr;
  const auto e = runCli("eval '" + out + "' --gt-reference '" +
                        tmp.file("sim/gt/reference" + gt_suffix + ".ply") + "' --gt-current '" +
                        tmp.file("sim/gt/current" + gt_suffix + ".ply") + "' --json");
  EXPECT_EQ(e.exit_code, 0) << e.out;
  if (e.exit_code != 0) return nullptr;
  return nlohmann::json::parse(e.out.substr(e.out.find('{')));
}

TEST(Demo, TabletopFindsEveryChangeAndWritesItsReport) {
  TempDir tmp;
  const nlohmann::json j = runDemo("", tmp);
  ASSERT_FALSE(j.is_null());
  // Every changed object found (3 changes: add, remove, move = 2 objects per side).
  EXPECT_EQ(j["missed"].get<int>(), 0);
  EXPECT_GE(j["recall"].get<double>(), 0.95);
  EXPECT_EQ(j["removed"]["missed"].get<int>(), 0);
  EXPECT_EQ(j["added"]["missed"].get<int>(), 0);
  EXPECT_EQ(j["wrong"].get<int>(), 0);
  EXPECT_GE(j["f1"].get<double>(), 0.9);
  EXPECT_GT(j["timings"]["frames"].get<int>(), 0);
  std::ifstream md(tmp.file("report.md"));
  const std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("| pooled |"), std::string::npos);
  EXPECT_NE(text.find("detect/planes/"), std::string::npos);
  std::ifstream png(tmp.file("detect/planes/ref_1_to_cur_0_raw.png"), std::ios::binary);
  EXPECT_TRUE(png.good());

  // `detect` on the demo's inputs in other forms: the reference as its TUM folder (fused by the
  // CLI, frame by frame as the demo does), the current as the demo's saved map. Same maps, same
  // changes: the scores equal the demo's.
  const std::string det = tmp.file("detect_mixed");
  const auto d = runCli("detect '" + tmp.file("sim/reference") + "' '" + tmp.file("current.psdf") +
                        "' --out '" + det + "'");
  ASSERT_EQ(d.exit_code, 0) << d.out;
  const auto e = runCli("eval '" + det + "' --gt-reference '" + tmp.file("sim/gt/reference.ply") +
                        "' --gt-current '" + tmp.file("sim/gt/current.ply") + "' --json");
  ASSERT_EQ(e.exit_code, 0) << e.out;
  const nlohmann::json m = nlohmann::json::parse(e.out.substr(e.out.find('{')));
  EXPECT_NEAR(m["f1"].get<double>(), j["f1"].get<double>(), 1e-9);
  EXPECT_EQ(m["missed"].get<int>(), j["missed"].get<int>());
  EXPECT_EQ(m["wrong"].get<int>(), j["wrong"].get<int>());

  // The same sessions as whole-scene reconstruction clouds (7 mm TSDF surface points, no normals
  // or viewpoints): splatted maps, rough far surfaces (design.md, "Rough surfaces", "Edges and
  // rims"). Today F1 0.99, M 0, W 0.
  const nlohmann::json r = detectClouds(tmp, "_recon", "_recon");
  ASSERT_FALSE(r.is_null());
  EXPECT_EQ(r["missed"].get<int>(), 0);
  EXPECT_LE(r["wrong"].get<int>(), 1);
  EXPECT_GE(r["f1"].get<double>(), 0.9);
}

TEST(Demo, OtherSeedsRecoverTheirDriftDespiteMovedAndChangedObjects) {
  // Seeds 2-5: 1 cm / 1 degree of localisation error between the sessions. Seed 2 has a moved
  // book stack the refinement must not follow; on seeds 3 and 5 changed objects make most of the
  // table's mismatches, and only the session drift's rings and paired test find the drift
  // (docs/design.md). Measured F1 0.99, 0.99, 0.98, 0.99, W 0 on each.
  for (const int seed : {2, 3, 4, 5}) {
    SCOPED_TRACE(seed);
    TempDir tmp;
    const nlohmann::json j = runDemo("--seed " + std::to_string(seed), tmp);
    ASSERT_FALSE(j.is_null());
    EXPECT_EQ(j["missed"].get<int>(), 0);
    EXPECT_EQ(j["wrong"].get<int>(), 0);
    EXPECT_GE(j["f1"].get<double>(), 0.95);
  }
}

TEST(Demo, AShelfsCompartmentIsItsBoards) {
  // Room seed 14: a 33 cm bottle added on a shelf board 42 cm under the next one. Its top stands
  // above the board's band, in the band of the wall behind the shelf, beside the shelf's back
  // panel; it is the board's (design.md, "A shelf's compartment is its board's"), not a
  // "replaced" cluster of the wall's (W 1, F1 0.55 without the rule).
  TempDir tmp;
  const nlohmann::json j = runDemo("--scene room --seed 14", tmp);
  ASSERT_FALSE(j.is_null());
  EXPECT_EQ(j["wrong"].get<int>(), 0);
  EXPECT_EQ(j["missed"].get<int>(), 0);
  EXPECT_GE(j["f1"].get<double>(), 0.85);
}

TEST(Demo, RoomKeepsWallsShelfAndTableLegsOutOfTheChanges) {
  // The simulated room of seed 1: desks at 0.719 and 0.754 m (two planes, not one tilted plane)
  // and a coffee table, a shelf of 5 boards against a wall, objects on the floor and two walls,
  // a 1 cm / 1 degree localisation error (corrected from the walls). design.md, "Rules beyond
  // the paper": each rule removes wrong clusters of this scene (W 5 before them; the last two,
  // table legs on the floor, went with "Structure through the band").
  TempDir tmp;
  const nlohmann::json j = runDemo("--scene room", tmp);
  ASSERT_FALSE(j.is_null());
  EXPECT_EQ(j["wrong"].get<int>(), 0);
  EXPECT_EQ(j["missed"].get<int>(), 0);
  EXPECT_GE(j["recall"].get<double>(), 0.9);
  EXPECT_GE(j["precision"].get<double>(), 0.85);
  EXPECT_GE(j["f1"].get<double>(), 0.9);

  // The same sessions as whole-scene clouds without normals or viewpoints (design.md, "Unseen
  // above", "Slivers"): the reconstruction (7 mm TSDF surface points) and its mesh's vertices.
  // Raw accumulated clouds are tested on the room suite's scenes (room_suite_test.cpp).
  for (const std::string form : {"_recon", "_mesh"}) {
    const nlohmann::json r = detectClouds(tmp, form, "_recon");
    ASSERT_FALSE(r.is_null()) << form;
    EXPECT_EQ(r["missed"].get<int>(), 0) << form;
    EXPECT_LE(r["wrong"].get<int>(), 2) << form;
    EXPECT_GE(r["f1"].get<double>(), 0.9) << form;
  }
}

}  // namespace
