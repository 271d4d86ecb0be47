// Pass 1b: the in-band flags of a frame's pixels and the allocation of the blocks their
// truncation segments cross (the scalar reference; block_allocation_avx2.cpp is its row kernel).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "block_sets.hpp"
#include "fusion_internal.hpp"
#include "planesdf/memory.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf::fusion_detail {

/// Allocates the blocks of `per_thread` key lists in key order; returns their indices. Throws
/// planesdf::Error, allocating nothing, when the new blocks exceed the memory limit of `cfg`.
std::vector<Eigen::Vector3i> allocateKeys(TsdfVolume& vol,
                                          const std::vector<std::vector<std::uint64_t>>& per_thread,
                                          const Config& cfg) {
  std::vector<std::uint64_t> keys;
  for (const auto& k : per_thread) keys.insert(keys.end(), k.begin(), k.end());
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  requireMemory(keys.size() * sizeof(TsdfBlock), cfg, "",
                std::to_string(keys.size()) + " new TSDF blocks at voxel_size " +
                    std::to_string(vol.voxelSize()) + " m (fuse_band " +
                    std::to_string(cfg.fuse_band) + " m)");
  std::vector<Eigen::Vector3i> out;
  out.reserve(keys.size());
  for (const std::uint64_t k : keys) {
    out.push_back(detail::unpackBlockKey(k));
    vol.allocateBlock(out.back());
  }
  return out;
}

/// Pass 1b (per volume), parallel over rows: flags the pixels whose point lies in the band
/// (`in_band`, the others only carve) and allocates the blocks crossed by the ray segments of
/// in-band points within the truncation of their surface (|depth difference| * k <= trunc),
/// clipped to the band's voxels. Returns the in-band count.
/// The local AABB of the frustum between camera depths z0 and z1.
void frustumLocalBox(const Camera& cam, double z0, double z1, Eigen::Vector3d& lo,
                     Eigen::Vector3d& hi) {
  lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  hi = -lo;
  const double us[2] = {-0.5, cam.width - 0.5}, vs[2] = {-0.5, cam.height - 0.5};
  const double zs[2] = {z0, z1};
  for (const double z : zs)
    for (const double u : us)
      for (const double v : vs) {
        const Eigen::Vector3d pc(z * (u - cam.cx) / cam.fx, z * (v - cam.cy) / cam.fy, z);
        const Eigen::Vector3d pl = cam.R_cl_d.transpose() * (pc - cam.t_cl_d);
        lo = lo.cwiseMin(pl);
        hi = hi.cwiseMax(pl);
      }
}

/// One pixel of the allocation pass (the reference code; allocateRowAvx2 computes the same
/// values). Returns 1 when the pixel's point is in the band.
int allocatePixel(const AllocRow& r, int u, SegmentBlocks& segments) {
  r.flag[u] = 0;
  const float k = r.k[u];
  if (k == 0.0f) return 0;  // no measurement, or grazing (carves only)
  const float d = r.depth[u];
  // The ray in local coordinates per unit depth, and the point's height.
  const float xu = r.xn[u];
  const float dir[3] = {xu * r.dir_col[0] + r.dir_row[0], xu * r.dir_col[1] + r.dir_row[1],
                        xu * r.dir_col[2] + r.dir_row[2]};
  const float pz = r.t[2] + d * dir[2];
  if (!(pz >= r.band.pt_lo && pz <= r.band.pt_hi)) return 0;
  r.flag[u] = 1;
  // Segment over depths d + s of this pixel's ray, for the voxels it fuses: trunc / k in front
  // (distance trunc), behind up to the distance kBehindFraction * trunc and at most trunc in
  // depth; clipped to the band's voxels.
  float s0 = -r.trunc / k, s1 = std::min(r.trunc, -kBehindFraction * s0);
  if (dir[2] != 0.0f) {
    float sa = (r.band.alloc_lo - pz) / dir[2], sb = (r.band.alloc_hi - pz) / dir[2];
    if (sa > sb) std::swap(sa, sb);
    s0 = std::max(s0, sa);
    s1 = std::min(s1, sb);
  }
  if (s0 > s1) return 1;
  const float a0 = (d + s0) * r.inv_bs, a1 = (d + s1) * r.inv_bs;
  segments.add(
      Eigen::Vector3f(r.t_bs[0] + a0 * dir[0], r.t_bs[1] + a0 * dir[1], r.t_bs[2] + a0 * dir[2]),
      Eigen::Vector3f(r.t_bs[0] + a1 * dir[0], r.t_bs[1] + a1 * dir[1], r.t_bs[2] + a1 * dir[2]));
  return 1;
}

