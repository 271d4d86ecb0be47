#include "planesdf/io/tum.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "planesdf/error.hpp"
#include "test_support.hpp"

namespace planesdf::io {
namespace {
namespace fs = std::filesystem;
using planesdf::test::TempDir;
using planesdf::test::writeBytes;

using test::kPi;

// ---- a tiny PNG encoder (stored deflate blocks), so the tests need no OpenCV --------------------

std::uint32_t crc32(const std::string& bytes) {
  std::uint32_t crc = 0xFFFFFFFFu;
  for (const char ch : bytes) {
    crc ^= static_cast<unsigned char>(ch);
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return crc ^ 0xFFFFFFFFu;
}

std::string bigEndian32(std::uint32_t v) {
  return {static_cast<char>(v >> 24), static_cast<char>(v >> 16), static_cast<char>(v >> 8),
          static_cast<char>(v)};
}

std::string pngChunk(const std::string& type, const std::string& data) {
  return bigEndian32(static_cast<std::uint32_t>(data.size())) + type + data +
         bigEndian32(crc32(type + data));
}

std::string zlibStored(const std::string& raw) {
  std::string out = "\x78\x01";
  std::size_t pos = 0;
  do {
    const std::size_t n = std::min<std::size_t>(65535, raw.size() - pos);
    const bool last = pos + n == raw.size();
    out += static_cast<char>(last ? 1 : 0);
    out += static_cast<char>(n & 0xFF);
    out += static_cast<char>(n >> 8);
    out += static_cast<char>(~n & 0xFF);
    out += static_cast<char>((~n >> 8) & 0xFF);
    out += raw.substr(pos, n);
    pos += n;
  } while (pos < raw.size());
  std::uint32_t a = 1, b = 0;
  for (const char ch : raw) {
    a = (a + static_cast<unsigned char>(ch)) % 65521;
    b = (b + a) % 65521;
  }
  return out + bigEndian32((b << 16) | a);
}

/// A PNG of `channels` samples per pixel (row-major `samples`), `bit_depth` 8 or 16.
std::string makePng(int width, int height, int bit_depth, int color_type, int channels,
                    const std::vector<std::uint16_t>& samples) {
  std::string ihdr = bigEndian32(width) + bigEndian32(height);
  ihdr += static_cast<char>(bit_depth);
  ihdr += static_cast<char>(color_type);
  ihdr += std::string(3, '\0');
  std::string raw;
  for (int v = 0; v < height; ++v) {
    raw += '\0';  // filter: none
    for (int i = 0; i < width * channels; ++i) {
      const std::uint16_t s = samples[static_cast<std::size_t>(v) * width * channels + i];
      if (bit_depth == 16) raw += static_cast<char>(s >> 8);
      raw += static_cast<char>(s & 0xFF);
    }
  }
  return std::string("\x89PNG\r\n\x1A\n", 8) + pngChunk("IHDR", ihdr) +
         pngChunk("IDAT", zlibStored(raw)) + pngChunk("IEND", "");
}

// ---- fixtures -----------------------------------------------------------------------------------

Intrinsics smallIntrinsics() {
  Intrinsics k;
  k.fx = 50.0;
  k.fy = 51.0;
  k.cx = 31.5;
  k.cy = 23.5;
  k.width = 64;
  k.height = 48;
  return k;
}

Pose makePose(double angle, const Eigen::Vector3d& axis, const Eigen::Vector3d& t) {
  Pose p = Pose::Identity();
  p.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  p.translation() = t;
  return p;
}

/// Writes depth.txt, groundtruth.txt and (when non-empty) intrinsics.txt into `dir`.
void writeIndex(const TempDir& dir, const std::string& depth, const std::string& groundtruth,
                const std::string& intrinsics = "") {
  writeBytes(dir.file("depth.txt"), depth);
  writeBytes(dir.file("groundtruth.txt"), groundtruth);
  if (!intrinsics.empty()) writeBytes(dir.file("intrinsics.txt"), intrinsics);
}

const char* const kSmallIntrinsicsTxt =
    "fx 50\nfy 51\ncx 31.5\ncy 23.5\nwidth 64\nheight 48\ndepth_scale 1000\n";

/// Expects `f` to throw planesdf::Error whose what() contains `path` and `keyword`.
void expectError(const std::function<void()>& f, const std::string& path,
                 const std::string& keyword) {
  try {
    f();
    ADD_FAILURE() << "no error thrown; expected one naming " << path << " with '" << keyword << "'";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(path), std::string::npos) << what;
    EXPECT_NE(what.find(keyword), std::string::npos) << what;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "not a planesdf::Error: " << e.what();
  }
}

double angleBetween(const Pose& a, const Pose& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

// ---- round trip ---------------------------------------------------------------------------------

TEST(Tum, WriteThenReadRoundTrip) {
  TempDir dir;
  const std::string folder = dir.file("seq");
  const Intrinsics k = smallIntrinsics();
  std::vector<DepthFrame> frames;
  std::vector<Pose> poses;
  for (int i = 0; i < 5; ++i) {
    DepthFrame f;
    f.intrinsics = k;
    f.timestamp = 1305031102.175304 + 0.033 * i;
    for (int v = 0; v < k.height; ++v)
      for (int u = 0; u < k.width; ++u)
        f.depth.push_back(
            (u + v) % 7 == 0 ? 0.0f : static_cast<float>(0.4 + 0.013 * u + 0.007 * v + 0.1 * i));
    f.depth[1 * k.width + 1] = std::nanf("");
    f.depth[2 * k.width + 1] = -1.0f;
    frames.push_back(f);
    poses.push_back(makePose(0.3 * i, {1, 2, 3}, {0.1 * i, -0.2 * i, 1.5 + 0.05 * i}));
  }
  writeTumSequence(folder, frames, poses, 1000.0);
  EXPECT_TRUE(fs::is_regular_file(folder + "/depth/1305031102.175304.png"));
  EXPECT_TRUE(isTumFolder(folder));

  const TumSequence seq = readTumSequence(folder);
  ASSERT_EQ(seq.frames.size(), 5u);
  EXPECT_EQ(seq.dropped_frames, 0u);
  EXPECT_EQ(seq.depth_scale, 1000.0);
  EXPECT_EQ(seq.intrinsics.fx, 50.0);
  EXPECT_EQ(seq.intrinsics.fy, 51.0);
  EXPECT_EQ(seq.intrinsics.cx, 31.5);
  EXPECT_EQ(seq.intrinsics.cy, 23.5);
  EXPECT_EQ(seq.intrinsics.width, 64);
  EXPECT_EQ(seq.intrinsics.height, 48);
  for (std::size_t i = 0; i < 5; ++i) {
    EXPECT_NEAR(seq.frames[i].timestamp, frames[i].timestamp, 1e-6);
    EXPECT_LT((seq.frames[i].pose.matrix() - poses[i].matrix()).cwiseAbs().maxCoeff(), 1e-9) << i;
    const DepthFrame d = loadTumDepth(seq, i);
    EXPECT_EQ(d.timestamp, seq.frames[i].timestamp);
    ASSERT_EQ(d.depth.size(), frames[i].depth.size());
    for (std::size_t p = 0; p < d.depth.size(); ++p) {
      const float want = frames[i].depth[p];
      if (DepthFrame::isValidDepth(want))
        ASSERT_NEAR(d.depth[p], want, 0.5 / 1000.0 + 1e-6) << "frame " << i << " pixel " << p;
      else
        ASSERT_EQ(d.depth[p], 0.0f) << "frame " << i << " pixel " << p;
    }
  }
}

TEST(Tum, WriteDepthPngRoundsClampsAndZeroesInvalid) {
  TempDir dir;
  DepthFrame f;
  f.intrinsics.width = 6;
  f.intrinsics.height = 1;
  f.depth = {0.0f, std::nanf(""), -2.0f, 1.2344f, 1.2346f, 100.0f};
  writeDepthPng(dir.file("d.png"), f, 1000.0);
  const DepthFrame d = readDepthPng(dir.file("d.png"), f.intrinsics, 1000.0);
  ASSERT_EQ(d.depth.size(), 6u);
  EXPECT_EQ(d.depth[0], 0.0f);
  EXPECT_EQ(d.depth[1], 0.0f);
  EXPECT_EQ(d.depth[2], 0.0f);
  EXPECT_FLOAT_EQ(d.depth[3], 1.234f);   // 1234.4 rounds down
  EXPECT_FLOAT_EQ(d.depth[4], 1.235f);   // 1234.6 rounds up
  EXPECT_FLOAT_EQ(d.depth[5], 65.535f);  // clamped to 65535
}

// ---- association --------------------------------------------------------------------------------

TEST(Tum, InterpolatesBetweenBracketingPoses) {
  TempDir dir;
  // Pose at 1.00: identity; at 1.05: 60 degrees about z, translation (1, 2, 3).
  writeIndex(dir, "# depth\n1.025 depth/a.png\n1.01 depth/b.png\n",
             "# timestamp tx ty tz qx qy qz qw\n"
             "1.00 0 0 0 0 0 0 1\n"
             "1.05 1 2 3 0 0 0.5 0.86602540378443865\n",
             kSmallIntrinsicsTxt);
  const TumSequence seq = readTumSequence(dir.path());
  ASSERT_EQ(seq.frames.size(), 2u);
  EXPECT_EQ(seq.dropped_frames, 0u);
  const Pose identity = Pose::Identity();

  const TumFrame& b = seq.frames[0];  // t = 1.01: alpha 0.2
  EXPECT_DOUBLE_EQ(b.timestamp, 1.01);
  EXPECT_LT((b.pose.translation() - Eigen::Vector3d(0.2, 0.4, 0.6)).norm(), 1e-9);
  EXPECT_NEAR(angleBetween(identity, b.pose), 12.0 * kPi / 180.0, 1e-9);

  const TumFrame& a = seq.frames[1];  // t = 1.025: halfway
  EXPECT_LT((a.pose.translation() - Eigen::Vector3d(0.5, 1.0, 1.5)).norm(), 1e-9);
  EXPECT_NEAR(angleBetween(identity, a.pose), 30.0 * kPi / 180.0, 1e-9);
  const Eigen::AngleAxisd aa(a.pose.linear());
  EXPECT_NEAR(aa.axis().z(), 1.0, 1e-9);
  EXPECT_EQ(a.depth_path, (fs::path(dir.path()) / "depth/a.png").string());
}

TEST(Tum, NearestPoseWhenGapTooLargeAndDroppedFrames) {
  TempDir dir;
  // Poses 0.5 s apart: too far to interpolate (max_interp_gap 0.1), so the nearest one within
  // max_time_diff (0.02) is taken, else the frame is dropped.
  writeIndex(dir,
             "0.5 d/0.png\n3.015 d/1.png\n3.2 d/2.png\n3.49 d/3.png\n3.51 d/4.png\n3.6 d/5.png\n",
             "3.0 5 0 0 0 0 0 1\n3.5 6 0 0 1 0 0 0\n", kSmallIntrinsicsTxt);
  TumSequence seq = readTumSequence(dir.path());
  ASSERT_EQ(seq.frames.size(), 3u);
  EXPECT_EQ(seq.dropped_frames, 3u);
  EXPECT_DOUBLE_EQ(seq.frames[0].timestamp, 3.015);
  EXPECT_DOUBLE_EQ(seq.frames[0].pose.translation().x(), 5.0);
  EXPECT_TRUE(seq.frames[0].pose.linear().isIdentity(1e-12));
  EXPECT_DOUBLE_EQ(seq.frames[1].timestamp, 3.49);
  EXPECT_DOUBLE_EQ(seq.frames[1].pose.translation().x(), 6.0);
  EXPECT_NEAR(angleBetween(Pose::Identity(), seq.frames[1].pose), kPi, 1e-9);
  EXPECT_DOUBLE_EQ(seq.frames[2].timestamp, 3.51);
  EXPECT_DOUBLE_EQ(seq.frames[2].pose.translation().x(), 6.0);

  // A wider max_time_diff takes 3.2 (nearest 3.0) and 3.6 (nearest 3.5); 0.5 stays dropped.
  TumOptions wide;
  wide.max_time_diff = 0.25;
  seq = readTumSequence(dir.path(), wide);
  ASSERT_EQ(seq.frames.size(), 5u);
  EXPECT_EQ(seq.dropped_frames, 1u);
  EXPECT_DOUBLE_EQ(seq.frames[1].pose.translation().x(), 5.0);
  EXPECT_DOUBLE_EQ(seq.frames[4].pose.translation().x(), 6.0);

  // A wider max_interp_gap interpolates 3.2 between the two: x = 5.4.
  TumOptions interp;
  interp.max_interp_gap = 0.5;
  seq = readTumSequence(dir.path(), interp);
  ASSERT_EQ(seq.frames.size(), 4u);  // 3.015, 3.2, 3.49 interpolated; 3.51 nearest; 0.5/3.6 not
  EXPECT_EQ(seq.dropped_frames, 2u);
  EXPECT_DOUBLE_EQ(seq.frames[1].timestamp, 3.2);
  EXPECT_NEAR(seq.frames[1].pose.translation().x(), 5.4, 1e-9);
}

TEST(Tum, SortsUnsortedIndexFiles) {
  TempDir dir;
  writeIndex(dir, "3.0 depth/3.png\n\n1.0 depth/1.png\n# comment\n2.0 depth/2.png\n",
             "2.0 20 0 0 0 0 0 1\r\n3.0 30 0 0 0 0 0 1\r\n1.0 10 0 0 0 0 0 1\r\n",
             kSmallIntrinsicsTxt);
  const TumSequence seq = readTumSequence(dir.path());
  ASSERT_EQ(seq.frames.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_DOUBLE_EQ(seq.frames[i].timestamp, static_cast<double>(i + 1));
    EXPECT_DOUBLE_EQ(seq.frames[i].pose.translation().x(), 10.0 * (i + 1));
    EXPECT_EQ(fs::path(seq.frames[i].depth_path).filename().string(),
              std::to_string(i + 1) + ".png");
  }
}

// ---- intrinsics ---------------------------------------------------------------------------------

TEST(Tum, IntrinsicsOptionOverridesFile) {
  TempDir dir;
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0 1\n",
             "fx -1\nfy 500\ncx 31.5\ncy 23.5\nwidth 64\nheight 48\ndepth_scale 5000\n");
  Intrinsics given = smallIntrinsics();
  given.fx = 600.0;
  given.width = 32;
  given.height = 24;
  TumOptions options;
  options.intrinsics = given;
  TumSequence seq = readTumSequence(dir.path(), options);
  EXPECT_EQ(seq.intrinsics.fx, 600.0);  // the file's invalid fx is overridden
  EXPECT_EQ(seq.intrinsics.width, 32);
  EXPECT_EQ(seq.intrinsics.height, 24);
  EXPECT_EQ(seq.depth_scale, 5000.0);  // still from intrinsics.txt
  options.depth_scale = 250.0;
  seq = readTumSequence(dir.path(), options);
  EXPECT_EQ(seq.depth_scale, 250.0);

  // Without intrinsics.txt the option alone is enough; depth_scale defaults to 1000.
  fs::remove(dir.file("intrinsics.txt"));
  options.depth_scale.reset();
  seq = readTumSequence(dir.path(), options);
  EXPECT_EQ(seq.intrinsics.fx, 600.0);
  EXPECT_EQ(seq.depth_scale, 1000.0);

  options.depth_scale = 0.0;
  expectError([&] { readTumSequence(dir.path(), options); }, dir.path(), "depth-scale");
  options.depth_scale.reset();
  options.intrinsics->fx = -1.0;
  expectError([&] { readTumSequence(dir.path(), options); }, dir.path(), "focal");
}

TEST(Tum, SingleLineIntrinsicsWithTumDepthScale) {
  TempDir dir;
  fs::create_directory(dir.file("depth"));
  std::vector<std::uint16_t> raw(640 * 480, 5000);  // 1 m at TUM's scale 5000
  raw[20 * 640 + 10] = 12345;                       // 2.469 m
  raw[479 * 640 + 639] = 0;                         // invalid
  writeBytes(dir.file("depth/1.png"), makePng(640, 480, 16, 0, 1, raw));
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0 1\n",
             "# fx fy cx cy depth_scale (freiburg1)\n517.3 516.5 318.6 255.3 5000\n");
  const TumSequence seq = readTumSequence(dir.path());
  EXPECT_EQ(seq.depth_scale, 5000.0);
  EXPECT_EQ(seq.intrinsics.fx, 517.3);
  EXPECT_EQ(seq.intrinsics.fy, 516.5);
  EXPECT_EQ(seq.intrinsics.cx, 318.6);
  EXPECT_EQ(seq.intrinsics.cy, 255.3);
  EXPECT_EQ(seq.intrinsics.width, 640);
  EXPECT_EQ(seq.intrinsics.height, 480);
  const DepthFrame d = loadTumDepth(seq, 0);
  EXPECT_EQ(d.timestamp, 1.0);
  EXPECT_FLOAT_EQ(d.at(0, 0), 1.0f);
  EXPECT_FLOAT_EQ(d.at(10, 20), 2.469f);
  EXPECT_EQ(d.at(639, 479), 0.0f);
}

TEST(Tum, MalformedIntrinsicsFileNamesLine) {
  TempDir dir;
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0 1\n");
  const std::string path = dir.file("intrinsics.txt");
  writeBytes(path, "fx 50\nfy 50\n# c\nfocal 3\n");
  expectError([&] { readTumSequence(dir.path()); }, path, "line 4: unknown key 'focal'");
  writeBytes(path, "fx 50\nfy abc\n");
  expectError([&] { readTumSequence(dir.path()); }, path, "line 2: fy 'abc' is not a finite");
  writeBytes(path, "fx 50\nfy 50\ncx 1\ncy 1\nwidth 64.5\n");
  expectError([&] { readTumSequence(dir.path()); }, path, "line 5: width");
  writeBytes(path, "fx 50\nfy 50\ncx 1\n");
  expectError([&] { readTumSequence(dir.path()); }, path, "missing key 'cy'");
  writeBytes(path, "500 500 320 240 -5\n");
  expectError([&] { readTumSequence(dir.path()); }, path, "line 1: depth_scale");
  writeBytes(path, "500 500 320\n");
  expectError([&] { readTumSequence(dir.path()); }, path, "line 1: expected 'fx fy cx cy");
}

// ---- bad input ----------------------------------------------------------------------------------

TEST(Tum, MissingFolderIsError) {
  TempDir dir;
  const std::string missing = dir.file("no_such_sequence");
  EXPECT_FALSE(isTumFolder(missing));
  expectError([&] { readTumSequence(missing); }, missing, "does not exist");
}

TEST(Tum, FileInsteadOfFolderIsError) {
  TempDir dir;
  const std::string file = dir.file("depth.txt");
  writeBytes(file, "1.0 depth/1.png\n");
  EXPECT_FALSE(isTumFolder(file));
  expectError([&] { readTumSequence(file); }, file, "not a folder");
}

TEST(Tum, FolderWithoutDepthTxtIsError) {
  TempDir dir;
  writeBytes(dir.file("groundtruth.txt"), "1.0 0 0 0 0 0 0 1\n");
  EXPECT_FALSE(isTumFolder(dir.path()));
  expectError([&] { readTumSequence(dir.path()); }, dir.path(),
              "not a TUM RGB-D sequence: no depth.txt");
  writeBytes(dir.file("depth.txt"), "1.0 depth/1.png\n");
  fs::remove(dir.file("groundtruth.txt"));
  EXPECT_TRUE(isTumFolder(dir.path()));
  expectError([&] { readTumSequence(dir.path()); }, dir.path(), "groundtruth.txt");
}

TEST(Tum, MalformedIndexLineNamesFileAndLine) {
  TempDir dir;
  const std::string gt = dir.file("groundtruth.txt");
  writeIndex(dir, "1.0 depth/1.png\n",
             "# timestamp tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n",
             kSmallIntrinsicsTxt);
  expectError([&] { readTumSequence(dir.path()); }, gt, "line 3: expected");
  writeBytes(gt, "1.0 0 0 0 0 0 0 1\n\n2.0 0 x 0 0 0 0 1\n");
  expectError([&] { readTumSequence(dir.path()); }, gt, "line 3: ty 'x' is not a finite number");
  writeBytes(gt, "1.0 0 0 nan 0 0 0 1\n");
  expectError([&] { readTumSequence(dir.path()); }, gt, "line 1: tz 'nan'");
  writeBytes(gt, "1.0 0 0 0 0 0 0 1\n");
  const std::string depth = dir.file("depth.txt");
  writeBytes(depth, "1.0 depth/1.png\n1.5\n");
  expectError([&] { readTumSequence(dir.path()); }, depth, "line 2: expected 'timestamp filename'");
  writeBytes(depth, "one depth/1.png\n");
  expectError([&] { readTumSequence(dir.path()); }, depth, "line 1: timestamp 'one'");
  // Five frames at one time would be fused five times with the same pose.
  writeBytes(depth, "1.0 depth/1.png\n2.0 depth/2.png\n2.0 depth/3.png\n2.0 depth/4.png\n");
  expectError([&] { readTumSequence(dir.path()); }, depth, "line 3: timestamp 2 repeats line 2's");
}

TEST(Tum, ZeroQuaternionIsError) {
  TempDir dir;
  const std::string gt = dir.file("groundtruth.txt");
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0 1\n2.0 1 2 3 0 0 0 0\n",
             kSmallIntrinsicsTxt);
  expectError([&] { readTumSequence(dir.path()); }, gt, "line 2: quaternion");
  writeBytes(gt, "1.0 0 0 0 1e-300 0 0 0\n");
  expectError([&] { readTumSequence(dir.path()); }, gt, "line 1: quaternion");
}

