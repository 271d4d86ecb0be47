// PCD reading and writing (PCL's point cloud format) without PCL.
//
// Reading resolves the header into one `Column` per stored value of a point (a field with
// COUNT n gives n columns), each knowing its binary type and where its values go in the
// PointCloud. The three DATA layouts then differ only in where a column's values are:
//   binary             row-major records: value i at  data + offset + i * point_size
//   binary_compressed  LZF, decompressing to one block per field (structure of arrays):
//                      value i at  data + points * offset + i * (size * count)
//   ascii              whitespace-separated tokens, one point per line.
// Binary data is little-endian, as PCL writes it on every platform it supports.
#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <ostream>
#include <set>
#include <string>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/pcd.hpp"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "pcd.cpp reads and writes little-endian binary data; add byte swapping for this platform"
#endif

namespace planesdf::io {
namespace {

// ---- small helpers ------------------------------------------------------------------------------

// A header token for an error message: at most 40 characters, control bytes replaced, so a binary
// file passed as PCD gives a readable message.
std::string quote(std::string_view s) {
  std::string q = "'";
  for (std::size_t i = 0; i < s.size() && i < 40; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    q.push_back(c >= 32 && c < 127 ? static_cast<char>(c) : '?');
  }
  if (s.size() > 40) q += "...";
  return q + "'";
}

bool isSpace(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v';
}

// Splits a line on blanks (no allocation of the token text; views into `line`).
std::vector<std::string_view> splitTokens(std::string_view line) {
  std::vector<std::string_view> tokens;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && isSpace(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !isSpace(line[i])) ++i;
    if (i > start) tokens.push_back(line.substr(start, i - start));
  }
  return tokens;
}

// Whole-token parses; false unless every character was consumed. A leading '+' is accepted.
template <typename T>
bool parseNumber(std::string_view tok, T& out) {
  if (!tok.empty() && tok.front() == '+') tok.remove_prefix(1);
  if (tok.empty()) return false;
  const char* end = tok.data() + tok.size();
  std::from_chars_result r{};
  if constexpr (std::is_same_v<T, float>) {
    r = std::from_chars(tok.data(), end, out, std::chars_format::general);
    if (r.ec == std::errc::result_out_of_range) {
      // Beyond float range (1e50, 1e-50): read as double, then overflow to inf / underflow to 0
      // as strtof would.
      double d = 0;
      r = std::from_chars(tok.data(), end, d, std::chars_format::general);
      const double fmax = std::numeric_limits<float>::max();
      out = d > fmax    ? std::numeric_limits<float>::infinity()
            : d < -fmax ? -std::numeric_limits<float>::infinity()
                        : static_cast<float>(d);
    }
  } else if constexpr (std::is_floating_point_v<T>) {
    r = std::from_chars(tok.data(), end, out, std::chars_format::general);
  } else {
    r = std::from_chars(tok.data(), end, out);
  }
  return r.ec == std::errc{} && r.ptr == end;
}

std::uint64_t checkedMul(std::uint64_t a, std::uint64_t b, const std::string& name,
                         const std::string& what) {
  if (a != 0 && b > std::numeric_limits<std::uint64_t>::max() / a)
    throw Error(name, what + " is too large");
  return a * b;
}

// ---- binary value types ------------------------------------------------------------------------

// The stored type of a PCD field (TYPE letter + SIZE).
enum class Src : std::uint8_t { I8, U8, I16, U16, I32, U32, I64, U64, F32, F64 };

bool srcFromPcd(char type, int size, Src& out) {
  switch (type) {
    case 'I':
    case 'U': {
      const bool u = type == 'U';
      if (size == 1)
        out = u ? Src::U8 : Src::I8;
      else if (size == 2)
        out = u ? Src::U16 : Src::I16;
      else if (size == 4)
        out = u ? Src::U32 : Src::I32;
      else if (size == 8)
        out = u ? Src::U64 : Src::I64;
      else
        return false;
      return true;
    }
    case 'F':
      if (size == 4)
        out = Src::F32;
      else if (size == 8)
        out = Src::F64;
      else
        return false;
      return true;
    default:
      return false;
  }
}

// The ScalarField type a stored type is kept as. 64-bit integers have no ScalarType; they are
// held as Float64 (exact up to 2^53) and written back as F 8.
ScalarType scalarTypeOf(Src s) {
  switch (s) {
    case Src::I8:
      return ScalarType::Int8;
    case Src::U8:
      return ScalarType::UInt8;
    case Src::I16:
      return ScalarType::Int16;
    case Src::U16:
      return ScalarType::UInt16;
    case Src::I32:
      return ScalarType::Int32;
    case Src::U32:
      return ScalarType::UInt32;
    case Src::F32:
      return ScalarType::Float32;
    case Src::I64:
    case Src::U64:
    case Src::F64:
      return ScalarType::Float64;
  }
  return ScalarType::Float64;
}

// Calls f(T{}) with the C++ type of `s`, so one template handles every stored type.
template <typename F>
void withSrcType(Src s, F&& f) {
  switch (s) {
    case Src::I8:
      f(std::int8_t{});
      break;
    case Src::U8:
      f(std::uint8_t{});
      break;
    case Src::I16:
      f(std::int16_t{});
      break;
    case Src::U16:
      f(std::uint16_t{});
      break;
    case Src::I32:
      f(std::int32_t{});
      break;
    case Src::U32:
      f(std::uint32_t{});
      break;
    case Src::I64:
      f(std::int64_t{});
      break;
    case Src::U64:
      f(std::uint64_t{});
      break;
    case Src::F32:
      f(float{});
      break;
    case Src::F64:
      f(double{});
      break;
  }
}

template <typename T>
T load(const char* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}

template <typename T>
void store(char* p, T v) {
  std::memcpy(p, &v, sizeof(T));
}

// ---- header -------------------------------------------------------------------------------------

enum class DataKind { Ascii, Binary, Compressed };

// Most values (FIELDS entries times COUNT) one point may have.
constexpr std::uint64_t kMaxColumns = 65536;

// Where the values of one column go.
enum class Role : std::uint8_t { Skip, Point, Normal, Color, Scalar };

struct Column {
  std::string name;  // for error messages (name or name_k)
  Role role = Role::Skip;
  Src src = Src::F32;
  char type = 'F';
  std::size_t size = 4;          // bytes of one value
  std::size_t field_offset = 0;  // byte offset of the field in a binary record
  std::size_t field_bytes = 0;   // size * count of the field
  std::size_t element = 0;       // index within the field (0..count-1)
  int component = 0;             // 0..2 for Point / Normal
  std::size_t scalar = 0;        // index into cloud.fields for Scalar
};

struct Header {
  std::vector<Column> columns;
  std::vector<ScalarField> scalars;  // empty fields, in column order
  bool has_normals = false;
  bool has_colors = false;
  std::uint64_t width = 0;
  std::uint64_t height = 0;
  std::uint64_t points = 0;
  std::uint64_t point_size = 0;  // bytes of one binary record
  Pose viewpoint = Pose::Identity();
  DataKind kind = DataKind::Binary;
  std::size_t data_start = 0;  // byte offset of the data
  std::size_t data_line = 0;   // 1-based line number of the first data line
};

// The raw header lines, before they are resolved into columns.
struct RawHeader {
  std::vector<std::string_view> fields, sizes, types, counts, viewpoint;
  std::string_view version, width, height, points, data;
  std::size_t line_of_fields = 0;
};

std::uint64_t parseCount(std::string_view tok, const std::string& key, const std::string& name) {
  std::uint64_t v = 0;
  if (!parseNumber(tok, v)) throw Error(name, key + " " + quote(tok) + " is not a number");
  return v;
}

RawHeader readHeaderLines(const std::string& bytes, const std::string& name, Header& h) {
  RawHeader raw;
  std::set<std::string> seen;
  std::size_t pos = 0;
  std::size_t line_no = 0;
  while (pos < bytes.size()) {
    std::size_t eol = bytes.find('\n', pos);
    if (eol == std::string::npos) eol = bytes.size();
    const std::string_view line(bytes.data() + pos, eol - pos);
    pos = eol < bytes.size() ? eol + 1 : eol;
    ++line_no;
    const std::vector<std::string_view> tok = splitTokens(line);
    if (tok.empty() || tok[0].front() == '#') continue;
    const std::string key(tok[0]);
    const std::string where = "header line " + std::to_string(line_no) + ": ";
    const std::vector<std::string_view> values(tok.begin() + 1, tok.end());
    if (!seen.insert(key).second) throw Error(name, where + "duplicate " + key);
    auto single = [&]() {
      if (values.size() != 1)
        throw Error(name, where + key + " needs one value, has " + std::to_string(values.size()));
      return values[0];
    };
    if (key == "VERSION") {
      raw.version = single();
    } else if (key == "FIELDS") {
      raw.fields = values;
      raw.line_of_fields = line_no;
    } else if (key == "SIZE") {
      raw.sizes = values;
    } else if (key == "TYPE") {
      raw.types = values;
    } else if (key == "COUNT") {
      raw.counts = values;
    } else if (key == "WIDTH") {
      raw.width = single();
    } else if (key == "HEIGHT") {
      raw.height = single();
    } else if (key == "VIEWPOINT") {
      raw.viewpoint = values;
      if (values.size() != 7)
        throw Error(name, where + "VIEWPOINT needs 7 values (tx ty tz qw qx qy qz), has " +
                              std::to_string(values.size()));
    } else if (key == "POINTS") {
      raw.points = single();
    } else if (key == "DATA") {
      raw.data = single();
      h.data_start = pos;
      h.data_line = line_no + 1;
      return raw;
    } else {
      throw Error(name, where + "unknown header key " + quote(key));
    }
  }
  throw Error(name, "header has no DATA line (not a PCD file, or truncated header)");
}

void parseViewpoint(const RawHeader& raw, const std::string& name, Header& h) {
  if (raw.viewpoint.empty()) return;
  double v[7];
  for (int i = 0; i < 7; ++i)
    if (!parseNumber(raw.viewpoint[i], v[i]) || !std::isfinite(v[i]))
      throw Error(name, "VIEWPOINT value " + quote(raw.viewpoint[i]) + " is not a finite number");
  Eigen::Quaterniond q(v[3], v[4], v[5], v[6]);
  const double norm = q.coeffs().stableNorm();  // no overflow for components near 1e308
  if (!(norm > 1e-12)) throw Error(name, "VIEWPOINT quaternion (qw qx qy qz) is zero");
  q.coeffs() /= norm;
  h.viewpoint = Pose::Identity();
  h.viewpoint.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  h.viewpoint.linear() = q.toRotationMatrix();
}

// One FIELDS entry with its SIZE, TYPE and COUNT and its byte offset in a record.
struct Decl {
  std::string name;
  Src src;
  char type;
  std::size_t size, count, offset;
};

// The FIELDS/SIZE/TYPE/COUNT declarations, checked, with their offsets; `point_size` receives
// the record size.
std::vector<Decl> declarationsOf(const RawHeader& raw, const std::string& name,
                                 std::size_t& point_size) {
  const std::size_t nf = raw.fields.size();
  if (nf == 0) throw Error(name, "header has no FIELDS");
  auto arity = [&](const std::vector<std::string_view>& v, const char* key) {
    if (v.size() != nf)
      throw Error(name, std::string(key) + " has " + std::to_string(v.size()) +
                            " values but FIELDS has " + std::to_string(nf));
  };
  if (raw.sizes.empty()) throw Error(name, "header has no SIZE");
  if (raw.types.empty()) throw Error(name, "header has no TYPE");
  arity(raw.sizes, "SIZE");
  arity(raw.types, "TYPE");
  if (!raw.counts.empty()) arity(raw.counts, "COUNT");

  std::vector<Decl> decls;
  std::uint64_t offset = 0;
  std::uint64_t columns = 0;
  for (std::size_t f = 0; f < nf; ++f) {
    Decl d;
    d.name = std::string(raw.fields[f]);
    const std::string what = "field " + quote(d.name) + ": ";
    std::uint64_t size = 0;
    if (!parseNumber(raw.sizes[f], size))
      throw Error(name, what + "SIZE " + quote(raw.sizes[f]) + " is not a number");
    if (raw.types[f].size() != 1)
      throw Error(name, what + "TYPE " + quote(raw.types[f]) + " is not one of I, U, F");
    d.type = raw.types[f][0];
    if (size > 8 || !srcFromPcd(d.type, static_cast<int>(size), d.src))
      throw Error(name, what + "unsupported TYPE/SIZE combination " + quote(raw.types[f]) + " " +
                            std::to_string(size) + " (I/U take 1, 2, 4, 8; F takes 4, 8)");
    std::uint64_t count = 1;
    if (!raw.counts.empty() && !parseNumber(raw.counts[f], count))
      throw Error(name, what + "COUNT " + quote(raw.counts[f]) + " is not a number");
    // Bounds that keep size computations far from overflow and the per-column bookkeeping
    // small, before anything is checked against the data (the largest PCL descriptor has a
    // COUNT of 1980).
    if (count < 1 || count > kMaxColumns)
      throw Error(name, what + "COUNT " + std::to_string(count) + " is out of range [1, " +
                            std::to_string(kMaxColumns) + "]");
    columns += count;
    if (columns > kMaxColumns)
      throw Error(name, "too many values per point (over " + std::to_string(kMaxColumns) +
                            " in FIELDS/COUNT)");
    d.size = size;
    d.count = count;
    d.offset = offset;
    offset += size * count;
    decls.push_back(std::move(d));
  }
  point_size = offset;
  return decls;
}

// The columns of the declared fields (padding, the point, the normal, the colour, scalars).
void columnsOf(const std::vector<Decl>& decls, const std::string& name, Header& h) {
  std::set<std::string> names;
  for (const Decl& d : decls) {
    const std::string what = "field " + quote(d.name) + ": ";
    Role role = Role::Scalar;
    int component = 0;
    if (d.name == "_") {
      role = Role::Skip;  // padding
    } else if (d.name == "x" || d.name == "y" || d.name == "z") {
      role = Role::Point;
      component = d.name[0] - 'x';
    } else if (h.has_normals &&
               (d.name == "normal_x" || d.name == "normal_y" || d.name == "normal_z")) {
      role = Role::Normal;
      component = d.name[7] - 'x';
    } else if ((d.name == "rgb" || d.name == "rgba") && !h.has_colors) {
      if (d.size != 4) throw Error(name, what + "colour field must have SIZE 4");
      role = Role::Color;
      h.has_colors = true;
    }
    if (role != Role::Scalar && role != Role::Skip && d.count != 1)
      throw Error(name, what + "COUNT must be 1");
    for (std::size_t e = 0; e < d.count; ++e) {
      Column c;
      c.name = d.count > 1 ? d.name + "_" + std::to_string(e) : d.name;
      if (role != Role::Skip && !names.insert(c.name).second)
        throw Error(name, "duplicate field " + quote(c.name) + " in FIELDS");
      c.role = role;
      c.src = d.src;
      c.type = d.type;
      c.size = d.size;
      c.field_offset = d.offset;
      c.field_bytes = d.size * d.count;
      c.element = e;
      c.component = component;
      if (role == Role::Scalar) {
        c.scalar = h.scalars.size();
        ScalarField sf;
        sf.name = c.name;
        sf.type = scalarTypeOf(d.src);
        h.scalars.push_back(std::move(sf));
      }
      h.columns.push_back(std::move(c));
    }
  }
}

// Resolves FIELDS/SIZE/TYPE/COUNT into columns and the record layout.
void resolveFields(const RawHeader& raw, const std::string& name, Header& h) {
  const std::vector<Decl> decls = declarationsOf(raw, name, h.point_size);
  auto find = [&](const char* n) -> int {
    for (std::size_t f = 0; f < decls.size(); ++f)
      if (decls[f].name == n) return static_cast<int>(f);
    return -1;
  };
  for (const char* axis : {"x", "y", "z"})
    if (find(axis) < 0)
      throw Error(name, std::string("required field '") + axis + "' is missing from FIELDS");
  h.has_normals = find("normal_x") >= 0 && find("normal_y") >= 0 && find("normal_z") >= 0;

  columnsOf(decls, name, h);
}

Header parseHeader(const std::string& bytes, const std::string& name) {
  Header h;
  const RawHeader raw = readHeaderLines(bytes, name, h);
  if (!raw.version.empty()) {
    static const char* const kVersions[] = {"0.5", "0.6", "0.7", ".5", ".6", ".7"};
    if (std::find(std::begin(kVersions), std::end(kVersions), raw.version) == std::end(kVersions))
      throw Error(name, "unsupported VERSION " + quote(raw.version) + " (expected 0.5 to 0.7)");
  }
  if (raw.fields.empty()) throw Error(name, "header has no FIELDS");
  if (raw.width.empty()) throw Error(name, "header has no WIDTH");
  if (raw.height.empty()) throw Error(name, "header has no HEIGHT");
  if (raw.points.empty()) throw Error(name, "header has no POINTS");
  resolveFields(raw, name, h);

  h.width = parseCount(raw.width, "WIDTH", name);
  h.height = parseCount(raw.height, "HEIGHT", name);
  h.points = parseCount(raw.points, "POINTS", name);
  const std::uint64_t u32 = std::numeric_limits<std::uint32_t>::max();
  if (h.width > u32) throw Error(name, "WIDTH " + std::to_string(h.width) + " is too large");
  if (h.height > u32) throw Error(name, "HEIGHT " + std::to_string(h.height) + " is too large");
  if (h.width * h.height != h.points)
    throw Error(name, "WIDTH*HEIGHT = " + std::to_string(h.width) + "*" + std::to_string(h.height) +
                          " does not match POINTS " + std::to_string(h.points));
  parseViewpoint(raw, name, h);

  if (raw.data == "ascii")
    h.kind = DataKind::Ascii;
  else if (raw.data == "binary")
    h.kind = DataKind::Binary;
  else if (raw.data == "binary_compressed")
    h.kind = DataKind::Compressed;
  else
    throw Error(name, "unsupported DATA " + quote(raw.data) +
                          " (expected ascii, binary or binary_compressed)");
  return h;
}

// ---- decoding -----------------------------------------------------------------------------------

// Allocates the cloud's arrays for `h` (sizes already checked against the file).
PointCloud makeCloud(const Header& h) {
  PointCloud cloud;
  const auto n = static_cast<std::size_t>(h.points);
  cloud.points.resize(n);
  if (h.has_normals) cloud.normals.resize(n);
  if (h.has_colors) cloud.colors.resize(n);
  cloud.fields = h.scalars;
  for (ScalarField& f : cloud.fields) f.values.resize(n);
  cloud.width = static_cast<std::uint32_t>(h.width);
  cloud.height = static_cast<std::uint32_t>(h.height);
  cloud.sensor_pose = h.viewpoint;
  return cloud;
}

std::array<std::uint8_t, 3> unpackColor(std::uint32_t v) {
  return {static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v)};
}

