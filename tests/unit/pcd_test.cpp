// Unit tests of the PCD reader/writer and the LZF codec (src/io/pcd.cpp, src/io/lzf.cpp).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/pcd.hpp"
#include "test_support.hpp"

namespace planesdf {
namespace {

using io::lzfCompress;
using io::lzfDecompress;
using io::PcdFormat;
using test::TempDir;
using test::writeBytes;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

std::string randomBytes(std::size_t n, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::string s(n, '\0');
  for (char& c : s) c = static_cast<char>(rng() & 0xff);
  return s;
}

std::string roundTrip(const std::string& in) {
  const std::string packed = lzfCompress(in);
  return lzfDecompress(packed.data(), packed.size(), in.size(), "test");
}

template <typename T>
std::string bytesOf(T v) {
  std::string s(sizeof(T), '\0');
  std::memcpy(s.data(), &v, sizeof(T));
  return s;
}

std::uint32_t floatBits(float f) {
  std::uint32_t u = 0;
  std::memcpy(&u, &f, 4);
  return u;
}

// Expects `f` to throw planesdf::Error whose what() names `path` and contains `keyword`.
template <typename F>
void expectError(F&& f, const std::string& path, const std::string& keyword) {
  try {
    f();
    ADD_FAILURE() << "no error thrown; expected one mentioning '" << keyword << "'";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(path), std::string::npos) << what;
    EXPECT_NE(what.find(keyword), std::string::npos) << "'" << keyword << "' not in: " << what;
    EXPECT_EQ(e.path(), path);
  }
}

// Writes `bytes` as a .pcd file and expects readPcd to fail mentioning `keyword`.
void expectBadPcd(const std::string& bytes, const std::string& keyword) {
  TempDir dir;
  const std::string path = dir.file("bad.pcd");
  writeBytes(path, bytes);
  SCOPED_TRACE("keyword: " + keyword);
  expectError([&] { io::readPcd(path); }, path, keyword);
}

std::string xyzHeader(const std::string& data, std::uint64_t points = 2,
                      const std::string& extra_fields = "", const std::string& extra_size = "",
                      const std::string& extra_type = "") {
  return "VERSION 0.7\nFIELDS x y z" + extra_fields + "\nSIZE 4 4 4" + extra_size + "\nTYPE F F F" +
         extra_type + "\nWIDTH " + std::to_string(points) + "\nHEIGHT 1\nPOINTS " +
         std::to_string(points) + "\nDATA " + data + "\n";
}

// A 4x3 organised cloud with NaN holes, normals, colours, several field types and a pose.
PointCloud sampleCloud() {
  PointCloud c;
  c.width = 4;
  c.height = 3;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-3.0f, 3.0f);
  for (int i = 0; i < 12; ++i) {
    c.points.emplace_back(u(rng), u(rng), u(rng) + 4.0f);
    c.normals.emplace_back(Eigen::Vector3f(u(rng), u(rng), u(rng)).normalized());
    c.colors.push_back({static_cast<std::uint8_t>(i * 20), static_cast<std::uint8_t>(255 - i),
                        static_cast<std::uint8_t>(i * 7 + 1)});
  }
  c.points[1] = Eigen::Vector3f::Constant(kNaN);
  c.points[6] = Eigen::Vector3f(kNaN, kNaN, kNaN);
  c.points[11].z() = kNaN;
  // Add every field first: addField may reallocate `fields`, invalidating references.
  c.addField("label", ScalarType::UInt32);
  c.addField("uc", ScalarType::UInt8);
  c.addField("offset", ScalarType::Int16);
  c.addField("weight", ScalarType::Float64);
  c.addField("object_id", ScalarType::Int32);
  auto& label = *c.field("label");
  auto& uc = *c.field("uc");
  auto& i16 = *c.field("offset");
  auto& dbl = *c.field("weight");
  auto& i32 = *c.field("object_id");
  for (int i = 0; i < 12; ++i) {
    label.values[i] = 4000000000.0 + i;
    uc.values[i] = 255 - i * 3;
    i16.values[i] = -300 * i;
    dbl.values[i] = 0.1 * i + 1e-12;
    i32.values[i] = i % 2 ? -i : 100000 * i;
  }
  c.sensor_pose = Eigen::Translation3d(0.25, -1.5, 2.0) *
                  Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized());
  return c;
}

