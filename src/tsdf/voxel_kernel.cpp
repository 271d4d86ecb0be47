// Pass 2 for one block: culling, the occlusion bound and the scalar voxel row kernel (the
// reference for voxel_kernel_avx2.cpp).

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "fusion_internal.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf::fusion_detail {
namespace {

/// Bound on the tangent-plane term of q, |n' . (voxel - its pixel's ray point)|, in pixel
/// footprints at the voxel's depth: |n'| <= 1 / kMinCosine = 5 and the voxel is at most half a
/// pixel diagonal (0.71 px) off its pixel's ray.
constexpr float kTangentSlackPx = 3.6f;

/// Fuses the row of kTsdfBlockSide voxels whose first centre is (rx, ry, rz) in camera
/// coordinates (the reference implementation; fuseRowAvx2 gives bit-identical results).
inline void fuseRowScalar(const RowKernel& k, float rx, float ry, float rz, TsdfVoxel* voxels,
                          BlockOutcome& out) {
  for (int x = 0; x < kTsdfBlockSide; ++x) {
    const float fxx = static_cast<float>(x);
    const float px = rx + fxx * k.ax_x, py = ry + fxx * k.ax_y, zc = rz + fxx * k.ax_z;
    if (!(zc >= k.z_min && zc <= k.z_max)) continue;
    const float inv = 1.0f / zc;
    const float uf = k.fx * px * inv + k.cx;
    const float vf = k.fy * py * inv + k.cy;
    if (!(uf >= -0.5f && uf < k.w_lim && vf >= -0.5f && vf < k.h_lim)) continue;
    out.in_view = true;
    const int ui = std::min(static_cast<int>(uf + 0.5f), k.W - 1);
    const int vi = std::min(static_cast<int>(vf + 0.5f), k.H - 1);
    const std::size_t pix = static_cast<std::size_t>(vi) * k.W + ui;
    const PixelMeasurement m = k.pixels[pix];
    if (m.dq == 0) continue;
    // The pixel's normalised coordinates, computed as analysePixels tabulates them.
    const float xn = (static_cast<float>(ui) - k.cx) * k.inv_fx;
    const float yn = (static_cast<float>(vi) - k.cy) * k.inv_fy;
    const float q = (m.nx * (px - xn * zc) + m.ny * (py - yn * zc)) * (1.0f / kNormalScale) +
                    (m.dq * k.depth_scale - zc);
    if (q < -k.trunc) continue;  // behind the surface by more than the truncation (in depth)
    const float cos_ray = static_cast<float>(m.kq < 0 ? -m.kq : m.kq) * (1.0f / kCosineScale);
    float sdf = cos_ray * q;
    if (sdf < -k.behind) continue;  // deeper behind the surface than the band behind it
    // Silhouette guard: |sdf| (at most trunc) against the lateral distance to an edge.
    if (k.guard_near && std::fabs(sdf) > k.guard_sdf &&
        k.guard[(vi >> kGuardTileShift) * k.tiles_x + (ui >> kGuardTileShift)] <= zc + k.trunc) {
      if (sdf > 0.0f) {
        if (std::min(sdf, k.trunc) * k.edge_scale > k.edge_dist[pix] * zc) continue;
      } else if (k.guard_behind) {
        // Behind: only a silhouette can put the voxel beyond the object's hidden side, and
        // only if it lies within |sdf| * sin(angle between ray and surface) of the voxel's
        // line of sight (the ray meets the surface |sdf| / cos before the voxel).
        const float sin_ray = std::sqrt(std::max(0.0f, 1.0f - cos_ray * cos_ray));
        const float edge_px = k.silhouette_dist[pix] + kSilhouetteOffsetPx;
        if (std::min(-sdf, k.trunc) * sin_ray * k.edge_scale > edge_px * zc) continue;
      }
    }
    if (sdf >= k.trunc)
      sdf = k.trunc;
    else if (m.kq < 0 || !k.in_band[pix])
      continue;  // grazing or outside the band: carves free space only
    out.changed |= fuseVoxel(voxels[x], sdf, k.max_weight);
    ++out.updates;
  }
}

/// A block in camera coordinates: its first voxel centre (also in the plane frame, whose z is the
/// height) and its axes scaled to one voxel.
struct BlockInCamera {
  Eigen::Vector3d c0_local;
  Eigen::Vector3f c0, ax, ay, az;

