// The allocation pass's AVX2 row kernel (allocateRowAvx2), bit-identical to allocatePixel in
// block_allocation.cpp; compiled for AVX2 through target attributes (no per-file flags).

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>

#include "block_sets.hpp"
#include "fusion_internal.hpp"

namespace planesdf::fusion_detail {

#if PLANESDF_AVX2_KERNEL
/// allocatePixel for a row, 8 pixels at a time (AVX2, no FMA: every lane performs the scalar
/// code's operations in the same order, so flags and segments are bit-identical). A group whose
/// segments' block box lies inside a box already known to be allocated skips the segments (they
/// cannot add a block). Returns the in-band count.
__attribute__((target("avx2"))) int allocateRowAvx2(const AllocRow& r, SegmentBlocks& segments) {
  int count = 0, u = 0;
  const __m256 zero = _mm256_setzero_ps();
  for (; u + 8 <= r.W; u += 8) {
    const __m256 k = _mm256_loadu_ps(r.k + u);
    __m256 m = _mm256_cmp_ps(k, zero, _CMP_NEQ_UQ);
    if (_mm256_movemask_ps(m) == 0) {
      std::memset(r.flag + u, 0, 8);
      continue;
    }
    const __m256 d = _mm256_loadu_ps(r.depth + u);
    const __m256 xu = _mm256_loadu_ps(r.xn + u);
    __m256 dir[3];
    for (int i = 0; i < 3; ++i)
      dir[i] = _mm256_add_ps(_mm256_mul_ps(xu, _mm256_set1_ps(r.dir_col[i])),
                             _mm256_set1_ps(r.dir_row[i]));
    const __m256 pz = _mm256_add_ps(_mm256_set1_ps(r.t[2]), _mm256_mul_ps(d, dir[2]));
    m = _mm256_and_ps(m,
                      _mm256_and_ps(_mm256_cmp_ps(pz, _mm256_set1_ps(r.band.pt_lo), _CMP_GE_OQ),
                                    _mm256_cmp_ps(pz, _mm256_set1_ps(r.band.pt_hi), _CMP_LE_OQ)));
    const int in_band = _mm256_movemask_ps(m);
    for (int i = 0; i < 8; ++i) r.flag[u + i] = static_cast<std::uint8_t>((in_band >> i) & 1);
    if (in_band == 0) continue;
    count += __builtin_popcount(static_cast<unsigned>(in_band));
    const __m256 trunc = _mm256_set1_ps(r.trunc);
    __m256 s0 = _mm256_div_ps(_mm256_set1_ps(-r.trunc), k);
    __m256 s1 = _mm256_min_ps(_mm256_mul_ps(_mm256_set1_ps(-kBehindFraction), s0), trunc);
    const __m256 sa = _mm256_div_ps(_mm256_sub_ps(_mm256_set1_ps(r.band.alloc_lo), pz), dir[2]);
    const __m256 sb = _mm256_div_ps(_mm256_sub_ps(_mm256_set1_ps(r.band.alloc_hi), pz), dir[2]);
    const __m256 swap = _mm256_cmp_ps(sa, sb, _CMP_GT_OQ);
    const __m256 lo = _mm256_blendv_ps(sa, sb, swap), hi = _mm256_blendv_ps(sb, sa, swap);
    const __m256 clip = _mm256_cmp_ps(dir[2], zero, _CMP_NEQ_UQ);
    s0 = _mm256_blendv_ps(s0, _mm256_max_ps(lo, s0), clip);
    s1 = _mm256_blendv_ps(s1, _mm256_min_ps(hi, s1), clip);
    const int seg = in_band & ~_mm256_movemask_ps(_mm256_cmp_ps(s0, s1, _CMP_GT_OQ));
    if (seg == 0) continue;
    const __m256 inv_bs = _mm256_set1_ps(r.inv_bs);
    const __m256 a0 = _mm256_mul_ps(_mm256_add_ps(d, s0), inv_bs);
    const __m256 a1 = _mm256_mul_ps(_mm256_add_ps(d, s1), inv_bs);
    alignas(32) float A[3][8], B[3][8];
    alignas(32) int ia[3][8], ib[3][8];
    for (int i = 0; i < 3; ++i) {
      const __m256 tb = _mm256_set1_ps(r.t_bs[i]);
      const __m256 pa = _mm256_add_ps(tb, _mm256_mul_ps(a0, dir[i]));
      const __m256 pb = _mm256_add_ps(tb, _mm256_mul_ps(a1, dir[i]));
      _mm256_store_ps(A[i], pa);
      _mm256_store_ps(B[i], pb);
      // floorToInt: truncate, minus one where that rounded up.
      const __m256i ta = _mm256_cvttps_epi32(pa), tb_ = _mm256_cvttps_epi32(pb);
      _mm256_store_si256(reinterpret_cast<__m256i*>(ia[i]),
                         _mm256_add_epi32(ta, _mm256_castps_si256(_mm256_cmp_ps(
                                                  pa, _mm256_cvtepi32_ps(ta), _CMP_LT_OQ))));
      _mm256_store_si256(reinterpret_cast<__m256i*>(ib[i]),
                         _mm256_add_epi32(tb_, _mm256_castps_si256(_mm256_cmp_ps(
                                                   pb, _mm256_cvtepi32_ps(tb_), _CMP_LT_OQ))));
    }
    Eigen::Vector3i box_lo = Eigen::Vector3i::Constant(std::numeric_limits<int>::max());
    Eigen::Vector3i box_hi = Eigen::Vector3i::Constant(std::numeric_limits<int>::min());
    for (int l = 0; l < 8; ++l) {
      if (!((seg >> l) & 1)) continue;
      for (int i = 0; i < 3; ++i) {
        box_lo[i] = std::min({box_lo[i], ia[i][l], ib[i][l]});
        box_hi[i] = std::max({box_hi[i], ia[i][l], ib[i][l]});
      }
    }
    if (segments.boxKnown(box_lo, box_hi)) continue;
    for (int l = 0; l < 8; ++l)
      if ((seg >> l) & 1)
        segments.add(Eigen::Vector3f(A[0][l], A[1][l], A[2][l]),
                     Eigen::Vector3f(B[0][l], B[1][l], B[2][l]));
    segments.noteBox(box_lo, box_hi);
  }
  for (; u < r.W; ++u) count += allocatePixel(r, u, segments);
  return count;
}
#endif

}  // namespace planesdf::fusion_detail