bool sameFloat(float a, float b) {
  return floatBits(a) == floatBits(b) || (a != a && b != b);
}

void expectSameCloud(const PointCloud& a, const PointCloud& b) {
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a.isValid(i), b.isValid(i)) << "point " << i;
    for (int k = 0; k < 3; ++k)
      EXPECT_TRUE(sameFloat(a.points[i][k], b.points[i][k])) << "point " << i << " coord " << k;
  }
  ASSERT_EQ(a.normals.size(), b.normals.size());
  for (std::size_t i = 0; i < a.normals.size(); ++i)
    for (int k = 0; k < 3; ++k) EXPECT_TRUE(sameFloat(a.normals[i][k], b.normals[i][k]));
  EXPECT_EQ(a.colors, b.colors);
  ASSERT_EQ(a.fields.size(), b.fields.size());
  for (std::size_t f = 0; f < a.fields.size(); ++f) {
    EXPECT_EQ(a.fields[f].name, b.fields[f].name);
    EXPECT_EQ(a.fields[f].type, b.fields[f].type) << a.fields[f].name;
    EXPECT_EQ(a.fields[f].values, b.fields[f].values) << a.fields[f].name;
  }
  EXPECT_TRUE(a.sensor_pose.isApprox(b.sensor_pose, 1e-12));
}

// ---- LZF ---------------------------------------------------------------------------------------

TEST(Lzf, RoundTripEmpty) {
  EXPECT_TRUE(lzfCompress("").empty());
  EXPECT_EQ(lzfDecompress(nullptr, 0, 0, "empty"), "");
  EXPECT_EQ(roundTrip(""), "");
}

TEST(Lzf, RoundTripShort) {
  for (const std::string s : {"a", "ab", "abc", "aaaa", "abcabcabcabc", "hello, hello, hello!"})
    EXPECT_EQ(roundTrip(s), s);
  // Every length 0..300 of a pattern that mixes literals and matches.
  std::string s;
  for (int n = 0; n < 300; ++n) {
    EXPECT_EQ(roundTrip(s), s) << "length " << n;
    s.push_back(static_cast<char>("abcab"[n % 5] + (n % 17 == 0)));
  }
}

TEST(Lzf, RoundTripRepetitive) {
  const std::string zeros(100000, '\0');
  const std::string packed = lzfCompress(zeros);
  EXPECT_LT(packed.size(), zeros.size() / 50);  // runs of 264 bytes in 3-byte references
  EXPECT_EQ(lzfDecompress(packed.data(), packed.size(), zeros.size(), "z"), zeros);
  std::string pattern;
  for (int i = 0; i < 50000; ++i) pattern += "xyz" + std::to_string(i % 97);
  const std::string p2 = lzfCompress(pattern);
  EXPECT_LT(p2.size(), pattern.size() / 4);
  EXPECT_EQ(roundTrip(pattern), pattern);
}

TEST(Lzf, RoundTripRandomIncompressible) {
  for (std::size_t n : {1u, 31u, 32u, 33u, 1000u, 100000u}) {
    const std::string in = randomBytes(n, static_cast<std::uint32_t>(n));
    const std::string packed = lzfCompress(in);
    EXPECT_LE(packed.size(), n + n / 32 + 1);  // only literal-run overhead
    EXPECT_EQ(lzfDecompress(packed.data(), packed.size(), n, "r"), in) << "size " << n;
  }
}

TEST(Lzf, RoundTripMixedOneMegabyte) {
  std::mt19937 rng(42);
  std::string in;
  while (in.size() < (1u << 20)) {
    switch (rng() % 4) {
      case 0:
        in += randomBytes(rng() % 500, rng());
        break;
      case 1:
        in.append(rng() % 2000, static_cast<char>(rng()));
        break;
      case 2:  // repeat a chunk from up to 10 KB back (near and beyond the 8 KB window)
        if (!in.empty()) {
          const std::size_t back = 1 + rng() % std::min<std::size_t>(in.size(), 10000);
          const std::size_t len = rng() % 600;
          for (std::size_t k = 0; k < len; ++k) in.push_back(in[in.size() - back]);
        }
        break;
      default: {
        const float f = static_cast<float>(rng() % 1000) * 0.001f;
        for (int k = 0; k < 100; ++k) in += bytesOf(f + static_cast<float>(k) * 1e-3f);
      }
    }
  }
  in.resize(1u << 20);
  const std::string packed = lzfCompress(in);
  EXPECT_LT(packed.size(), in.size());
  EXPECT_EQ(lzfDecompress(packed.data(), packed.size(), in.size(), "m"), in);
}

