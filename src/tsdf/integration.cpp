// Projective integration of depth frames (integrateDepth): the blocks in the frustum, in image
// order, each updated by the voxel kernel. See tsdf.hpp for the contracts.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "../numeric.hpp"
#include "block_sets.hpp"
#include "fusion_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {
namespace fusion_detail {
namespace {

/// Slots of the allocated blocks that may hold a voxel centre in the frustum's local AABB and
/// the voxel band, in slot order. Enumerates the AABB's block cells or scans all blocks,
/// whichever is fewer.
std::vector<std::uint32_t> frustumCandidates(const TsdfVolume& vol, const Camera& cam,
                                             const Band& band, const BlockGrid& grid) {
  std::vector<std::uint32_t> slots;
  Eigen::Vector3i vlo, vhi;
  if (!vol.blockBounds(&vlo, &vhi)) return slots;
  Eigen::Vector3d lo, hi;
  frustumLocalBox(cam, cam.z_min, cam.z_max, lo, hi);
  lo.z() = std::max(lo.z(), static_cast<double>(band.vox_lo));
  hi.z() = std::min(hi.z(), static_cast<double>(band.vox_hi));
  if ((lo.array() > hi.array()).any()) return slots;
  const double bs = vol.blockSize();
  const auto cell = [&](double x) { return static_cast<int>(std::floor(x / bs)); };
  const Eigen::Vector3i blo =
      Eigen::Vector3i(cell(lo.x()), cell(lo.y()), cell(lo.z())).cwiseMax(vlo);
  const Eigen::Vector3i bhi =
      Eigen::Vector3i(cell(hi.x()), cell(hi.y()), cell(hi.z())).cwiseMin(vhi);
  if ((blo.array() > bhi.array()).any()) return slots;
  const Eigen::Vector3d extent = (bhi - blo).cast<double>().array() + 1.0;
  const double cells = extent.prod();
  if (cells <= static_cast<double>(vol.numBlocks())) {
    for (int z = blo.z(); z <= bhi.z(); ++z)
      for (int y = blo.y(); y <= bhi.y(); ++y)
        for (int x = blo.x(); x <= bhi.x(); ++x) {
          const Eigen::Vector3i b(x, y, z);
          // The frame's grid knows every allocated block it covers: no lookup for empty cells.
          const std::ptrdiff_t g = grid.find(b);
          if (g >= 0 && !grid.known(g)) continue;
          const std::ptrdiff_t s = vol.blockSlot(b);
          if (s >= 0) slots.push_back(static_cast<std::uint32_t>(s));
        }
    std::sort(slots.begin(), slots.end());
  } else {
    for (std::size_t s = 0; s < vol.numBlocks(); ++s) {
      const Eigen::Vector3i& b = vol.blockIndex(s);
      if ((b.array() >= blo.array()).all() && (b.array() <= bhi.array()).all())
        slots.push_back(static_cast<std::uint32_t>(s));
    }
  }
  return slots;
}

/// Indices into `slots` ordered by the image tile their block centre projects to (row-major
/// tiles of 32 px; blocks behind the camera last), so that consecutive blocks read nearby pixel
/// measurements from cache. Ties keep slot order (deterministic).
std::vector<std::uint32_t> imageOrder(const TsdfVolume& vol,
                                      const std::vector<std::uint32_t>& slots, const Camera& cam) {
  constexpr double kTile = 32.0;
  const double half = 0.5 * vol.blockSize();
  const int tiles_x = static_cast<int>(std::ceil(cam.width / kTile)) + 2;
  const int tiles_y = static_cast<int>(std::ceil(cam.height / kTile)) + 2;
  const std::int64_t behind = static_cast<std::int64_t>(tiles_y) * tiles_x;  // the last bucket
  std::vector<std::int64_t> keyed(slots.size());
  for (std::size_t i = 0; i < slots.size(); ++i) {
    const Eigen::Vector3d c_local =
        vol.blockIndex(slots[i]).cast<double>() * vol.blockSize() + Eigen::Vector3d::Constant(half);
    const Eigen::Vector3d c = cam.R_cl_d * c_local + cam.t_cl_d;
    std::int64_t key = behind;
    if (c.z() > 1e-6) {
      const double u = cam.fx * c.x() / c.z() + cam.cx, v = cam.fy * c.y() / c.z() + cam.cy;
      const auto tile = [&](double x, int n) {
        return std::clamp(static_cast<int>(std::floor(x / kTile)) + 1, 0, n);
      };
      const int ty = tile(v, tiles_y - 1);
      key = static_cast<std::int64_t>(ty) * tiles_x + tile(u, tiles_x - 1);
    }
    keyed[i] = key;
  }
  // Counting sort by tile (stable: ties keep slot order).
  std::vector<std::uint32_t> start(static_cast<std::size_t>(behind) + 2, 0);
  for (const std::int64_t k : keyed) ++start[static_cast<std::size_t>(k) + 1];
  for (std::size_t b = 1; b < start.size(); ++b) start[b] += start[b - 1];
  std::vector<std::uint32_t> order(slots.size());
  for (std::size_t i = 0; i < keyed.size(); ++i)
    order[start[static_cast<std::size_t>(keyed[i])]++] = static_cast<std::uint32_t>(i);
  return order;
}

}  // namespace
}  // namespace fusion_detail

