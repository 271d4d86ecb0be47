// The AVX2 voxel row kernel of pass 2 (fuseRowAvx2, fuseSliceAvx2), bit-identical to
// fuseRowScalar in voxel_kernel.cpp; AVX2 through target attributes (no per-file flags).

#include <cstdint>

#include "fusion_internal.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf::fusion_detail {

#if PLANESDF_AVX2_KERNEL
namespace {

/// The silhouette guard of fuseRowAvx2: `m` without the lanes near a depth edge (in front of a
/// foreground edge, or behind a silhouette) that the scalar code skips.
__attribute__((target("avx2"), always_inline)) inline __m256 silhouetteGuard(
    const RowKernel& k, __m256 m, __m256 sdf, __m256 cos_ray, __m256 zc, __m256i ui, __m256i vi,
    __m256i pix) {
  const __m256 trunc = _mm256_set1_ps(k.trunc);
  const __m256i zero = _mm256_setzero_si256();
  const __m256 abs_sdf = _mm256_andnot_ps(_mm256_set1_ps(-0.0f), sdf);
  __m256 g = _mm256_and_ps(m, _mm256_cmp_ps(abs_sdf, _mm256_set1_ps(k.guard_sdf), _CMP_GT_OQ));
  if (k.guard_near && _mm256_movemask_ps(g) != 0) {
    const __m256i tile = _mm256_add_epi32(
        _mm256_mullo_epi32(_mm256_srli_epi32(vi, kGuardTileShift), _mm256_set1_epi32(k.tiles_x)),
        _mm256_srli_epi32(ui, kGuardTileShift));
    const __m256 edge_depth = _mm256_mask_i32gather_ps(_mm256_setzero_ps(), k.guard, tile, g, 4);
    g = _mm256_and_ps(g, _mm256_cmp_ps(edge_depth, _mm256_add_ps(zc, trunc), _CMP_LE_OQ));
    const __m256 front = _mm256_and_ps(g, _mm256_cmp_ps(sdf, _mm256_setzero_ps(), _CMP_GT_OQ));
    const __m256i bytes = _mm256_set1_epi32(0xff);
    const __m256 edge_scale = _mm256_set1_ps(k.edge_scale);
    if (_mm256_movemask_ps(front) != 0) {
      const __m256i ed = _mm256_and_si256(
          bytes, _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(k.edge_dist), pix,
                                             _mm256_castps_si256(front), 1));
      const __m256 skip = _mm256_cmp_ps(_mm256_mul_ps(_mm256_min_ps(sdf, trunc), edge_scale),
                                        _mm256_mul_ps(_mm256_cvtepi32_ps(ed), zc), _CMP_GT_OQ);
      m = _mm256_andnot_ps(_mm256_and_ps(front, skip), m);
    }
    const __m256 behind = _mm256_andnot_ps(front, g);
    if (k.guard_behind && _mm256_movemask_ps(behind) != 0) {
      const __m256 sin_ray = _mm256_sqrt_ps(
          _mm256_max_ps(_mm256_sub_ps(_mm256_set1_ps(1.0f), _mm256_mul_ps(cos_ray, cos_ray)),
                        _mm256_setzero_ps()));
      const __m256i sd = _mm256_and_si256(
          bytes, _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(k.silhouette_dist),
                                             pix, _mm256_castps_si256(behind), 1));
      const __m256 edge_px =
          _mm256_add_ps(_mm256_cvtepi32_ps(sd), _mm256_set1_ps(kSilhouetteOffsetPx));
      const __m256 neg_sdf = _mm256_xor_ps(sdf, _mm256_set1_ps(-0.0f));
      const __m256 skip = _mm256_cmp_ps(
          _mm256_mul_ps(_mm256_mul_ps(_mm256_min_ps(neg_sdf, trunc), sin_ray), edge_scale),
          _mm256_mul_ps(edge_px, zc), _CMP_GT_OQ);
      m = _mm256_andnot_ps(_mm256_and_ps(behind, skip), m);
    }
  }
  return m;
}

