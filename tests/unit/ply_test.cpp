// Tests for planesdf::io PLY reading and writing: round trips, every property type, skipped
// elements, and every kind of bad input (each must throw planesdf::Error naming the file).

#include "planesdf/io/ply.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <iterator>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "planesdf/error.hpp"
#include "test_support.hpp"

namespace {

using planesdf::Error;
using planesdf::PointCloud;
using planesdf::ScalarField;
using planesdf::ScalarType;
using planesdf::io::PlyFormat;
using planesdf::io::readPly;
using planesdf::io::writePly;
using planesdf::io::writePlyMesh;
using planesdf::test::TempDir;
using planesdf::test::writeBytes;
namespace fs = std::filesystem;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// The bytes of `v` in little- or big-endian order, independent of the host's order.
template <typename T>
std::string bytesOf(T v, bool big_endian = false) {
  char raw[sizeof(T)];
  std::memcpy(raw, &v, sizeof(T));
  std::uint16_t one = 1;
  unsigned char host_first = 0;
  std::memcpy(&host_first, &one, 1);
  const bool host_little = host_first == 1;
  std::string out(raw, sizeof(T));
  if (host_little == big_endian) out.assign(out.rbegin(), out.rend());
  return out;
}

// Same value, NaN equal to NaN and -0 different from +0.
bool sameBits(double a, double b) {
  if (std::isnan(a) || std::isnan(b)) return std::isnan(a) && std::isnan(b);
  return a == b && std::signbit(a) == std::signbit(b);
}

void expectSameCloud(const PointCloud& a, const PointCloud& b) {
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(b.width, b.size());
  EXPECT_EQ(b.height, 1u);
  EXPECT_TRUE(b.sensor_pose.isApprox(planesdf::Pose::Identity()));
  for (std::size_t i = 0; i < a.size(); ++i)
    for (int k = 0; k < 3; ++k)
      EXPECT_TRUE(sameBits(a.points[i][k], b.points[i][k]))
          << "point " << i << "[" << k << "]: " << a.points[i][k] << " vs " << b.points[i][k];
  ASSERT_EQ(a.normals.size(), b.normals.size());
  for (std::size_t i = 0; i < a.normals.size(); ++i)
    for (int k = 0; k < 3; ++k) EXPECT_TRUE(sameBits(a.normals[i][k], b.normals[i][k]));
  EXPECT_EQ(a.colors, b.colors);
  ASSERT_EQ(a.fields.size(), b.fields.size());
  for (std::size_t f = 0; f < a.fields.size(); ++f) {
    EXPECT_EQ(a.fields[f].name, b.fields[f].name);
    EXPECT_EQ(a.fields[f].type, b.fields[f].type) << a.fields[f].name;
    ASSERT_EQ(a.fields[f].values.size(), b.fields[f].values.size());
    for (std::size_t i = 0; i < a.size(); ++i)
      EXPECT_TRUE(sameBits(a.fields[f].values[i], b.fields[f].values[i]))
          << a.fields[f].name << "[" << i << "]: " << a.fields[f].values[i] << " vs "
          << b.fields[f].values[i];
  }
}

// A cloud with awkward values: extremes of every type, denormals, -0, a NaN point.
PointCloud sampleCloud() {
  PointCloud c;
  const float fmax = std::numeric_limits<float>::max();
  const float fmin = std::numeric_limits<float>::min();
  const float denorm = std::numeric_limits<float>::denorm_min();
  c.points = {{0.1f, -2.5f, 3e-7f},
              {fmax, -fmin, denorm},
              {1.0f / 3.0f, 123456.789f, -0.0f},
              {kNaN, kNaN, kNaN},
              {-fmax, 7.0f, 16777216.0f}};
  c.normals = {{0, 0, 1},
               {0.6f, 0.8f, 0},
               {1.0f / 3.0f, 2.0f / 3.0f, -2.0f / 3.0f},
               {kNaN, kNaN, kNaN},
               {-1, 0, 0}};
  c.colors = {{0, 0, 0}, {255, 255, 255}, {1, 128, 254}, {10, 20, 30}, {200, 100, 50}};
  c.width = 5;
  c.height = 1;
  c.addField("object_id", ScalarType::Int32).values = {0, -2147483648.0, 2147483647.0, 42, -1};
  c.addField("label", ScalarType::UInt8).values = {0, 255, 7, 1, 128};
  c.addField("change_id", ScalarType::Int16).values = {-32768, 32767, 0, -1, 300};
  c.addField("intensity", ScalarType::Float64).values = {0.1, 1e300, 4.9e-324, 3.141592653589793,
                                                         -0.0};
  c.addField("i8", ScalarType::Int8).values = {-128, 127, 0, -1, 5};
  c.addField("u16", ScalarType::UInt16).values = {0, 65535, 1, 2, 3};
  c.addField("u32", ScalarType::UInt32).values = {0, 4294967295.0, 1, 2, 3};
  c.addField("f32", ScalarType::Float32).values = {0.1f, -1e-40f, 3.4e38f, kNaN, 1.5f};
  return c;
}

// Writes `bytes` to a file and expects readPly to throw a planesdf::Error whose message names
// the file and contains every keyword.
void expectReadError(const std::string& bytes, std::initializer_list<std::string> keywords) {
  TempDir dir;
  const std::string path = dir.file("bad.ply");
  writeBytes(path, bytes);
  try {
    readPly(path);
    ADD_FAILURE() << "no error for input:\n" << bytes.substr(0, 300);
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(path), std::string::npos) << what;
    EXPECT_EQ(e.path(), path);
    for (const std::string& k : keywords) EXPECT_NE(what.find(k), std::string::npos) << what;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "wrong exception type: " << e.what();
  }
}

