// Core data structs and the atomic-output helper.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

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
