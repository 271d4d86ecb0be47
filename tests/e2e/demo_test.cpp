// `planesdf demo` end to end: the built-in default run (simulated tabletop, fixed seed) writes
// its report and detects every simulated change. Seed 1 today: pooled F1 0.979, M 0, W 0 (the
// issue-5 target). The last wrong cluster was a table leg on the floor whose outline the two orbits
// saw differently; it is now the same object in place (sameInPlace), not a change.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "test_support.hpp"

namespace {
using planesdf::test::runCli;
using planesdf::test::TempDir;

TEST(Demo, TabletopFindsEveryChangeAndWritesItsReport) {
  TempDir tmp;
  const auto r = runCli("demo --out '" + tmp.path() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  std::ifstream in(tmp.file("report.json"));
  ASSERT_TRUE(in.good());
  const nlohmann::json j = nlohmann::json::parse(in);
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
}

TEST(Demo, RoomKeepsWallsFloorAndFarTablePlaneOutOfTheChanges) {
  // The simulated room (seed 1: two tables merged into one plane, a shelf, four walls, an object
  // hung on a wall). Before the wall-structure rule and the support limit of computePlaneMaps,
  // the walls' noisy surfaces and the merged table plane's band across the room made 73 events
  // (W 121, F1 0.03); now W 11, M 2, F1 0.10. What is left: the shelf and the table legs seen
  // differently by the two sessions, far-wall speckle; the swap on the shelf's top board (no plane
  // under it: M 2, its removed and its added object) is missed.
  TempDir tmp;
  const auto r = runCli("demo --scene room --out '" + tmp.path() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  std::ifstream in(tmp.file("report.json"));
  ASSERT_TRUE(in.good());
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_LE(j["wrong"].get<int>(), 15);
  EXPECT_LE(j["missed"].get<int>(), 2);
  EXPECT_GE(j["recall"].get<double>(), 0.8);
  EXPECT_GE(j["f1"].get<double>(), 0.08);
}

}  // namespace