std::string xyzHeader(const std::string& format, const std::string& count) {
  return "ply\nformat " + format + " 1.0\nelement vertex " + count +
         "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
}

std::vector<std::string> filesIn(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  return names;
}

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void roundTrip(PlyFormat format, const std::string& expected_format_line) {
  TempDir dir;
  const std::string path = dir.file("cloud.ply");
  const PointCloud c = sampleCloud();
  writePly(path, c, format);
  const std::string text = readText(path);
  EXPECT_EQ(text.rfind("ply\n" + expected_format_line + "\ncomment generated by planesdf\n", 0), 0u)
      << text.substr(0, 100);
  const PointCloud back = readPly(path);
  expectSameCloud(c, back);
  EXPECT_EQ(back.countValid(), 4u);
}

}  // namespace

// ---- round trips --------------------------------------------------------------------------------

TEST(Ply, RoundTripAsciiIsExact) {
  roundTrip(PlyFormat::Ascii, "format ascii 1.0");
}

TEST(Ply, RoundTripBinaryLittleEndianIsExact) {
  roundTrip(PlyFormat::BinaryLittleEndian, "format binary_little_endian 1.0");
}

TEST(Ply, RoundTripBinaryBigEndianIsExact) {
  roundTrip(PlyFormat::BinaryBigEndian, "format binary_big_endian 1.0");
}

TEST(Ply, WriterDefaultsToBinaryLittleEndianWithTypedHeader) {
  TempDir dir;
  const std::string path = dir.file("cloud.ply");
  PointCloud c;
  c.points = {{1.0f, 2.0f, 3.0f}};
  c.colors = {{4, 5, 6}};
  c.width = 1;
  c.addField("object_id", ScalarType::Int32, 7);
  writePly(path, c);
  const std::string header =
      "ply\nformat binary_little_endian 1.0\ncomment generated by planesdf\n"
      "element vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
      "property uchar red\nproperty uchar green\nproperty uchar blue\n"
      "property int object_id\nend_header\n";
  const std::string body =
      bytesOf(1.0f) + bytesOf(2.0f) + bytesOf(3.0f) + "\x04\x05\x06" + bytesOf(std::int32_t{7});
  EXPECT_EQ(readText(path), header + body);
}

TEST(Ply, EmptyCloudRoundTrips) {
  TempDir dir;
  PointCloud c;
  c.addField("label", ScalarType::UInt16);
  for (PlyFormat f : {PlyFormat::Ascii, PlyFormat::BinaryLittleEndian}) {
    writePly(dir.file("empty.ply"), c, f);
    const PointCloud back = readPly(dir.file("empty.ply"));
    EXPECT_TRUE(back.empty());
    EXPECT_EQ(back.width, 0u);
    ASSERT_EQ(back.fields.size(), 1u);
    EXPECT_EQ(back.fields[0].name, "label");
    EXPECT_EQ(back.fields[0].type, ScalarType::UInt16);
  }
}

TEST(Ply, LargeBinaryCloudRoundTrips) {
  TempDir dir;
  const std::string path = dir.file("big.ply");
  PointCloud c;
  const std::size_t n = 300000;
  c.points.resize(n);
  c.colors.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    c.points[i] = {0.001f * static_cast<float>(i), -static_cast<float>(i), 1.0f};
    c.colors[i] = {static_cast<std::uint8_t>(i), static_cast<std::uint8_t>(i >> 8), 3};
  }
  c.width = static_cast<std::uint32_t>(n);
  auto& ids = c.addField("object_id", ScalarType::UInt32).values;
  for (std::size_t i = 0; i < n; ++i) ids[i] = static_cast<double>(i * 7);
  writePly(path, c, PlyFormat::BinaryBigEndian);
  const PointCloud back = readPly(path);
  ASSERT_EQ(back.size(), n);
  EXPECT_EQ(back.points, c.points);
  EXPECT_EQ(back.colors, c.colors);
  ASSERT_NE(back.field("object_id"), nullptr);
  EXPECT_EQ(back.field("object_id")->values, ids);
}

