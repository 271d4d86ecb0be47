// Height map of a PlaneSDF volume (DESIGN §2 "height map"): a top-down walk of every voxel
// column, 64 columns (one block column) at a time, parallel over block columns.

#include "planesdf/height_map.hpp"

#include "../numeric.hpp"
#include "planesdf/error.hpp"

#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace planesdf {
namespace {

int resolveThreads(int requested) {
  return requested > 0 ? requested : std::max(1, omp_get_max_threads());
}

/// The allocated blocks of one (bx, by) block column, highest first.
using BlockColumn = std::vector<const TsdfBlock*>;

/// Buckets the volume's blocks by (bx, by) over the block bounds [lo, hi]; each bucket sorted
/// by block z, descending.
std::vector<BlockColumn> bucketBlockColumns(const TsdfVolume& vol, const Eigen::Vector3i& lo,
                                            const Eigen::Vector3i& hi) {
  const int nbx = hi.x() - lo.x() + 1;
  const int nby = hi.y() - lo.y() + 1;
  std::vector<BlockColumn> columns(static_cast<std::size_t>(nbx) * static_cast<std::size_t>(nby));
  vol.forEachBlock([&](const TsdfBlock& b) {
    const std::size_t c = static_cast<std::size_t>(b.index.y() - lo.y()) * nbx +
                          static_cast<std::size_t>(b.index.x() - lo.x());
    columns[c].push_back(&b);
  });
  for (BlockColumn& col : columns)
    std::sort(col.begin(), col.end(),
              [](const TsdfBlock* a, const TsdfBlock* b) { return a->index.z() > b->index.z(); });
  return columns;
}

constexpr int kColumnsPerBlock = kTsdfBlockSide * kTsdfBlockSide;

/// The walk state of one voxel column (see computeHeightMap).
struct ColumnState {
  float above_sdf = 0.0f;       // the voxel directly above the current one ...
  bool above_observed = false;  // ... and whether it is observed
  bool done = false;            // a surface was found: `value` is final
  float value = kUnobserved;
  float lowest_free = std::numeric_limits<float>::infinity();  // centre h of the lowest free
};
using BlockColumnState = std::array<ColumnState, kColumnsPerBlock>;

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
int walkLayer(const TsdfVoxel* layer, int k, bool adjacent, float vs, float w_eff,
              BlockColumnState& cols) {
  const float centre = (static_cast<float>(k) + 0.5f) * vs;
  int active = 0;
  for (int c = 0; c < kColumnsPerBlock; ++c) {
    ColumnState& st = cols[static_cast<std::size_t>(c)];
    if (st.done) continue;
    const TsdfVoxel& v = layer[c];
    const bool observed = v.weight >= w_eff;
    if (observed && v.sdf <= 0.0f) {
      if (!adjacent || !st.above_observed) {  // below unobserved space: its top face
        st.value = std::max(0.0f, static_cast<float>(k + 1) * vs);
        st.done = true;
        continue;
      }
      if (st.above_sdf > 0.0f) {  // free above, inside here: the crossing between the centres
        st.value = std::max(0.0f, centre + vs * (v.sdf / (v.sdf - st.above_sdf)));
        st.done = true;
        continue;
      }
    } else if (observed) {
      st.lowest_free = centre;  // walking down: always the lowest so far
    }
    st.above_observed = observed;
    st.above_sdf = v.sdf;
    ++active;
  }
  return active;
}

/// Advances the columns over a whole block at once when it is all free (no surface possible;
/// the state becomes that of its bottom layer) or all unobserved. False for a mixed block.
bool skipUniformBlock(const TsdfBlock& b, float vs, float w_eff, bool avx2,
                      BlockColumnState& cols) {
  const BlockKind kind = classifyBlock(b, w_eff, avx2);
  if (kind == BlockKind::kMixed) return false;
  const float bottom_centre = (static_cast<float>(b.index.z() * kTsdfBlockSide) + 0.5f) * vs;
  for (int c = 0; c < kColumnsPerBlock; ++c) {
    ColumnState& st = cols[static_cast<std::size_t>(c)];
    st.above_observed = kind == BlockKind::kAllFree;
    st.above_sdf = b.voxels[static_cast<std::size_t>(c)].sdf;  // bottom layer
    if (kind == BlockKind::kAllFree) st.lowest_free = bottom_centre;
  }
  return true;
}

/// The height-map values of the 64 voxel columns of a block column, written to
/// out[lx + 8 * ly]. Walks the blocks top-down one z-layer (64 contiguous voxels) at a time, so
/// the voxel reads stream through memory, skipping uniform blocks whole; stops when every
/// column has found its surface.
void blockColumnHeights(const BlockColumn& blocks, float vs, float w_min, float h_obj, bool avx2,
                        float* out) {
  // weight > 0 && weight >= w_min, as one comparison.
  const float w_eff = std::max(w_min, std::numeric_limits<float>::denorm_min());
  BlockColumnState cols{};
  int above_k = std::numeric_limits<int>::max();  // k of the layer walked last
  int active = kColumnsPerBlock;
  for (std::size_t i = 0; i < blocks.size() && active > 0; ++i) {
    const TsdfBlock& b = *blocks[i];
    const int kbase = b.index.z() * kTsdfBlockSide;
    if (skipUniformBlock(b, vs, w_eff, avx2, cols)) {
      above_k = kbase;
      continue;
    }
    for (int lz = kTsdfBlockSide - 1; lz >= 0 && active > 0; --lz) {
      const int k = kbase + lz;
      const TsdfVoxel* layer = &b.voxels[static_cast<std::size_t>(kColumnsPerBlock * lz)];
      active = walkLayer(layer, k, above_k == k + 1, vs, w_eff, cols);
      above_k = k;
    }
  }
  for (int c = 0; c < kColumnsPerBlock; ++c) {
    const ColumnState& st = cols[static_cast<std::size_t>(c)];
    out[c] = st.done ? st.value : (st.lowest_free <= h_obj ? 0.0f : kUnobserved);
  }
}

}  // namespace