// Copies one column of binary values (value i at src + i * stride) into the cloud.
void decodeColumn(const Column& c, const char* src, std::size_t stride, std::size_t n,
                  PointCloud& cloud) {
  switch (c.role) {
    case Role::Skip:
      return;
    case Role::Color: {
      auto* dst = cloud.colors.data();
      for (std::size_t i = 0; i < n; ++i)
        dst[i] = unpackColor(load<std::uint32_t>(src + i * stride));
      return;
    }
    case Role::Point:
    case Role::Normal: {
      Eigen::Vector3f* dst = c.role == Role::Point ? cloud.points.data() : cloud.normals.data();
      const int k = c.component;
      withSrcType(c.src, [&](auto zero) {
        using T = decltype(zero);
        for (std::size_t i = 0; i < n; ++i)
          dst[i][k] = static_cast<float>(load<T>(src + i * stride));
      });
      return;
    }
    case Role::Scalar: {
      double* dst = cloud.fields[c.scalar].values.data();
      withSrcType(c.src, [&](auto zero) {
        using T = decltype(zero);
        for (std::size_t i = 0; i < n; ++i) dst[i] = static_cast<double>(load<T>(src + i * stride));
      });
      return;
    }
  }
}

PointCloud decodeBinary(const Header& h, const std::string& bytes, const std::string& name) {
  const std::size_t remaining = bytes.size() - h.data_start;
  if (h.point_size > 0 && h.points > remaining / h.point_size)
    throw Error(name, "binary data truncated: POINTS " + std::to_string(h.points) + " * " +
                          std::to_string(h.point_size) + " bytes per point exceeds the " +
                          std::to_string(remaining) + " bytes in the file");
  PointCloud cloud = makeCloud(h);
  const char* data = bytes.data() + h.data_start;
  for (const Column& c : h.columns)
    decodeColumn(c, data + c.field_offset + c.element * c.size, h.point_size, cloud.size(), cloud);
  return cloud;
}