/// fuseVoxel on the active lanes `m` (`bits` its mask) of a row with observations `sdf`. The
/// row's 8 voxels (sdf, weight pairs) load as two vectors; within 128-bit lanes, shuffling gives
/// sdf and weight in voxel order 0 1 4 5 2 3 6 7, and unpacking puts them back. The new values
/// and the mask are permuted to that order.
__attribute__((target("avx2"), always_inline)) inline void fuseLanes(const RowKernel& k, __m256 sdf,
                                                                     __m256 m, int bits,
                                                                     TsdfVoxel* voxels,
                                                                     BlockOutcome& out) {
  float* raw = &voxels[0].sdf;
  const __m256 v0 = _mm256_loadu_ps(raw), v1 = _mm256_loadu_ps(raw + 8);
  const __m256 old_s = _mm256_shuffle_ps(v0, v1, 0x88);
  const __m256 old_w = _mm256_shuffle_ps(v0, v1, 0xdd);
  const __m256i order = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
  const __m256 obs = _mm256_permutevar8x32_ps(sdf, order);
  const __m256 act = _mm256_permutevar8x32_ps(m, order);
  const __m256 w_plus = _mm256_add_ps(old_w, _mm256_set1_ps(1.0f));
  const __m256 new_w = _mm256_min_ps(w_plus, _mm256_set1_ps(k.max_weight));
  const __m256 new_s = _mm256_add_ps(old_s, _mm256_div_ps(_mm256_sub_ps(obs, old_s), w_plus));
  const __m256 differs = _mm256_or_ps(_mm256_cmp_ps(new_s, old_s, _CMP_NEQ_UQ),
                                      _mm256_cmp_ps(new_w, old_w, _CMP_NEQ_UQ));
  out.changed |= _mm256_movemask_ps(_mm256_and_ps(differs, act)) != 0;
  out.updates += static_cast<std::uint32_t>(__builtin_popcount(static_cast<unsigned>(bits)));
  const __m256 s_out = _mm256_blendv_ps(old_s, new_s, act);
  const __m256 w_out = _mm256_blendv_ps(old_w, new_w, act);
  _mm256_storeu_ps(raw, _mm256_unpacklo_ps(s_out, w_out));
  _mm256_storeu_ps(raw + 8, _mm256_unpackhi_ps(s_out, w_out));
}