  Eigen::Vector3f voxel(float x, float y, float z) const { return c0 + x * ax + y * ay + z * az; }
};

BlockInCamera blockInCamera(const Eigen::Vector3i& index, const Camera& cam, double vs) {
  BlockInCamera b;
  b.c0_local = (index.cast<double>() * kTsdfBlockSide).array() * vs + 0.5 * vs;
  b.c0 = (cam.R_cl_d * b.c0_local + cam.t_cl_d).cast<float>();
  b.ax = cam.R_cl.col(0) * static_cast<float>(vs);
  b.ay = cam.R_cl.col(1) * static_cast<float>(vs);
  b.az = cam.R_cl.col(2) * static_cast<float>(vs);
  return b;
}

RowKernel rowKernel(const Camera& cam, const DepthUpdateParams& prm, const Eigen::Vector3f& ax) {
  const FrameMeasurements& fm = *prm.fm;
  const float fx = cam.fx, fy = cam.fy;
  // Pixels per metre of lateral distance at unit depth (the smaller focal length: the lateral
  // distance is never overestimated).
  const float edge_scale = std::min(fx, fy);
  RowKernel k{};
  k.pixels = fm.pixels.data();
  k.guard = fm.guard.data();
  k.edge_dist = fm.edge_dist.data();
  k.silhouette_dist = fm.silhouette_dist.data();
  k.in_band = prm.in_band;
  k.W = cam.width;
  k.H = cam.height;
  k.tiles_x = fm.tiles_x;
  k.ax_x = ax.x();
  k.ax_y = ax.y();
  k.ax_z = ax.z();
  k.fx = fx;
  k.fy = fy;
  k.cx = cam.cx;
  k.cy = cam.cy;
  k.inv_fx = 1.0f / fx;
  k.inv_fy = 1.0f / fy;
  k.z_min = cam.z_min;
  k.z_max = cam.z_max;
  k.w_lim = cam.width - 0.5f;
  k.h_lim = cam.height - 0.5f;
  k.trunc = prm.trunc;
  k.behind = kBehindFraction * prm.trunc;
  k.guard_sdf = kGuardSdf * prm.voxel;
  k.edge_scale = edge_scale;
  k.depth_scale = fm.depth_scale;
  k.max_weight = prm.max_weight;
  k.guard_behind = prm.guard_behind;
  k.guard_near = true;
  return k;
}

/// Slice z of the block holds band voxels.
bool sliceInBand(const BlockInCamera& b, const DepthUpdateParams& prm, int z) {
  const float h = static_cast<float>(b.c0_local.z() + z * static_cast<double>(prm.voxel));
  return h >= prm.band.vox_lo && h <= prm.band.vox_hi;
}

/// The first band slice's rows (one cache line each), requested before the work on the block.
void prefetchFirstBandSlice(const TsdfBlock& blk, const BlockInCamera& b,
                            const DepthUpdateParams& prm) {
  int z0 = 0;
  while (z0 < kTsdfBlockSide && !sliceInBand(b, prm, z0)) ++z0;
  if (z0 < kTsdfBlockSide)
    for (int y = 0; y < kTsdfBlockSide; ++y)
      __builtin_prefetch(&blk.voxels[(z0 * kTsdfBlockSide + y) * kTsdfBlockSide], 1);
}

/// The pixels a block's voxel centres can project to (nearest pixel, inside the projected box of
/// its corner centres) and its largest depth; `in_front` false when a corner is behind the
/// camera (no bound then).
struct ProjectedBox {
  bool in_front = true;
  float umin = kInf, umax = -kInf, vmin = kInf, vmax = -kInf, zmax = -kInf;