TEST(Tum, NanOrNonUnitQuaternionNamesFileAndLine) {
  // A quaternion written with rounded decimals (length within 0.001 of 1) is normalised; one
  // further from unit length, or with a NaN, is an error naming the file and the line.
  TempDir dir;
  const std::string gt = dir.file("groundtruth.txt");
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0.7071 0.7071\n", kSmallIntrinsicsTxt);
  const TumSequence seq = readTumSequence(dir.path());
  ASSERT_EQ(seq.frames.size(), 1u);
  EXPECT_NEAR(angleBetween(seq.frames[0].pose,
                           makePose(kPi / 2, Eigen::Vector3d::UnitZ(), Eigen::Vector3d::Zero())),
              0.0, 1e-4);
  EXPECT_NEAR(seq.frames[0].pose.linear().determinant(), 1.0, 1e-12);
  EXPECT_LT((seq.frames[0].pose.linear().transpose() * seq.frames[0].pose.linear() -
             Eigen::Matrix3d::Identity())
                .norm(),
            1e-12);
  writeBytes(gt, "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 2\n");
  expectError([&] { readTumSequence(dir.path()); }, gt,
              "line 2: quaternion (0 0 0 2) has length 2, not 1 (within 0.001)");
  writeBytes(gt, "1.0 0 0 0 0.5 0.5 0.5 0.51\n");
  expectError([&] { readTumSequence(dir.path()); }, gt,
              "line 1: quaternion (0.5 0.5 0.5 0.51) has length 1.005");
  writeBytes(gt, "1.0 0 0 0 0 0 0 1\n# comment\n2.0 0 0 0 0 nan 0 1\n");
  expectError([&] { readTumSequence(dir.path()); }, gt, "line 3: qy 'nan' is not a finite number");
  writeBytes(gt, "1.0 0 0 0 0 0 0 NaN\n");
  expectError([&] { readTumSequence(dir.path()); }, gt, "line 1: qw 'NaN' is not a finite number");
}