std::size_t HeightMap::numObserved() const {
  return static_cast<std::size_t>(
      std::count_if(heights.begin(), heights.end(), [](float h) { return h != kUnobserved; }));
}

HeightMap computeHeightMap(const TsdfVolume& vol, const Config& cfg) {
  HeightMap hm;
  hm.cell_size = vol.voxelSize();
  Eigen::Vector3i lo, hi;
  if (!vol.blockBounds(&lo, &hi)) return hm;
  hm.width = (hi.x() - lo.x() + 1) * kTsdfBlockSide;
  hm.height = (hi.y() - lo.y() + 1) * kTsdfBlockSide;
  if (hm.numCells() > kMaxHeightMapCells)
    throw Error("", "height map of " + std::to_string(hm.width) + " x " +
                        std::to_string(hm.height) + " cells exceeds the limit of " +
                        std::to_string(kMaxHeightMapCells) +
                        ": the volume's blocks are spread too far apart");
  hm.i0 = lo.x() * kTsdfBlockSide;
  hm.j0 = lo.y() * kTsdfBlockSide;
  hm.heights.assign(hm.numCells(), kUnobserved);

  const std::vector<BlockColumn> columns = bucketBlockColumns(vol, lo, hi);
  const int nbx = hi.x() - lo.x() + 1;
  const int num_columns = static_cast<int>(columns.size());
  const float vs = static_cast<float>(vol.voxelSize());
  const bool avx2 = cfg.simd && detail::cpuHasAvx2();
#pragma omp parallel for num_threads(resolveThreads(cfg.threads)) \
    schedule(dynamic, 16) if (num_columns >= 64)
  for (int c = 0; c < num_columns; ++c) {
    const BlockColumn& col = columns[static_cast<std::size_t>(c)];
    if (col.empty()) continue;
    std::array<float, kColumnsPerBlock> values;
    blockColumnHeights(col, vs, cfg.w_min, static_cast<float>(cfg.h_obj), avx2, values.data());
    const int x0 = (c % nbx) * kTsdfBlockSide;
    const int y0 = (c / nbx) * kTsdfBlockSide;
    for (int ly = 0; ly < kTsdfBlockSide; ++ly)
      std::copy_n(values.begin() + ly * kTsdfBlockSide, kTsdfBlockSide, &hm.at(x0, y0 + ly));
  }
  return hm;
}

}  // namespace planesdf
