// `planesdf info INPUT`: what a cloud file, TUM folder or session map holds; checks that it loads.
#include <iomanip>
#include <iostream>

#include "commands.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/io/tum.hpp"
#include "planesdf/map.hpp"
#include "session_input.hpp"

namespace planesdf::cli {

namespace {

/// A session map: its frames, kept points, memory and, per plane, the plane and its volume.
void printMap(const std::string& input) {
  const Map map = Map::load(input);
  std::size_t voxels = 0;
  for (const PlaneSdf& p : map.planes()) voxels += p.volume.numVoxels();
  std::cout << "session map " << input << "\n"
            << "  frames:    " << map.frames() << "\n"
            << "  planes:    " << map.planes().size() << "\n"
            << "  voxels:    " << voxels << " allocated ("
            << (map.planes().empty() ? 0.0 : map.planes().front().volume.voxelSize() * 1000.0)
            << " mm)\n"
            << "  points:    " << map.points().size() << " kept\n"
            << "  memory:    " << std::fixed << std::setprecision(1)
            << static_cast<double>(map.memoryBytes()) / 1e6 << " MB\n";
  const Eigen::IOFormat fmt(3, Eigen::DontAlignCols, " ", " ", "", "", "(", ")");
  for (const PlaneSdf& p : map.planes()) {
    const Plane& q = p.plane;
    const Eigen::Vector2d size =
        q.extent.isEmpty() ? Eigen::Vector2d::Zero() : Eigen::Vector2d(q.extent.sizes());
    std::cout << "  plane " << q.id << ": "
              << (q.orientation == Plane::Orientation::Horizontal ? "horizontal" : "vertical")
              << ", normal " << q.normal.transpose().format(fmt) << ", offset "
              << std::setprecision(3) << q.offset << " m, extent " << std::setprecision(2)
              << size.x() << " x " << size.y() << " m, " << p.volume.numBlocks() << " blocks, "
              << std::setprecision(1) << static_cast<double>(p.volume.memoryBytes()) / 1e6
              << " MB\n";
  }
}

}  // namespace

int runInfo(const std::string& input) {
  const std::string ext = lowerExtension(input);
  if (ext == ".psdf") {
    printMap(input);
    return 0;
  }
  if (ext == ".rawlog") {
    printRawlogInfo(input);
    return 0;
  }
  if (planesdf::io::isTumFolder(input)) {
    const auto seq = planesdf::io::readTumSequence(input);
    const auto& k = seq.intrinsics;
    std::cout << "TUM RGB-D sequence " << input << "\n"
              << "  frames:      " << seq.frames.size() << " (" << seq.dropped_frames
              << " without a pose dropped)\n"
              << "  intrinsics:  fx=" << k.fx << " fy=" << k.fy << " cx=" << k.cx << " cy=" << k.cy
              << " " << k.width << "x" << k.height << "\n"
              << "  depth scale: " << seq.depth_scale << " per metre\n";
    return 0;
  }
  const planesdf::PointCloud cloud = planesdf::io::readSceneCloud(input);
  Eigen::AlignedBox3f box;
  for (const auto& p : cloud.points)
    if (planesdf::PointCloud::isValid(p)) box.extend(p);
  std::cout << "point cloud " << input << "\n"
            << "  points:    " << cloud.size() << " (" << cloud.countValid() << " valid)\n"
            << "  layout:    " << (cloud.isOrganized() ? "organised " : "unorganised ")
            << cloud.width << "x" << cloud.height << "\n"
            << "  normals:   " << (cloud.hasNormals() ? "yes" : "no") << "\n"
            << "  colours:   " << (cloud.hasColors() ? "yes" : "no") << "\n";
  std::cout << "  fields:   ";
  for (const auto& f : cloud.fields) std::cout << " " << f.name;
  std::cout << (cloud.fields.empty() ? " none\n" : "\n");
  if (!box.isEmpty()) {
    const Eigen::IOFormat fmt(4, Eigen::DontAlignCols, " ", " ", "", "", "(", ")");
    std::cout << "  bounds:    " << box.min().transpose().format(fmt) << " .. "
              << box.max().transpose().format(fmt) << "\n";
  }
  const Eigen::Vector3d t = cloud.sensor_pose.translation();
  std::cout << "  sensor at: (" << t.x() << " " << t.y() << " " << t.z() << ")\n";
  return 0;
}

}  // namespace planesdf::cli