  bool outsideImage(const RowKernel& k) const {
    return umax < -0.5f || umin >= k.w_lim || vmax < -0.5f || vmin >= k.h_lim;
  }
};

ProjectedBox projectedBox(const BlockInCamera& b, const RowKernel& k) {
  ProjectedBox box;
  const float e = static_cast<float>(kTsdfBlockSide - 1);
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3f p = b.voxel((i & 1) ? e : 0.0f, (i & 2) ? e : 0.0f, (i & 4) ? e : 0.0f);
    if (!(p.z() > 1e-3f)) {
      box.in_front = false;
      break;
    }
    const float u = k.fx * p.x() / p.z() + k.cx, v = k.fy * p.y() / p.z() + k.cy;
    box.umin = std::min(box.umin, u);
    box.umax = std::max(box.umax, u);
    box.vmin = std::min(box.vmin, v);
    box.vmax = std::max(box.vmax, v);
    box.zmax = std::max(box.zmax, p.z());
  }
  return box;
}

/// The nearest pixel of coordinate x, clamped to [0, n).
int nearestPixel(float x, int n) {
  return static_cast<int>(std::clamp(x + 0.5f, 0.0f, static_cast<float>(n - 1)));
}

/// Occlusion bound. Over the pixels of `box`, the largest measured depth dmax: a voxel deeper
/// than dmax + trunc + the tangent-plane term (|n'| * the voxel's lateral offset from its pixel's
/// ray, at most kTangentSlackPx pixel footprints) has q < -trunc, untouched. Returns that depth;
/// sets k.guard_near to whether the silhouette guard can act on the block.
float occlusionBound(const ProjectedBox& box, const FrameMeasurements& fm, RowKernel& k) {
  const int tx0 = nearestPixel(box.umin, k.W) >> kGuardTileShift;
  const int tx1 = nearestPixel(box.umax, k.W) >> kGuardTileShift;
  const int ty0 = nearestPixel(box.vmin, k.H) >> kGuardTileShift;
  const int ty1 = nearestPixel(box.vmax, k.H) >> kGuardTileShift;
  float dmax = -kInf, gmin = kInf;
  for (int ty = ty0; ty <= ty1; ++ty)
    for (int tx = tx0; tx <= tx1; ++tx) {
      const std::size_t t = static_cast<std::size_t>(ty) * fm.tiles_x + tx;
      dmax = std::max(dmax, fm.tile_max_depth[t]);
      gmin = std::min(gmin, fm.guard[t]);
    }
  // The guard acts where its tile's edge depth <= zc + trunc; zc <= zmax (plus rounding).
  k.guard_near = gmin <= box.zmax + k.trunc + 1e-3f;
  return dmax + k.trunc + kTangentSlackPx * box.zmax / k.edge_scale + 1e-3f;
}

/// The measurements the voxel loop will gather, requested ahead (one cache line = 8 px).
void prefetchPixels(const ProjectedBox& box, const RowKernel& k) {
  const int u0 = nearestPixel(box.umin, k.W), u1 = nearestPixel(box.umax, k.W);
  for (int v = nearestPixel(box.vmin, k.H); v <= nearestPixel(box.vmax, k.H); ++v)
    for (int u = u0; u <= u1 + 7; u += 8)
      __builtin_prefetch(k.pixels + static_cast<std::size_t>(v) * k.W + std::min(u, u1));
}