TEST(Lzf, DecodesHandWrittenStream) {
  // literal "ab" (ctrl 1), then a reference of 1+2 = 3 bytes at distance 0+1+1 = 2 (overlapping),
  // then a long reference: ctrl 0xe0 (len 7), extra 3 -> 12 bytes, distance 1.
  const std::string stream = std::string(
      "\x01"
      "ab"
      "\x20\x01"
      "\xe0\x03\x00",
      8);
  EXPECT_EQ(lzfDecompress(stream.data(), stream.size(), 5 + 12, "h"),
            "ababa" + std::string(12, 'a'));
}

TEST(Lzf, CorruptStreamsThrow) {
  auto bad = [](const std::string& s, std::size_t expected, const std::string& keyword) {
    SCOPED_TRACE(keyword);
    expectError([&] { lzfDecompress(s.data(), s.size(), expected, "blob.lzf"); }, "blob.lzf",
                keyword);
  };
  bad(std::string("\x20\x00", 2), 3, "corrupt LZF data");  // reference with no output
  bad(std::string("\x00"
                  "a"
                  "\x20\x05",
                  4),
      4, "corrupt LZF data");  // distance 6 > 1
  bad(std::string("\x05"
                  "abc",
                  4),
      6, "corrupt LZF data");  // literal run cut short
  bad(std::string("\x01"
                  "ab"
                  "\xe0",
                  4),
      20, "corrupt LZF data");  // missing length byte
  bad(std::string("\x01"
                  "ab"
                  "\x20",
                  4),
      5, "corrupt LZF data");  // missing offset byte
  bad(std::string("\x02"
                  "abc",
                  4),
      2, "corrupt LZF data");  // literal exceeds output
  bad(std::string("\x00"
                  "a"
                  "\x40\x00",
                  4),
      3, "corrupt LZF data");  // reference exceeds output
  bad(std::string("\x02"
                  "abc",
                  4),
      10, "header says 10");  // underflow
  bad(std::string("\x00"
                  "a",
                  2),
      1000000, "cannot expand");  // impossible ratio
  // Random garbage never crashes: it either decodes to exactly the size or throws.
  for (std::uint32_t seed = 0; seed < 300; ++seed) {
    const std::string junk = randomBytes(1 + seed % 64, seed);
    try {
      EXPECT_EQ(lzfDecompress(junk.data(), junk.size(), seed % 200, "j").size(), seed % 200);
    } catch (const Error&) {
    }
  }
}

// ---- PCD reading -------------------------------------------------------------------------------