PointCloud decodeCompressed(const Header& h, const std::string& bytes, const std::string& name) {
  const std::size_t remaining = bytes.size() - h.data_start;
  const char* data = bytes.data() + h.data_start;
  if (remaining < 8) {
    if (h.points == 0) return makeCloud(h);
    throw Error(name, "binary_compressed data truncated: no compressed/uncompressed size words");
  }
  const std::uint32_t compressed = load<std::uint32_t>(data);
  const std::uint32_t uncompressed = load<std::uint32_t>(data + 4);
  if (compressed > remaining - 8)
    throw Error(name, "binary_compressed data truncated: compressed size " +
                          std::to_string(compressed) + " exceeds the " +
                          std::to_string(remaining - 8) + " bytes left in the file");
  const std::uint64_t expected = checkedMul(h.points, h.point_size, name, "POINTS * point size");
  if (uncompressed != expected)
    throw Error(name, "binary_compressed uncompressed size " + std::to_string(uncompressed) +
                          " does not match POINTS * point size = " + std::to_string(expected));
  // LZF expands at most ~88x; refuse absurd ratios before allocating the output.
  if (uncompressed > std::uint64_t{compressed} * 100 + 1024)
    throw Error(name, "binary_compressed uncompressed size " + std::to_string(uncompressed) +
                          " is impossible for " + std::to_string(compressed) +
                          " compressed bytes (corrupt sizes)");
  const std::string soa = lzfDecompress(data + 8, compressed, uncompressed, name);
  PointCloud cloud = makeCloud(h);
  const std::size_t n = cloud.size();
  // Each field is one block of n * field_bytes bytes, at n * (the field's record offset).
  for (const Column& c : h.columns)
    decodeColumn(c, soa.data() + n * c.field_offset + c.element * c.size, c.field_bytes, n, cloud);
  return cloud;
}

