// Height map of a PlaneSDF volume (design.md, "Pipeline"): a top-down walk of every voxel
// column, 64 columns (one block column) at a time, parallel over block columns.

#include "planesdf/height_map.hpp"

#include "../numeric.hpp"
#include "../parallel.hpp"
#include "planesdf/error.hpp"
#include "planesdf/memory.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <string>
#include <vector>

namespace planesdf {
namespace {

/// The allocated blocks of one (bx, by) block column, highest first, with their block z.
using BlockColumn = std::vector<std::pair<int, const TsdfBlock*>>;

/// Buckets the volume's blocks by (bx, by) over the block bounds [lo, hi]; each bucket sorted
/// by block z, descending. Reads the volume's index array, not the blocks (a block's index
/// lies on the cache line after its voxels).
std::vector<BlockColumn> bucketBlockColumns(const TsdfVolume& vol, const Eigen::Vector3i& lo,
                                            const Eigen::Vector3i& hi) {
  const int nbx = hi.x() - lo.x() + 1;
  const int nby = hi.y() - lo.y() + 1;
  std::vector<BlockColumn> columns(static_cast<std::size_t>(nbx) * static_cast<std::size_t>(nby));
  for (std::size_t slot = 0; slot < vol.numBlocks(); ++slot) {
    const Eigen::Vector3i& b = vol.blockIndex(slot);
    if (b.x() < lo.x() || b.x() > hi.x() || b.y() < lo.y() || b.y() > hi.y()) continue;
    const std::size_t c =
        static_cast<std::size_t>(b.y() - lo.y()) * nbx + static_cast<std::size_t>(b.x() - lo.x());
    columns[c].emplace_back(b.z(), &vol.block(slot));
  }
  for (BlockColumn& col : columns)
    std::sort(col.begin(), col.end(),
              [](const auto& a, const auto& b) { return a.first > b.first; });
  return columns;
}

constexpr int kColumnsPerBlock = kTsdfBlockSide * kTsdfBlockSide;

/// The walk state of the 64 voxel columns of a block column (see computeHeightMap), one array
/// per field so that a layer is walked 8 columns at a time (AVX2). Flags are 0 or -1 (all bits).
struct BlockColumnState {
  static constexpr float kInfinity = std::numeric_limits<float>::infinity();
  alignas(32) float above_sdf[kColumnsPerBlock] = {};              // the voxel directly above ...
  alignas(32) std::int32_t above_observed[kColumnsPerBlock] = {};  // ... and whether observed
  alignas(32) std::int32_t done[kColumnsPerBlock] = {};  // a surface was found: `value` final
  alignas(32) float value[kColumnsPerBlock] = {};
  alignas(32) float lowest_free[kColumnsPerBlock] = {};  // centre h of the lowest free voxel
  alignas(32) std::int32_t unseen_above[kColumnsPerBlock] = {};  // `value` is a top face
  BlockColumnState() { std::fill(std::begin(lowest_free), std::end(lowest_free), kInfinity); }
};

/// What a whole block holds, for the fast paths of the walk.
enum class BlockKind { kMixed, kAllFree, kAllUnobserved };

/// kAllFree when every voxel is observed (weight >= w_eff) free space, kAllUnobserved when none
/// is observed. A branch-free count over the 512 voxels, vectorised: inlined into a default and
/// an AVX2 (8 voxels at a time) build of the same loop.
__attribute__((always_inline)) inline BlockKind classifyVoxels(const TsdfBlock& b, float w_eff) {
  int free = 0, unobserved = 0;
  for (const TsdfVoxel& v : b.voxels) {
    free += (v.weight >= w_eff) & (v.sdf > 0.0f);
    unobserved += v.weight < w_eff;
  }
  if (free == kTsdfBlockVoxels) return BlockKind::kAllFree;
  if (unobserved == kTsdfBlockVoxels) return BlockKind::kAllUnobserved;
  return BlockKind::kMixed;
}

#if defined(__x86_64__) && defined(__GNUC__)
__attribute__((target("avx2"))) BlockKind classifyBlockAvx2(const TsdfBlock& b, float w_eff) {
  return classifyVoxels(b, w_eff);
}
#endif

/// classifyBlock with the AVX2 build when `avx2` (the caller checked the CPU).
BlockKind classifyBlock(const TsdfBlock& b, float w_eff, bool avx2) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (avx2) return classifyBlockAvx2(b, w_eff);
#endif
  static_cast<void>(avx2);
  return classifyVoxels(b, w_eff);
}

/// Advances every column without a surface by one z-layer (64 contiguous voxels at height
/// index k; `adjacent`: the previous layer walked was k + 1). Returns the columns left.
/// Branch-free over the columns: a column that is done keeps its state (the reference code of
/// walkLayerAvx2, which gives bit-identical results).
int walkLayerScalar(const TsdfVoxel* layer, int k, bool adjacent, float vs, float w_eff,
                    BlockColumnState& cols) {
  const float centre = (static_cast<float>(k) + 0.5f) * vs;
  const float top_face = static_cast<float>(k + 1) * vs;
  const std::int32_t adj = adjacent ? -1 : 0;
  int active = 0;
  for (int c = 0; c < kColumnsPerBlock; ++c) {
    const float sdf = layer[c].sdf;
    const std::int32_t observed = layer[c].weight >= w_eff ? -1 : 0;
    const std::int32_t le0 = sdf <= 0.0f ? -1 : 0;
    const float above = cols.above_sdf[c];
    const std::int32_t open_inside = ~cols.done[c] & observed & le0;
    // Inside below unobserved space: its top face; inside below free space: the crossing
    // between the centres; inside below inside: the walk goes on.
    const std::int32_t below_observed = adj & cols.above_observed[c];
    const std::int32_t top = open_inside & ~below_observed;
    const std::int32_t cross = open_inside & below_observed & (above > 0.0f ? -1 : 0);
    const float found = top != 0 ? top_face : centre + vs * (sdf / (sdf - above));
    const std::int32_t hit = top | cross;
    cols.value[c] = hit != 0 ? (0.0f < found ? found : 0.0f) : cols.value[c];
    cols.unseen_above[c] = hit != 0 ? top : cols.unseen_above[c];
    // Walking down, an observed voxel that is not inside is always the lowest free so far.
    const std::int32_t free_here = ~cols.done[c] & observed & ~le0;
    cols.lowest_free[c] = free_here != 0 ? centre : cols.lowest_free[c];
    const std::int32_t still = ~cols.done[c] & ~hit;
    cols.above_observed[c] = still != 0 ? observed : cols.above_observed[c];
    cols.above_sdf[c] = still != 0 ? sdf : above;
    cols.done[c] = ~still;
    active += still & 1;
  }
  return active;
}

#if defined(__x86_64__) && defined(__GNUC__)
/// walkLayerScalar 8 columns at a time (no FMA: the same operations in the same order). A
/// layer's 8 (sdf, weight) pairs load as two vectors, de-interleaved by a shuffle and a permute.
__attribute__((target("avx2"))) int walkLayerAvx2(const TsdfVoxel* layer, int k, bool adjacent,
                                                  float vs, float w_eff, BlockColumnState& cols) {
  const __m256 centre = _mm256_set1_ps((static_cast<float>(k) + 0.5f) * vs);
  const __m256 top_face = _mm256_set1_ps(static_cast<float>(k + 1) * vs);
  const __m256 vvs = _mm256_set1_ps(vs), weff = _mm256_set1_ps(w_eff);
  const __m256 zero = _mm256_setzero_ps();
  const __m256 ones = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
  const __m256 adj = adjacent ? ones : zero;
  const __m256i order = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
  int active = 0;
  for (int c = 0; c < kColumnsPerBlock; c += 8) {
    const float* raw = &layer[c].sdf;
    const __m256 v0 = _mm256_loadu_ps(raw), v1 = _mm256_loadu_ps(raw + 8);
    const __m256 sdf = _mm256_permutevar8x32_ps(_mm256_shuffle_ps(v0, v1, 0x88), order);
    const __m256 w = _mm256_permutevar8x32_ps(_mm256_shuffle_ps(v0, v1, 0xdd), order);
    const __m256 observed = _mm256_cmp_ps(w, weff, _CMP_GE_OQ);
    const __m256 le0 = _mm256_cmp_ps(sdf, zero, _CMP_LE_OQ);
    const __m256 above = _mm256_load_ps(cols.above_sdf + c);
    const __m256 above_observed = _mm256_load_ps(
        reinterpret_cast<const float*>(static_cast<const void*>(cols.above_observed + c)));
    const __m256 done =
        _mm256_load_ps(reinterpret_cast<const float*>(static_cast<const void*>(cols.done + c)));
    const __m256 open_inside = _mm256_andnot_ps(done, _mm256_and_ps(observed, le0));
    const __m256 below_observed = _mm256_and_ps(adj, above_observed);
    const __m256 top = _mm256_andnot_ps(below_observed, open_inside);
    const __m256 cross = _mm256_and_ps(_mm256_and_ps(open_inside, below_observed),
                                       _mm256_cmp_ps(above, zero, _CMP_GT_OQ));
    const __m256 crossing =
        _mm256_add_ps(centre, _mm256_mul_ps(vvs, _mm256_div_ps(sdf, _mm256_sub_ps(sdf, above))));
    const __m256 found = _mm256_blendv_ps(crossing, top_face, top);
    const __m256 clamped = _mm256_and_ps(found, _mm256_cmp_ps(zero, found, _CMP_LT_OQ));
    const __m256 hit = _mm256_or_ps(top, cross);
    _mm256_store_ps(cols.value + c, _mm256_blendv_ps(_mm256_load_ps(cols.value + c), clamped, hit));
    float* unseen = reinterpret_cast<float*>(static_cast<void*>(cols.unseen_above + c));
    _mm256_store_ps(unseen, _mm256_blendv_ps(_mm256_load_ps(unseen), top, hit));
    const __m256 free_here = _mm256_andnot_ps(done, _mm256_andnot_ps(le0, observed));
    _mm256_store_ps(cols.lowest_free + c,
                    _mm256_blendv_ps(_mm256_load_ps(cols.lowest_free + c), centre, free_here));
    const __m256 still = _mm256_andnot_ps(_mm256_or_ps(done, hit), ones);
    _mm256_store_ps(reinterpret_cast<float*>(static_cast<void*>(cols.above_observed + c)),
                    _mm256_blendv_ps(above_observed, observed, still));
    _mm256_store_ps(cols.above_sdf + c, _mm256_blendv_ps(above, sdf, still));
    _mm256_store_ps(reinterpret_cast<float*>(static_cast<void*>(cols.done + c)),
                    _mm256_xor_ps(still, ones));
    active += __builtin_popcount(static_cast<unsigned>(_mm256_movemask_ps(still)));
  }
  return active;
}
#endif

/// walkLayerScalar with the AVX2 build when `avx2` (the caller checked the CPU).
int walkLayer(const TsdfVoxel* layer, int k, bool adjacent, float vs, float w_eff, bool avx2,
              BlockColumnState& cols) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (avx2) return walkLayerAvx2(layer, k, adjacent, vs, w_eff, cols);
#endif
  static_cast<void>(avx2);
  return walkLayerScalar(layer, k, adjacent, vs, w_eff, cols);
}

