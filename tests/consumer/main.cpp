// Links the installed library, writes and reads back a cloud, exits 0 on success.
#include <cstdio>
#include <filesystem>

#include "planesdf/planesdf.hpp"  // the umbrella header, as installed
#ifdef HAVE_PLANESDF_OCTOMAP
#include "planesdf/octomap/octomap_conversion.hpp"
#endif

int main() {
  planesdf::PointCloud c;
  c.points = {{0.f, 0.f, 1.f}, {1.f, 2.f, 3.f}};
  c.width = 2;
  const auto path = (std::filesystem::temp_directory_path() / "planesdf_consumer.ply").string();
  planesdf::io::writePly(path, c);
  const auto back = planesdf::io::readPly(path);
  std::filesystem::remove(path);
  // A struct with a Pose crosses the library boundary both ways (the build may use
  // -march=native: the layouts must still agree).
  c.sensor_pose.translation() = Eigen::Vector3d(1.0, 2.0, 3.0);
  const auto pcd = (std::filesystem::temp_directory_path() / "planesdf_consumer.pcd").string();
  planesdf::io::writePcd(pcd, c);
  const auto viewed = planesdf::io::readPcd(pcd);
  std::filesystem::remove(pcd);
  if (!viewed.sensor_pose.translation().isApprox(Eigen::Vector3d(1.0, 2.0, 3.0))) return 1;
  const planesdf::Config cfg;
#ifdef HAVE_PLANESDF_OCTOMAP
  if (planesdf::octomap_adapter::toOctomap(back).size() != 2) return 1;
#endif
  std::printf("consumer: read %zu points back; default voxel %.3f m\n", back.size(),
              cfg.voxel_size);
  return back.size() == 2 && cfg.voxel_size == 0.007 ? 0 : 1;
}
