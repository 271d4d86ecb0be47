#include "planesdf/io/cloud.hpp"

#include <algorithm>
#include <cctype>
#include <filesystem>

#include "planesdf/error.hpp"
#include "planesdf/io/pcd.hpp"
#include "planesdf/io/ply.hpp"

namespace planesdf::io {
namespace {
std::string lowerExtension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}
}  // namespace

PointCloud readCloud(const std::string& path) {
  const std::string ext = lowerExtension(path);
  if (ext == ".ply") return readPly(path);
  if (ext == ".pcd") return readPcd(path);
  throw Error(path, "unsupported point cloud extension '" + ext + "' (expected .ply or .pcd)");
}

void requireValidPoints(const PointCloud& cloud, const std::string& path) {
  if (cloud.empty()) throw Error(path, "the cloud has no points");
  if (cloud.countValid() == 0)
    throw Error(path, "none of the " + std::to_string(cloud.size()) +
                          " points is valid (every coordinate is NaN or Inf)");
}

PointCloud readSceneCloud(const std::string& path) {
  PointCloud cloud = readCloud(path);
  requireValidPoints(cloud, path);
  return cloud;
}

void writeCloud(const std::string& path, const PointCloud& cloud) {
  const std::string ext = lowerExtension(path);
  if (ext == ".ply") return writePly(path, cloud);
  if (ext == ".pcd") return writePcd(path, cloud);
  throw Error(path, "unsupported point cloud extension '" + ext + "' (expected .ply or .pcd)");
}

}  // namespace planesdf::io