/// fuseRowScalar for the 8 voxels of a row at once (AVX2, no FMA: every lane performs the
/// scalar code's operations in the same order, so the results are bit-identical). Lanes that
/// the scalar code leaves by `continue` are masked out; gathers read only active lanes.
__attribute__((target("avx2"), always_inline)) inline void fuseRowAvx2(const RowKernel& k, float rx,
                                                                       float ry, float rz,
                                                                       TsdfVoxel* voxels,
                                                                       BlockOutcome& out) {
  static_assert(kTsdfBlockSide == 8, "one AVX2 vector per row of voxels");
  const __m256 xi = _mm256_setr_ps(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
  const __m256 px = _mm256_add_ps(_mm256_set1_ps(rx), _mm256_mul_ps(xi, _mm256_set1_ps(k.ax_x)));
  const __m256 py = _mm256_add_ps(_mm256_set1_ps(ry), _mm256_mul_ps(xi, _mm256_set1_ps(k.ax_y)));
  const __m256 zc = _mm256_add_ps(_mm256_set1_ps(rz), _mm256_mul_ps(xi, _mm256_set1_ps(k.ax_z)));
  __m256 m = _mm256_and_ps(_mm256_cmp_ps(zc, _mm256_set1_ps(k.z_min), _CMP_GE_OQ),
                           _mm256_cmp_ps(zc, _mm256_set1_ps(k.z_max), _CMP_LE_OQ));
  if (_mm256_movemask_ps(m) == 0) return;
  const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), zc);
  const __m256 uf = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(k.fx), px), inv),
                                  _mm256_set1_ps(k.cx));
  const __m256 vf = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(k.fy), py), inv),
                                  _mm256_set1_ps(k.cy));
  const __m256 lo = _mm256_set1_ps(-0.5f);
  m = _mm256_and_ps(m, _mm256_and_ps(_mm256_cmp_ps(uf, lo, _CMP_GE_OQ),
                                     _mm256_cmp_ps(uf, _mm256_set1_ps(k.w_lim), _CMP_LT_OQ)));
  m = _mm256_and_ps(m, _mm256_and_ps(_mm256_cmp_ps(vf, lo, _CMP_GE_OQ),
                                     _mm256_cmp_ps(vf, _mm256_set1_ps(k.h_lim), _CMP_LT_OQ)));
  if (_mm256_movemask_ps(m) == 0) return;
  out.in_view = true;
  const __m256 half = _mm256_set1_ps(0.5f);
  __m256i mi = _mm256_castps_si256(m);
  // Pixel indices (inactive lanes: 0, so that no index is ever out of range).
  const __m256i ui = _mm256_and_si256(
      mi,
      _mm256_min_epi32(_mm256_cvttps_epi32(_mm256_add_ps(uf, half)), _mm256_set1_epi32(k.W - 1)));
  const __m256i vi = _mm256_and_si256(
      mi,
      _mm256_min_epi32(_mm256_cvttps_epi32(_mm256_add_ps(vf, half)), _mm256_set1_epi32(k.H - 1)));
  const __m256i pix = _mm256_add_epi32(_mm256_mullo_epi32(vi, _mm256_set1_epi32(k.W)), ui);
  // PixelMeasurement as two 32-bit words: (nx | ny << 16) and (dq | kq << 16).
  const int* words = reinterpret_cast<const int*>(static_cast<const void*>(k.pixels));
  const __m256i pix2 = _mm256_slli_epi32(pix, 1);
  const __m256i zero = _mm256_setzero_si256();
  const __m256i w0 = _mm256_mask_i32gather_epi32(zero, words, pix2, mi, 4);
  const __m256i w1 = _mm256_mask_i32gather_epi32(zero, words + 1, pix2, mi, 4);
  const __m256i dq = _mm256_and_si256(w1, _mm256_set1_epi32(0xffff));
  const __m256i kq = _mm256_srai_epi32(w1, 16);
  mi = _mm256_andnot_si256(_mm256_cmpeq_epi32(dq, zero), mi);
  m = _mm256_castsi256_ps(mi);
  if (_mm256_movemask_ps(m) == 0) return;
  const __m256 nx = _mm256_cvtepi32_ps(_mm256_srai_epi32(_mm256_slli_epi32(w0, 16), 16));
  const __m256 ny = _mm256_cvtepi32_ps(_mm256_srai_epi32(w0, 16));
  const __m256 xn = _mm256_mul_ps(_mm256_sub_ps(_mm256_cvtepi32_ps(ui), _mm256_set1_ps(k.cx)),
                                  _mm256_set1_ps(k.inv_fx));
  const __m256 yn = _mm256_mul_ps(_mm256_sub_ps(_mm256_cvtepi32_ps(vi), _mm256_set1_ps(k.cy)),
                                  _mm256_set1_ps(k.inv_fy));
  const __m256 tangent = _mm256_add_ps(_mm256_mul_ps(nx, _mm256_sub_ps(px, _mm256_mul_ps(xn, zc))),
                                       _mm256_mul_ps(ny, _mm256_sub_ps(py, _mm256_mul_ps(yn, zc))));
  const __m256 q = _mm256_add_ps(
      _mm256_mul_ps(tangent, _mm256_set1_ps(1.0f / kNormalScale)),
      _mm256_sub_ps(_mm256_mul_ps(_mm256_cvtepi32_ps(dq), _mm256_set1_ps(k.depth_scale)), zc));
  const __m256 trunc = _mm256_set1_ps(k.trunc);
  m = _mm256_and_ps(m, _mm256_cmp_ps(q, _mm256_set1_ps(-k.trunc), _CMP_NLT_UQ));
  const __m256 cos_ray =
      _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_abs_epi32(kq)), _mm256_set1_ps(1.0f / kCosineScale));
  __m256 sdf = _mm256_mul_ps(cos_ray, q);
  m = _mm256_and_ps(m, _mm256_cmp_ps(sdf, _mm256_set1_ps(-k.behind), _CMP_NLT_UQ));
  if (_mm256_movemask_ps(m) == 0) return;
  m = silhouetteGuard(k, m, sdf, cos_ray, zc, ui, vi, pix);
  // Free space clamps to trunc; nearer values need a fused (not grazing), in-band pixel.
  const __m256 free_space = _mm256_cmp_ps(sdf, trunc, _CMP_GE_OQ);
  sdf = _mm256_blendv_ps(sdf, trunc, free_space);
  const __m256 near = _mm256_andnot_ps(free_space, m);
  if (_mm256_movemask_ps(near) != 0) {
    const __m256i in_band =
        _mm256_and_si256(_mm256_set1_epi32(0xff),
                         _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(k.in_band),
                                                     pix, _mm256_castps_si256(near), 1));
    const __m256i fused = _mm256_andnot_si256(
        _mm256_or_si256(_mm256_cmpgt_epi32(zero, kq), _mm256_cmpeq_epi32(in_band, zero)),
        _mm256_castps_si256(near));
    m = _mm256_or_ps(_mm256_and_ps(m, free_space), _mm256_castsi256_ps(fused));
  }
  const int bits = _mm256_movemask_ps(m);
  if (bits == 0) return;
  fuseLanes(k, sdf, m, bits, voxels, out);
}

}  // namespace

/// fuseRowAvx2 for the kTsdfBlockSide rows of one slice of a block: the row's first centre
/// moves by `ay` from (sx, sy, sz); `voxels` is the slice's first voxel. One function, so that
/// the rows' independent work overlaps.
__attribute__((target("avx2"))) void fuseSliceAvx2(const RowKernel& k, float sx, float sy, float sz,
                                                   float ay_x, float ay_y, float ay_z,
                                                   TsdfVoxel* voxels, BlockOutcome& out) {
  for (int y = 0; y < kTsdfBlockSide; ++y)  // the next slice's rows (one cache line each)
    __builtin_prefetch(voxels + (kTsdfBlockSide + y) * kTsdfBlockSide, 1);
  for (int y = 0; y < kTsdfBlockSide; ++y) {
    const float fyy = static_cast<float>(y);
    fuseRowAvx2(k, sx + fyy * ay_x, sy + fyy * ay_y, sz + fyy * ay_z, voxels + y * kTsdfBlockSide,
                out);
  }
}
#endif

}  // namespace planesdf::fusion_detail