TEST(Tum, MissingPngIsError) {
  TempDir dir;
  writeIndex(dir, "1.0 depth/missing.png\n", "1.0 0 0 0 0 0 0 1\n", kSmallIntrinsicsTxt);
  const TumSequence seq = readTumSequence(dir.path());
  ASSERT_EQ(seq.frames.size(), 1u);
  expectError([&] { loadTumDepth(seq, 0); }, "depth/missing.png", "does not exist");
  expectError([&] { loadTumDepth(seq, 1); }, dir.path(), "out of range");
}

TEST(Tum, EightBitPngIsError) {
  TempDir dir;
  fs::create_directory(dir.file("depth"));
  writeBytes(dir.file("depth/1.png"),
             makePng(64, 48, 8, 0, 1, std::vector<std::uint16_t>(64 * 48, 7)));
  writeBytes(dir.file("depth/2.png"),
             makePng(64, 48, 8, 2, 3, std::vector<std::uint16_t>(64 * 48 * 3, 7)));
  writeIndex(dir, "1.0 depth/1.png\n2.0 depth/2.png\n", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n",
             kSmallIntrinsicsTxt);
  const TumSequence seq = readTumSequence(dir.path());
  ASSERT_EQ(seq.frames.size(), 2u);
  expectError([&] { loadTumDepth(seq, 0); }, "depth/1.png",
              "expected a 16-bit single-channel depth PNG, got 8-bit grayscale");
  expectError([&] { loadTumDepth(seq, 1); }, "depth/2.png",
              "expected a 16-bit single-channel depth PNG, got 8-bit RGB");
}

