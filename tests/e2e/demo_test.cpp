// `planesdf demo` end to end: the built-in default run (simulated tabletop, fixed seed) writes
// its report and detects every simulated change. The issue-5 target (F1 >= 0.9, M = W = 0) is not
// met yet: false clusters come from static structure seen differently by the two orbits (table
// legs on the floor and on the table's side plane); the precision bound below is what the
// pipeline reaches today and guards against regressions.
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
  // Not yet the target: see the file comment.
  EXPECT_LE(j["wrong"].get<int>(), 6);
  EXPECT_GE(j["f1"].get<double>(), 0.45);
  EXPECT_GT(j["timings"]["frames"].get<int>(), 0);
  std::ifstream md(tmp.file("report.md"));
  const std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("| pooled |"), std::string::npos);
  EXPECT_NE(text.find("detect/planes/"), std::string::npos);
  std::ifstream png(tmp.file("detect/planes/ref_1_to_cur_0_raw.png"), std::ios::binary);
  EXPECT_TRUE(png.good());
}

}  // namespace
