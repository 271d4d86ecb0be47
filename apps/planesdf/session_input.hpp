#pragma once
// Loading one session for the CLI: a .ply/.pcd scene cloud, a TUM RGB-D folder, a .psdf map or
// (MRPT adapter builds) a .rawlog of 3D range scans.

#include <string>

#include "planesdf/error.hpp"
#include "planesdf/map.hpp"

namespace planesdf::cli {

/// The file name's extension, lower case, with its dot ("" when none).
std::string lowerExtension(const std::string& path);
/// Prints what a .rawlog holds: its 3D range scans, their image size, intrinsics and the extent
/// of their trajectory. Throws planesdf::Error naming the file (also when the MRPT adapter is
/// not built).
void printRawlogInfo(const std::string& path);
/// Parses "fx,fy,cx,cy[,width,height]" (throws planesdf::Error("--intrinsics", ...)).
Intrinsics parseIntrinsics(const std::string& text);

/// The map of one session input. TUM folders are fused frame by frame with progress on stderr
/// (prefixed by `label`); clouds go through Map::fromCloud; .psdf maps are loaded as saved;
/// .rawlog files (CObservation3DRangeScan, see planesdf/mrpt/range_scan.hpp) are fused scan by
/// scan when the MRPT adapter is built, else planesdf::Error names the file.
/// When `up_defaulted` (no --up given) and the input is an organised cloud in its own camera
/// frame (identity sensor pose), the up axis is estimated (auto) and a note goes to stderr.
Map loadSession(const std::string& input, const Config& cfg, const std::string& intrinsics,
                const std::string& label, bool up_defaulted = false);

/// Runs `f`; a planesdf::Error that names no file is rethrown naming `input`, so every CLI error
/// line says which input it is about.
template <class F>
auto namingInput(const std::string& input, F&& f) {
  try {
    return f();
  } catch (const Error& e) {
    if (!e.path().empty()) throw;
    throw Error(input, e.message());
  }
}

}  // namespace planesdf::cli