/// True when a voxel centre of slice z projects into the image within the depth range.
bool sliceInView(const BlockInCamera& b, const RowKernel& k, int z) {
  for (int y = 0; y < kTsdfBlockSide; ++y)
    for (int x = 0; x < kTsdfBlockSide; ++x) {
      const Eigen::Vector3f p =
          b.voxel(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
      if (!(p.z() >= k.z_min && p.z() <= k.z_max)) continue;
      const float uf = k.fx * p.x() / p.z() + k.cx, vf = k.fy * p.y() / p.z() + k.cy;
      if (uf >= -0.5f && uf < k.w_lim && vf >= -0.5f && vf < k.h_lim) return true;
    }
  return false;
}

/// Fuses slice z of the block (its rows along the block's x axis).
void fuseSlice(TsdfBlock& blk, const BlockInCamera& b, const RowKernel& k,
               [[maybe_unused]] bool simd, int z, BlockOutcome& out) {
  const float fz = static_cast<float>(z);
  const float sx = b.c0.x() + fz * b.az.x(), sy = b.c0.y() + fz * b.az.y();
  const float sz = b.c0.z() + fz * b.az.z();
  TsdfVoxel* slice = &blk.voxels[z * kTsdfBlockSide * kTsdfBlockSide];
#if PLANESDF_AVX2_KERNEL
  if (simd) {
    fuseSliceAvx2(k, sx, sy, sz, b.ay.x(), b.ay.y(), b.ay.z(), slice, out);
    return;
  }
#endif
  for (int y = 0; y < kTsdfBlockSide; ++y) {
    const float fyy = static_cast<float>(y);
    fuseRowScalar(k, sx + fyy * b.ay.x(), sy + fyy * b.ay.y(), sz + fyy * b.ay.z(),
                  slice + y * kTsdfBlockSide, out);
  }
}

}  // namespace

/// Pass 2 for one block (integer index `index`, from the volume's index array: reading
/// blk.index would miss the cache on the line after the voxels): projects its voxel centres
/// (memory order) and fuses them. Slices of the block beyond the occlusion bound are skipped
/// whole (the result is identical).
BlockOutcome updateBlockFromDepth(TsdfBlock& blk, const Eigen::Vector3i& index, const Camera& cam,
                                  const FrustumCull& cull, const DepthUpdateParams& prm) {
  BlockOutcome out;
  const BlockInCamera b = blockInCamera(index, cam, prm.voxel);
  const float half = 0.5f * (kTsdfBlockSide - 1);
  const float radius = std::sqrt(3.0f) * half * prm.voxel * 1.0001f + 1e-6f;
  if (!cull.mayIntersect(b.c0 + half * (b.ax + b.ay + b.az), radius)) return out;

  RowKernel kernel = rowKernel(cam, prm, b.ax);
  prefetchFirstBandSlice(blk, b, prm);
  // Slice z lies wholly beyond the occlusion bound: its nearest voxel is deeper.
  const float near_dz =
      (kTsdfBlockSide - 1) * (std::min(0.0f, b.ax.z()) + std::min(0.0f, b.ay.z()));
  float occluded_from = kInf;
  const auto sliceOccluded = [&](int z) {
    return b.c0.z() + static_cast<float>(z) * b.az.z() + near_dz > occluded_from;
  };
  const ProjectedBox box = projectedBox(b, kernel);
  if (box.in_front) {
    if (box.outsideImage(kernel)) return out;
    occluded_from = occlusionBound(box, *prm.fm, kernel);
    bool any_slice = false;  // unless every slice of the block is occluded
    for (int z = 0; z < kTsdfBlockSide && !any_slice; ++z)
      any_slice = sliceInBand(b, prm, z) && !sliceOccluded(z);
    if (any_slice) prefetchPixels(box, kernel);
  }
  for (int z = 0; z < kTsdfBlockSide; ++z) {
    if (!sliceInBand(b, prm, z)) continue;
    if (sliceOccluded(z)) {
      if (!out.in_view) out.in_view = sliceInView(b, kernel, z);
      continue;
    }
    fuseSlice(blk, b, kernel, prm.simd, z, out);
  }
  return out;
}

}  // namespace planesdf::fusion_detail
