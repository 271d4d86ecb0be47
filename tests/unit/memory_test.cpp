// Large-array memory (memory.hpp) and the slab storage of TSDF blocks.

#include <gtest/gtest.h>

#include <cstdint>
#include <memory>
#include <numeric>
#include <set>
#include <vector>

#include "memory_internal.hpp"
#include "planesdf/memory.hpp"
#include "planesdf/tsdf.hpp"

namespace {

using planesdf::TsdfBlock;
using planesdf::TsdfVolume;
using planesdf::detail::kHugePageBytes;

TEST(LargeMemory, SmallAndLargeRequestsHoldWhatIsWritten) {
  for (const std::size_t bytes : {std::size_t{64}, std::size_t{100000}, kHugePageBytes - 8,
                                  kHugePageBytes, 3 * kHugePageBytes + 12345}) {
    auto* p = static_cast<std::uint32_t*>(planesdf::detail::allocateLarge(bytes));
    ASSERT_NE(p, nullptr);
    EXPECT_EQ(reinterpret_cast<std::uintptr_t>(p) % alignof(std::max_align_t), 0u);
#if defined(__linux__)
    if (bytes >= kHugePageBytes) {
      EXPECT_EQ(reinterpret_cast<std::uintptr_t>(p) % kHugePageBytes, 0u);
    }
#endif
    const std::size_t n = bytes / sizeof(std::uint32_t);
    for (std::size_t i = 0; i < n; ++i) p[i] = static_cast<std::uint32_t>(i * 2654435761u);
    std::size_t wrong = 0;
    for (std::size_t i = 0; i < n; ++i)
      wrong += p[i] != static_cast<std::uint32_t>(i * 2654435761u);
    EXPECT_EQ(wrong, 0u) << bytes << " bytes";
    planesdf::detail::freeLarge(p, bytes);
  }
  planesdf::detail::freeLarge(nullptr, kHugePageBytes);  // no-op
}

TEST(LargeMemory, AdvisingHugePagesKeepsTheContents) {
  std::vector<double> v(3 * kHugePageBytes / sizeof(double));
  std::iota(v.begin(), v.end(), 0.0);
  planesdf::detail::adviseHugePages(v.data(), v.size() * sizeof(double));
  planesdf::detail::adviseHugePages(v.data() + 1, 100);  // no whole huge page inside: no-op
  planesdf::detail::adviseHugePages(nullptr, kHugePageBytes * 4);
  EXPECT_EQ(v[0], 0.0);
  EXPECT_EQ(v[v.size() - 1], static_cast<double>(v.size() - 1));
}

TEST(LargeMemory, VectorsWithTheAllocatorGrowCopyAndMove) {
  using Vec = std::vector<std::uint64_t, planesdf::detail::LargeAllocator<std::uint64_t>>;
  Vec v;
  for (std::uint64_t i = 0; i < 1000000; ++i) v.push_back(i * i);  // crosses 2 MiB several times
  Vec copy = v;
  const Vec moved = std::move(v);
  ASSERT_EQ(copy.size(), 1000000u);
  ASSERT_EQ(moved.size(), 1000000u);
  for (std::uint64_t i = 0; i < 1000000; i += 999) {
    EXPECT_EQ(copy[i], i * i);
    EXPECT_EQ(moved[i], i * i);
  }
  copy.assign(10, 7u);
  EXPECT_EQ(copy.size(), 10u);
  EXPECT_EQ(copy[9], 7u);
}

TEST(BlockSlabs, BlocksKeepTheirAddressesAndStartUnobserved) {
  TsdfVolume vol(0.01, 0.04);
  std::vector<TsdfBlock*> first;
  constexpr int kBlocks = 5000;  // small slabs, then full huge-page slabs
  for (int i = 0; i < kBlocks; ++i) {
    TsdfBlock& b = vol.allocateBlock(Eigen::Vector3i(i % 100, i / 100, -3));
    first.push_back(&b);
    EXPECT_EQ(b.index, Eigen::Vector3i(i % 100, i / 100, -3));
    b.voxels[i % 512].weight = static_cast<float>(i + 1);
  }
  ASSERT_EQ(vol.numBlocks(), static_cast<std::size_t>(kBlocks));
  std::set<const TsdfBlock*> distinct;
  int observed = 0;
  for (int i = 0; i < kBlocks; ++i) {
    const TsdfBlock* b = vol.findBlock(Eigen::Vector3i(i % 100, i / 100, -3));
    ASSERT_EQ(b, first[static_cast<std::size_t>(i)]) << "block " << i << " moved";
    EXPECT_EQ(b, &vol.block(static_cast<std::size_t>(i)));
    distinct.insert(b);
    for (const auto& v : b->voxels) observed += v.weight > 0.0f ? 1 : 0;
    EXPECT_EQ(b->voxels[i % 512].weight, static_cast<float>(i + 1));
    EXPECT_EQ(b->revision, 0u);
  }
  EXPECT_EQ(distinct.size(), static_cast<std::size_t>(kBlocks));
  EXPECT_EQ(observed, kBlocks);  // every other voxel starts unobserved
  // A copy has its own blocks with the same contents; a move takes them over.
  const TsdfVolume copy = vol;
  EXPECT_NE(copy.findBlock(Eigen::Vector3i(5, 5, -3)), vol.findBlock(Eigen::Vector3i(5, 5, -3)));
  EXPECT_EQ(copy.findBlock(Eigen::Vector3i(5, 5, -3))->voxels[505 % 512].weight, 506.0f);
  TsdfVolume moved = std::move(vol);
  EXPECT_EQ(moved.findBlock(Eigen::Vector3i(7, 3, -3)), first[307]);
  // Cleared, the volume allocates afresh.
  moved.clear();
  EXPECT_EQ(moved.numBlocks(), 0u);
  EXPECT_EQ(moved.allocateBlock(Eigen::Vector3i(1, 2, 3)).voxels[0].weight, 0.0f);
  EXPECT_EQ(moved.numBlocks(), 1u);
}

TEST(BlockSlabs, MemoryPerVoxelStaysWithinTwelveBytesAsAVolumeGrows) {
  // 8 bytes per voxel plus the block header, the unused tail of the last slab (at most a
  // quarter of the blocks, or one slab of 16 blocks), the hash table and the slot array.
  TsdfVolume vol(0.01, 0.04);
  int n = 0;
  for (const int target : {64, 65, 100, 1000, 2036, 2037, 2100, 5000, 20000}) {
    for (; n < target; ++n) vol.allocateBlock(Eigen::Vector3i(n % 211, n / 211, 0));
    const double per_voxel =
        static_cast<double>(vol.memoryBytes()) / static_cast<double>(vol.numVoxels());
    EXPECT_GE(per_voxel, 8.0) << target << " blocks";
    EXPECT_LE(per_voxel, 12.0) << target << " blocks";
  }
}

TEST(HugePagePool, HandsOutEachFilledChunkOnceThenNothing) {
  planesdf::detail::HugePagePool pool;
  EXPECT_EQ(pool.bytes(), 0u);
  EXPECT_EQ(pool.take(), nullptr);
  pool.fill(2);
  pool.fill(1);  // adds
  EXPECT_EQ(pool.bytes(), 3 * kHugePageBytes);
  std::set<void*> taken;
  for (int i = 0; i < 3; ++i) {
    void* c = pool.take();
    ASSERT_NE(c, nullptr);
#if defined(__linux__)
    EXPECT_EQ(reinterpret_cast<std::uintptr_t>(c) % kHugePageBytes, 0u);
#endif
    auto* bytes = static_cast<unsigned char*>(c);
    bytes[0] = 1;  // the whole chunk is usable
    bytes[kHugePageBytes - 1] = 2;
    taken.insert(c);
  }
  EXPECT_EQ(taken.size(), 3u);
  EXPECT_EQ(pool.take(), nullptr);
  EXPECT_EQ(pool.bytes(), 0u);
  for (void* c : taken) planesdf::detail::freeLarge(c, kHugePageBytes);
  pool.fill(1);  // unmapped by the pool's destructor
}

TEST(HugePagePool, AVolumeTakesWholeChunksBeforeFreshMemory) {
  auto pool = std::make_shared<planesdf::detail::HugePagePool>();
  pool->fill(2);
  TsdfVolume vol(0.01, 0.04);
  vol.useHugePagePool(pool);
  const std::size_t per_chunk = kHugePageBytes / sizeof(TsdfBlock);  // 509 blocks
  const auto inChunk = [](const TsdfBlock* b, const TsdfBlock* first) {
    const auto a = reinterpret_cast<std::uintptr_t>(b), f = reinterpret_cast<std::uintptr_t>(first);
    return a >= f && a + sizeof(TsdfBlock) <= f + kHugePageBytes;
  };
  TsdfBlock& first = vol.allocateBlock(Eigen::Vector3i(0, 0, 0));
  EXPECT_EQ(pool->bytes(), kHugePageBytes);  // the first block took a whole chunk
  EXPECT_EQ(reinterpret_cast<std::uintptr_t>(&first) % kHugePageBytes, 0u);
  const std::size_t n = 3 * per_chunk;  // two chunks, then fresh slabs
  for (std::size_t i = 1; i < n; ++i) {
    TsdfBlock& b =
        vol.allocateBlock(Eigen::Vector3i(static_cast<int>(i % 97), static_cast<int>(i / 97), 1));
    for (const auto& v : b.voxels) ASSERT_EQ(v.weight, 0.0f) << "block " << i;
    b.voxels[0].sdf = static_cast<float>(i);
    if (i < per_chunk) {
      EXPECT_TRUE(inChunk(&b, &first)) << "block " << i;
    } else if (i == per_chunk) {
      EXPECT_FALSE(inChunk(&b, &first));
    }
  }
  EXPECT_EQ(pool->bytes(), 0u);
  EXPECT_EQ(vol.numBlocks(), n);
  for (std::size_t i = 1; i < n; ++i)
    ASSERT_EQ(vol.findBlock(Eigen::Vector3i(static_cast<int>(i % 97), static_cast<int>(i / 97), 1))
                  ->voxels[0]
                  .sdf,
              static_cast<float>(i));
  // A moved volume keeps using the pool; a copy does not share it.
  pool->fill(1);
  TsdfVolume moved = std::move(vol);
  moved.allocateBlock(Eigen::Vector3i(-5, -5, -5));  // room in the last fresh slab
  TsdfVolume copy = moved;
  EXPECT_EQ(copy.numBlocks(), n + 1);
  EXPECT_EQ(pool->bytes(), kHugePageBytes);
}

TEST(RetainFreedMemory, AppliesWithGlibc) {
#if defined(__GLIBC__) && !defined(__SANITIZE_ADDRESS__)
  EXPECT_TRUE(planesdf::retainFreedMemory());
  // Memory keeps working: a large block freed and requested again holds what is written.
  for (int round = 0; round < 2; ++round) {
    std::vector<std::uint32_t> v(8u << 20);
    std::iota(v.begin(), v.end(), 0u);
    EXPECT_EQ(v[(8u << 20) - 1], (8u << 20) - 1);
  }
#elif defined(__SANITIZE_ADDRESS__)
  planesdf::retainFreedMemory();  // AddressSanitizer's allocator ignores mallopt (returns 0)
#else
  EXPECT_FALSE(planesdf::retainFreedMemory());
#endif
}

}  // namespace