std::size_t allocateInBand(TsdfVolume& vol, const std::vector<float>& depth_img,
                           const std::vector<float>& k_exact, const FrameMeasurements& fm,
                           const Camera& cam, const Band& band, int threads, bool simd,
                           BlockGrid& grid, std::vector<std::uint8_t>& in_band, const Config& cfg,
                           std::vector<Eigen::Vector3i>& allocated) {
  const int W = cam.width, H = cam.height;
  const float trunc = static_cast<float>(vol.truncation());
  const float inv_bs = static_cast<float>(1.0 / vol.blockSize());
  const Eigen::Matrix3f& R = cam.R_lc;
  const Eigen::Vector3f& t = cam.t_lc;
  in_band.resize(static_cast<std::size_t>(W) * H + kGatherPadding);
  std::vector<std::vector<std::uint64_t>> new_keys(threads);
  // The block cells segments can reach: the frustum out to z_max + trunc, the allocation band,
  // one block of margin. (Segments leaving it still work, through hash lookups.)
  {
    Eigen::Vector3d lo, hi;
    frustumLocalBox(cam, cam.z_min, static_cast<double>(cam.z_max) + trunc, lo, hi);
    lo.z() = std::max(lo.z(), static_cast<double>(band.alloc_lo));
    hi.z() = std::min(hi.z(), static_cast<double>(band.alloc_hi));
    const double bs = vol.blockSize();
    const auto cell = [&](double x) {  // clamped well inside int
      return static_cast<int>(std::clamp(std::floor(x / bs), -1e9, 1e9));
    };
    if (lo.allFinite() && hi.allFinite())
      grid.reset(vol, Eigen::Vector3i(cell(lo.x()), cell(lo.y()), cell(lo.z())).array() - 1,
                 Eigen::Vector3i(cell(hi.x()), cell(hi.y()), cell(hi.z())).array() + 1);
    else
      grid.clear();  // a non-finite pose: no grid
  }
  // Per worker: its segment walker (created on its first rows) and its count of in-band pixels.
  std::vector<std::unique_ptr<SegmentBlocks>> segments(static_cast<std::size_t>(threads));
  std::vector<std::size_t> counts(static_cast<std::size_t>(threads), 0);
  parallelChunks(H, threads, 8, [&](int worker, long long v0, long long v1) {
    auto& seg = segments[static_cast<std::size_t>(worker)];
    if (!seg) seg = std::make_unique<SegmentBlocks>(vol, grid);
    std::size_t& count = counts[static_cast<std::size_t>(worker)];
    for (int v = static_cast<int>(v0); v < v1; ++v) {
      const float yn = fm.yn[v];
      const std::size_t row = static_cast<std::size_t>(v) * W;
      const AllocRow r{depth_img.data() + row,
                       k_exact.data() + row,
                       fm.xn.data(),
                       in_band.data() + row,
                       W,
                       {R(0, 0), R(1, 0), R(2, 0)},
                       {yn * R(0, 1) + R(0, 2), yn * R(1, 1) + R(1, 2), yn * R(2, 1) + R(2, 2)},
                       {t.x(), t.y(), t.z()},
                       {t.x() * inv_bs, t.y() * inv_bs, t.z() * inv_bs},
                       trunc,
                       inv_bs,
                       band};
#if PLANESDF_AVX2_KERNEL
      if (simd) {
        count += static_cast<std::size_t>(allocateRowAvx2(r, *seg));
        continue;
      }
#endif
      for (int u = 0; u < W; ++u) count += static_cast<std::size_t>(allocatePixel(r, u, *seg));
    }
  });
  std::size_t count = 0;
  for (std::size_t w = 0; w < segments.size(); ++w) {
    count += counts[w];
    if (segments[w]) new_keys[w] = segments[w]->newKeys();
  }
  allocated = allocateKeys(vol, new_keys, cfg);
  return count;
}

}  // namespace planesdf::fusion_detail