/// Advances the columns over a whole block (block z `bz`) at once when it is all free (no surface
/// possible; the state becomes that of its bottom layer) or all unobserved. False for a mixed
/// block.
bool skipUniformBlock(const TsdfBlock& b, int bz, float vs, float w_eff, bool avx2,
                      BlockColumnState& cols) {
  const BlockKind kind = classifyBlock(b, w_eff, avx2);
  if (kind == BlockKind::kMixed) return false;
  const float bottom_centre = (static_cast<float>(bz * kTsdfBlockSide) + 0.5f) * vs;
  for (int c = 0; c < kColumnsPerBlock; ++c) {
    if (cols.done[c]) continue;
    cols.above_observed[c] = kind == BlockKind::kAllFree ? -1 : 0;
    cols.above_sdf[c] = b.voxels[static_cast<std::size_t>(c)].sdf;  // bottom layer
    if (kind == BlockKind::kAllFree) cols.lowest_free[c] = bottom_centre;
  }
  return true;
}

/// The height-map values of the 64 voxel columns of a block column, written to
/// out[lx + 8 * ly]. Walks the blocks top-down one z-layer (64 contiguous voxels) at a time, so
/// the voxel reads stream through memory, skipping uniform blocks whole; stops when every
/// column has found its surface.
void blockColumnHeights(const BlockColumn& blocks, float vs, float w_min, float h_obj, bool avx2,
                        float* out, std::uint8_t* unseen_above) {
  // weight > 0 && weight >= w_min, as one comparison.
  const float w_eff = std::max(w_min, std::numeric_limits<float>::denorm_min());
  BlockColumnState cols;
  int above_k = std::numeric_limits<int>::max();  // k of the layer walked last
  int active = kColumnsPerBlock;
  for (std::size_t i = 0; i < blocks.size() && active > 0; ++i) {
    const TsdfBlock& b = *blocks[i].second;
    const int kbase = blocks[i].first * kTsdfBlockSide;
    if (i + 1 < blocks.size()) {  // the next block's voxels, while this one is walked
      const char* next = reinterpret_cast<const char*>(blocks[i + 1].second->voxels.data());
      for (std::size_t o = 0; o < sizeof(TsdfBlock::voxels); o += 64) __builtin_prefetch(next + o);
    }
    if (skipUniformBlock(b, blocks[i].first, vs, w_eff, avx2, cols)) {
      above_k = kbase;
      continue;
    }
    for (int lz = kTsdfBlockSide - 1; lz >= 0 && active > 0; --lz) {
      const int k = kbase + lz;
      const TsdfVoxel* layer = &b.voxels[static_cast<std::size_t>(kColumnsPerBlock * lz)];
      active = walkLayer(layer, k, above_k == k + 1, vs, w_eff, avx2, cols);
      above_k = k;
    }
  }
  for (int c = 0; c < kColumnsPerBlock; ++c) {
    out[c] = cols.done[c] ? cols.value[c] : (cols.lowest_free[c] <= h_obj ? 0.0f : kUnobserved);
    unseen_above[c] = cols.done[c] && cols.unseen_above[c] ? 1 : 0;
  }
}

