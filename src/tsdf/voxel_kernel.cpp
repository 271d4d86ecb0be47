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

}  // namespace

/// Pass 2 for one block (integer index `index`, from the volume's index array: reading
/// blk.index would miss the cache on the line after the voxels): projects its voxel centres
/// (memory order) and fuses them.
BlockOutcome updateBlockFromDepth(TsdfBlock& blk, const Eigen::Vector3i& index, const Camera& cam,
                                  const FrustumCull& cull, const DepthUpdateParams& prm) {
  BlockOutcome out;
  const double vs = prm.voxel;
  const Eigen::Vector3d c0_local = (index.cast<double>() * kTsdfBlockSide).array() * vs + 0.5 * vs;
  const Eigen::Vector3f c0 = (cam.R_cl_d * c0_local + cam.t_cl_d).cast<float>();
  const Eigen::Vector3f ax = cam.R_cl.col(0) * prm.voxel;
  const Eigen::Vector3f ay = cam.R_cl.col(1) * prm.voxel;
  const Eigen::Vector3f az = cam.R_cl.col(2) * prm.voxel;
  const float half = 0.5f * (kTsdfBlockSide - 1);
  const float radius = std::sqrt(3.0f) * half * prm.voxel * 1.0001f + 1e-6f;
  if (!cull.mayIntersect(c0 + half * (ax + ay + az), radius)) return out;

  const float w_lim = cam.width - 0.5f, h_lim = cam.height - 0.5f;
  const int W = cam.width, H = cam.height;
  const FrameMeasurements& fm = *prm.fm;
  const float fx = cam.fx, fy = cam.fy, cx = cam.cx, cy = cam.cy;
  const float trunc = prm.trunc;
  // Pixels per metre of lateral distance at unit depth (the smaller focal length: the lateral
  // distance is never overestimated).
  const float edge_scale = std::min(fx, fy);
  RowKernel kernel{fm.pixels.data(),
                   fm.guard.data(),
                   fm.edge_dist.data(),
                   fm.silhouette_dist.data(),
                   prm.in_band,
                   W,
                   H,
                   fm.tiles_x,
                   ax.x(),
                   ax.y(),
                   ax.z(),
                   fx,
                   fy,
                   cx,
                   cy,
                   1.0f / fx,
                   1.0f / fy,
                   cam.z_min,
                   cam.z_max,
                   w_lim,
                   h_lim,
                   trunc,
                   kBehindFraction * trunc,
                   kGuardSdf * prm.voxel,
                   edge_scale,
                   fm.depth_scale,
                   prm.max_weight,
                   prm.guard_behind};

  // Occlusion bound. Over the pixels the block's voxel centres can project to (nearest pixel,
  // inside the projected box of its corner centres), the largest measured depth dmax. A voxel
  // deeper than dmax + trunc + the tangent-plane term (|n'| * the voxel's lateral offset from its
  // pixel's ray, at most kTangentSlackPx pixel footprints) has q < -trunc: untouched. Slices of
  // the block beyond that are skipped whole (the result is identical).
  const float near_dz = (kTsdfBlockSide - 1) * (std::min(0.0f, ax.z()) + std::min(0.0f, ay.z()));
  float occluded_from = kInf;
  // Slice z of the block holds band voxels / lies wholly beyond the occlusion bound.
  const auto sliceInBand = [&](int z) {
    const float h = static_cast<float>(c0_local.z() + z * vs);
    return h >= prm.band.vox_lo && h <= prm.band.vox_hi;
  };
  {  // the first band slice's rows (one cache line each) are requested before the work below
    int z0 = 0;
    while (z0 < kTsdfBlockSide && !sliceInBand(z0)) ++z0;
    if (z0 < kTsdfBlockSide)
      for (int y = 0; y < kTsdfBlockSide; ++y)
        __builtin_prefetch(&blk.voxels[(z0 * kTsdfBlockSide + y) * kTsdfBlockSide], 1);
  }
  const auto sliceOccluded = [&](int z) {
    return c0.z() + static_cast<float>(z) * az.z() + near_dz > occluded_from;
  };
  {
    const float e = static_cast<float>(kTsdfBlockSide - 1);
    float umin = kInf, umax = -kInf, vmin = kInf, vmax = -kInf, zmax = -kInf;
    bool in_front = true;
    for (int i = 0; i < 8; ++i) {
      const Eigen::Vector3f p =
          c0 + ((i & 1) ? e : 0.0f) * ax + ((i & 2) ? e : 0.0f) * ay + ((i & 4) ? e : 0.0f) * az;
      if (!(p.z() > 1e-3f)) {
        in_front = false;
        break;
      }
      const float u = fx * p.x() / p.z() + cx, v = fy * p.y() / p.z() + cy;
      umin = std::min(umin, u);
      umax = std::max(umax, u);
      vmin = std::min(vmin, v);
      vmax = std::max(vmax, v);
      zmax = std::max(zmax, p.z());
    }
    if (in_front) {
      if (umax < -0.5f || umin >= w_lim || vmax < -0.5f || vmin >= h_lim) return out;
      const auto pixel = [](float x, int n) {
        return static_cast<int>(std::clamp(x + 0.5f, 0.0f, static_cast<float>(n - 1)));
      };
      const int tx0 = pixel(umin, W) >> kGuardTileShift, tx1 = pixel(umax, W) >> kGuardTileShift;
      const int ty0 = pixel(vmin, H) >> kGuardTileShift, ty1 = pixel(vmax, H) >> kGuardTileShift;
      float dmax = -kInf, gmin = kInf;
      for (int ty = ty0; ty <= ty1; ++ty)
        for (int tx = tx0; tx <= tx1; ++tx) {
          const std::size_t t = static_cast<std::size_t>(ty) * fm.tiles_x + tx;
          dmax = std::max(dmax, fm.tile_max_depth[t]);
          gmin = std::min(gmin, fm.guard[t]);
        }
      // The guard acts where its tile's edge depth <= zc + trunc; zc <= zmax (plus rounding).
      kernel.guard_near = gmin <= zmax + trunc + 1e-3f;
      occluded_from = dmax + trunc + kTangentSlackPx * zmax / edge_scale + 1e-3f;
      // The measurements the voxel loop will gather, requested ahead (one cache line = 8 px),
      // unless every slice of the block is occluded (see below).
      bool any_slice = false;
      for (int z = 0; z < kTsdfBlockSide && !any_slice; ++z)
        any_slice = sliceInBand(z) && !sliceOccluded(z);
      if (any_slice) {
        const int u0 = pixel(umin, W), u1 = pixel(umax, W);
        for (int v = pixel(vmin, H); v <= pixel(vmax, H); ++v)
          for (int u = u0; u <= u1 + 7; u += 8)
            __builtin_prefetch(fm.pixels.data() + static_cast<std::size_t>(v) * W +
                               std::min(u, u1));
      }
    }
  }
  // True when a voxel centre of slice z projects into the image within the depth range.
  const auto sliceInView = [&](int z) {
    for (int y = 0; y < kTsdfBlockSide; ++y)
      for (int x = 0; x < kTsdfBlockSide; ++x) {
        const Eigen::Vector3f p = c0 + static_cast<float>(x) * ax + static_cast<float>(y) * ay +
                                  static_cast<float>(z) * az;
        if (!(p.z() >= cam.z_min && p.z() <= cam.z_max)) continue;
        const float uf = fx * p.x() / p.z() + cx, vf = fy * p.y() / p.z() + cy;
        if (uf >= -0.5f && uf < w_lim && vf >= -0.5f && vf < h_lim) return true;
      }
    return false;
  };

  for (int z = 0; z < kTsdfBlockSide; ++z) {
    if (!sliceInBand(z)) continue;
    if (sliceOccluded(z)) {
      if (!out.in_view) out.in_view = sliceInView(z);
      continue;
    }
    const float fz = static_cast<float>(z);
    const float sx = c0.x() + fz * az.x(), sy = c0.y() + fz * az.y(), sz = c0.z() + fz * az.z();
    TsdfVoxel* slice = &blk.voxels[z * kTsdfBlockSide * kTsdfBlockSide];
#if PLANESDF_AVX2_KERNEL
    if (prm.simd) {
      fuseSliceAvx2(kernel, sx, sy, sz, ay.x(), ay.y(), ay.z(), slice, out);
      continue;
    }
#endif
    for (int y = 0; y < kTsdfBlockSide; ++y) {
      const float fyy = static_cast<float>(y);
      fuseRowScalar(kernel, sx + fyy * ay.x(), sy + fyy * ay.y(), sz + fyy * ay.z(),
                    slice + y * kTsdfBlockSide, out);
    }
  }
  return out;
}

}  // namespace planesdf::fusion_detail