// Parses one ascii token of column `c` into `out` (as a double; exact for every stored type but
// 64-bit integers beyond 2^53). Colours give their packed 32-bit value.
bool parseAsciiValue(std::string_view tok, const Column& c, double& out) {
  if (c.role == Role::Color) {
    // PCL writes colours as the packed unsigned integer (even for `rgb F`); a non-integer token
    // of an F field is a float whose bits are the packed colour.
    std::uint32_t u = 0;
    if (parseNumber(tok, u)) {
      out = u;
      return true;
    }
    std::int32_t s = 0;
    if (c.type == 'I' && parseNumber(tok, s)) {
      out = static_cast<std::uint32_t>(s);
      return true;
    }
    float f = 0;
    if (c.type != 'F' || !parseNumber(tok, f)) return false;
    std::memcpy(&u, &f, 4);
    out = u;
    return true;
  }
  bool ok = false;
  withSrcType(c.src, [&](auto zero) {
    using T = decltype(zero);
    T v{};
    if constexpr (std::is_floating_point_v<T>) {
      // Parsed in the stored precision, so a float round-trips exactly.
      ok = parseNumber(tok, v);
    } else {
      // Integers: also accept an integral value written as a decimal ("3.0").
      ok = parseNumber(tok, v);
      double d = 0;
      if (!ok && parseNumber(tok, d) && d == std::floor(d) &&
          d >= static_cast<double>(std::numeric_limits<T>::lowest()) &&
          d <= static_cast<double>(std::numeric_limits<T>::max())) {
        v = static_cast<T>(d);
        ok = true;
      }
    }
    out = static_cast<double>(v);
  });
  return ok;
}

