#include "planesdf/io/tum.hpp"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <optional>
#include <ostream>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"

namespace planesdf::io {
namespace {
namespace fs = std::filesystem;

constexpr double kDefaultDepthScale = 1000.0;
constexpr int kMaxImageSide = 16384;
/// A ground-truth quaternion may deviate this much from unit length (rounding of its decimals).
constexpr double kQuaternionNormTolerance = 1e-3;

// ---- text helpers -------------------------------------------------------------------------------

/// One non-blank, non-comment line of an index file, split at whitespace.
struct TextLine {
  std::size_t number = 0;  ///< 1-based
  std::vector<std::string_view> tokens;
};

bool isSpace(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

/// Splits `text` into data lines; blank lines and lines starting with `#` are skipped. The
/// returned views point into `text`.
std::vector<TextLine> dataLines(const std::string& text) {
  std::vector<TextLine> lines;
  std::string_view rest(text);
  if (rest.substr(0, 3) == "\xEF\xBB\xBF") rest.remove_prefix(3);  // UTF-8 byte order mark
  std::size_t number = 0;
  while (!rest.empty()) {
    const std::size_t eol = rest.find('\n');
    std::string_view line = rest.substr(0, eol);
    rest.remove_prefix(eol == std::string_view::npos ? rest.size() : eol + 1);
    ++number;
    TextLine parsed;
    parsed.number = number;
    std::size_t i = 0;
    while (i < line.size()) {
      while (i < line.size() && isSpace(line[i])) ++i;
      std::size_t j = i;
      while (j < line.size() && !isSpace(line[j])) ++j;
      if (j > i) parsed.tokens.push_back(line.substr(i, j - i));
      i = j;
    }
    if (parsed.tokens.empty() || parsed.tokens.front().front() == '#') continue;
    lines.push_back(std::move(parsed));
  }
  return lines;
}

/// A token for an error message: quoted, at most 40 characters, control characters replaced.
std::string quote(std::string_view token) {
  constexpr std::size_t kMax = 40;
  std::string out = "'";
  for (std::size_t i = 0; i < token.size() && i < kMax; ++i) {
    const auto c = static_cast<unsigned char>(token[i]);
    out += (c < 0x20 || c == 0x7F) ? '?' : static_cast<char>(c);
  }
  if (token.size() > kMax) out += "...";
  return out + "'";
}

std::string lineTag(std::size_t number) {
  return "line " + std::to_string(number) + ": ";
}

/// Parses a whole token as a finite double (locale-independent); false otherwise.
bool parseFinite(std::string_view token, double& value) {
  if (!token.empty() && token.front() == '+') token.remove_prefix(1);
  if (token.empty()) return false;
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(token.data(), end, value);
  return ec == std::errc() && ptr == end && std::isfinite(value);
}

/// Parses a token of `line` in `path` as a finite double or throws naming the line and `what`.
double numberOrThrow(const std::string& path, const TextLine& line, std::size_t index,
                     const char* what) {
  double value = 0.0;
  if (!parseFinite(line.tokens[index], value))
    throw Error(path, lineTag(line.number) + what + " " + quote(line.tokens[index]) +
                          " is not a finite number");
  return value;
}

/// Shortest text that reads back as exactly `value` (locale-independent).
std::string formatShortest(double value) {
  std::array<char, 64> buf{};
  const auto result = std::to_chars(buf.data(), buf.data() + buf.size(), value);
  return std::string(buf.data(), result.ptr);
}

/// `value` with six significant digits (locale-independent).
std::string formatGeneral6(double value) {
  std::array<char, 64> buf{};
  const auto result =
      std::to_chars(buf.data(), buf.data() + buf.size(), value, std::chars_format::general, 6);
  return std::string(buf.data(), result.ptr);
}

/// `value` with exactly six decimals (locale-independent); `value` must be finite.
std::string formatFixed6(double value) {
  std::array<char, 512> buf{};  // enough for any finite double in fixed notation
  const auto result =
      std::to_chars(buf.data(), buf.data() + buf.size(), value, std::chars_format::fixed, 6);
  return std::string(buf.data(), result.ptr);
}

bool isPositiveFinite(double v) {
  return std::isfinite(v) && v > 0.0;
}

// ---- index files --------------------------------------------------------------------------------

struct DepthEntry {
  double timestamp = 0.0;
  std::string relative_path;
  std::size_t line = 0;
};

std::vector<DepthEntry> readDepthIndex(const std::string& path) {
  const std::string text = readFile(path);
  std::vector<DepthEntry> entries;
  for (const TextLine& line : dataLines(text)) {
    if (line.tokens.size() != 2)
      throw Error(path, lineTag(line.number) + "expected 'timestamp filename', got " +
                            std::to_string(line.tokens.size()) + " fields");
    DepthEntry e;
    e.timestamp = numberOrThrow(path, line, 0, "timestamp");
    e.relative_path = std::string(line.tokens[1]);
    e.line = line.number;
    entries.push_back(std::move(e));
  }
  if (entries.empty()) throw Error(path, "lists no depth frames");
  std::stable_sort(entries.begin(), entries.end(), [](const DepthEntry& a, const DepthEntry& b) {
    return a.timestamp < b.timestamp;
  });
  // One time, one frame: a repeated timestamp would fuse the same pose several times.
  for (std::size_t i = 1; i < entries.size(); ++i)
    if (entries[i].timestamp == entries[i - 1].timestamp)
      throw Error(path, lineTag(entries[i].line) + "timestamp " +
                            formatShortest(entries[i].timestamp) + " repeats line " +
                            std::to_string(entries[i - 1].line) + "'s");
  return entries;
}

struct StampedPose {
  double timestamp = 0.0;
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
};

std::vector<StampedPose> readGroundTruth(const std::string& path) {
  static const char* const kNames[] = {"timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"};
  const std::string text = readFile(path);
  std::vector<StampedPose> poses;
  for (const TextLine& line : dataLines(text)) {
    if (line.tokens.size() != 8)
      throw Error(path, lineTag(line.number) +
                            "expected 'timestamp tx ty tz qx qy qz qw' (8 numbers), got " +
                            std::to_string(line.tokens.size()) + " fields");
    std::array<double, 8> v{};
    for (std::size_t i = 0; i < v.size(); ++i) v[i] = numberOrThrow(path, line, i, kNames[i]);
    // TUM order is qx qy qz qw; Eigen's constructor takes w first.
    Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
    const double norm = q.coeffs().stableNorm();
    const std::string quaternion = "quaternion (" + std::string(line.tokens[4]) + " " +
                                   std::string(line.tokens[5]) + " " + std::string(line.tokens[6]) +
                                   " " + std::string(line.tokens[7]) + ")";
    if (!std::isfinite(norm) || norm < 1e-9)
      throw Error(path, lineTag(line.number) + quaternion + " has zero or non-finite length");
    // Rounded decimals are normalised; a length further from 1 is no rotation written down.
    if (std::abs(norm - 1.0) > kQuaternionNormTolerance)
      throw Error(path, lineTag(line.number) + quaternion + " has length " + formatGeneral6(norm) +
                            ", not 1 (within 0.001)");
    q.coeffs() /= norm;
    poses.push_back({v[0], Eigen::Vector3d(v[1], v[2], v[3]), q});
  }
  if (poses.empty()) throw Error(path, "has no poses");
  std::stable_sort(poses.begin(), poses.end(), [](const StampedPose& a, const StampedPose& b) {
    return a.timestamp < b.timestamp;
  });
  return poses;
}

// ---- intrinsics.txt -----------------------------------------------------------------------------

struct IntrinsicsFile {
  Intrinsics intrinsics;
  std::optional<double> depth_scale;
};

double depthScaleOrThrow(const std::string& path, const TextLine& line, std::size_t index) {
  const double s = numberOrThrow(path, line, index, "depth_scale");
  if (!(s > 0.0)) throw Error(path, lineTag(line.number) + "depth_scale must be positive");
  return s;
}

int imageSideOrThrow(const std::string& path, const TextLine& line, const char* key) {
  const double v = numberOrThrow(path, line, 1, key);
  if (v != std::floor(v) || v < 1.0 || v > kMaxImageSide)
    throw Error(path, lineTag(line.number) + key + " " + quote(line.tokens[1]) +
                          " must be an integer in [1, " + std::to_string(kMaxImageSide) + "]");
  return static_cast<int>(v);
}

/// The single-line form `fx fy cx cy [depth_scale]` (image size stays at the TUM 640x480).
IntrinsicsFile parseIntrinsicsLine(const std::string& path, const std::vector<TextLine>& lines) {
  const TextLine& line = lines.front();
  if (lines.size() > 1)
    throw Error(path, lineTag(lines[1].number) +
                          "expected a single line 'fx fy cx cy [depth_scale]' or 'key value' "
                          "lines");
  if (line.tokens.size() != 4 && line.tokens.size() != 5)
    throw Error(path, lineTag(line.number) +
                          "expected 'fx fy cx cy [depth_scale]' (4 or 5 numbers), got " +
                          std::to_string(line.tokens.size()) + " fields");
  IntrinsicsFile out;
  out.intrinsics.fx = numberOrThrow(path, line, 0, "fx");
  out.intrinsics.fy = numberOrThrow(path, line, 1, "fy");
  out.intrinsics.cx = numberOrThrow(path, line, 2, "cx");
  out.intrinsics.cy = numberOrThrow(path, line, 3, "cy");
  if (line.tokens.size() == 5) out.depth_scale = depthScaleOrThrow(path, line, 4);
  return out;
}

/// The `key value` form; fx fy cx cy are required, width/height default to 640x480.
IntrinsicsFile parseIntrinsicsKeys(const std::string& path, const std::vector<TextLine>& lines) {
  IntrinsicsFile out;
  std::vector<std::string_view> seen;
  for (const TextLine& line : lines) {
    const std::string_view key = line.tokens.front();
    if (line.tokens.size() != 2)
      throw Error(path, lineTag(line.number) + "expected 'key value', got " +
                            std::to_string(line.tokens.size()) + " fields");
    if (std::find(seen.begin(), seen.end(), key) != seen.end())
      throw Error(path, lineTag(line.number) + "duplicate key " + quote(key));
    seen.push_back(key);
    if (key == "fx") {
      out.intrinsics.fx = numberOrThrow(path, line, 1, "fx");
    } else if (key == "fy") {
      out.intrinsics.fy = numberOrThrow(path, line, 1, "fy");
    } else if (key == "cx") {
      out.intrinsics.cx = numberOrThrow(path, line, 1, "cx");
    } else if (key == "cy") {
      out.intrinsics.cy = numberOrThrow(path, line, 1, "cy");
    } else if (key == "width") {
      out.intrinsics.width = imageSideOrThrow(path, line, "width");
    } else if (key == "height") {
      out.intrinsics.height = imageSideOrThrow(path, line, "height");
    } else if (key == "depth_scale") {
      out.depth_scale = depthScaleOrThrow(path, line, 1);
    } else {
      throw Error(path, lineTag(line.number) + "unknown key " + quote(key) +
                            " (expected fx, fy, cx, cy, width, height or depth_scale)");
    }
  }
  for (const char* required : {"fx", "fy", "cx", "cy"})
    if (std::find(seen.begin(), seen.end(), std::string_view(required)) == seen.end())
      throw Error(path, std::string("missing key '") + required + "'");
  return out;
}

IntrinsicsFile readIntrinsicsFile(const std::string& path) {
  const std::string text = readFile(path);
  const std::vector<TextLine> lines = dataLines(text);
  if (lines.empty()) throw Error(path, "holds no intrinsics");
  double ignored = 0.0;
  return parseFinite(lines.front().tokens.front(), ignored) ? parseIntrinsicsLine(path, lines)
                                                            : parseIntrinsicsKeys(path, lines);
}

// ---- association --------------------------------------------------------------------------------

Pose makePose(const Eigen::Vector3d& translation, const Eigen::Quaterniond& rotation) {
  Pose pose = Pose::Identity();
  pose.linear() = rotation.normalized().toRotationMatrix();
  pose.translation() = translation;
  return pose;
}

/// The pose at time `t` (poses sorted by time): interpolated when bracketed by two poses at most
/// max_interp_gap apart, else the nearest within max_time_diff, else none.
std::optional<Pose> poseAt(const std::vector<StampedPose>& poses, double t,
                           const TumOptions& options) {
  const auto it =
      std::lower_bound(poses.begin(), poses.end(), t,
                       [](const StampedPose& p, double time) { return p.timestamp < time; });
  if (it != poses.end() && it->timestamp == t) return makePose(it->translation, it->rotation);
  const StampedPose* before = it == poses.begin() ? nullptr : &*(it - 1);
  const StampedPose* after = it == poses.end() ? nullptr : &*it;
  if (before && after) {
    const double gap = after->timestamp - before->timestamp;
    if (gap <= options.max_interp_gap) {
      const double alpha = gap > 0.0 ? (t - before->timestamp) / gap : 0.0;
      const Eigen::Vector3d translation =
          (1.0 - alpha) * before->translation + alpha * after->translation;
      return makePose(translation, before->rotation.slerp(alpha, after->rotation));
    }
  }
  const StampedPose* nearest = before;
  if (!nearest || (after && after->timestamp - t < t - before->timestamp)) nearest = after;
  if (nearest && std::abs(nearest->timestamp - t) <= options.max_time_diff)
    return makePose(nearest->translation, nearest->rotation);
  return std::nullopt;
}

// ---- PNG ----------------------------------------------------------------------------------------

std::string pngColorTypeName(int color_type) {
  switch (color_type) {
    case 0:
      return "grayscale";
    case 2:
      return "RGB";
    case 3:
      return "palette";
    case 4:
      return "grayscale+alpha";
    case 6:
      return "RGBA";
    default:
      return "colour type " + std::to_string(color_type);
  }
}

std::string matTypeName(int type) {
  static const char* const kDepths[] = {"8U", "8S", "16U", "16S", "32S", "32F", "64F", "16F"};
  return std::string("CV_") + kDepths[CV_MAT_DEPTH(type)] + "C" + std::to_string(CV_MAT_CN(type));
}

std::uint32_t readBigEndian32(const unsigned char* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) |
         std::uint32_t{p[3]};
}

/// Checks the PNG signature and IHDR chunk before decoding, so a wrong type or size is reported
/// without decoding (or allocating for) the image.
void checkPngHeader(const std::string& path, const Intrinsics& intrinsics) {
  requireRegularFile(path);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path, "cannot open depth PNG");
  std::array<unsigned char, 26> h{};
  in.read(reinterpret_cast<char*>(h.data()), static_cast<std::streamsize>(h.size()));
  static const unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  if (in.gcount() < 8 || !std::equal(kSignature, kSignature + 8, h.begin()))
    throw Error(path, "not a PNG file (bad signature)");
  if (in.gcount() < static_cast<std::streamsize>(h.size()) || readBigEndian32(&h[8]) != 13 ||
      !std::equal(h.begin() + 12, h.begin() + 16, "IHDR"))
    throw Error(path, "truncated or corrupt PNG header (no IHDR chunk)");
  const int bit_depth = h[24];
  const int color_type = h[25];
  if (bit_depth != 16 || color_type != 0)
    throw Error(path, "expected a 16-bit single-channel depth PNG, got " +
                          std::to_string(bit_depth) + "-bit " + pngColorTypeName(color_type));
  const std::uint32_t width = readBigEndian32(&h[16]);
  const std::uint32_t height = readBigEndian32(&h[20]);
  if (width != static_cast<std::uint32_t>(intrinsics.width) ||
      height != static_cast<std::uint32_t>(intrinsics.height))
    throw Error(path, "image size " + std::to_string(width) + "x" + std::to_string(height) +
                          " does not match the intrinsics' " + std::to_string(intrinsics.width) +
                          "x" + std::to_string(intrinsics.height));
}

void checkDepthScale(const std::string& path, double depth_scale) {
  if (!isPositiveFinite(depth_scale))
    throw Error(path,
                "depth_scale " + formatShortest(depth_scale) + " must be positive and finite");
}

std::uint16_t depthToPngValue(float metres, double depth_scale) {
  if (!DepthFrame::isValidDepth(metres)) return 0;
  const double v = std::round(static_cast<double>(metres) * depth_scale);
  return static_cast<std::uint16_t>(std::min(v, 65535.0));
}

}  // namespace