TEST(Pcd, ReadsHandWrittenAsciiFixture) {
  TempDir dir;
  const std::string path = dir.file("fixture.pcd");
  writeBytes(path,
             "# .PCD v0.7 - hand-written fixture\n"
             "VERSION .7\n"
             "FIELDS x y z rgb intensity label\n"
             "SIZE 4 4 4 4 4 4\n"
             "TYPE F F F F F U\n"
             "COUNT 1 1 1 1 1 1\n"
             "WIDTH 3\n"
             "HEIGHT 1\n"
             "VIEWPOINT 0.5 -1 2 1 0 0 0\n"
             "POINTS 3\n"
             "DATA ascii\n"
             "1.5 -2.25 3 2.3464059e-38 0.75 7\n"
             "nan nan nan 9.25571649e-40 1 0\r\n"
             "0.1 0.2 0.3 4227327 -0.5 4294967295");  // integer rgb as PCL writes it, no EOL
  const PointCloud c = io::readPcd(path);
  ASSERT_EQ(c.size(), 3u);
  EXPECT_EQ(c.width, 3u);
  EXPECT_EQ(c.height, 1u);
  EXPECT_FALSE(c.isOrganized());
  EXPECT_EQ(c.points[0], Eigen::Vector3f(1.5f, -2.25f, 3.0f));
  EXPECT_FALSE(c.isValid(1));
  EXPECT_EQ(c.points[2], Eigen::Vector3f(0.1f, 0.2f, 0.3f));
  EXPECT_EQ(c.countValid(), 2u);
  ASSERT_TRUE(c.hasColors());
  EXPECT_EQ(c.colors[0], (std::array<std::uint8_t, 3>{255, 128, 64}));  // bits 0x00FF8040
  EXPECT_EQ(c.colors[1], (std::array<std::uint8_t, 3>{10, 20, 30}));    // bits 0x000A141E
  EXPECT_EQ(c.colors[2], (std::array<std::uint8_t, 3>{0x40, 0x80, 0xFF}));
  EXPECT_FALSE(c.hasNormals());
  ASSERT_EQ(c.fields.size(), 2u);
  const ScalarField* intensity = c.field("intensity");
  ASSERT_NE(intensity, nullptr);
  EXPECT_EQ(intensity->type, ScalarType::Float32);
  EXPECT_EQ(intensity->values, (std::vector<double>{0.75, 1.0, -0.5}));
  const ScalarField* label = c.field("label");
  ASSERT_NE(label, nullptr);
  EXPECT_EQ(label->type, ScalarType::UInt32);
  EXPECT_EQ(label->values, (std::vector<double>{7, 0, 4294967295.0}));
  EXPECT_TRUE(c.sensor_pose.linear().isIdentity());
  EXPECT_EQ(c.sensor_pose.translation(), Eigen::Vector3d(0.5, -1, 2));
}

TEST(Pcd, ReadsHandBuiltBinaryWithCountPaddingAndTypes) {
  // Records: x y z (F4), _ (2 padding bytes), hist (U2, COUNT 3), d (F8), c (I1), rgba (U4).
  std::string data;
  for (int i = 0; i < 2; ++i) {
    data += bytesOf(1.0f + i) + bytesOf(2.0f + i) + bytesOf(3.0f + i);
    data += std::string("\xAA\xBB", 2);
    for (int k = 0; k < 3; ++k) data += bytesOf(static_cast<std::uint16_t>(1000 * i + k));
    data += bytesOf(-0.125 * (i + 1));
    data += bytesOf(static_cast<std::int8_t>(-100 + i));
    data += bytesOf(static_cast<std::uint32_t>(0xFF102030u + i));
  }
  const std::string file =
      "VERSION 0.7\nFIELDS x y z _ hist d c rgba\nSIZE 4 4 4 1 2 8 1 4\n"
      "TYPE F F F U U F I U\nCOUNT 1 1 1 2 3 1 1 1\nWIDTH 2\nHEIGHT 1\n"
      "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary\n" +
      data;
  const PointCloud c = io::parsePcd(file, "mem.pcd");
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c.points[1], Eigen::Vector3f(2, 3, 4));
  ASSERT_EQ(c.fields.size(), 5u);  // hist_0 hist_1 hist_2 d c; padding skipped
  EXPECT_EQ(c.fields[0].name, "hist_0");
  EXPECT_EQ(c.fields[2].name, "hist_2");
  EXPECT_EQ(c.fields[2].type, ScalarType::UInt16);
  EXPECT_EQ(c.field("hist_1")->values, (std::vector<double>{1, 1001}));
  EXPECT_EQ(c.field("d")->type, ScalarType::Float64);
  EXPECT_EQ(c.field("d")->values, (std::vector<double>{-0.125, -0.25}));
  EXPECT_EQ(c.field("c")->type, ScalarType::Int8);
  EXPECT_EQ(c.field("c")->values, (std::vector<double>{-100, -99}));
  EXPECT_EQ(c.colors[0], (std::array<std::uint8_t, 3>{0x10, 0x20, 0x30}));  // alpha dropped
  EXPECT_EQ(c.colors[1], (std::array<std::uint8_t, 3>{0x10, 0x20, 0x31}));
}