TEST(Tum, PngSizeMismatchIsError) {
  TempDir dir;
  fs::create_directory(dir.file("depth"));
  writeBytes(dir.file("depth/1.png"),
             makePng(32, 24, 16, 0, 1, std::vector<std::uint16_t>(32 * 24, 1000)));
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0 1\n", kSmallIntrinsicsTxt);
  const TumSequence seq = readTumSequence(dir.path());
  expectError([&] { loadTumDepth(seq, 0); }, "depth/1.png", "32x24 does not match");
}

TEST(Tum, CorruptPngIsError) {
  TempDir dir;
  const std::string good = makePng(64, 48, 16, 0, 1, std::vector<std::uint16_t>(64 * 48, 1000));
  const std::string path = dir.file("d.png");
  writeBytes(path, good.substr(0, good.size() / 2));
  expectError([&] { readDepthPng(path, smallIntrinsics(), 1000.0); }, path, "cannot decode");
  writeBytes(path, "not a png at all");
  expectError([&] { readDepthPng(path, smallIntrinsics(), 1000.0); }, path, "not a PNG");
  writeBytes(path, good);
  expectError([&] { readDepthPng(path, smallIntrinsics(), 0.0); }, path, "depth_scale");
  EXPECT_FLOAT_EQ(readDepthPng(path, smallIntrinsics(), 1000.0).at(5, 5), 1.0f);
}