// ---- public API ---------------------------------------------------------------------------------

bool isTumFolder(const std::string& folder) {
  std::error_code ec;
  return fs::is_directory(folder, ec) && fs::is_regular_file(fs::path(folder) / "depth.txt", ec);
}

TumSequence readTumSequence(const std::string& folder, const TumOptions& options) {
  std::error_code ec;
  const fs::file_status status = fs::status(folder, ec);
  if (!fs::exists(status)) throw Error(folder, "folder does not exist");
  if (!fs::is_directory(status)) throw Error(folder, "is not a folder");
  const fs::path dir(folder);
  if (!fs::exists(dir / "depth.txt", ec))
    throw Error(folder, "not a TUM RGB-D sequence: no depth.txt");
  if (!fs::exists(dir / "groundtruth.txt", ec))
    throw Error(folder, "no groundtruth.txt (the camera poses are required)");
  if (!(options.max_time_diff >= 0.0) || !(options.max_interp_gap >= 0.0))
    throw Error(folder, "max_time_diff and max_interp_gap must be non-negative");

  TumSequence seq;
  seq.folder = folder;

  // Intrinsics and depth scale: explicit options > intrinsics.txt > defaults. intrinsics.txt is
  // still read for its depth_scale when only the intrinsics are given.
  const std::string intrinsics_path = (dir / "intrinsics.txt").string();
  std::optional<IntrinsicsFile> from_file;
  const bool need_file = !options.intrinsics || !options.depth_scale;
  if (need_file && fs::exists(intrinsics_path, ec)) from_file = readIntrinsicsFile(intrinsics_path);
  if (options.intrinsics) {
    try {
      options.intrinsics->validate(folder);
    } catch (const Error& e) {
      throw Error(folder, "--intrinsics: " + e.message());
    }
    seq.intrinsics = *options.intrinsics;
  } else if (from_file) {
    from_file->intrinsics.validate(intrinsics_path);
    seq.intrinsics = from_file->intrinsics;
  } else {
    throw Error(folder, "no intrinsics.txt and no --intrinsics given");
  }
  if (options.depth_scale) {
    if (!isPositiveFinite(*options.depth_scale))
      throw Error(folder, "--depth-scale " + formatShortest(*options.depth_scale) +
                              " must be positive and finite");
    seq.depth_scale = *options.depth_scale;
  } else if (from_file && from_file->depth_scale) {
    seq.depth_scale = *from_file->depth_scale;
  } else {
    seq.depth_scale = kDefaultDepthScale;
  }

  const std::vector<DepthEntry> depth = readDepthIndex((dir / "depth.txt").string());
  const std::vector<StampedPose> poses = readGroundTruth((dir / "groundtruth.txt").string());
  for (const DepthEntry& entry : depth) {
    const std::optional<Pose> pose = poseAt(poses, entry.timestamp, options);
    if (!pose) {
      ++seq.dropped_frames;
      continue;
    }
    TumFrame frame;
    frame.timestamp = entry.timestamp;
    frame.depth_path = (dir / entry.relative_path).string();
    frame.pose = *pose;
    seq.frames.push_back(std::move(frame));
  }
  if (seq.frames.empty())
    throw Error(folder, "no depth frame has a ground-truth pose (" + std::to_string(depth.size()) +
                            " depth frames from " + formatShortest(depth.front().timestamp) +
                            " to " + formatShortest(depth.back().timestamp) + " s, " +
                            std::to_string(poses.size()) + " poses from " +
                            formatShortest(poses.front().timestamp) + " to " +
                            formatShortest(poses.back().timestamp) + " s)");
  return seq;
}

