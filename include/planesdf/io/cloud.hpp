#pragma once
/// \file cloud.hpp
/// Format dispatch by file extension (.ply / .pcd, case-insensitive).

#include <string>

#include "planesdf/types.hpp"

namespace planesdf::io {

/// Reads a .ply or .pcd file; throws planesdf::Error for other extensions or bad content.
PointCloud readCloud(const std::string& path);

/// readCloud() for clouds a pipeline must use: also throws planesdf::Error naming the file when
/// the cloud has no valid point (empty, or every coordinate NaN/Inf).
PointCloud readSceneCloud(const std::string& path);

/// Throws planesdf::Error naming `path` when `cloud` has no point with finite coordinates.
void requireValidPoints(const PointCloud& cloud, const std::string& path);

/// Writes a .ply (binary little endian) or .pcd (binary_compressed) file atomically.
void writeCloud(const std::string& path, const PointCloud& cloud);

}  // namespace planesdf::io