TEST(Pcd, ReadsHandBuiltCompressedStructureOfArrays) {
  // 3 points, fields x y z normal_x normal_y normal_z label(U1 COUNT 2): SoA, one block per field.
  const float xs[] = {1, 2, 3}, ys[] = {4, 5, kNaN}, zs[] = {7, 8, 9};
  std::string soa;
  for (float v : xs) soa += bytesOf(v);
  for (float v : ys) soa += bytesOf(v);
  for (float v : zs) soa += bytesOf(v);
  for (int axis = 0; axis < 3; ++axis)
    for (int i = 0; i < 3; ++i) soa += bytesOf(axis == i ? 1.0f : 0.0f);
  soa += std::string("\x01\x02\x03\x04\x05\x06", 6);  // label: point-major pairs (1,2) (3,4) (5,6)
  const std::string packed = lzfCompress(soa);
  const std::string file =
      "VERSION 0.7\nFIELDS x y z normal_x normal_y normal_z label\nSIZE 4 4 4 4 4 4 1\n"
      "TYPE F F F F F F U\nCOUNT 1 1 1 1 1 1 2\nWIDTH 3\nHEIGHT 1\nPOINTS 3\n"
      "DATA binary_compressed\n" +
      bytesOf(static_cast<std::uint32_t>(packed.size())) +
      bytesOf(static_cast<std::uint32_t>(soa.size())) + packed + std::string(100, '\0');
  const PointCloud c = io::parsePcd(file, "soa.pcd");
  ASSERT_EQ(c.size(), 3u);
  EXPECT_EQ(c.points[0], Eigen::Vector3f(1, 4, 7));
  EXPECT_EQ(c.points[1], Eigen::Vector3f(2, 5, 8));
  EXPECT_FALSE(c.isValid(2));
  EXPECT_EQ(c.points[2].z(), 9.0f);
  ASSERT_TRUE(c.hasNormals());
  EXPECT_EQ(c.normals[0], Eigen::Vector3f(1, 0, 0));
  EXPECT_EQ(c.normals[2], Eigen::Vector3f(0, 0, 1));
  EXPECT_EQ(c.field("label_0")->values, (std::vector<double>{1, 3, 5}));
  EXPECT_EQ(c.field("label_1")->values, (std::vector<double>{2, 4, 6}));
  EXPECT_TRUE(c.sensor_pose.isApprox(Pose::Identity()));
}

TEST(Pcd, ViewpointQuaternionIsNormalised) {
  const std::string file =
      "VERSION 0.6\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\n"
      "VIEWPOINT 1 2 3 0 0 0 2\nPOINTS 1\nDATA ascii\n0 0 1\n";
  const PointCloud c = io::parsePcd(file, "vp.pcd");
  EXPECT_EQ(c.sensor_pose.translation(), Eigen::Vector3d(1, 2, 3));
  // (0, 0, 0, 2) -> unit quaternion (w 0, z 1): 180 degrees about z.
  EXPECT_TRUE(
      c.sensor_pose.linear().isApprox(Eigen::Vector3d(-1, -1, 1).asDiagonal().toDenseMatrix()));
  EXPECT_NEAR(c.sensor_pose.linear().determinant(), 1.0, 1e-12);
  // Huge components: the squared norm overflows, the stable norm does not. (1, 1e308, 1e308, 0)
  // is 180 degrees about (1, 1, 0), not the identity.
  const PointCloud huge = io::parsePcd(
      "VERSION 0.6\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\n"
      "VIEWPOINT 0 0 0 1 1e308 1e308 0\nPOINTS 1\nDATA ascii\n0 0 1\n",
      "vp.pcd");
  const Eigen::Matrix3d expected =
      Eigen::Quaterniond(0, std::sqrt(0.5), std::sqrt(0.5), 0).toRotationMatrix();
  EXPECT_TRUE(huge.sensor_pose.linear().isApprox(expected, 1e-9)) << huge.sensor_pose.linear();
}

// ---- PCD round trips ---------------------------------------------------------------------------

void roundTripFormat(PcdFormat format) {
  TempDir dir;
  const std::string path = dir.file("cloud.pcd");
  const PointCloud in = sampleCloud();
  io::writePcd(path, in, format);
  const PointCloud out = io::readPcd(path);
  EXPECT_TRUE(out.isOrganized());
  EXPECT_EQ(out.width, 4u);
  EXPECT_EQ(out.height, 3u);
  EXPECT_FALSE(out.isValid(1));
  EXPECT_FALSE(out.isValid(6));
  EXPECT_FALSE(out.isValid(11));
  EXPECT_EQ(out.countValid(), 9u);
  expectSameCloud(in, out);
}

