// The planesdf CLI as a user meets it: help for every subcommand, exit codes, one-line errors
// naming the file, and subcommands whose issue is not done saying so with exit code 2.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <string>

#include "test_support.hpp"

namespace {
using planesdf::test::runCli;
using planesdf::test::TempDir;

int countLines(const std::string& s) {
  return static_cast<int>(std::count(s.begin(), s.end(), '\n'));
}

TEST(Cli, HelpForEverySubcommand) {
  for (const std::string sub : {"demo", "simulate", "fuse", "detect", "eval", "bench", "info"}) {
    const auto r = runCli(sub + " --help");
    EXPECT_EQ(r.exit_code, 0) << sub << ": " << r.out;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << sub;
  }
  const auto top = runCli("--help");
  EXPECT_EQ(top.exit_code, 0);
  for (const char* sub : {"demo", "simulate", "fuse", "detect", "eval"})
    EXPECT_NE(top.out.find(sub), std::string::npos) << sub;
}

TEST(Cli, DetectAndFuseHelpListPipelineFlags) {
  for (const std::string sub : {"fuse", "detect"}) {
    const auto r = runCli(sub + " --help");
    for (const char* flag : {"--up", "--voxel", "--band", "--delta-h", "--intrinsics", "--config"})
      EXPECT_NE(r.out.find(flag), std::string::npos) << sub << " lacks " << flag;
  }
}

TEST(Cli, UsageErrorsExitTwo) {
  EXPECT_EQ(runCli("").exit_code, 2);
  EXPECT_EQ(runCli("frobnicate").exit_code, 2);
  EXPECT_EQ(runCli("eval somedir").exit_code, 2);  // --gt-* missing
  EXPECT_EQ(runCli("demo --scene kitchen").exit_code, 2);
}

TEST(Cli, MissingInputIsOneLineNamingTheFile) {
  TempDir tmp;
  const std::string missing = tmp.file("nope.pcd");
  const auto r = runCli("info '" + missing + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(countLines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find(missing), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("does not exist"), std::string::npos) << r.out;
}

TEST(Cli, CorruptInputIsOneLineNamingTheFile) {
  TempDir tmp;
  const std::string bad = tmp.file("bad.ply");
  planesdf::test::writeBytes(
      bad,
      "ply\nformat ascii 1.0\nelement vertex 1000000000000\n"
      "property float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n");
  const auto r = runCli("info '" + bad + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(countLines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find(bad), std::string::npos) << r.out;
}

TEST(Cli, CloudsWithoutAValidPointAreBadInput) {
  TempDir tmp;
  const std::string nan_ply = tmp.file("nan.ply");
  planesdf::test::writeBytes(nan_ply,
                             "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n"
                             "property float y\nproperty float z\nend_header\n"
                             "nan nan nan\ninf 0 1\n");
  const std::string empty_pcd = tmp.file("empty.pcd");
  planesdf::test::writeBytes(empty_pcd,
                             "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
                             "COUNT 1 1 1\nWIDTH 0\nHEIGHT 1\nPOINTS 0\nDATA ascii\n");
  for (const std::string& f : {nan_ply, empty_pcd}) {
    const auto r = runCli("info '" + f + "'");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_EQ(countLines(r.out), 1) << r.out;
    EXPECT_NE(r.out.find(f), std::string::npos) << r.out;
  }
  EXPECT_NE(runCli("info '" + nan_ply + "'").out.find("NaN or Inf"), std::string::npos);
}

TEST(Cli, RunningOutOfMemoryIsOneLineNamingTheInput) {
  // Two 2 m x 2 m planes at 4 mm spacing fused at 2 mm voxels need about 1.4 GB; under an
  // 800 MB address-space limit an allocation fails below the memory budget's estimate.
  TempDir tmp;
  const std::string cloud = tmp.file("planes.ply");
  std::string body;
  int n = 0;
  for (int i = 0; i < 500; ++i)
    for (int j = 0; j < 500; ++j)
      for (const std::array<float, 3>& p : {std::array<float, 3>{0.004f * i, 0.004f * j, 0.0f},
                                            std::array<float, 3>{0.004f * i, 0.0f, 0.004f * j}}) {
        body.append(reinterpret_cast<const char*>(p.data()), sizeof(p));
        ++n;
      }
  planesdf::test::writeBytes(cloud, "ply\nformat binary_little_endian 1.0\nelement vertex " +
                                        std::to_string(n) +
                                        "\nproperty float x\nproperty float y\nproperty float "
                                        "z\nend_header\n" +
                                        body);
  const std::string out = tmp.file("map.psdf");
  const auto r =
      runCli("fuse '" + cloud + "' --out '" + out + "' --voxel 0.002", "ulimit -v 800000; ");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_EQ(countLines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find("fusing " + cloud + ": out of memory"), std::string::npos) << r.out;
  EXPECT_FALSE(std::filesystem::exists(out));
}

TEST(Cli, FolderThatIsNotATumSequence) {
  TempDir tmp;
  const auto r = runCli("info '" + tmp.path() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(countLines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find(tmp.path()), std::string::npos) << r.out;
}

TEST(Cli, InfoOnRealMosdScene) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  const auto r = runCli("info '" + planesdf::test::mosdDir() + "/scenes/learn0.pcd'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("307200"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("organised 640x480"), std::string::npos) << r.out;
}

TEST(Cli, BenchRejectsANegativeFrameCount) {
  // `bench` itself is tested in bench_cli_test.cpp.
  const auto r = runCli("bench --frames -1");
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("--frames"), std::string::npos) << r.out;
  EXPECT_EQ(countLines(r.out), 1) << r.out;
}

TEST(Cli, InfoOnASessionMapListsItsPlanes) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  TempDir tmp;
  const std::string map = tmp.file("learn0.psdf");
  const auto fused =
      runCli("fuse '" + planesdf::test::mosdDir() + "/scenes/learn0.pcd' --out '" + map + "'");
  ASSERT_EQ(fused.exit_code, 0) << fused.out;
  const auto r = runCli("info '" + map + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("session map"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("plane 0: horizontal"), std::string::npos) << r.out;  // the table
  EXPECT_NE(r.out.find(" blocks, "), std::string::npos) << r.out;
  // A truncated map is bad input: one line naming the file.
  const std::string cut = tmp.file("cut.psdf");
  planesdf::test::writeBytes(cut, "PSDF");
  const auto bad = runCli("info '" + cut + "'");
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_EQ(countLines(bad.out), 1) << bad.out;
  EXPECT_NE(bad.out.find(cut), std::string::npos) << bad.out;
}

}  // namespace