PointCloud decodeAscii(const Header& h, const std::string& bytes, const std::string& name) {
  const std::size_t remaining = bytes.size() - h.data_start;
  const std::size_t ncols = h.columns.size();
  // Every value takes at least one character and one separator (the last one maybe none).
  if (h.points > (remaining + 1) / (2 * ncols))
    throw Error(name, "ascii data truncated: POINTS " + std::to_string(h.points) + " with " +
                          std::to_string(ncols) + " values each cannot fit in the " +
                          std::to_string(remaining) + " bytes in the file");
  PointCloud cloud = makeCloud(h);
  const std::size_t n = cloud.size();
  std::size_t pos = h.data_start;
  std::size_t line_no = h.data_line - 1;
  std::size_t i = 0;
  while (i < n && pos < bytes.size()) {
    std::size_t eol = bytes.find('\n', pos);
    if (eol == std::string::npos) eol = bytes.size();
    const std::string_view line(bytes.data() + pos, eol - pos);
    pos = eol < bytes.size() ? eol + 1 : eol;
    ++line_no;
    std::size_t k = 0;  // cursor in line
    while (k < line.size() && isSpace(line[k])) ++k;
    if (k == line.size() || line[k] == '#') continue;  // blank or comment line
    const std::string where =
        "line " + std::to_string(line_no) + " (point " + std::to_string(i) + "): ";
    std::size_t col = 0;
    while (k < line.size()) {
      const std::size_t start = k;
      while (k < line.size() && !isSpace(line[k])) ++k;
      const std::string_view tok = line.substr(start, k - start);
      while (k < line.size() && isSpace(line[k])) ++k;
      if (col >= ncols) {
        ++col;
        continue;  // counted for the error below
      }
      const Column& c = h.columns[col++];
      double v = 0;
      if (!parseAsciiValue(tok, c, v))
        throw Error(name, where + "field " + quote(c.name) + ": " + quote(tok) +
                              " is not a valid value of TYPE " + c.type + " SIZE " +
                              std::to_string(c.size));
      switch (c.role) {
        case Role::Skip:
          break;
        case Role::Point:
          cloud.points[i][c.component] = static_cast<float>(v);
          break;
        case Role::Normal:
          cloud.normals[i][c.component] = static_cast<float>(v);
          break;
        case Role::Color:
          cloud.colors[i] = unpackColor(static_cast<std::uint32_t>(v));
          break;
        case Role::Scalar:
          cloud.fields[c.scalar].values[i] = v;
          break;
      }
    }
    if (col != ncols)
      throw Error(name, where + "expected " + std::to_string(ncols) + " values, found " +
                            std::to_string(col));
    ++i;
  }
  if (i != n)
    throw Error(name, "ascii data truncated: POINTS is " + std::to_string(n) + " but only " +
                          std::to_string(i) + " points were found");
  return cloud;
}