TEST(Pcd, RoundTripAsciiOrganised) {
  roundTripFormat(PcdFormat::Ascii);
}
TEST(Pcd, RoundTripBinaryOrganised) {
  roundTripFormat(PcdFormat::Binary);
}
TEST(Pcd, RoundTripCompressedOrganised) {
  roundTripFormat(PcdFormat::BinaryCompressed);
}

TEST(Pcd, RoundTripUnorganisedAllFormats) {
  TempDir dir;
  PointCloud in;
  std::mt19937 rng(3);
  for (int i = 0; i < 2000; ++i) {
    // Random finite bit patterns, denormals included: ascii must reproduce them exactly.
    Eigen::Vector3f p;
    for (int k = 0; k < 3; ++k) {
      std::uint32_t bits = rng();
      if ((bits & 0x7f800000u) == 0x7f800000u) bits &= 0xbfffffffu;
      std::memcpy(&p[k], &bits, 4);
    }
    in.points.push_back(p);
  }
  in.width = 2000;
  auto& d = in.addField("curvature", ScalarType::Float64);
  for (double& v : d.values)
    v = std::ldexp(static_cast<double>(rng()), -static_cast<int>(rng() % 80));
  for (PcdFormat f : {PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed}) {
    const std::string path = dir.file("u" + std::to_string(static_cast<int>(f)) + ".pcd");
    io::writePcd(path, in, f);
    const std::string text = io::readFile(path);
    EXPECT_NE(text.find("\nWIDTH 2000\nHEIGHT 1\n"), std::string::npos);
    EXPECT_NE(text.find("\nVIEWPOINT 0 0 0 1 0 0 0\n"), std::string::npos);
    const PointCloud out = io::readPcd(path);
    EXPECT_FALSE(out.isOrganized());
    expectSameCloud(in, out);
  }
}

TEST(Pcd, RoundTripEmptyCloud) {
  TempDir dir;
  for (PcdFormat f : {PcdFormat::Ascii, PcdFormat::Binary, PcdFormat::BinaryCompressed}) {
    const std::string path = dir.file("empty.pcd");
    io::writePcd(path, PointCloud{}, f);
    const PointCloud out = io::readPcd(path);
    EXPECT_TRUE(out.empty());
    EXPECT_EQ(out.width, 0u);
  }
}

TEST(Pcd, WriterHeaderMatchesPclConventions) {
  TempDir dir;
  const std::string path = dir.file("h.pcd");
  io::writePcd(path, sampleCloud(), PcdFormat::Binary);
  const std::string text = io::readFile(path);
  EXPECT_EQ(text.rfind("# .PCD v0.7", 0), 0u);
  EXPECT_NE(text.find("\nFIELDS x y z normal_x normal_y normal_z rgb label uc offset weight "
                      "object_id\nSIZE 4 4 4 4 4 4 4 4 1 2 8 4\nTYPE F F F F F F F U U I F I\n"),
            std::string::npos)
      << text.substr(0, 400);
  EXPECT_NE(text.find("\nWIDTH 4\nHEIGHT 3\n"), std::string::npos);
  EXPECT_NE(text.find("\nPOINTS 12\nDATA binary\n"), std::string::npos);
  // rgb is the packed 0x00RRGGBB in a float's bits: first point's colour (0, 255, 1).
  const std::size_t data = text.find("DATA binary\n") + 12;
  std::uint32_t rgb = 0;
  std::memcpy(&rgb, text.data() + data + 24, 4);
  EXPECT_EQ(rgb, 0x0000FF01u);
}

// ---- PCD errors ---------------------------------------------------------------------------------

TEST(Pcd, MissingEmptyAndNonPcdFiles) {
  TempDir dir;
  expectError([&] { io::readPcd(dir.file("nope.pcd")); }, dir.file("nope.pcd"), "does not exist");
  expectBadPcd("", "empty");
  expectBadPcd("VERSION 0.7\nFIELDS x y z\n", "no DATA");
  expectBadPcd(randomBytes(5000, 1), "header");
}