/// Trims the block bounds [lo, hi] (x and y) to the block columns that meet `window` (u, v in
/// metres), by whole steps of lcm(block side, roughness tile) cells from the full bounds'
/// origin: the trimmed grid's roughness tiles are the full grid's (computeRoughness). False
/// when no block column meets the window.
bool trimToWindow(const Eigen::AlignedBox2d& window, double voxel_size, int roughness_tile,
                  Eigen::Vector3i& lo, Eigen::Vector3i& hi) {
  // 64-bit: an unvalidated tile up to INT_MAX must not overflow (a step past the grid trims
  // nothing).
  const long long tile = roughness_tile > 0 ? roughness_tile : kTsdfBlockSide;
  const long long step = std::lcm<long long>(kTsdfBlockSide, tile) / kTsdfBlockSide;  // blocks
  const double block = voxel_size * kTsdfBlockSide;
  for (int a = 0; a < 2; ++a) {
    const double wlo = std::floor(window.min()(a) / block);
    const double whi = std::floor(window.max()(a) / block);
    if (!(wlo <= hi(a)) || !(whi >= lo(a))) return false;
    const long long first = static_cast<long long>(std::max<double>(lo(a), wlo)) - lo(a);
    const long long last = static_cast<long long>(std::min<double>(hi(a), whi)) - lo(a);
    hi(a) = static_cast<int>(std::min<long long>(hi(a), lo(a) + (last / step + 1) * step - 1));
    lo(a) = static_cast<int>(lo(a) + first / step * step);
  }
  return true;
}

}  // namespace

