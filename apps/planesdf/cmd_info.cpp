// `planesdf info INPUT`: what a cloud file or TUM folder holds; checks that it loads.
#include <iostream>

#include "commands.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/io/tum.hpp"

namespace planesdf::cli {

int runInfo(const std::string& input) {
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
