// End-to-end PCD I/O on the real mOSD scenes (PCL-written binary_compressed files).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/pcd.hpp"
#include "test_support.hpp"

namespace planesdf {
namespace {

std::vector<std::string> sceneFiles() {
  std::vector<std::string> files;
  const std::filesystem::path dir = test::mosdDir() + "/scenes";
  if (!std::filesystem::is_directory(dir)) return files;
  for (const auto& e : std::filesystem::directory_iterator(dir))
    if (e.path().extension() == ".pcd") files.push_back(e.path().string());
  std::sort(files.begin(), files.end());
  return files;
}

std::uint32_t bitsOf(float f) {
  std::uint32_t u = 0;
  std::memcpy(&u, &f, 4);
  return u;
}

TEST(MosdIo, EverySceneLoadsAsAnOrganisedKinectFrame) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  const std::vector<std::string> files = sceneFiles();
  ASSERT_GE(files.size(), 20u);
  for (const std::string& path : files) {
    SCOPED_TRACE(path);
    const PointCloud c = io::readPcd(path);
    ASSERT_EQ(c.size(), 307200u);
    EXPECT_EQ(c.width, 640u);
    EXPECT_EQ(c.height, 480u);
    EXPECT_TRUE(c.isOrganized());
    EXPECT_NO_THROW(c.validate(path));

    const std::size_t valid = c.countValid();
    EXPECT_GT(valid, 100000u);  // most of a tabletop Kinect frame is measured
    EXPECT_LT(valid, 307200u);  // ... but not all: NaN holes are kept as invalid points
    std::size_t bad_z = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
      if (!c.isValid(i)) {
        // An invalid pixel is NaN in all coordinates, as PCL writes it.
        EXPECT_TRUE(std::isnan(c.points[i].x()) && std::isnan(c.points[i].z())) << i;
        continue;
      }
      const float z = c.points[i].z();
      if (!(z > 0.3f && z < 5.0f)) ++bad_z;
    }
    EXPECT_EQ(bad_z, 0u);

    ASSERT_TRUE(c.hasColors());
    EXPECT_FALSE(c.hasNormals());
    // Colours are real: not all one value.
    const auto& first = c.colors[c.size() / 2];
    EXPECT_TRUE(std::any_of(c.colors.begin(), c.colors.end(),
                            [&](const auto& col) { return col != first; }));
    const ScalarField* label = c.field("label");
    ASSERT_NE(label, nullptr);
    EXPECT_EQ(label->type, ScalarType::UInt32);
    EXPECT_EQ(label->values.size(), c.size());
    const double max_label = *std::max_element(label->values.begin(), label->values.end());
    EXPECT_GT(max_label, 0.0);  // annotated objects exist
    EXPECT_LT(max_label, 1000.0);
    EXPECT_EQ(c.fields.size(), 1u);
    EXPECT_TRUE(c.sensor_pose.matrix().isIdentity());
  }
}

TEST(MosdIo, CompressedWriteReadRoundTripIsBitExact) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  const std::vector<std::string> files = sceneFiles();
  ASSERT_FALSE(files.empty());
  const PointCloud in = io::readPcd(files.back());
  test::TempDir dir;
  const std::string out_path = dir.file("copy.pcd");
  io::writePcd(out_path, in, io::PcdFormat::BinaryCompressed);
  // LZF is a real compression: the copy is far smaller than the 6 MB of raw SoA data.
  EXPECT_LT(std::filesystem::file_size(out_path), 4000000u);
  const PointCloud out = io::readPcd(out_path);
  ASSERT_EQ(out.size(), in.size());
  EXPECT_EQ(out.width, in.width);
  EXPECT_EQ(out.height, in.height);
  EXPECT_EQ(out.countValid(), in.countValid());
  std::size_t mismatches = 0;
  for (std::size_t i = 0; i < in.size(); ++i) {
    if (in.isValid(i) != out.isValid(i)) ++mismatches;
    if (!in.isValid(i)) continue;
    for (int k = 0; k < 3; ++k) mismatches += bitsOf(in.points[i][k]) != bitsOf(out.points[i][k]);
    mismatches += in.colors[i] != out.colors[i];
  }
  EXPECT_EQ(mismatches, 0u);
  ASSERT_NE(out.field("label"), nullptr);
  EXPECT_EQ(out.field("label")->type, ScalarType::UInt32);
  EXPECT_EQ(out.field("label")->values, in.field("label")->values);
  EXPECT_TRUE(out.sensor_pose.matrix().isIdentity());
}

}  // namespace
}  // namespace planesdf