DepthFrame loadTumDepth(const TumSequence& seq, std::size_t i) {
  if (i >= seq.frames.size())
    throw Error(seq.folder, "frame index " + std::to_string(i) + " out of range (" +
                                std::to_string(seq.frames.size()) + " frames)");
  DepthFrame frame = readDepthPng(seq.frames[i].depth_path, seq.intrinsics, seq.depth_scale);
  frame.timestamp = seq.frames[i].timestamp;
  return frame;
}

DepthFrame readDepthPng(const std::string& path, const Intrinsics& intrinsics, double depth_scale) {
  intrinsics.validate(path);
  checkDepthScale(path, depth_scale);
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) throw Error(path, "depth PNG does not exist");
  if (!fs::is_regular_file(status)) throw Error(path, "depth PNG is not a regular file");
  checkPngHeader(path, intrinsics);

  cv::Mat image;
  try {
    image = cv::imread(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    throw Error(path, "cannot decode depth PNG: " + e.err);
  }
  if (image.empty()) throw Error(path, "cannot decode depth PNG (corrupt or truncated?)");
  if (image.type() != CV_16UC1)
    throw Error(path,
                "expected a 16-bit single-channel depth PNG, got " + matTypeName(image.type()));
  if (image.cols != intrinsics.width || image.rows != intrinsics.height)
    throw Error(path, "image size " + std::to_string(image.cols) + "x" +
                          std::to_string(image.rows) + " does not match the intrinsics' " +
                          std::to_string(intrinsics.width) + "x" +
                          std::to_string(intrinsics.height));

  DepthFrame frame;
  frame.intrinsics = intrinsics;
  frame.depth.resize(static_cast<std::size_t>(image.cols) * image.rows);
  for (int v = 0; v < image.rows; ++v) {
    const auto* row = image.ptr<std::uint16_t>(v);
    float* out = frame.depth.data() + static_cast<std::size_t>(v) * image.cols;
    for (int u = 0; u < image.cols; ++u)
      out[u] = row[u] == 0 ? 0.0f : static_cast<float>(row[u] / depth_scale);
  }
  return frame;
}