// ---- every property type ------------------------------------------------------------------------

namespace {

const char* const kAllTypesHeaderProps =
    "property char a\nproperty uchar b\nproperty short c\nproperty ushort d\nproperty int e\n"
    "property uint f\nproperty float x\nproperty double y\nproperty int8 g\nproperty uint8 h\n"
    "property int16 i\nproperty uint16 j\nproperty int32 k\nproperty uint32 l\n"
    "property float32 z\nproperty float64 m\nend_header\n";

// Expected values of the all-types fixtures: vertex 0 holds each type's minimum, vertex 1 its
// maximum (floats: small and large values).
void expectAllTypes(const PointCloud& c) {
  ASSERT_EQ(c.size(), 2u);
  const struct {
    const char* name;
    ScalarType type;
    double lo, hi;
  } expected[] = {
      {"a", ScalarType::Int8, -128, 127},
      {"b", ScalarType::UInt8, 0, 255},
      {"c", ScalarType::Int16, -32768, 32767},
      {"d", ScalarType::UInt16, 0, 65535},
      {"e", ScalarType::Int32, -2147483648.0, 2147483647.0},
      {"f", ScalarType::UInt32, 0, 4294967295.0},
      {"g", ScalarType::Int8, -128, 127},
      {"h", ScalarType::UInt8, 0, 255},
      {"i", ScalarType::Int16, -32768, 32767},
      {"j", ScalarType::UInt16, 0, 65535},
      {"k", ScalarType::Int32, -2147483648.0, 2147483647.0},
      {"l", ScalarType::UInt32, 0, 4294967295.0},
      {"m", ScalarType::Float64, -1e-300, 1.7e308},
  };
  ASSERT_EQ(c.fields.size(), std::size(expected));
  for (std::size_t f = 0; f < std::size(expected); ++f) {
    const ScalarField& field = c.fields[f];  // fields keep the file's property order
    EXPECT_EQ(field.name, expected[f].name);
    EXPECT_EQ(field.type, expected[f].type) << field.name;
    EXPECT_EQ(field.values[0], expected[f].lo) << field.name;
    EXPECT_EQ(field.values[1], expected[f].hi) << field.name;
  }
  EXPECT_EQ(c.points[0], Eigen::Vector3f(0.25f, -0.5f, -3.0e38f));
  EXPECT_EQ(c.points[1], Eigen::Vector3f(1e-30f, 12345.0f, 3.0e38f));
  EXPECT_FALSE(c.hasNormals());
  EXPECT_FALSE(c.hasColors());
}

std::string allTypesBinary(bool big) {
  std::string b;
  // vertex 0: minima
  b += bytesOf(std::int8_t{-128}, big) + bytesOf(std::uint8_t{0}, big) +
       bytesOf(std::int16_t{-32768}, big) + bytesOf(std::uint16_t{0}, big) +
       bytesOf(std::numeric_limits<std::int32_t>::min(), big) + bytesOf(std::uint32_t{0}, big) +
       bytesOf(0.25f, big) + bytesOf(-0.5, big) + bytesOf(std::int8_t{-128}, big) +
       bytesOf(std::uint8_t{0}, big) + bytesOf(std::int16_t{-32768}, big) +
       bytesOf(std::uint16_t{0}, big) + bytesOf(std::numeric_limits<std::int32_t>::min(), big) +
       bytesOf(std::uint32_t{0}, big) + bytesOf(-3.0e38f, big) + bytesOf(-1e-300, big);
  // vertex 1: maxima
  b += bytesOf(std::int8_t{127}, big) + bytesOf(std::uint8_t{255}, big) +
       bytesOf(std::int16_t{32767}, big) + bytesOf(std::uint16_t{65535}, big) +
       bytesOf(std::int32_t{2147483647}, big) + bytesOf(std::uint32_t{4294967295u}, big) +
       bytesOf(1e-30f, big) + bytesOf(12345.0, big) + bytesOf(std::int8_t{127}, big) +
       bytesOf(std::uint8_t{255}, big) + bytesOf(std::int16_t{32767}, big) +
       bytesOf(std::uint16_t{65535}, big) + bytesOf(std::int32_t{2147483647}, big) +
       bytesOf(std::uint32_t{4294967295u}, big) + bytesOf(3.0e38f, big) + bytesOf(1.7e308, big);
  return b;
}

PointCloud parse(const std::string& bytes) {
  return planesdf::io::parsePly(bytes, "mem.ply");
}

/// Four vertices with an object_id field (for two triangles).
PointCloud meshVertices() {
  PointCloud c;
  c.points = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0.5f}};
  c.width = 4;
  c.addField("object_id", ScalarType::Int32).values = {1, 2, 3, 4};
  return c;
}

}  // namespace

