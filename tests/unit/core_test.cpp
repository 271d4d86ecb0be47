// Core data structs and the atomic-output helper.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <csignal>

#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <vector>

#include "io/atomic_file_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/types.hpp"
#include "test_support.hpp"

namespace {
namespace fs = std::filesystem;
using planesdf::Error;
using planesdf::PointCloud;
using planesdf::test::TempDir;

std::string slurp(const std::string& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(AtomicFile, WritesAndReplaces) {
  TempDir tmp;
  const std::string p = tmp.file("out.txt");
  planesdf::io::writeFileAtomic(p, [](std::ostream& o) { o << "first"; });
  EXPECT_EQ(slurp(p), "first");
  planesdf::io::writeFileAtomic(p, [](std::ostream& o) { o << "second"; });
  EXPECT_EQ(slurp(p), "second");
  EXPECT_EQ(std::distance(fs::directory_iterator(tmp.path()), fs::directory_iterator{}), 1);
}

TEST(AtomicFile, FailedWriteKeepsOldFileAndLeavesNoTemporary) {
  TempDir tmp;
  const std::string p = tmp.file("out.txt");
  planesdf::io::writeFileAtomic(p, [](std::ostream& o) { o << "good"; });
  EXPECT_THROW(planesdf::io::writeFileAtomic(p,
                                             [](std::ostream& o) {
                                               o << "half";
                                               throw Error("x", "simulated failure");
                                             }),
               Error);
  EXPECT_EQ(slurp(p), "good");
  EXPECT_EQ(std::distance(fs::directory_iterator(tmp.path()), fs::directory_iterator{}), 1);
}

TEST(AtomicFile, MissingFolderNamesThePath) {
  TempDir tmp;
  const std::string p = tmp.file("no/such/folder/out.txt");
  try {
    planesdf::io::writeFileAtomic(p, [](std::ostream& o) { o << "x"; });
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), p);
    EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos) << e.what();
  }
}

std::vector<std::string> entries(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

bool supportsAnonymousFiles(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_TMPFILE | O_WRONLY, 0600);
  if (fd >= 0) ::close(fd);
  return fd >= 0;
}

TEST(AtomicFile, NamedFallbackWritesReplacesAndCleansUp) {
  TempDir tmp;
  const std::string p = tmp.file("out.txt");
  planesdf::io::writeFileAtomic(
      p, [](std::ostream& o) { o << "first"; }, false);
  planesdf::io::writeFileAtomic(
      p, [](std::ostream& o) { o << std::string(200000, 'x'); }, false);
  EXPECT_EQ(slurp(p), std::string(200000, 'x'));
  EXPECT_THROW(planesdf::io::writeFileAtomic(
                   p, [](std::ostream&) { throw Error("x", "simulated failure"); }, false),
               Error);
  EXPECT_EQ(entries(tmp.path()), std::vector<std::string>{"out.txt"});
}

TEST(AtomicFile, KillDuringWriteLeavesOnlyTheOldFile) {
  // The temporary file has no name until it is complete: a SIGKILL mid-write leaves nothing.
  // (The death test forks, so the child writes into this test's folder.)
  TempDir tmp;
  if (!supportsAnonymousFiles(tmp.path())) GTEST_SKIP() << "no O_TMPFILE on " << tmp.path();
  const std::string p = tmp.file("map.psdf");
  planesdf::io::writeFileAtomic(p, [](std::ostream& o) { o << "old"; });
  EXPECT_EXIT(planesdf::io::writeFileAtomic(p,
                                            [](std::ostream& o) {
                                              o << std::string(300000, 'n');
                                              o.flush();
                                              std::raise(SIGKILL);
                                            }),
              ::testing::KilledBySignal(SIGKILL), "");
  EXPECT_EQ(entries(tmp.path()), std::vector<std::string>{"map.psdf"});
  EXPECT_EQ(slurp(p), "old");
}