void writeDepthPng(const std::string& path, const DepthFrame& frame, double depth_scale) {
  const Intrinsics& in = frame.intrinsics;
  in.validate(path);
  checkDepthScale(path, depth_scale);
  const std::size_t expected = static_cast<std::size_t>(in.width) * in.height;
  if (frame.depth.size() != expected)
    throw Error(path, "depth frame has " + std::to_string(frame.depth.size()) + " values for a " +
                          std::to_string(in.width) + "x" + std::to_string(in.height) + " image");

  cv::Mat image(in.height, in.width, CV_16UC1);
  for (int v = 0; v < in.height; ++v) {
    auto* row = image.ptr<std::uint16_t>(v);
    for (int u = 0; u < in.width; ++u) row[u] = depthToPngValue(frame.at(u, v), depth_scale);
  }
  std::vector<unsigned char> buffer;
  try {
    if (!cv::imencode(".png", image, buffer)) throw Error(path, "PNG encoding failed");
  } catch (const cv::Exception& e) {
    throw Error(path, "PNG encoding failed: " + e.err);
  }
  writeFileAtomic(path, [&](std::ostream& out) {
    out.write(reinterpret_cast<const char*>(buffer.data()),
              static_cast<std::streamsize>(buffer.size()));
  });
}

void writeTumSequence(const std::string& folder, const std::vector<DepthFrame>& frames,
                      const std::vector<Pose>& poses, double depth_scale) {
  if (frames.size() != poses.size())
    throw Error(folder, std::to_string(frames.size()) + " depth frames but " +
                            std::to_string(poses.size()) + " poses");
  if (frames.empty()) throw Error(folder, "no frames to write");
  checkDepthScale(folder, depth_scale);
  const Intrinsics& in = frames.front().intrinsics;
  std::vector<std::string> stamps;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const Intrinsics& k = frames[i].intrinsics;
    if (k.fx != in.fx || k.fy != in.fy || k.cx != in.cx || k.cy != in.cy || k.width != in.width ||
        k.height != in.height)
      throw Error(folder, "frame " + std::to_string(i) + " has intrinsics different from frame 0");
    if (!std::isfinite(frames[i].timestamp))
      throw Error(folder, "frame " + std::to_string(i) + " has a non-finite timestamp");
    if (!poses[i].matrix().allFinite())
      throw Error(folder, "pose " + std::to_string(i) + " is not finite");
    stamps.push_back(formatFixed6(frames[i].timestamp));
  }
  {
    std::vector<std::string> sorted = stamps;
    std::sort(sorted.begin(), sorted.end());
    const auto dup = std::adjacent_find(sorted.begin(), sorted.end());
    if (dup != sorted.end())
      throw Error(folder, "two frames have the same timestamp " + *dup + " (to 6 decimals)");
  }
  in.validate(folder);

  const fs::path dir(folder);
  std::error_code ec;
  fs::create_directories(dir / "depth", ec);
  if (ec || !fs::is_directory(dir / "depth"))
    throw Error(folder, "cannot create folder '" + (dir / "depth").string() +
                            "': " + (ec ? ec.message() : std::string("not a folder")));

  std::string depth_txt = "# depth maps\n# timestamp filename\n";
  std::string groundtruth_txt = "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n";
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const std::string relative = "depth/" + stamps[i] + ".png";
    writeDepthPng((dir / relative).string(), frames[i], depth_scale);
    depth_txt += stamps[i] + " " + relative + "\n";
    const Eigen::Vector3d t = poses[i].translation();
    const Eigen::Quaterniond q = Eigen::Quaterniond(poses[i].linear()).normalized();
    groundtruth_txt += stamps[i];
    for (double v : {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()})
      groundtruth_txt += " " + formatShortest(v);
    groundtruth_txt += "\n";
  }
  const std::string intrinsics_txt =
      "# pinhole intrinsics (pixels); depth PNG value = metres * depth_scale\n"
      "fx " +
      formatShortest(in.fx) + "\nfy " + formatShortest(in.fy) + "\ncx " + formatShortest(in.cx) +
      "\ncy " + formatShortest(in.cy) + "\nwidth " + std::to_string(in.width) + "\nheight " +
      std::to_string(in.height) + "\ndepth_scale " + formatShortest(depth_scale) + "\n";

  const auto writeText = [](const fs::path& path, const std::string& text) {
    writeFileAtomic(path.string(), [&](std::ostream& out) { out << text; });
  };
  writeText(dir / "depth.txt", depth_txt);
  writeText(dir / "groundtruth.txt", groundtruth_txt);
  writeText(dir / "intrinsics.txt", intrinsics_txt);
}

}  // namespace planesdf::io