TEST(Ply, ReadsEveryPropertyTypeAscii) {
  const std::string text = std::string("ply\nformat ascii 1.0\nelement vertex 2\n") +
                           kAllTypesHeaderProps +
                           "-128 0 -32768 0 -2147483648 0 0.25 -0.5 -128 0 -32768 0 -2147483648 "
                           "0 -3e38 -1e-300\n"
                           "127 255 32767 65535 2147483647 4294967295 1e-30 12345 +127 255 32767 "
                           "65535 2147483647 4294967295 3e38 1.7e308\n";
  expectAllTypes(parse(text));
}

TEST(Ply, ReadsEveryPropertyTypeBinaryLittleEndian) {
  expectAllTypes(parse(std::string("ply\nformat binary_little_endian 1.0\nelement vertex 2\n") +
                       kAllTypesHeaderProps + allTypesBinary(false)));
}

TEST(Ply, ReadsEveryPropertyTypeBinaryBigEndian) {
  expectAllTypes(parse(std::string("ply\nformat binary_big_endian 1.0\nelement vertex 2\n") +
                       kAllTypesHeaderProps + allTypesBinary(true)));
}

TEST(Ply, ReadsHandWrittenBigEndianBytes) {
  // Bytes spelled out by hand: float 1.0 = 3f800000, float -2.0 = c0000000, double 0.5 =
  // 3fe0000000000000, short 258 = 0102, uint 16909060 = 01020304, uchar 200 = c8.
  const std::string header =
      "ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\n"
      "property float y\nproperty double z\nproperty short object_id\nproperty uint change_id\n"
      "property uchar label\nend_header\n";
  const std::string v0(
      "\x3f\x80\x00\x00\xc0\x00\x00\x00\x3f\xe0\x00\x00\x00\x00\x00\x00"
      "\x01\x02\x01\x02\x03\x04\xc8",
      23);
  const std::string v1(
      "\xc0\x00\x00\x00\x3f\x80\x00\x00\xbf\xe0\x00\x00\x00\x00\x00\x00"
      "\xff\xfe\x00\x00\x00\x01\x00",
      23);
  const PointCloud c = parse(header + v0 + v1);
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c.points[0], Eigen::Vector3f(1.0f, -2.0f, 0.5f));
  EXPECT_EQ(c.points[1], Eigen::Vector3f(-2.0f, 1.0f, -0.5f));
  ASSERT_EQ(c.fields.size(), 3u);
  EXPECT_EQ(c.field("object_id")->values, (std::vector<double>{258, -2}));
  EXPECT_EQ(c.field("object_id")->type, ScalarType::Int16);
  EXPECT_EQ(c.field("change_id")->values, (std::vector<double>{16909060, 1}));
  EXPECT_EQ(c.field("change_id")->type, ScalarType::UInt32);
  EXPECT_EQ(c.field("label")->values, (std::vector<double>{200, 0}));
}

// ---- skipped elements, named properties, colours ------------------------------------------------

TEST(Ply, AsciiSkipsOtherElementsBeforeAndAfterVertices) {
  const PointCloud c = parse(
      "ply\nformat ascii 1.0\ncomment made by hand\nobj_info nothing\n"
      "element material 1\nproperty float shininess\n"
      "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 2\nproperty list uchar int vertex_indices\n"
      "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
      "0.5\n"
      "0 0 0\n1 0 0\n0 1 0\n"
      "3 0 1 2\n4 2 1 0 1\n"
      "0 1\n");
  ASSERT_EQ(c.size(), 3u);
  EXPECT_EQ(c.points[1], Eigen::Vector3f(1, 0, 0));
  EXPECT_EQ(c.points[2], Eigen::Vector3f(0, 1, 0));
  EXPECT_TRUE(c.fields.empty());
}