TEST(AtomicFile, TheNextReplacementRemovesAKilledRunsTemporaryButNotARunningOnes) {
  // A run killed between naming its finished file and the rename leaves `.NAME.tmpXXXXXX`; a
  // running writer holds its temporary file locked.
  TempDir tmp;
  const std::string p = tmp.file("map.psdf");
  planesdf::io::writeFileAtomic(p, [](std::ostream& o) { o << "old"; });
  planesdf::test::writeBytes(tmp.file(".map.psdf.tmpdead01"), "killed");
  planesdf::test::writeBytes(tmp.file(".map.psdf.tmplive01"), "running");
  planesdf::test::writeBytes(tmp.file(".other.psdf.tmpdead02"), "another file's");
  planesdf::test::writeBytes(tmp.file(".map.psdf.tmpdead0123"), "not a temporary name");
  const int held = ::open(tmp.file(".map.psdf.tmplive01").c_str(), O_RDONLY);
  ASSERT_GE(held, 0);
  ASSERT_EQ(::flock(held, LOCK_EX), 0);
  for (bool anonymous : {true, false}) {
    planesdf::io::writeFileAtomic(
        p, [](std::ostream& o) { o << "new"; }, anonymous);
    EXPECT_EQ(slurp(p), "new");
    EXPECT_EQ(entries(tmp.path()),
              (std::vector<std::string>{".map.psdf.tmpdead0123", ".map.psdf.tmplive01",
                                        ".other.psdf.tmpdead02", "map.psdf"}));
    planesdf::test::writeBytes(tmp.file(".map.psdf.tmpdead01"), "killed");
  }
  ::close(held);
}

void writeFolder(const std::string& dir, const std::vector<std::string>& files,
                 const std::string& text) {
  for (const std::string& f : files) {
    fs::create_directories(fs::path(dir + "/" + f).parent_path());
    planesdf::test::writeBytes(dir + "/" + f, text);
  }
}

TEST(ReplaceFolder, TheNewFolderReplacesTheOldOneWhole) {
  TempDir tmp;
  const std::string out = tmp.file("out");
  writeFolder(out, {"a.txt", "planes/old.png"}, "old");
  planesdf::io::replaceFolderAtomic(
      out, [](const std::string& d) { writeFolder(d, {"a.txt"}, "new"); },
      [](const std::string&) { return true; });
  EXPECT_EQ(entries(out), std::vector<std::string>{"a.txt"});
  EXPECT_EQ(slurp(out + "/a.txt"), "new");
  EXPECT_EQ(entries(tmp.path()), std::vector<std::string>{"out"});
  // The folder gets the permissions of any new folder (umask), not a private temporary's.
  fs::create_directory(tmp.file("plain"));
  EXPECT_EQ(fs::status(out).permissions(), fs::status(tmp.file("plain")).permissions());
}

TEST(ReplaceFolder, FailedOrRefusedBuildKeepsTheOldFolder) {
  TempDir tmp;
  const std::string out = tmp.file("out");
  writeFolder(out, {"a.txt", "b.txt"}, "old");
  EXPECT_THROW(planesdf::io::replaceFolderAtomic(
                   out,
                   [](const std::string& d) {
                     writeFolder(d, {"a.txt"}, "new");
                     throw Error(d, "simulated failure");
                   },
                   [](const std::string&) { return true; }),
               Error);
  EXPECT_THROW(planesdf::io::replaceFolderAtomic(
                   out, [](const std::string&) {}, [](const std::string&) { return false; }),
               Error);
  EXPECT_EQ(entries(out), (std::vector<std::string>{"a.txt", "b.txt"}));
  EXPECT_EQ(slurp(out + "/a.txt"), "old");
  EXPECT_EQ(entries(tmp.path()), std::vector<std::string>{"out"});
}