std::size_t HeightMap::numObserved() const {
  return static_cast<std::size_t>(
      std::count_if(heights.begin(), heights.end(), [](float h) { return h != kUnobserved; }));
}

HeightMap computeHeightMap(const TsdfVolume& vol, const Config& cfg) {
  return computeHeightMap(vol, cfg, Eigen::AlignedBox2d());
}

HeightMap computeHeightMap(const TsdfVolume& vol, const Config& cfg,
                           const Eigen::AlignedBox2d& window) {
  HeightMap hm;
  hm.cell_size = vol.voxelSize();
  Eigen::Vector3i lo, hi;
  if (!vol.blockBounds(&lo, &hi)) return hm;
  if (!window.isEmpty() && !trimToWindow(window, vol.voxelSize(), cfg.roughness_tile, lo, hi))
    return hm;
  hm.width = (hi.x() - lo.x() + 1) * kTsdfBlockSide;
  hm.height = (hi.y() - lo.y() + 1) * kTsdfBlockSide;
  if (hm.numCells() > kMaxHeightMapCells)
    throw Error("", "height map of " + std::to_string(hm.width) + " x " +
                        std::to_string(hm.height) + " cells exceeds the limit of " +
                        std::to_string(kMaxHeightMapCells) +
                        ": the volume's blocks are spread too far apart");
  requireMemory(hm.numCells() * kHeightMapBytesPerCell, cfg, "",
                "a height map of " + std::to_string(hm.width) + " x " + std::to_string(hm.height) +
                    " cells (the volume's blocks span it)");
  hm.i0 = lo.x() * kTsdfBlockSide;
  hm.j0 = lo.y() * kTsdfBlockSide;
  hm.heights.assign(hm.numCells(), kUnobserved);
  hm.unseen_above.assign(hm.numCells(), 0);

  const std::vector<BlockColumn> columns = bucketBlockColumns(vol, lo, hi);
  const int nbx = hi.x() - lo.x() + 1;
  const int num_columns = static_cast<int>(columns.size());
  const float vs = static_cast<float>(vol.voxelSize());
  const bool avx2 = cfg.simd && detail::cpuHasAvx2();
  const auto fillColumn = [&](int c) {
    const BlockColumn& col = columns[static_cast<std::size_t>(c)];
    if (col.empty()) return;
    std::array<float, kColumnsPerBlock> values;
    std::array<std::uint8_t, kColumnsPerBlock> unseen;
    blockColumnHeights(col, vs, cfg.w_min, static_cast<float>(cfg.h_obj), avx2, values.data(),
                       unseen.data());
    const int x0 = (c % nbx) * kTsdfBlockSide;
    const int y0 = (c / nbx) * kTsdfBlockSide;
    for (int ly = 0; ly < kTsdfBlockSide; ++ly) {
      std::copy_n(values.begin() + ly * kTsdfBlockSide, kTsdfBlockSide, &hm.at(x0, y0 + ly));
      std::copy_n(unseen.begin() + ly * kTsdfBlockSide, kTsdfBlockSide,
                  &hm.unseen_above[hm.index(x0, y0 + ly)]);
    }
  };
  // Small maps (under 64 block columns) on the calling thread.
  const int threads = num_columns >= 64 ? detail::resolveThreads(cfg.threads) : 1;
  detail::parallelChunks(num_columns, threads, 16, [&](int, long long begin, long long end) {
    for (long long c = begin; c < end; ++c) fillColumn(static_cast<int>(c));
  });
  return hm;
}

}  // namespace planesdf