TEST(Ply, BinarySkipsListElementsBeforeAndAfterVertices) {
  for (bool big : {false, true}) {
    SCOPED_TRACE(big ? "big endian" : "little endian");
    std::string b = std::string("ply\nformat ") +
                    (big ? "binary_big_endian" : "binary_little_endian") +
                    " 1.0\n"
                    "element pre 2\nproperty list ushort double values\nproperty uchar tag\n"
                    "element vertex 2\nproperty double x\nproperty double y\nproperty double z\n"
                    "element face 2\nproperty list uchar int vertex_indices\n"
                    "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n";
    // pre: a 2-item list then a tag, then a 0-item list and a tag
    b += bytesOf(std::uint16_t{2}, big) + bytesOf(1.5, big) + bytesOf(2.5, big) + "\x07";
    b += bytesOf(std::uint16_t{0}, big) + "\x08";
    b += bytesOf(1.0, big) + bytesOf(2.0, big) + bytesOf(3.0, big);
    b += bytesOf(-4.0, big) + bytesOf(-5.0, big) + bytesOf(-6.0, big);
    b += std::string("\x03") + bytesOf(0, big) + bytesOf(1, big) + bytesOf(2, big);
    b +=
        std::string("\x04") + bytesOf(3, big) + bytesOf(2, big) + bytesOf(1, big) + bytesOf(0, big);
    b += bytesOf(0, big) + bytesOf(1, big);
    const PointCloud c = parse(b);
    ASSERT_EQ(c.size(), 2u);
    EXPECT_EQ(c.points[0], Eigen::Vector3f(1, 2, 3));
    EXPECT_EQ(c.points[1], Eigen::Vector3f(-4, -5, -6));

    // The same file with its last face list cut short is truncated.
    expectReadError(b.substr(0, b.size() - 9), {"truncated", "face"});
  }
}

TEST(Ply, AsciiSkippedRecordsMustHoldTheirListLengths) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
      "property float z\nelement face 2\nproperty uchar flags\n"
      "property list uchar int vertex_indices\nend_header\n0 0 0\n";
  EXPECT_EQ(parse(header + "1 3 0 0 0\n7 0\n").size(), 1u);  // an empty list
  // Lines 12 and 13 hold the faces. The last line cut short, one value too many, a bad or negative
  // length, a missing list.
  expectReadError(header + "1 3 0 0 0\n1 3 0 0\n", {"line 13", "face", "record 1", "expected 5"});
  expectReadError(header + "1 3 0 0 0 0\n1 3 0 0 0\n", {"line 12", "record 0", "found 6"});
  expectReadError(header + "1 x 0 0 0\n1 3 0 0 0\n", {"line 12", "vertex_indices", "'x'"});
  expectReadError(header + "1 -1\n1 3 0 0 0\n", {"line 12", "length", "'-1'"});
  expectReadError(header + "1 3 0 0 0\n1\n", {"line 13", "expected 2", "found 1"});
}

TEST(Ply, MeshWritesFacesThatReadPlySkips) {
  const PointCloud vertices = meshVertices();
  const std::vector<planesdf::Triangle> faces = {{0, 1, 2}, {2, 1, 3}};
  const std::string vertex_header =
      "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
      "property int object_id\nelement face 2\nproperty list uchar int vertex_indices\n"
      "end_header\n";
  for (const PlyFormat f :
       {PlyFormat::Ascii, PlyFormat::BinaryLittleEndian, PlyFormat::BinaryBigEndian}) {
    SCOPED_TRACE(static_cast<int>(f));
    TempDir dir;
    const std::string path = dir.file("mesh.ply");
    writePlyMesh(path, vertices, faces, f);
    expectSameCloud(vertices, readPly(path));
    const std::string text = readText(path);
    const std::size_t header_end = text.find("end_header\n") + 11;
    EXPECT_NE(text.find(vertex_header), std::string::npos) << text.substr(0, header_end);
    const std::string body = text.substr(header_end);
    if (f == PlyFormat::Ascii) {
      EXPECT_EQ(body, "0 0 0 1\n1 0 0 2\n0 1 0 3\n1 1 0.5 4\n3 0 1 2\n3 2 1 3\n");
      continue;
    }
    const bool big = f == PlyFormat::BinaryBigEndian;
    std::string expected_faces;
    for (const planesdf::Triangle& t : faces) {
      expected_faces += '\x03';
      for (const std::uint32_t v : t) expected_faces += bytesOf(static_cast<std::int32_t>(v), big);
    }
    ASSERT_EQ(body.size(), 4u * 16u + expected_faces.size());
    EXPECT_EQ(body.substr(4u * 16u), expected_faces);
    // A cut last face is a truncated file.
    expectReadError(text.substr(0, text.size() - 2), {"face", "truncated"});
  }
}

TEST(Ply, MeshWithoutFacesOrVerticesRoundTrips) {
  TempDir dir;
  writePlyMesh(dir.file("a.ply"), meshVertices(), {});
  EXPECT_EQ(readPly(dir.file("a.ply")).size(), 4u);
  EXPECT_NE(readText(dir.file("a.ply")).find("element face 0\n"), std::string::npos);
  writePlyMesh(dir.file("b.ply"), PointCloud{}, {}, PlyFormat::Ascii);
  EXPECT_TRUE(readPly(dir.file("b.ply")).empty());
}