TEST(Tum, NonPositiveFxIsError) {
  TempDir dir;
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0 1\n",
             "fx 0\nfy 50\ncx 31.5\ncy 23.5\nwidth 64\nheight 48\n");
  expectError([&] { readTumSequence(dir.path()); }, dir.file("intrinsics.txt"), "focal");
}

TEST(Tum, NoIntrinsicsIsError) {
  TempDir dir;
  writeIndex(dir, "1.0 depth/1.png\n", "1.0 0 0 0 0 0 0 1\n");
  expectError([&] { readTumSequence(dir.path()); }, dir.path(),
              "no intrinsics.txt and no --intrinsics given");
}

TEST(Tum, NoFrameWithPoseIsError) {
  TempDir dir;
  writeIndex(dir, "1.0 depth/1.png\n2.0 depth/2.png\n", "10.0 0 0 0 0 0 0 1\n",
             kSmallIntrinsicsTxt);
  expectError([&] { readTumSequence(dir.path()); }, dir.path(),
              "no depth frame has a ground-truth pose");
  writeBytes(dir.file("groundtruth.txt"), "# nothing\n");
  expectError([&] { readTumSequence(dir.path()); }, dir.file("groundtruth.txt"), "no poses");
  writeBytes(dir.file("depth.txt"), "\n# nothing\n");
  expectError([&] { readTumSequence(dir.path()); }, dir.file("depth.txt"), "no depth frames");
}

