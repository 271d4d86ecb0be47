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
  const planesdf::Config cfg;
#ifdef HAVE_PLANESDF_OCTOMAP
  if (planesdf::octomap_adapter::toOctomap(back).size() != 2) return 1;
#endif
  std::printf("consumer: read %zu points back; default voxel %.3f m\n", back.size(),
              cfg.voxel_size);
  return back.size() == 2 && cfg.voxel_size == 0.007 ? 0 : 1;
}