// The fusion files' shared helpers, named unqualified as in one anonymous namespace.
using namespace fusion_detail;

IntegrationResult integrateDepth(TsdfVolume& vol, const DepthFrameAnalysis& analysis,
                                 const Pose& T_local_camera, const Config& cfg) {
  if (!analysis.impl_) throw Error("", "depth frame analysis: analyse() was not called");
  validateFusionConfig(cfg);
  const DepthFrameAnalysis::Impl& a = *analysis.impl_;
  const Camera cam = makeCamera(a.intrinsics, T_local_camera, cfg);
  if (static_cast<float>(vol.truncation()) != a.truncation || cam.z_min != a.z_min ||
      cam.z_max != a.z_max || cam.z_surface != a.z_surface)
    throw Error("", "depth frame analysis: made for truncation " + std::to_string(a.truncation) +
                        " m and depths [" + std::to_string(a.z_min) + ", " +
                        std::to_string(a.z_max) + "] m, used with truncation " +
                        std::to_string(vol.truncation()) + " m and depths [" +
                        std::to_string(cam.z_min) + ", " + std::to_string(cam.z_max) +
                        "] m (or another surface_max_depth)");
  IntegrationResult res;
  const int threads = resolveThreads(cfg.threads);
  const Band band = makeBand(cfg, vol.voxelSize(), vol.truncation());
  // Per-thread scratch reused across calls (every entry is rewritten): no large allocation and
  // page faulting per call.
  thread_local std::vector<std::uint8_t> in_band;
  thread_local BlockGrid grid;  // the block cells around the frustum (see allocateInBand)
  const bool simd = cfg.simd && detail::cpuHasAvx2();
  res.num_points_fused = allocateInBand(vol, a.depth, a.k, a.fm, cam, band, threads, simd, grid,
                                        in_band, cfg, res.allocated_blocks);
  const std::vector<std::uint32_t> slots = frustumCandidates(vol, cam, band, grid);
  std::vector<BlockOutcome> outcomes(slots.size());
  const FrustumCull cull(cam);
  DepthUpdateParams prm{&a.fm,
                        in_band.data(),
                        static_cast<float>(vol.truncation()),
                        cfg.max_weight,
                        static_cast<float>(vol.voxelSize()),
                        band,
                        cfg.silhouette_guard_behind,
                        simd};
  const std::vector<std::uint32_t> order = imageOrder(vol, slots, cam);
  const int n = static_cast<int>(order.size());
  parallelChunks(n, threads, 4, [&](int, long long begin, long long end) {
    for (long long i = begin; i < end; ++i) {
      const std::uint32_t j = order[i];
      outcomes[j] =
          updateBlockFromDepth(vol.block(slots[j]), vol.blockIndex(slots[j]), cam, cull, prm);
    }
  });
  finishIntegration(vol, slots, outcomes, res);
  return res;
}

IntegrationResult integrateDepth(TsdfVolume& vol, const DepthFrame& frame,
                                 const Pose& T_local_camera, const Config& cfg) {
  // Per-thread scratch reused across calls: no large allocation and page faulting per frame.
  thread_local DepthFrameAnalysis analysis;
  analysis.analyse(frame, vol.truncation(), cfg);
  return integrateDepth(vol, analysis, T_local_camera, cfg);
}

}  // namespace planesdf