TEST(Pcd, HeaderErrorsNameTheProblem) {
  const std::string ok_tail = "WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n";
  expectBadPcd("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOLOR 1\n" + ok_tail,
               "unknown header key 'COLOR'");
  expectBadPcd("VERSION 0.9\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n" + ok_tail, "VERSION");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\n" + ok_tail, "no TYPE");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n",
               "no WIDTH");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nDATA ascii\n1 2 3\n",
               "no POINTS");
  expectBadPcd("FIELDS x y z\nSIZE 4 4\nTYPE F F F\n" + ok_tail, "SIZE has 2 values but FIELDS");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F\n" + ok_tail, "TYPE has 2 values");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1\n" + ok_tail, "COUNT has 2");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 2\nTYPE F F F\n" + ok_tail, "unsupported TYPE/SIZE");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F Q\n" + ok_tail, "unsupported TYPE/SIZE");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 3\nTYPE F F U\n" + ok_tail, "unsupported TYPE/SIZE");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 0\n" + ok_tail, "COUNT 0");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 2\nPOINTS 3\nDATA ascii\n",
               "does not match POINTS");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nPOINTS many\nDATA ascii\n",
               "POINTS 'many' is not a number");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nPOINTS -1\nDATA ascii\n",
               "POINTS");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA zip\n",
               "unsupported DATA 'zip'");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nVIEWPOINT 0 0 0 0 0 0 0\n" + ok_tail,
               "quaternion");
  expectBadPcd("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nVIEWPOINT 0 0 0 1\n" + ok_tail,
               "VIEWPOINT needs 7");
  expectBadPcd("FIELDS x y y\nSIZE 4 4 4\nTYPE F F F\n" + ok_tail, "'z' is missing");
  expectBadPcd("FIELDS a b c\nSIZE 4 4 4\nTYPE F F F\n" + ok_tail, "'x' is missing");
  expectBadPcd("FIELDS x y z i i\nSIZE 4 4 4 4 4\nTYPE F F F F F\n" + ok_tail, "duplicate");
  expectBadPcd("FIELDS x y z\nFIELDS x y z\n" + ok_tail, "duplicate FIELDS");
}

TEST(Pcd, AbsurdPointCountsFailBeforeAllocating) {
  const std::string huge = "WIDTH 1000000\nHEIGHT 1000000\nPOINTS 1000000000000\n";
  const std::string fields = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n";
  expectBadPcd(fields + huge + "DATA binary\n" + std::string(64, '\0'), "truncated");
  expectBadPcd(fields + huge + "DATA ascii\n1 2 3\n", "truncated");
  expectBadPcd(fields + huge + "DATA binary_compressed\n" + bytesOf(std::uint32_t{4}) +
                   bytesOf(std::uint32_t{0xFFFFFFF0u}) + "abcd",
               "does not match POINTS");
  expectBadPcd(fields + "WIDTH 99999999999\nHEIGHT 1\nPOINTS 99999999999\nDATA binary\n",
               "WIDTH 99999999999 is too large");
  expectBadPcd(fields + "WIDTH 1\nHEIGHT 1\nPOINTS 99999999999999999999999\nDATA binary\n",
               "POINTS");
  expectBadPcd(
      "FIELDS x y z h\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 65537\n" + huge + "DATA binary\n",
      "COUNT 65537 is out of range");
  expectBadPcd("FIELDS x y z h g\nSIZE 4 4 4 4 4\nTYPE F F F F F\nCOUNT 1 1 1 65000 1000\n" + huge +
                   "DATA binary\n",
               "too many values");
  expectBadPcd("FIELDS x y z h\nSIZE 8 8 8 8\nTYPE F F F F\nCOUNT 1 1 1 65000\n" + huge +
                   "DATA binary_compressed\n" + bytesOf(std::uint32_t{0}) +
                   bytesOf(std::uint32_t{0}),
               "does not match POINTS");
}

