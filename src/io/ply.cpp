#include "planesdf/io/ply.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <ostream>
#include <string>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <unordered_set>
#include <utility>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"

namespace planesdf::io {
namespace {

// ---- scalar types -------------------------------------------------------------------------------

struct TypeName {
  std::string_view name;
  ScalarType type;
};

// Classic PLY names first: writePly uses the first name listed for a type.
constexpr TypeName kTypeNames[] = {
    {"char", ScalarType::Int8},       {"uchar", ScalarType::UInt8},
    {"short", ScalarType::Int16},     {"ushort", ScalarType::UInt16},
    {"int", ScalarType::Int32},       {"uint", ScalarType::UInt32},
    {"float", ScalarType::Float32},   {"double", ScalarType::Float64},
    {"int8", ScalarType::Int8},       {"uint8", ScalarType::UInt8},
    {"int16", ScalarType::Int16},     {"uint16", ScalarType::UInt16},
    {"int32", ScalarType::Int32},     {"uint32", ScalarType::UInt32},
    {"float32", ScalarType::Float32}, {"float64", ScalarType::Float64}};

bool parseTypeName(std::string_view s, ScalarType& type) {
  for (const TypeName& t : kTypeNames)
    if (t.name == s) {
      type = t.type;
      return true;
    }
  return false;
}

std::string_view typeName(ScalarType type) {
  for (const TypeName& t : kTypeNames)
    if (t.type == type) return t.name;
  return "?";
}

bool isIntegerType(ScalarType t) {
  return t != ScalarType::Float32 && t != ScalarType::Float64;
}

// Range [first, second] of an integer type (as doubles, which hold every value of every
// supported type).
std::pair<double, double> integerRange(ScalarType t) {
  switch (t) {
    case ScalarType::Int8:
      return {-128.0, 127.0};
    case ScalarType::UInt8:
      return {0.0, 255.0};
    case ScalarType::Int16:
      return {-32768.0, 32767.0};
    case ScalarType::UInt16:
      return {0.0, 65535.0};
    case ScalarType::Int32:
      return {-2147483648.0, 2147483647.0};
    case ScalarType::UInt32:
      return {0.0, 4294967295.0};
    default:
      return {-std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  }
}

// True when `v` can be stored as `t` without overflow (and, for integer types, exactly).
bool representable(double v, ScalarType t) {
  if (t == ScalarType::Float64) return true;
  if (t == ScalarType::Float32)
    return !std::isfinite(v) || std::fabs(v) <= std::numeric_limits<float>::max();
  const auto [lo, hi] = integerRange(t);
  return std::isfinite(v) && v == std::trunc(v) && v >= lo && v <= hi;
}

bool hostIsLittleEndian() {
  const std::uint16_t one = 1;
  unsigned char first = 0;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

// Copies `n` bytes, reversing their order when `swap` (file and host byte order differ).
inline void copyBytes(char* dst, const char* src, std::size_t n, bool swap) {
  if (!swap) {
    std::memcpy(dst, src, n);
    return;
  }
  for (std::size_t k = 0; k < n; ++k) dst[k] = src[n - 1 - k];
}

template <typename T>
inline double loadAs(const char* p, bool swap) {
  T v;
  char raw[sizeof(T)];
  copyBytes(raw, p, sizeof(T), swap);
  std::memcpy(&v, raw, sizeof(T));
  return static_cast<double>(v);
}

// One binary value of type `t` at `p`, as double (exact for every supported type).
inline double loadValue(const char* p, ScalarType t, bool swap) {
  switch (t) {
    case ScalarType::Int8:
      return loadAs<std::int8_t>(p, swap);
    case ScalarType::UInt8:
      return loadAs<std::uint8_t>(p, swap);
    case ScalarType::Int16:
      return loadAs<std::int16_t>(p, swap);
    case ScalarType::UInt16:
      return loadAs<std::uint16_t>(p, swap);
    case ScalarType::Int32:
      return loadAs<std::int32_t>(p, swap);
    case ScalarType::UInt32:
      return loadAs<std::uint32_t>(p, swap);
    case ScalarType::Float32:
      return loadAs<float>(p, swap);
    case ScalarType::Float64:
      return loadAs<double>(p, swap);
  }
  return 0.0;
}

template <typename T>
inline void storeAs(char* p, double v, bool swap) {
  const T x = static_cast<T>(v);
  char raw[sizeof(T)];
  std::memcpy(raw, &x, sizeof(T));
  copyBytes(p, raw, sizeof(T), swap);
}

// Writes `v` (already checked with representable()) as type `t` at `p`.
inline void storeValue(char* p, double v, ScalarType t, bool swap) {
  switch (t) {
    case ScalarType::Int8:
      return storeAs<std::int8_t>(p, v, swap);
    case ScalarType::UInt8:
      return storeAs<std::uint8_t>(p, v, swap);
    case ScalarType::Int16:
      return storeAs<std::int16_t>(p, v, swap);
    case ScalarType::UInt16:
      return storeAs<std::uint16_t>(p, v, swap);
    case ScalarType::Int32:
      return storeAs<std::int32_t>(p, v, swap);
    case ScalarType::UInt32:
      return storeAs<std::uint32_t>(p, v, swap);
    case ScalarType::Float32:
      return storeAs<float>(p, v, swap);
    case ScalarType::Float64:
      return storeAs<double>(p, v, swap);
  }
}

// double -> float without the undefined behaviour of converting an out-of-range value.
inline float toFloat(double v) {
  constexpr double kMax = std::numeric_limits<float>::max();
  if (v > kMax) return std::numeric_limits<float>::infinity();
  if (v < -kMax) return -std::numeric_limits<float>::infinity();
  return static_cast<float>(v);  // NaN stays NaN
}

inline std::uint8_t clampByte(double v) {
  if (!(v > 0.0)) return 0;  // also NaN
  if (v >= 255.0) return 255;
  return static_cast<std::uint8_t>(std::lround(v));
}

// A header word for an error message: printable, and short even if the "header" is binary junk.
std::string quote(std::string_view s) {
  std::string out = "'";
  for (std::size_t i = 0; i < s.size() && i < 40; ++i)
    out += (s[i] >= 0x20 && s[i] < 0x7f) ? s[i] : '?';
  if (s.size() > 40) out += "...";
  return out + "'";
}

// ---- header -------------------------------------------------------------------------------------

struct Property {
  std::string name;
  ScalarType type = ScalarType::Float32;  // the item type for a list
  bool is_list = false;
  ScalarType count_type = ScalarType::UInt8;
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::vector<Property> props;
};

struct Header {
  PlyFormat format = PlyFormat::Ascii;
  std::vector<Element> elements;
  std::size_t data_begin = 0;  // byte offset of the first byte after end_header's newline
  int last_line = 0;           // line number of end_header
};

inline bool isBlank(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

// The next '\n'-terminated line from `pos` (without "\r\n"); false at the end of `bytes`.
bool nextLine(std::string_view bytes, std::size_t& pos, std::string_view& line) {
  if (pos >= bytes.size()) return false;
  std::size_t end = bytes.find('\n', pos);
  const std::size_t next = end == std::string_view::npos ? bytes.size() : end + 1;
  if (end == std::string_view::npos) end = bytes.size();
  if (end > pos && bytes[end - 1] == '\r') --end;
  line = bytes.substr(pos, end - pos);
  pos = next;
  return true;
}

// Splits a header line into at most `max_words` words; false if it has more.
bool splitWords(std::string_view line, std::size_t max_words,
                std::vector<std::string_view>& words) {
  words.clear();
  std::size_t i = 0;
  while (true) {
    while (i < line.size() && isBlank(line[i])) ++i;
    if (i == line.size()) return true;
    if (words.size() == max_words) return false;
    const std::size_t start = i;
    while (i < line.size() && !isBlank(line[i])) ++i;
    words.push_back(line.substr(start, i - start));
  }
}

std::uint64_t parseCount(std::string_view s, const std::string& name, const std::string& where) {
  if (!s.empty() && s[0] == '-')
    throw Error(name, where + ": element count " + quote(s) + " is negative");
  std::uint64_t v = 0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec == std::errc::result_out_of_range)
    throw Error(name, where + ": element count " + quote(s) + " is too large");
  if (ec != std::errc() || ptr != s.data() + s.size())
    throw Error(name, where + ": element count " + quote(s) + " is not a number");
  return v;
}

Header parseHeader(std::string_view bytes, const std::string& name) {
  if (bytes.empty()) throw Error(name, "file is empty");
  std::size_t pos = 0;
  std::string_view line;
  nextLine(bytes, pos, line);
  // Only the first 3 bytes are compared so a binary file never gets tokenised here.
  if (line.substr(0, 3) != "ply" ||
      !std::all_of(line.begin() + 3, line.end(), [](char c) { return isBlank(c); }))
    throw Error(name, "line 1: not a PLY file (no 'ply' magic)");

  Header h;
  bool have_format = false;
  int lineno = 1;
  std::vector<std::string_view> w;
  // Hash sets keep duplicate checks linear even for a header with millions of properties.
  std::unordered_set<std::string> element_names, prop_names;
  while (nextLine(bytes, pos, line)) {
    ++lineno;
    const std::string where = "header line " + std::to_string(lineno);
    std::size_t first = 0;
    while (first < line.size() && isBlank(line[first])) ++first;
    const std::string_view keyword =
        line.substr(first, line.find_first_of(" \t\r\v\f", first) - first);
    if (keyword.empty() || keyword == "comment" || keyword == "obj_info") continue;
    if (!splitWords(line, 5, w))
      throw Error(name, where + ": malformed header line " + quote(line));
    if (w[0] == "end_header") {
      if (!have_format) throw Error(name, where + ": header has no format line");
      h.data_begin = pos;
      h.last_line = lineno;
      return h;
    }
    if (w[0] == "format") {
      if (w.size() != 3) throw Error(name, where + ": expected 'format <type> 1.0'");
      if (have_format) throw Error(name, where + ": duplicate format line");
      if (w[1] == "ascii") {
        h.format = PlyFormat::Ascii;
      } else if (w[1] == "binary_little_endian") {
        h.format = PlyFormat::BinaryLittleEndian;
      } else if (w[1] == "binary_big_endian") {
        h.format = PlyFormat::BinaryBigEndian;
      } else {
        throw Error(name, where + ": unknown format " + quote(w[1]) +
                              " (expected ascii, binary_little_endian or binary_big_endian)");
      }
      have_format = true;
    } else if (w[0] == "element") {
      if (w.size() != 3) throw Error(name, where + ": expected 'element <name> <count>'");
      Element e;
      e.name = std::string(w[1]);
      if (!element_names.insert(e.name).second)
        throw Error(name, where + ": duplicate element " + quote(w[1]));
      prop_names.clear();
      e.count = parseCount(w[2], name, where);
      h.elements.push_back(std::move(e));
    } else if (w[0] == "property") {
      if (h.elements.empty()) throw Error(name, where + ": property before any element");
      Element& e = h.elements.back();
      Property p;
      std::string_view type_word;
      if (w.size() == 3 && w[1] != "list") {
        type_word = w[1];
      } else if (w.size() == 5 && w[1] == "list") {
        p.is_list = true;
        if (!parseTypeName(w[2], p.count_type))
          throw Error(name, where + ": unknown property type " + quote(w[2]));
        if (!isIntegerType(p.count_type))
          throw Error(name, where + ": list count type " + quote(w[2]) + " is not an integer type");
        type_word = w[3];
      } else {
        throw Error(name, where +
                              ": expected 'property <type> <name>' or "
                              "'property list <count type> <type> <name>'");
      }
      if (!parseTypeName(type_word, p.type))
        throw Error(name, where + ": unknown property type " + quote(type_word));
      p.name = std::string(w.back());
      if (!prop_names.insert(p.name).second)
        throw Error(
            name, where + ": duplicate property " + quote(p.name) + " in element " + quote(e.name));
      e.props.push_back(std::move(p));
    } else {
      throw Error(name, where + ": unknown header keyword " + quote(w[0]));
    }
  }
  throw Error(name, "header has no end_header line (truncated or not a PLY file)");
}

// ---- vertex property roles ----------------------------------------------------------------------

// What a vertex property becomes in the PointCloud. X..Z, NX..NZ and Red..Blue are consecutive.
enum class Role : std::uint8_t { X, Y, Z, NX, NY, NZ, Red, Green, Blue, Ignore, Field };

Role offsetRole(Role first, int k) {
  return static_cast<Role>(static_cast<int>(first) + k);
}

// Maps property names to roles. Normals and colours only when their whole triplet is present
// (a lone `nx` stays a scalar field); the first complete colour triplet wins. Shared by the
// reader and the writer (which checks that a field would read back as that field).
std::vector<Role> classify(const std::vector<std::string_view>& names) {
  std::vector<Role> roles(names.size(), Role::Field);
  auto index = [&](std::string_view n) -> std::size_t {
    for (std::size_t i = 0; i < names.size(); ++i)
      if (names[i] == n) return i;
    return names.size();
  };
  auto assign = [&](const std::array<std::string_view, 3>& set, Role first) {
    std::array<std::size_t, 3> idx{};
    for (int k = 0; k < 3; ++k) {
      idx[k] = index(set[k]);
      if (idx[k] == names.size() || roles[idx[k]] != Role::Field) return false;
    }
    for (int k = 0; k < 3; ++k) roles[idx[k]] = offsetRole(first, k);
    return true;
  };
  assign({"x", "y", "z"}, Role::X);
  assign({"nx", "ny", "nz"}, Role::NX);
  if (!assign({"red", "green", "blue"}, Role::Red) && !assign({"r", "g", "b"}, Role::Red))
    assign({"diffuse_red", "diffuse_green", "diffuse_blue"}, Role::Red);
  for (std::string_view a : {"alpha", "diffuse_alpha"}) {
    const std::size_t i = index(a);
    if (i < names.size() && roles[i] == Role::Field) roles[i] = Role::Ignore;
  }
  return roles;
}

// Checks the vertex element before any data is touched: x y z present, no list properties.
const Element& findVertexElement(const Header& h, const std::string& name) {
  const Element* vertex = nullptr;
  for (const Element& e : h.elements)
    if (e.name == "vertex") vertex = &e;
  if (!vertex) throw Error(name, "header: no 'vertex' element");
  for (const Property& p : vertex->props)
    if (p.is_list)
      throw Error(name, "header: list property " + quote(p.name) +
                            " in the vertex element is not supported");
  for (const char* axis : {"x", "y", "z"}) {
    const bool found = std::any_of(vertex->props.begin(), vertex->props.end(),
                                   [&](const Property& p) { return p.name == axis; });
    if (!found)
      throw Error(name, std::string("header: vertex element is missing property '") + axis + "'");
  }
  return *vertex;
}

// ---- reading ------------------------------------------------------------------------------------

// Where one vertex property goes: precomputed once so the per-vertex loop does no lookups.
struct Target {
  enum class Sink : std::uint8_t { None, Float, Double, Byte };
  ScalarType type = ScalarType::Float32;
  std::size_t offset = 0;  // byte offset inside a binary record
  Sink sink = Sink::None;
  float* f = nullptr;
  double* d = nullptr;
  std::uint8_t* b = nullptr;
  std::size_t stride = 1;  // destination elements between consecutive vertices
};

inline void put(const Target& t, std::size_t i, double v) {
  switch (t.sink) {
    case Target::Sink::Float:
      t.f[i * t.stride] = toFloat(v);
      break;
    case Target::Sink::Double:
      t.d[i * t.stride] = v;
      break;
    case Target::Sink::Byte:
      t.b[i * t.stride] = clampByte(v);
      break;
    case Target::Sink::None:
      break;
  }
}

// ---- binary fast path: one type-specialised loop per property ----

template <typename T, bool kSwap>
inline T loadRaw(const char* p) {
  char raw[sizeof(T)];
  copyBytes(raw, p, sizeof(T), kSwap);
  T v;
  std::memcpy(&v, raw, sizeof(T));
  return v;
}

// Reads property `t` of records [first, last) into its destination. Instantiated per stored type,
// destination and byte order so the loop has no switches.
template <typename T, Target::Sink kSink, bool kSwap>
void readColumn(const Target& t, const char* records, std::size_t record_size, std::size_t first,
                std::size_t last) {
  const char* p = records + first * record_size + t.offset;
  for (std::size_t i = first; i < last; ++i, p += record_size) {
    const T v = loadRaw<T, kSwap>(p);
    if constexpr (kSink == Target::Sink::Float) {
      if constexpr (std::is_same_v<T, double>) {
        t.f[i * t.stride] = toFloat(v);
      } else {
        t.f[i * t.stride] = static_cast<float>(v);
      }
    } else if constexpr (kSink == Target::Sink::Double) {
      t.d[i * t.stride] = static_cast<double>(v);
    } else if constexpr (kSink == Target::Sink::Byte) {
      if constexpr (std::is_same_v<T, std::uint8_t>) {
        t.b[i * t.stride] = v;
      } else {
        t.b[i * t.stride] = clampByte(static_cast<double>(v));
      }
    }
  }
}

using ColumnReader = void (*)(const Target&, const char*, std::size_t, std::size_t, std::size_t);

template <typename T>
ColumnReader columnReaderFor(Target::Sink sink, bool swap) {
  using S = Target::Sink;
  switch (sink) {
    case S::Float:
      return swap ? readColumn<T, S::Float, true> : readColumn<T, S::Float, false>;
    case S::Double:
      return swap ? readColumn<T, S::Double, true> : readColumn<T, S::Double, false>;
    case S::Byte:
      return swap ? readColumn<T, S::Byte, true> : readColumn<T, S::Byte, false>;
    case S::None:
      break;
  }
  return nullptr;
}

ColumnReader columnReader(ScalarType type, Target::Sink sink, bool swap) {
  switch (type) {
    case ScalarType::Int8:
      return columnReaderFor<std::int8_t>(sink, swap);
    case ScalarType::UInt8:
      return columnReaderFor<std::uint8_t>(sink, swap);
    case ScalarType::Int16:
      return columnReaderFor<std::int16_t>(sink, swap);
    case ScalarType::UInt16:
      return columnReaderFor<std::uint16_t>(sink, swap);
    case ScalarType::Int32:
      return columnReaderFor<std::int32_t>(sink, swap);
    case ScalarType::UInt32:
      return columnReaderFor<std::uint32_t>(sink, swap);
    case ScalarType::Float32:
      return columnReaderFor<float>(sink, swap);
    case ScalarType::Float64:
      return columnReaderFor<double>(sink, swap);
  }
  return nullptr;
}

// Destination arrays of the vertex element; floating-point colours are staged in float_colors
// because whether they are 0..1 or 0..255 is only known once all of them are read.
struct VertexPlan {
  std::vector<Target> targets;  // one per vertex property, in file order
  std::vector<float> float_colors;
  std::array<bool, 3> float_channel{};
};

// Sizes `cloud` for `n` vertices and points each property at its destination. Call only after the
// declared count has been checked against the file size.
VertexPlan planVertices(const Element& vertex, std::size_t n, PointCloud& cloud) {
  std::vector<std::string_view> names;
  for (const Property& p : vertex.props) names.push_back(p.name);
  const std::vector<Role> roles = classify(names);
  const bool has_normals = std::find(roles.begin(), roles.end(), Role::NX) != roles.end();
  const bool has_colors = std::find(roles.begin(), roles.end(), Role::Red) != roles.end();

  cloud.points.assign(n, Eigen::Vector3f::Zero());
  if (has_normals) cloud.normals.assign(n, Eigen::Vector3f::Zero());
  if (has_colors) cloud.colors.assign(n, {0, 0, 0});
  std::size_t n_fields = 0;
  for (Role r : roles) n_fields += r == Role::Field ? 1 : 0;
  cloud.fields.reserve(n_fields);  // keeps pointers into earlier fields valid

  // Base of each destination array; null when the array is empty (nothing is written then).
  auto base = [](auto& vec) { return vec.empty() ? nullptr : vec.data()->data(); };
  float* points = base(cloud.points);
  float* normals = base(cloud.normals);
  std::uint8_t* colors = base(cloud.colors);

  VertexPlan plan;
  std::size_t offset = 0;
  for (std::size_t k = 0; k < vertex.props.size(); ++k) {
    const Property& p = vertex.props[k];
    Target t;
    t.type = p.type;
    t.offset = offset;
    offset += static_cast<std::size_t>(scalarTypeSize(p.type));
    const Role r = roles[k];
    if (n == 0 || r == Role::Ignore) {
      // No destination: nothing to read, or a property that is read past (alpha).
    } else if (r <= Role::Z) {
      t.sink = Target::Sink::Float;
      t.f = points + static_cast<int>(r);
      t.stride = 3;
    } else if (r <= Role::NZ) {
      t.sink = Target::Sink::Float;
      t.f = normals + (static_cast<int>(r) - static_cast<int>(Role::NX));
      t.stride = 3;
    } else if (r <= Role::Blue) {
      const int c = static_cast<int>(r) - static_cast<int>(Role::Red);
      t.stride = 3;
      if (isIntegerType(p.type)) {
        t.sink = Target::Sink::Byte;
        t.b = colors + c;
      } else {
        if (plan.float_colors.empty()) plan.float_colors.assign(3 * n, 0.0f);
        plan.float_channel[c] = true;
        t.sink = Target::Sink::Float;
        t.f = plan.float_colors.data() + c;
      }
    }
    if (r == Role::Field) {  // created even when n == 0 so the field list survives
      ScalarField& f = cloud.fields.emplace_back();
      f.name = p.name;
      f.type = p.type;
      f.values.assign(n, 0.0);
      if (n) {
        t.sink = Target::Sink::Double;
        t.d = f.values.data();
      }
    }
    plan.targets.push_back(t);
  }
  return plan;
}

// Converts staged floating-point colour channels: 0..1 (the usual convention) is scaled to
// 0..255; if any value exceeds 1 the channels are taken to be 0..255 already.
void finishColors(const VertexPlan& plan, PointCloud& cloud) {
  if (plan.float_colors.empty()) return;
  const std::size_t n = cloud.colors.size();
  float max_value = 0.0f;
  for (std::size_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c)
      if (plan.float_channel[c]) max_value = std::max(max_value, plan.float_colors[3 * i + c]);
  const double scale = max_value <= 1.0f ? 255.0 : 1.0;
  for (std::size_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c)
      if (plan.float_channel[c])
        cloud.colors[i][c] = clampByte(plan.float_colors[3 * i + c] * scale);
}

std::size_t checkVertexCount(std::uint64_t count, const std::string& name) {
  if (count > std::numeric_limits<std::uint32_t>::max())
    throw Error(name, "element 'vertex': " + std::to_string(count) +
                          " vertices is more than a point cloud can hold");
  return static_cast<std::size_t>(count);
}

std::string truncatedMessage(const Element& e, std::size_t record_bytes, std::size_t remaining) {
  return "element " + quote(e.name) + ": data truncated: " + std::to_string(e.count) +
         " records of " + std::to_string(record_bytes) + " bytes need more than the " +
         std::to_string(remaining) + " bytes left in the file";
}

void readBinaryVertices(std::string_view bytes, std::size_t& pos, const Element& e, bool swap,
                        const std::string& name, PointCloud& cloud) {
  std::size_t stride = 0;
  for (const Property& p : e.props) stride += static_cast<std::size_t>(scalarTypeSize(p.type));
  const std::size_t remaining = bytes.size() - pos;
  // Checked before allocating, so a header claiming 10^12 vertices fails here.
  if (e.count > remaining / stride) throw Error(name, truncatedMessage(e, stride, remaining));
  const std::size_t n = checkVertexCount(e.count, name);
  VertexPlan plan = planVertices(e, n, cloud);
  std::vector<std::pair<ColumnReader, const Target*>> readers;
  for (const Target& t : plan.targets)
    if (ColumnReader r = columnReader(t.type, t.sink, swap)) readers.emplace_back(r, &t);
  // Blocks of records small enough to stay in cache while each property's loop runs over them.
  const std::size_t block = std::max<std::size_t>(1, 16384 / stride);
  const char* records = bytes.data() + pos;
  for (std::size_t first = 0; first < n; first += block) {
    const std::size_t last = std::min(n, first + block);
    for (const auto& [read, target] : readers) read(*target, records, stride, first, last);
  }
  finishColors(plan, cloud);
  pos += n * stride;
}

void skipBinaryElement(std::string_view bytes, std::size_t& pos, const Element& e, bool swap,
                       const std::string& name) {
  std::size_t min_record = 0;  // fixed part; lists count only their length prefix
  bool has_list = false;
  for (const Property& p : e.props) {
    min_record += static_cast<std::size_t>(scalarTypeSize(p.is_list ? p.count_type : p.type));
    has_list = has_list || p.is_list;
  }
  if (min_record == 0) return;  // no properties: the element occupies no bytes
  const std::size_t remaining = bytes.size() - pos;
  if (e.count > remaining / min_record)
    throw Error(name, truncatedMessage(e, min_record, remaining));
  if (!has_list) {
    pos += static_cast<std::size_t>(e.count) * min_record;
    return;
  }
  // Every record consumes at least one byte, so this loop is bounded by the file size.
  for (std::uint64_t r = 0; r < e.count; ++r) {
    for (const Property& p : e.props) {
      const std::size_t left = bytes.size() - pos;
      const auto size = static_cast<std::size_t>(scalarTypeSize(p.is_list ? p.count_type : p.type));
      // Built only when an error is thrown.
      auto where = [&] { return "element " + quote(e.name) + " record " + std::to_string(r); };
      if (size > left) throw Error(name, where() + ": data truncated");
      if (!p.is_list) {
        pos += size;
        continue;
      }
      const double items = loadValue(bytes.data() + pos, p.count_type, swap);
      pos += size;
      if (items < 0)
        throw Error(name, where() + ": list " + quote(p.name) + " has a negative length");
      const auto item_size = static_cast<std::size_t>(scalarTypeSize(p.type));
      if (static_cast<std::size_t>(items) > (bytes.size() - pos) / item_size)
        throw Error(name, where() + ": data truncated inside list " + quote(p.name));
      pos += static_cast<std::size_t>(items) * item_size;
    }
  }
}

// Ascii data lines: skips blank lines and counts line numbers for messages.
struct AsciiCursor {
  std::string_view bytes;
  std::size_t pos = 0;
  int lineno = 0;

  bool next(std::string_view& line) {
    while (nextLine(bytes, pos, line)) {
      ++lineno;
      if (!std::all_of(line.begin(), line.end(), isBlank)) return true;
    }
    return false;
  }
};

// Parses one ascii token as a value of type `t`; false if it is not a valid number of that type.
bool parseAsciiValue(const char* begin, const char* end, ScalarType t, double& out) {
  if (begin < end && *begin == '+') ++begin;  // from_chars does not take a leading '+'
  if (t == ScalarType::Float32) {
    // Parsed as float directly (not via double) so decimal -> float rounds only once.
    float f = 0.0f;
    const auto [ptr, ec] = std::from_chars(begin, end, f);
    out = f;
    return ec == std::errc() && ptr == end;
  }
  const auto [ptr, ec] = std::from_chars(begin, end, out);
  if (ec != std::errc() || ptr != end) return false;
  return !isIntegerType(t) || representable(out, t);
}

void readAsciiVertices(AsciiCursor& cur, const Element& e, const std::string& name,
                       PointCloud& cloud) {
  const std::size_t n_props = e.props.size();
  const std::size_t remaining = cur.bytes.size() - cur.pos;
  // Each value needs at least a digit and a separator; the last one may lack its newline.
  if (e.count > (remaining + 1) / (2 * n_props))
    throw Error(name, "element 'vertex': data truncated: " + std::to_string(e.count) +
                          " vertices of " + std::to_string(n_props) + " values cannot fit in the " +
                          std::to_string(remaining) + " bytes left in the file");
  const std::size_t n = checkVertexCount(e.count, name);
  VertexPlan plan = planVertices(e, n, cloud);
  std::string_view line;
  for (std::size_t i = 0; i < n; ++i) {
    if (!cur.next(line))
      throw Error(name, "data truncated: file ends after " + std::to_string(i) + " of " +
                            std::to_string(n) + " vertices");
    auto where = [&] {  // built only when an error is thrown
      return "line " + std::to_string(cur.lineno) + ": vertex " + std::to_string(i);
    };
    const char* p = line.data();
    const char* end = p + line.size();
    std::size_t k = 0;
    for (;; ++k) {
      while (p < end && isBlank(*p)) ++p;
      if (p == end) break;
      const char* token = p;
      while (p < end && !isBlank(*p)) ++p;
      if (k >= n_props) continue;  // only counted, for the message below
      double v = 0.0;
      if (!parseAsciiValue(token, p, e.props[k].type, v))
        throw Error(name, where() + ": property " + quote(e.props[k].name) + ": " +
                              quote(std::string_view(token, p - token)) + " is not a valid " +
                              std::string(typeName(e.props[k].type)) + " number");
      put(plan.targets[k], i, v);
    }
    if (k != n_props)
      throw Error(name, where() + ": expected " + std::to_string(n_props) + " values, found " +
                            std::to_string(k));
  }
  finishColors(plan, cloud);
}

// Checks one ascii record of a skipped element `e`: a value per scalar property, a length plus that
// many items per list (a list length must be a non-negative integer of its count type).
void checkAsciiRecord(std::string_view line, const Element& e, const AsciiCursor& cur,
                      std::uint64_t record, const std::string& name) {
  auto where = [&] {  // built only when an error is thrown
    return "line " + std::to_string(cur.lineno) + ": element " + quote(e.name) + " record " +
           std::to_string(record);
  };
  const char* p = line.data();
  const char* end = p + line.size();
  // The next token, or an empty view at the end of the line.
  const auto next = [&]() {
    while (p < end && isBlank(*p)) ++p;
    const char* token = p;
    while (p < end && !isBlank(*p)) ++p;
    return std::string_view(token, static_cast<std::size_t>(p - token));
  };
  std::uint64_t expected = 0, found = 0;
  for (const Property& prop : e.props) {
    const std::string_view token = next();
    ++expected;
    if (token.empty()) continue;
    ++found;
    if (!prop.is_list) continue;
    double length = 0.0;
    if (!parseAsciiValue(token.data(), token.data() + token.size(), prop.count_type, length) ||
        length < 0.0)
      throw Error(name, where() + ": list " + quote(prop.name) + ": length " + quote(token) +
                            " is not a valid " + std::string(typeName(prop.count_type)) + " count");
    const auto items = static_cast<std::uint64_t>(length);
    expected += items;
    for (std::uint64_t k = 0; k < items && !next().empty(); ++k) ++found;
  }
  while (!next().empty()) ++found;
  if (found != expected)
    throw Error(name, where() + ": expected " + std::to_string(expected) + " values, found " +
                          std::to_string(found) + " (truncated or malformed)");
}

// In ascii every record of a non-vertex element is one line (list or not), holding the values its
// list lengths call for.
void skipAsciiElement(AsciiCursor& cur, const Element& e, const std::string& name) {
  if (e.props.empty()) return;
  std::string_view line;
  for (std::uint64_t r = 0; r < e.count; ++r) {
    if (!cur.next(line))
      throw Error(name, "element " + quote(e.name) + ": data truncated: file ends after " +
                            std::to_string(r) + " of " + std::to_string(e.count) + " records");
    checkAsciiRecord(line, e, cur, r, name);
  }
}

// ---- writing ------------------------------------------------------------------------------------

// One property written per point: where its value comes from.
struct Column {
  std::string name;
  ScalarType type = ScalarType::Float32;
  const float* f = nullptr;         // points/normals (stride 3)
  const std::uint8_t* b = nullptr;  // colours (stride 3)
  const ScalarField* field = nullptr;

  double value(std::size_t i) const {
    if (f) return f[3 * i];
    if (b) return b[3 * i];
    return field->values[i];
  }
};

std::vector<Column> columnsOf(const PointCloud& cloud, const std::string& path) {
  std::vector<Column> cols;
  const char* axes[] = {"x", "y", "z"};
  const char* normal_names[] = {"nx", "ny", "nz"};
  const char* color_names[] = {"red", "green", "blue"};
  // With no points no value is ever read; a dummy keeps the pointer arithmetic defined.
  static const float kNoPoint[3] = {0.0f, 0.0f, 0.0f};
  const float* points = cloud.points.empty() ? kNoPoint : cloud.points.data()->data();
  for (int k = 0; k < 3; ++k) cols.push_back({axes[k], ScalarType::Float32, points + k, {}, {}});
  if (cloud.hasNormals())
    for (int k = 0; k < 3; ++k)
      cols.push_back(
          {normal_names[k], ScalarType::Float32, cloud.normals.data()->data() + k, {}, {}});
  if (cloud.hasColors())
    for (int k = 0; k < 3; ++k)
      cols.push_back(
          {color_names[k], ScalarType::UInt8, nullptr, cloud.colors.data()->data() + k, {}});
  for (const ScalarField& f : cloud.fields) {
    const bool bad_char = std::any_of(f.name.begin(), f.name.end(), [](char c) {
      return static_cast<unsigned char>(c) <= 0x20 || static_cast<unsigned char>(c) >= 0x7f;
    });
    if (f.name.empty() || bad_char)
      throw Error(path, "field " + quote(f.name) + ": name is not a valid PLY property name");
    cols.push_back({f.name, f.type, nullptr, nullptr, &f});
  }
  // Every field must read back as itself: no duplicates, no name the reader would take as a
  // coordinate, normal, colour or alpha.
  std::vector<std::string_view> names;
  for (const Column& c : cols) names.push_back(c.name);
  const std::vector<Role> roles = classify(names);
  std::unordered_set<std::string_view> seen;
  for (std::size_t i = 0; i < cols.size(); ++i) {
    if (!seen.insert(names[i]).second)
      throw Error(path, "field " + quote(names[i]) + ": duplicate property name");
    if (cols[i].field && roles[i] != Role::Field)
      throw Error(path, "field " + quote(names[i]) +
                            ": name is reserved in PLY (would not read back as a field)");
  }
  return cols;
}

std::string headerText(const std::vector<Column>& cols, std::size_t n, PlyFormat format,
                       const std::vector<Triangle>* faces) {
  std::string h = "ply\nformat ";
  h += format == PlyFormat::Ascii             ? "ascii"
       : format == PlyFormat::BinaryBigEndian ? "binary_big_endian"
                                              : "binary_little_endian";
  h += " 1.0\ncomment generated by planesdf\nelement vertex " + std::to_string(n) + "\n";
  for (const Column& c : cols)
    h += "property " + std::string(typeName(c.type)) + " " + c.name + "\n";
  if (faces)
    h += "element face " + std::to_string(faces->size()) +
         "\nproperty list uchar int vertex_indices\n";
  return h + "end_header\n";
}

void checkValue(double v, const Column& c, std::size_t i, const std::string& path) {
  if (!representable(v, c.type))
    throw Error(path, "field " + quote(c.name) + " at point " + std::to_string(i) + ": value " +
                          std::to_string(v) + " cannot be stored as " +
                          std::string(typeName(c.type)));
}

// Appends `v` as the shortest decimal text that reads back to exactly the same value.
void appendNumber(std::string& out, double v, ScalarType t) {
  char buf[64];
  std::to_chars_result r{};
  if (t == ScalarType::Float32) {
    r = std::to_chars(buf, buf + sizeof(buf), static_cast<float>(v));
  } else if (t == ScalarType::Float64) {
    r = std::to_chars(buf, buf + sizeof(buf), v);
  } else {
    r = std::to_chars(buf, buf + sizeof(buf), static_cast<long long>(v));
  }
  out.append(buf, r.ptr);
}

constexpr std::size_t kChunkBytes = 1 << 20;

void writeAsciiBody(std::ostream& out, const std::vector<Column>& cols, std::size_t n,
                    const std::string& path) {
  std::string chunk;
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t k = 0; k < cols.size(); ++k) {
      const double v = cols[k].value(i);
      if (cols[k].field) checkValue(v, cols[k], i, path);
      if (k) chunk += ' ';
      appendNumber(chunk, v, cols[k].type);
    }
    chunk += '\n';
    if (chunk.size() >= kChunkBytes) {
      out.write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
      chunk.clear();
    }
  }
  out.write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
}

void writeBinaryBody(std::ostream& out, const std::vector<Column>& cols, std::size_t n, bool swap,
                     const std::string& path) {
  std::size_t stride = 0;
  for (const Column& c : cols) stride += static_cast<std::size_t>(scalarTypeSize(c.type));
  const std::size_t per_chunk = std::max<std::size_t>(1, kChunkBytes / stride);
  std::string chunk;
  for (std::size_t first = 0; first < n; first += per_chunk) {
    const std::size_t count = std::min(per_chunk, n - first);
    chunk.resize(count * stride);
    char* p = chunk.data();
    for (std::size_t i = first; i < first + count; ++i) {
      for (const Column& c : cols) {
        const double v = c.value(i);
        if (c.field) checkValue(v, c, i, path);
        storeValue(p, v, c.type, swap);
        p += scalarTypeSize(c.type);
      }
    }
    out.write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
  }
}

// Throws unless every index of `faces` is a vertex of a cloud of `n` and fits a PLY int.
void checkFaces(const std::vector<Triangle>& faces, std::size_t n, const std::string& path) {
  if (n > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    throw Error(path, std::to_string(n) + " vertices are more than PLY int indices can address");
  for (std::size_t i = 0; i < faces.size(); ++i)
    for (const std::uint32_t v : faces[i])
      if (v >= n)
        throw Error(path, "face " + std::to_string(i) + ": vertex index " + std::to_string(v) +
                              " is not below the vertex count " + std::to_string(n));
}

void writeFaces(std::ostream& out, const std::vector<Triangle>& faces, PlyFormat format) {
  const bool swap = (format == PlyFormat::BinaryLittleEndian) != hostIsLittleEndian();
  constexpr std::size_t kPerChunk = 1 << 16;
  std::string chunk;
  for (std::size_t first = 0; first < faces.size(); first += kPerChunk) {
    const std::size_t last = std::min(faces.size(), first + kPerChunk);
    chunk.clear();
    for (std::size_t i = first; i < last; ++i) {
      if (format == PlyFormat::Ascii) {
        chunk += '3';
        for (const std::uint32_t v : faces[i]) {
          chunk += ' ';
          appendNumber(chunk, v, ScalarType::Int32);
        }
        chunk += '\n';
        continue;
      }
      char record[13];
      record[0] = 3;
      for (int k = 0; k < 3; ++k)
        storeValue(record + 1 + 4 * k, faces[i][k], ScalarType::Int32, swap);
      chunk.append(record, sizeof record);
    }
    out.write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
  }
}

// writePly (faces == nullptr) and writePlyMesh.
void writePlyFile(const std::string& path, const PointCloud& cloud,
                  const std::vector<Triangle>* faces, PlyFormat format) {
  cloud.validate(path);
  const std::vector<Column> cols = columnsOf(cloud, path);
  const std::size_t n = cloud.size();
  if (faces) checkFaces(*faces, n, path);
  const std::string header = headerText(cols, n, format, faces);
  const bool swap = (format == PlyFormat::BinaryLittleEndian) != hostIsLittleEndian();
  // Field values are range-checked while writing; a failure leaves any existing file in place.
  writeFileAtomic(path, [&](std::ostream& out) {
    out.write(header.data(), static_cast<std::streamsize>(header.size()));
    if (format == PlyFormat::Ascii) {
      writeAsciiBody(out, cols, n, path);
    } else {
      writeBinaryBody(out, cols, n, swap, path);
    }
    if (faces) writeFaces(out, *faces, format);
  });
}

}  // namespace

PointCloud parsePly(const std::string& bytes_in, const std::string& name) {
  const std::string_view bytes(bytes_in);
  const Header h = parseHeader(bytes, name);
  const Element& vertex = findVertexElement(h, name);

  PointCloud cloud;
  if (h.format == PlyFormat::Ascii) {
    AsciiCursor cur{bytes, h.data_begin, h.last_line};
    for (const Element& e : h.elements) {
      if (&e == &vertex) {
        readAsciiVertices(cur, e, name, cloud);
      } else {
        skipAsciiElement(cur, e, name);
      }
    }
  } else {
    const bool swap = (h.format == PlyFormat::BinaryLittleEndian) != hostIsLittleEndian();
    std::size_t pos = h.data_begin;
    for (const Element& e : h.elements) {
      if (&e == &vertex) {
        readBinaryVertices(bytes, pos, e, swap, name, cloud);
      } else {
        skipBinaryElement(bytes, pos, e, swap, name);
      }
    }
  }
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  cloud.height = 1;
  cloud.sensor_pose = Pose::Identity();
  return cloud;
}

PointCloud readPly(const std::string& path) {
  return parsePly(readFile(path), path);
}

void writePly(const std::string& path, const PointCloud& cloud, PlyFormat format) {
  writePlyFile(path, cloud, nullptr, format);
}

void writePlyMesh(const std::string& path, const PointCloud& vertices,
                  const std::vector<Triangle>& triangles, PlyFormat format) {
  writePlyFile(path, vertices, &triangles, format);
}

}  // namespace planesdf::io