// ---- writing ------------------------------------------------------------------------------------

// One written field: what it holds and how it is stored.
struct OutField {
  std::string name;
  char type = 'F';
  int size = 4;
  Role role = Role::Point;
  int component = 0;
  const ScalarField* scalar = nullptr;
};

const char* pcdTypeLetter(ScalarType t) {
  switch (t) {
    case ScalarType::Int8:
    case ScalarType::Int16:
    case ScalarType::Int32:
      return "I";
    case ScalarType::UInt8:
    case ScalarType::UInt16:
    case ScalarType::UInt32:
      return "U";
    case ScalarType::Float32:
    case ScalarType::Float64:
      return "F";
  }
  return "F";
}

std::vector<OutField> outputFields(const PointCloud& cloud, const std::string& path) {
  std::vector<OutField> out;
  for (int k = 0; k < 3; ++k)
    out.push_back({std::string(1, static_cast<char>('x' + k)), 'F', 4, Role::Point, k, nullptr});
  if (cloud.hasNormals())
    for (int k = 0; k < 3; ++k)
      out.push_back({"normal_" + std::string(1, static_cast<char>('x' + k)), 'F', 4, Role::Normal,
                     k, nullptr});
  if (cloud.hasColors()) out.push_back({"rgb", 'F', 4, Role::Color, 0, nullptr});
  std::set<std::string> names;
  for (const OutField& f : out) names.insert(f.name);
  names.insert({"rgb", "rgba", "normal_x", "normal_y", "normal_z"});
  for (const ScalarField& f : cloud.fields) {
    const bool bad_char = std::any_of(f.name.begin(), f.name.end(), [](char c) {
      return static_cast<unsigned char>(c) <= 32 || static_cast<unsigned char>(c) >= 127;
    });
    if (f.name.empty() || bad_char || f.name[0] == '_' || f.name[0] == '#')
      throw Error(path, "field " + quote(f.name) +
                            ": name is not a valid PCD field name (printable, no blanks, not "
                            "starting with '_' or '#')");
    if (!names.insert(f.name).second)
      throw Error(
          path, "field " + quote(f.name) + ": name clashes with another field or a reserved name");
    out.push_back({f.name, pcdTypeLetter(f.type)[0], scalarTypeSize(f.type), Role::Scalar, 0, &f});
  }
  return out;
}