TEST(Ply, MeshWithABadIndexThrowsAndKeepsExistingFile) {
  TempDir dir;
  const std::string path = dir.file("mesh.ply");
  writeBytes(path, "old content");
  try {
    writePlyMesh(path, meshVertices(), {{0, 1, 2}, {1, 4, 2}});
    FAIL() << "no error";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(path), std::string::npos) << what;
    EXPECT_NE(what.find("face 1"), std::string::npos) << what;
    EXPECT_NE(what.find("vertex index 4"), std::string::npos) << what;
  }
  EXPECT_EQ(readText(path), "old content");
  EXPECT_EQ(filesIn(dir.path()), std::vector<std::string>{"mesh.ply"});
}

TEST(Ply, ReadsExtraPropertiesByNameAndIgnoresAlpha) {
  const PointCloud c = parse(
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
      "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
      "property uchar alpha\nproperty uint object_id\nproperty uchar change_id\n"
      "property float nx\nproperty float intensity\nend_header\n"
      "1 2 3 10 20 30 255 17 1 0.5 0.25\n"
      "4 5 6 40 50 60 128 4000000000 0 -0.5 99\n");
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c.colors[0], (std::array<std::uint8_t, 3>{10, 20, 30}));
  EXPECT_EQ(c.colors[1], (std::array<std::uint8_t, 3>{40, 50, 60}));
  EXPECT_FALSE(c.hasNormals());  // nx alone is not a normal: kept as a field
  EXPECT_EQ(c.field("alpha"), nullptr);
  ASSERT_NE(c.field("object_id"), nullptr);
  EXPECT_EQ(c.field("object_id")->type, ScalarType::UInt32);
  EXPECT_EQ(c.field("object_id")->values, (std::vector<double>{17, 4000000000.0}));
  EXPECT_EQ(c.field("change_id")->type, ScalarType::UInt8);
  EXPECT_EQ(c.field("change_id")->values, (std::vector<double>{1, 0}));
  EXPECT_EQ(c.field("nx")->values, (std::vector<double>{0.5, -0.5}));
  EXPECT_EQ(c.field("intensity")->type, ScalarType::Float32);
  EXPECT_EQ(c.field("intensity")->values, (std::vector<double>{0.25, 99}));
  EXPECT_EQ(c.fields.size(), 4u);
}

TEST(Ply, ColourAliasesAndFloatColoursAreScaled) {
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  PointCloud c = parse("ply\nformat ascii 1.0\nelement vertex 2\n" + xyz +
                       "property float r\nproperty float g\nproperty float b\nend_header\n"
                       "0 0 0 0 0.5 1\n0 0 0 1 0.2 0.004\n");
  ASSERT_EQ(c.colors.size(), 2u);
  EXPECT_EQ(c.colors[0], (std::array<std::uint8_t, 3>{0, 128, 255}));
  EXPECT_EQ(c.colors[1], (std::array<std::uint8_t, 3>{255, 51, 1}));
  EXPECT_TRUE(c.fields.empty());

  c = parse("ply\nformat ascii 1.0\nelement vertex 1\n" + xyz +
            "property uchar diffuse_red\nproperty uchar diffuse_green\n"
            "property uchar diffuse_blue\nproperty uchar diffuse_alpha\nend_header\n"
            "0 0 0 9 8 7 6\n");
  ASSERT_EQ(c.colors.size(), 1u);
  EXPECT_EQ(c.colors[0], (std::array<std::uint8_t, 3>{9, 8, 7}));
  EXPECT_TRUE(c.fields.empty());

  // Float colours above 1 are taken as 0..255 already.
  c = parse("ply\nformat ascii 1.0\nelement vertex 1\n" + xyz +
            "property float red\nproperty float green\nproperty float blue\nend_header\n"
            "0 0 0 0.5 128 300\n");
  EXPECT_EQ(c.colors[0], (std::array<std::uint8_t, 3>{1, 128, 255}));

  // Normals need all three of nx ny nz.
  c = parse("ply\nformat ascii 1.0\nelement vertex 1\n" + xyz +
            "property double nz\nproperty double ny\nproperty double nx\nend_header\n"
            "0 0 0 1 0.5 0.25\n");
  ASSERT_TRUE(c.hasNormals());
  EXPECT_EQ(c.normals[0], Eigen::Vector3f(0.25f, 0.5f, 1.0f));
}