TEST(Tum, WriteSequenceRejectsInconsistentInput) {
  TempDir dir;
  const std::string folder = dir.file("out");
  DepthFrame f;
  f.intrinsics = smallIntrinsics();
  f.depth.assign(64 * 48, 1.0f);
  std::vector<DepthFrame> frames = {f, f};
  frames[1].timestamp = 1.0;
  const Pose p = Pose::Identity();
  expectError([&] { writeTumSequence(folder, frames, {p}); }, folder, "2 depth frames but 1");
  frames[1].intrinsics.fx = 49.0;
  expectError([&] { writeTumSequence(folder, frames, {p, p}); }, folder, "intrinsics");
  frames[1].intrinsics.fx = 50.0;
  frames[1].timestamp = 0.0;
  expectError([&] { writeTumSequence(folder, frames, {p, p}); }, folder, "same timestamp");
  frames[1].timestamp = 1.0;
  expectError([&] { writeTumSequence(folder, frames, {p, p}, -1.0); }, folder, "depth_scale");
  writeBytes(folder, "a file in the way");
  expectError([&] { writeTumSequence(folder, frames, {p, p}); }, folder, "cannot create folder");
}

TEST(Tum, GarbageInputOnlyThrowsPlanesdfError) {
  TempDir dir;
  const std::string folder = dir.file("seq");
  DepthFrame f;
  f.intrinsics = smallIntrinsics();
  f.depth.assign(64 * 48, 1.5f);
  writeTumSequence(folder, {f}, {Pose::Identity()});
  const std::string png = folder + "/depth/0.000000.png";
  const std::vector<std::string> files = {folder + "/depth.txt", folder + "/groundtruth.txt",
                                          folder + "/intrinsics.txt", png};
  std::vector<std::string> originals;
  for (const auto& file : files) {
    std::ifstream in(file, std::ios::binary);
    originals.emplace_back(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  std::mt19937 rng(12345);
  int loaded = 0;
  for (int iter = 0; iter < 400; ++iter) {
    const std::size_t which = iter % files.size();
    std::string bytes = originals[which];
    if (iter % 8 == 7) {
      bytes.resize(rng() % 64);
      for (char& c : bytes) c = static_cast<char>(rng());
    } else {
      const int flips = 1 + static_cast<int>(rng() % 4);
      for (int k = 0; k < flips && !bytes.empty(); ++k)
        bytes[rng() % bytes.size()] = static_cast<char>(rng());
    }
    writeBytes(files[which], bytes);
    try {
      const TumSequence seq = readTumSequence(folder);
      for (std::size_t i = 0; i < seq.frames.size(); ++i) loadTumDepth(seq, i);
      ++loaded;
    } catch (const Error& e) {
      EXPECT_FALSE(e.path().empty()) << e.what();
    } catch (const std::exception& e) {
      ADD_FAILURE() << "iteration " << iter << ": not a planesdf::Error: " << e.what();
    }
    writeBytes(files[which], originals[which]);
  }
  EXPECT_GT(loaded, 0);
}

}  // namespace
}  // namespace planesdf::io
