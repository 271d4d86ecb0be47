// `planesdf fuse INPUT --out MAP.psdf [--pictures DIR]`: the PlaneSDF map of one session.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>

#include "commands.hpp"
#include "planesdf/error.hpp"
#include "planesdf/height_map.hpp"
#include "session_input.hpp"

namespace planesdf::cli {

int runFuse(const FuseArgs& args) {
  const Config cfg = resolveConfig(args.pipeline);
  const auto t0 = std::chrono::steady_clock::now();
  const Map map =
      loadSession(args.input, cfg, args.pipeline.intrinsics, "fuse", upDefaulted(args.pipeline));
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (map.planes().empty())
    throw Error(args.input,
                "no horizontal or vertical plane found (try --up auto or another --up)");
  map.save(args.out);

  if (!args.pictures.empty()) {
    std::filesystem::create_directories(args.pictures);
    for (const PlaneSdf& ps : map.planes()) {
      const HeightMap hm =
          namingInput(args.input, [&] { return computeHeightMap(ps.volume, map.config()); });
      const std::string base = args.pictures + "/plane_" + std::to_string(ps.plane.id);
      writeHeightMapPng(base + "_height.png", hm);
      writeObjectMapPng(base + "_objects.png", computeObjectMap(hm, map.config()));
    }
  }

  std::printf("%zu planes, %.1f MB, %.0f ms -> %s\n", map.planes().size(),
              static_cast<double>(map.memoryBytes()) / (1 << 20), ms, args.out.c_str());
  for (const PlaneSdf& ps : map.planes()) {
    const Eigen::Vector3d& n = ps.plane.normal;
    std::printf("  plane %d  %-10s  n = (%+.3f %+.3f %+.3f)  d = %+.3f m  %zu blocks\n",
                ps.plane.id,
                ps.plane.orientation == Plane::Orientation::Horizontal ? "horizontal" : "vertical",
                n.x(), n.y(), n.z(), ps.plane.offset, ps.volume.numBlocks());
  }
  return kExitOk;
}

}  // namespace planesdf::cli