TEST(Ply, NanPointsAreKeptAndInvalid) {
  const PointCloud a = parse(xyzHeader("ascii", "3") + "1 2 3\nnan nan nan\n4 -nan 6\n");
  ASSERT_EQ(a.size(), 3u);
  EXPECT_TRUE(a.isValid(0));
  EXPECT_FALSE(a.isValid(1));
  EXPECT_FALSE(a.isValid(2));
  EXPECT_EQ(a.countValid(), 1u);
  EXPECT_EQ(a.points[2].x(), 4.0f);

  const PointCloud b =
      parse(xyzHeader("binary_little_endian", "2") + bytesOf(kNaN) + bytesOf(kNaN) + bytesOf(kNaN) +
            bytesOf(1.0f) + bytesOf(2.0f) + bytesOf(3.0f));
  ASSERT_EQ(b.size(), 2u);
  EXPECT_FALSE(b.isValid(0));
  EXPECT_TRUE(b.isValid(1));
  EXPECT_EQ(b.points[1], Eigen::Vector3f(1, 2, 3));
}

TEST(Ply, CrlfHeaderAndAsciiLinesAreAccepted) {
  const PointCloud a = parse(
      "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\n"
      "property float z\r\nend_header\r\n1 2 3\r\n\r\n4 5 6\r\n");
  ASSERT_EQ(a.size(), 2u);
  EXPECT_EQ(a.points[1], Eigen::Vector3f(4, 5, 6));

  const PointCloud b = parse(
      "ply\r\nformat binary_little_endian 1.0\r\nelement vertex 1\r\nproperty float x\r\n"
      "property float y\r\nproperty float z\r\nend_header\r\n" +
      bytesOf(13.0f) + bytesOf(10.0f) + bytesOf(-1.0f));
  ASSERT_EQ(b.size(), 1u);
  EXPECT_EQ(b.points[0], Eigen::Vector3f(13, 10, -1));
}

// ---- bad input ----------------------------------------------------------------------------------

TEST(Ply, MissingFileThrowsNamingIt) {
  TempDir dir;
  const std::string path = dir.file("nope.ply");
  try {
    readPly(path);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos) << e.what();
  }
}

TEST(Ply, BadHeadersThrowNamingFileAndProblem) {
  expectReadError("", {"empty"});
  expectReadError("PLY\nformat ascii 1.0\n", {"magic"});
  expectReadError("plyformat ascii 1.0\n", {"magic"});
  expectReadError(std::string("\x89PNG\r\n\x1a\n", 8) + std::string(1000, '\0'), {"magic"});
  expectReadError("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", {"end_header"});
  expectReadError(xyzHeader("binary_middle_endian", "1"),
                  {"unknown format", "binary_middle_endian"});
  expectReadError("ply\nelement vertex 0\nproperty float x\nend_header\n", {"no format"});
  expectReadError("ply\nformat ascii 1.0\nelement vertex 1\nproperty float16 x\nend_header\n",
                  {"header line 4", "unknown property type", "float16"});
  expectReadError(
      "ply\nformat ascii 1.0\nelement vertex 0\nproperty list float int x\nend_header\n",
      {"count type", "float"});
  expectReadError(xyzHeader("ascii", "ten"), {"header line 3", "not a number", "ten"});
  expectReadError(xyzHeader("ascii", "-5"), {"negative"});
  expectReadError(xyzHeader("ascii", "99999999999999999999999"), {"too large"});
  expectReadError("ply\nformat ascii 1.0\nproperty float x\nend_header\n", {"before any element"});
  expectReadError("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x y\nend_header\n",
                  {"header line 4", "expected 'property"});
  expectReadError("ply\nformat ascii 1.0\nvertices 3\nend_header\n", {"unknown header keyword"});
  expectReadError(
      "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float x\nend_header\n",
      {"duplicate property"});
}

TEST(Ply, VertexElementProblemsThrow) {
  expectReadError("ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int v\nend_header\n",
                  {"no 'vertex' element"});
  expectReadError(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
      "property float intensity\nend_header\n1 2 3\n",
      {"missing", "'z'"});
  expectReadError(
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
      "property float y\nproperty float z\nproperty list uchar int idx\nend_header\n",
      {"list property", "idx", "vertex"});
}

TEST(Ply, HugeDeclaredCountsFailBeforeAllocating) {
  const std::string xyz = bytesOf(1.0f) + bytesOf(2.0f) + bytesOf(3.0f);
  expectReadError(xyzHeader("binary_little_endian", "1000000000000") + xyz,
                  {"vertex", "truncated", "1000000000000"});
  expectReadError(xyzHeader("binary_big_endian", "18446744073709551615") + xyz, {"truncated"});
  expectReadError(xyzHeader("ascii", "1000000000000") + "1 2 3\n",
                  {"vertex", "truncated", "1000000000000"});
  expectReadError(
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
      "property float y\nproperty float z\nelement face 1000000000000\n"
      "property list uchar int vertex_indices\nend_header\n" +
          xyz,
      {"face", "truncated"});
  expectReadError(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1000000000000\nproperty list uchar int vertex_indices\n"
      "end_header\n1 2 3\n3 0 0 0\n",
      {"face", "truncated"});
}