TEST(Pcd, TruncatedAndCorruptDataFail) {
  // binary: 2 points need 24 bytes.
  expectBadPcd(xyzHeader("binary") + std::string(23, '\0'), "binary data truncated");
  // compressed: missing size words, compressed size past the end, wrong uncompressed size,
  // impossible ratio, corrupt stream.
  expectBadPcd(xyzHeader("binary_compressed") + "abc", "truncated");
  expectBadPcd(xyzHeader("binary_compressed") + bytesOf(std::uint32_t{100}) +
                   bytesOf(std::uint32_t{24}) + std::string(10, '\0'),
               "truncated");
  expectBadPcd(xyzHeader("binary_compressed") + bytesOf(std::uint32_t{2}) +
                   bytesOf(std::uint32_t{25}) + std::string(2, '\0'),
               "uncompressed size 25");
  expectBadPcd(xyzHeader("binary_compressed", 100000) + bytesOf(std::uint32_t{2}) +
                   bytesOf(std::uint32_t{1200000}) + std::string(2, '\0'),
               "impossible");
  expectBadPcd(xyzHeader("binary_compressed") + bytesOf(std::uint32_t{4}) +
                   bytesOf(std::uint32_t{24}) +
                   std::string("\x00"
                               "a"
                               "\x20\x07",
                               4),
               "corrupt LZF");
  expectBadPcd(xyzHeader("binary_compressed") + bytesOf(std::uint32_t{2}) +
                   bytesOf(std::uint32_t{24}) +
                   std::string("\x00"
                               "a",
                               2),
               "corrupt LZF");
  // ascii: a non-numeric token, a short line, too few points.
  expectBadPcd(xyzHeader("ascii") + "1 2 3\n4 oops 6\n", "line 10 (point 1): field 'y': 'oops'");
  expectBadPcd(xyzHeader("ascii") + "1.0 2.0 3.0\n4.0 5.0\n", "expected 3 values, found 2");
  expectBadPcd(xyzHeader("ascii") + "1 2 3\n4 5 6 7\n", "expected 3 values, found 4");
  expectBadPcd(xyzHeader("ascii", 3) + "1 2 3\n4 5 6\n", "ascii data truncated");
  expectBadPcd(xyzHeader("ascii", 3) + "1.0 2.0 3.0\n4.0 5.0 6.0\n", "only 2 points");
  expectBadPcd(xyzHeader("ascii", 1, " label", " 1", " U") + "1 2 3 256\n", "'256'");
  expectBadPcd(xyzHeader("ascii", 1, " label", " 1", " U") + "1 2 3 -1\n", "'-1'");
}

TEST(Pcd, FuzzedHeadersAndDataNeverCrash) {
  TempDir dir;
  const std::string path = dir.file("c.pcd");
  io::writePcd(path, sampleCloud(), PcdFormat::BinaryCompressed);
  const std::string good = io::readFile(path);
  std::mt19937 rng(11);
  for (int iter = 0; iter < 400; ++iter) {
    std::string bad = good;
    const int edits = 1 + static_cast<int>(rng() % 4);
    for (int e = 0; e < edits; ++e) bad[rng() % bad.size()] = static_cast<char>(rng());
    if (iter % 3 == 0) bad.resize(rng() % bad.size());
    try {
      const PointCloud c = io::parsePcd(bad, "fuzz.pcd");
      EXPECT_NO_THROW(c.validate());
    } catch (const Error& e) {
      EXPECT_EQ(e.path(), "fuzz.pcd");
    }
  }
}

// ---- PCD writing errors -------------------------------------------------------------------------

TEST(Pcd, WriteRejectsInvalidClouds) {
  TempDir dir;
  const std::string path = dir.file("out.pcd");
  PointCloud c = sampleCloud();
  c.colors.pop_back();
  expectError([&] { io::writePcd(path, c); }, path, "colors");

  c = sampleCloud();
  c.width = 5;
  expectError([&] { io::writePcd(path, c); }, path, "width*height");

  c = sampleCloud();
  c.field("uc")->values[3] = 256;
  expectError([&] { io::writePcd(path, c); }, path, "does not fit");
  c.field("uc")->values[3] = std::nan("");
  expectError([&] { io::writePcd(path, c, PcdFormat::Ascii); }, path, "does not fit");

  c = sampleCloud();
  c.addField("has space", ScalarType::Float32);
  expectError([&] { io::writePcd(path, c); }, path, "field name");
  c = sampleCloud();
  c.addField("x", ScalarType::Float32);
  expectError([&] { io::writePcd(path, c); }, path, "clashes");
  EXPECT_FALSE(std::filesystem::exists(path));  // nothing half-written

  expectError([&] { io::writePcd(dir.file("no/such/dir.pcd"), sampleCloud()); },
              dir.file("no/such/dir.pcd"), "does not exist");
}

}  // namespace
}  // namespace planesdf