std::string numberText(double v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, r.ptr);
}

std::string makeHeader(const PointCloud& cloud, const std::vector<OutField>& fields,
                       PcdFormat format, bool ascii_rgb_as_uint) {
  std::string s = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS";
  for (const auto& f : fields) s += " " + f.name;
  s += "\nSIZE";
  for (const auto& f : fields) s += " " + std::to_string(f.size);
  s += "\nTYPE";
  for (const auto& f : fields)
    s += std::string(" ") + (f.role == Role::Color && ascii_rgb_as_uint ? 'U' : f.type);
  s += "\nCOUNT";
  for (std::size_t i = 0; i < fields.size(); ++i) s += " 1";
  const bool organised = cloud.height > 1;
  s += "\nWIDTH " + std::to_string(organised ? cloud.width : cloud.size());
  s += "\nHEIGHT " + std::to_string(organised ? cloud.height : 1);
  const Eigen::Vector3d t = cloud.sensor_pose.translation();
  const Eigen::Quaterniond q(cloud.sensor_pose.linear());
  s += "\nVIEWPOINT " + numberText(t.x()) + " " + numberText(t.y()) + " " + numberText(t.z()) +
       " " + numberText(q.w()) + " " + numberText(q.x()) + " " + numberText(q.y()) + " " +
       numberText(q.z());
  s += "\nPOINTS " + std::to_string(cloud.size());
  s += format == PcdFormat::Ascii    ? "\nDATA ascii\n"
       : format == PcdFormat::Binary ? "\nDATA binary\n"
                                     : "\nDATA binary_compressed\n";
  return s;
}

std::uint32_t packColor(const std::array<std::uint8_t, 3>& c) {
  return (std::uint32_t{c[0]} << 16) | (std::uint32_t{c[1]} << 8) | c[2];
}

// Converts a ScalarField value to its integer type, refusing values that do not fit.
template <typename T>
T toInteger(double v, const OutField& f, std::size_t i, const std::string& path) {
  const double r = std::nearbyint(v);
  if (!(r >= static_cast<double>(std::numeric_limits<T>::lowest()) &&
        r <= static_cast<double>(std::numeric_limits<T>::max())))
    throw Error(path, "field " + quote(f.name) + ": value " + numberText(v) + " of point " +
                          std::to_string(i) + " does not fit its type " + f.type + " " +
                          std::to_string(f.size));
  return static_cast<T>(r);
}

// Calls f(T{}) with the C++ type of a ScalarType.
template <typename F>
void withScalarType(ScalarType t, F&& f) {
  switch (t) {
    case ScalarType::Int8:
      f(std::int8_t{});
      break;
    case ScalarType::UInt8:
      f(std::uint8_t{});
      break;
    case ScalarType::Int16:
      f(std::int16_t{});
      break;
    case ScalarType::UInt16:
      f(std::uint16_t{});
      break;
    case ScalarType::Int32:
      f(std::int32_t{});
      break;
    case ScalarType::UInt32:
      f(std::uint32_t{});
      break;
    case ScalarType::Float32:
      f(float{});
      break;
    case ScalarType::Float64:
      f(double{});
      break;
  }
}