TEST(Ply, TruncatedDataThrows) {
  const std::string xyz = bytesOf(1.0f) + bytesOf(2.0f) + bytesOf(3.0f);
  expectReadError(xyzHeader("binary_little_endian", "3") + xyz + xyz + xyz.substr(0, 6),
                  {"truncated", "vertex"});
  expectReadError(xyzHeader("binary_little_endian", "1"), {"truncated"});
  // Long enough to pass the bytes-per-value check, but the third line is missing.
  expectReadError(xyzHeader("ascii", "3") + "1.5 2.5 3.5\n4.5 5.5 6.5\n", {"truncated", "2 of 3"});
  // Too short for 3 vertices even at 2 bytes per value: rejected before reading.
  expectReadError(xyzHeader("ascii", "3") + "1 2 3\n4 5 6\n", {"truncated", "12 bytes"});
}

TEST(Ply, AsciiBadValuesNameLineAndVertex) {
  // The header has 7 lines, so vertex 1 is on line 9.
  expectReadError(xyzHeader("ascii", "3") + "1 2 3\n4 abc 6\n7 8 9\n",
                  {"line 9", "vertex 1", "'abc'", "'y'"});
  expectReadError(xyzHeader("ascii", "3") + "1.0 2.0 3.0\n4.0 5.0 6.0\n7.0 8.0\n",
                  {"line 10", "vertex 2", "expected 3 values, found 2"});
  expectReadError(xyzHeader("ascii", "2") + "1 2 3\n4 5 6 7\n",
                  {"line 9", "vertex 1", "expected 3 values, found 4"});
  expectReadError(xyzHeader("ascii", "1") + "1 2 3e99\n", {"vertex 0", "'3e99'"});
  expectReadError(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
      "property float z\nproperty uchar label\nend_header\n1 2 3 256\n",
      {"vertex 0", "'label'", "'256'", "uchar"});
  expectReadError(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
      "property float z\nproperty int label\nend_header\n1 2 3 1.5\n",
      {"vertex 0", "'1.5'"});
}

// ---- writing ------------------------------------------------------------------------------------

TEST(Ply, WriteIntoMissingFolderThrowsAndLeavesNoFile) {
  TempDir dir;
  const std::string path = dir.file("missing/out.ply");
  try {
    writePly(path, sampleCloud());
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(filesIn(dir.path()).empty());
}

TEST(Ply, FailedWriteKeepsExistingFile) {
  TempDir dir;
  const std::string path = dir.file("out.ply");
  writeBytes(path, "old content");
  PointCloud c = sampleCloud();
  c.field("object_id")->values[3] = 3.5;  // not an int: fails halfway through writing
  for (PlyFormat f : {PlyFormat::Ascii, PlyFormat::BinaryLittleEndian}) {
    try {
      writePly(path, c, f);
      FAIL() << "no error";
    } catch (const Error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(path), std::string::npos) << what;
      EXPECT_NE(what.find("object_id"), std::string::npos) << what;
      EXPECT_NE(what.find("point 3"), std::string::npos) << what;
    }
    EXPECT_EQ(readText(path), "old content");
    EXPECT_EQ(filesIn(dir.path()), std::vector<std::string>{"out.ply"});  // no temporary left
  }
}

TEST(Ply, WriteRejectsInconsistentCloudsAndReservedNames) {
  TempDir dir;
  const std::string path = dir.file("out.ply");
  auto expectWriteError = [&](const PointCloud& c, const std::string& keyword) {
    try {
      writePly(path, c);
      ADD_FAILURE() << "no error, expected " << keyword;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(keyword), std::string::npos) << e.what();
    }
  };
  PointCloud c = sampleCloud();
  c.normals.pop_back();
  expectWriteError(c, "normals");

  c = sampleCloud();
  c.fields.push_back(c.fields[0]);
  expectWriteError(c, "duplicate");

  c = sampleCloud();
  c.addField("x", ScalarType::Float32);
  expectWriteError(c, "duplicate");

  c = sampleCloud();
  c.normals.clear();
  c.addField("nx", ScalarType::Float32);
  c.addField("ny", ScalarType::Float32);
  c.addField("nz", ScalarType::Float32);
  expectWriteError(c, "reserved");

  c = sampleCloud();
  c.addField("two words", ScalarType::Float32);
  expectWriteError(c, "name");
  EXPECT_FALSE(fs::exists(path));
}
