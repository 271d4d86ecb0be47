#pragma once
/// \file tum.hpp
/// TUM RGB-D format folders: `depth.txt` (timestamp filename), `depth/*.png` (16-bit depth,
/// metres = value / depth_scale), `groundtruth.txt` (timestamp tx ty tz qx qy qz qw,
/// camera-to-world) and an optional `intrinsics.txt`.
///
/// intrinsics.txt holds `key value` lines (fx, fy, cx, cy, width, height, depth_scale; `#`
/// comments), or a single line `fx fy cx cy [depth_scale]`. Without it the intrinsics passed by
/// the caller (e.g. the `--intrinsics` flag) are used, and depth_scale defaults to 1000 (mm).

#include <optional>
#include <string>
#include <vector>

#include "planesdf/types.hpp"

namespace planesdf::io {

struct TumFrame {
  double timestamp = 0.0;
  std::string depth_path;  ///< absolute or relative to the current folder, ready to open
  Pose pose = Pose::Identity();
};

struct TumSequence {
  std::string folder;
  Intrinsics intrinsics;
  double depth_scale = 1000.0;     ///< PNG value per metre
  std::vector<TumFrame> frames;    ///< depth frames that received a pose, in time order
  std::size_t dropped_frames = 0;  ///< depth frames with no ground-truth pose near enough
};

struct TumOptions {
  /// Use these intrinsics when the folder has no intrinsics.txt (and override it when set).
  std::optional<Intrinsics> intrinsics;
  std::optional<double> depth_scale;
  /// A depth frame takes the nearest pose within this time (s) ...
  double max_time_diff = 0.02;
  /// ... or a pose interpolated between two poses that bracket it and are at most this far apart.
  double max_interp_gap = 0.1;
};

/// True when `folder` looks like a TUM sequence (a folder with depth.txt).
bool isTumFolder(const std::string& folder);

/// Reads the index files of a TUM folder and associates each depth frame with a pose
/// (interpolated when bracketed, else nearest). Throws planesdf::Error naming the folder or file
/// when it is not a TUM sequence, an index line is malformed (the error names the line; a
/// ground-truth number that is not finite, or a quaternion whose length is not 1 within 0.001),
/// no intrinsics are available, or no depth frame has a pose. Quaternions within that tolerance
/// are normalised.
TumSequence readTumSequence(const std::string& folder, const TumOptions& options = {});

/// Loads the 16-bit PNG of frame `i` as a DepthFrame in metres. Throws planesdf::Error naming the
/// PNG when it is missing, not 16-bit single-channel, or its size disagrees with the intrinsics.
DepthFrame loadTumDepth(const TumSequence& seq, std::size_t i);

/// Reads/writes one 16-bit depth PNG (value = metres * depth_scale), atomically on write.
DepthFrame readDepthPng(const std::string& path, const Intrinsics& intrinsics, double depth_scale);
void writeDepthPng(const std::string& path, const DepthFrame& frame, double depth_scale);

/// Writes a TUM folder (depth/, depth.txt, groundtruth.txt, intrinsics.txt) from frames and
/// poses; used by the simulator and by tests.
void writeTumSequence(const std::string& folder, const std::vector<DepthFrame>& frames,
                      const std::vector<Pose>& poses, double depth_scale = 1000.0);

}  // namespace planesdf::io