// Writes the values of one field at dst + i * stride.
void encodeField(const OutField& f, const PointCloud& cloud, char* dst, std::size_t stride,
                 const std::string& path) {
  const std::size_t n = cloud.size();
  switch (f.role) {
    case Role::Skip:
      return;
    case Role::Point:
    case Role::Normal: {
      const auto& v = f.role == Role::Point ? cloud.points : cloud.normals;
      for (std::size_t i = 0; i < n; ++i) store<float>(dst + i * stride, v[i][f.component]);
      return;
    }
    case Role::Color:
      for (std::size_t i = 0; i < n; ++i) store(dst + i * stride, packColor(cloud.colors[i]));
      return;
    case Role::Scalar: {
      const double* v = f.scalar->values.data();
      withScalarType(f.scalar->type, [&](auto zero) {
        using T = decltype(zero);
        for (std::size_t i = 0; i < n; ++i) {
          if constexpr (std::is_floating_point_v<T>) {
            store(dst + i * stride, static_cast<T>(v[i]));
          } else {
            store(dst + i * stride, toInteger<T>(v[i], f, i, path));
          }
        }
      });
      return;
    }
  }
}

template <typename T>
void appendNumber(std::string& s, T v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  s.append(buf, r.ptr);
}

std::string encodeAscii(const PointCloud& cloud, const std::vector<OutField>& fields,
                        const std::string& path) {
  std::string s;
  s.reserve(cloud.size() * fields.size() * 10);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    for (std::size_t k = 0; k < fields.size(); ++k) {
      const OutField& f = fields[k];
      if (k > 0) s.push_back(' ');
      switch (f.role) {
        case Role::Skip:
          break;
        // to_chars gives the shortest text that reads back to the same float (or double).
        case Role::Point:
          appendNumber(s, cloud.points[i][f.component]);
          break;
        case Role::Normal:
          appendNumber(s, cloud.normals[i][f.component]);
          break;
        case Role::Color:
          appendNumber(s, packColor(cloud.colors[i]));
          break;
        case Role::Scalar:
          withScalarType(f.scalar->type, [&](auto zero) {
            using T = decltype(zero);
            const double v = f.scalar->values[i];
            if constexpr (std::is_floating_point_v<T>) {
              appendNumber(s, static_cast<T>(v));
            } else {
              appendNumber(s, toInteger<T>(v, f, i, path));
            }
          });
          break;
      }
    }
    s.push_back('\n');
  }
  return s;
}

}  // namespace

PointCloud parsePcd(const std::string& bytes, const std::string& name) {
  if (bytes.empty()) throw Error(name, "file is empty");
  const Header h = parseHeader(bytes, name);
  switch (h.kind) {
    case DataKind::Ascii:
      return decodeAscii(h, bytes, name);
    case DataKind::Binary:
      return decodeBinary(h, bytes, name);
    case DataKind::Compressed:
      return decodeCompressed(h, bytes, name);
  }
  return {};
}

PointCloud readPcd(const std::string& path) {
  return parsePcd(readFile(path), path);
}

void writePcd(const std::string& path, const PointCloud& cloud, PcdFormat format) {
  cloud.validate(path);
  if (!cloud.sensor_pose.matrix().allFinite())
    throw Error(path, "sensor_pose (VIEWPOINT) is not finite");
  const std::vector<OutField> fields = outputFields(cloud, path);
  // PCL writes rgb in ascii as the packed unsigned integer with TYPE U; do the same.
  const std::string header = makeHeader(cloud, fields, format, format == PcdFormat::Ascii);

  std::string body;
  if (format == PcdFormat::Ascii) {
    body = encodeAscii(cloud, fields, path);
  } else {
    const std::size_t n = cloud.size();
    std::size_t point_size = 0;
    for (const OutField& f : fields) point_size += static_cast<std::size_t>(f.size);
    std::string buf(n * point_size, '\0');
    std::size_t offset = 0;
    for (const OutField& f : fields) {
      if (format == PcdFormat::Binary) {
        encodeField(f, cloud, buf.data() + offset, point_size, path);  // records
      } else {
        encodeField(f, cloud, buf.data() + n * offset, f.size, path);  // one block per field
      }
      offset += static_cast<std::size_t>(f.size);
    }
    if (format == PcdFormat::Binary) {
      body = std::move(buf);
    } else {
      if (buf.size() > std::numeric_limits<std::uint32_t>::max())
        throw Error(path, "cloud too large for binary_compressed (over 4 GiB of data)");
      const std::string packed = lzfCompress(buf);
      if (packed.size() > std::numeric_limits<std::uint32_t>::max())
        throw Error(path, "cloud too large for binary_compressed (over 4 GiB compressed)");
      body.resize(8);
      store(body.data(), static_cast<std::uint32_t>(packed.size()));
      store(body.data() + 4, static_cast<std::uint32_t>(buf.size()));
      body += packed;
    }
  }
  writeFileAtomic(path, [&](std::ostream& os) {
    os.write(header.data(), static_cast<std::streamsize>(header.size()));
    os.write(body.data(), static_cast<std::streamsize>(body.size()));
  });
}

}  // namespace planesdf::io