TEST(ReplaceFolder, KillDuringBuildKeepsTheOldFolderAndTheNextRunRemovesTheLeftover) {
  TempDir tmp;
  const std::string out = tmp.file("out");
  writeFolder(out, {"a.txt", "b.txt"}, "old");
  const auto any = [](const std::string&) { return true; };
  EXPECT_EXIT(planesdf::io::replaceFolderAtomic(
                  out,
                  [](const std::string& d) {
                    writeFolder(d, {"a.txt"}, "new");
                    std::raise(SIGKILL);
                  },
                  any),
              ::testing::KilledBySignal(SIGKILL), "");
  EXPECT_EQ(entries(out), (std::vector<std::string>{"a.txt", "b.txt"}));
  EXPECT_EQ(slurp(out + "/a.txt"), "old");
  ASSERT_EQ(entries(tmp.path()).size(), 2u);  // out and the killed run's out.tmpXXXXXX
  planesdf::io::replaceFolderAtomic(
      out, [](const std::string& d) { writeFolder(d, {"c.txt"}, "new"); }, any);
  EXPECT_EQ(entries(tmp.path()), std::vector<std::string>{"out"});
  EXPECT_EQ(entries(out), std::vector<std::string>{"c.txt"});
}

TEST(ReplaceFolder, NewFolderTrailingSlashAndFileInTheWay) {
  TempDir tmp;
  const auto any = [](const std::string&) { return true; };
  const auto build = [](const std::string& d) { writeFolder(d, {"a.txt"}, "new"); };
  planesdf::io::replaceFolderAtomic(tmp.file("sub/new/"), build, any);
  EXPECT_EQ(slurp(tmp.file("sub/new/a.txt")), "new");
  EXPECT_EQ(entries(tmp.file("sub")), std::vector<std::string>{"new"});
  EXPECT_THROW(planesdf::io::replaceFolderAtomic("", build, any), Error);  // not the cwd
  planesdf::test::writeBytes(tmp.file("file"), "x");
  try {
    planesdf::io::replaceFolderAtomic(tmp.file("file"), build, any);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), tmp.file("file"));
    EXPECT_NE(std::string(e.what()).find("not a folder"), std::string::npos) << e.what();
  }
}

TEST(ReadFile, MissingAndFolderInputs) {
  TempDir tmp;
  try {
    planesdf::io::readFile(tmp.file("missing.bin"));
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.bin: file does not exist"), std::string::npos);
  }
  try {
    planesdf::io::readFile(tmp.path());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("is a folder"), std::string::npos) << e.what();
  }
  // A FIFO would block the reader until a writer came: refused before it is opened.
  const std::string fifo = tmp.file("pipe.pcd");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  try {
    planesdf::io::readFile(fifo);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("pipe.pcd: not a regular file"), std::string::npos)
        << e.what();
  }
}

TEST(PointCloud, ValidityFieldsAndConsistency) {
  PointCloud c;
  c.points = {{0, 0, 1}, {std::numeric_limits<float>::quiet_NaN(), 0, 1}, {1, 1, 1}};
  c.width = 3;
  EXPECT_EQ(c.countValid(), 2u);
  EXPECT_FALSE(c.isValid(1));
  auto& f = c.addField("object_id", planesdf::ScalarType::Int32, 7);
  EXPECT_EQ(f.values.size(), 3u);
  ASSERT_NE(c.field("object_id"), nullptr);
  EXPECT_EQ(c.field("object_id")->values[2], 7.0);
  EXPECT_EQ(c.field("nope"), nullptr);
  EXPECT_NO_THROW(c.validate());
  c.colors.resize(2);
  EXPECT_THROW(c.validate("cloud.ply"), Error);
  c.colors.clear();
  c.width = 2;
  try {
    c.validate("cloud.ply");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cloud.ply: width*height"), std::string::npos);
  }
}

TEST(Intrinsics, RejectsNonsense) {
  planesdf::Intrinsics k;
  EXPECT_NO_THROW(k.validate());
  k.fx = -1;
  EXPECT_THROW(k.validate("intrinsics.txt"), Error);
  k.fx = 525;
  k.cy = std::numeric_limits<double>::infinity();
  EXPECT_THROW(k.validate(), Error);
  k.cy = 239.5;
  k.width = 100000;
  EXPECT_THROW(k.validate(), Error);
}

TEST(CloudDispatch, UnknownExtension) {
  try {
    planesdf::io::readCloud("scene.xyz");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("scene.xyz"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("extension"), std::string::npos);
  }
}

}  // namespace
