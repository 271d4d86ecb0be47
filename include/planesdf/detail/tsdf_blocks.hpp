#pragma once
/// \file tsdf_blocks.hpp
/// Internal: the block storage behind TsdfVolume (packed block keys, the block hash map, the
/// block slabs). Not part of the API: installed only because tsdf.hpp's inline lookups use it,
/// and it may change in any release.

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "planesdf/memory.hpp"

namespace planesdf {

struct TsdfBlock;

namespace detail {

constexpr int kBlockKeyBits = 21;
constexpr std::uint64_t kBlockKeyMask = (std::uint64_t{1} << kBlockKeyBits) - 1;
constexpr int kBlockKeyOffset = 1 << (kBlockKeyBits - 1);
constexpr std::uint64_t kEmptyBlockKey = ~std::uint64_t{0};  // never a packed key
/// splitmix64 finaliser: spreads the structured keys of neighbouring blocks over a table.
inline std::uint64_t mixBlockKey(std::uint64_t k) {
  k ^= k >> 31;
  k *= 0x7fb5d329728ea185ull;
  k ^= k >> 27;
  k *= 0x81dadef4bc2dd44dull;
  k ^= k >> 33;
  return k;
}

/// Packs a block index into a 64-bit key (21 bits per axis). Requires blockIndexInRange(b).
inline std::uint64_t packBlockKey(const Eigen::Vector3i& b) {
  const auto part = [](int c) {
    return static_cast<std::uint64_t>(static_cast<std::int64_t>(c) + kBlockKeyOffset) &
           kBlockKeyMask;
  };
  return part(b.x()) | (part(b.y()) << kBlockKeyBits) | (part(b.z()) << (2 * kBlockKeyBits));
}

/// Inverse of packBlockKey.
inline Eigen::Vector3i unpackBlockKey(std::uint64_t key) {
  const auto part = [&](int shift) {
    return static_cast<int>((key >> shift) & kBlockKeyMask) - kBlockKeyOffset;
  };
  return Eigen::Vector3i(part(0), part(kBlockKeyBits), part(2 * kBlockKeyBits));
}

/// Open-addressing (linear probing) hash map from a packed 64-bit block key to a 32-bit value.
/// Used by TsdfVolume for block lookup and by the fusion code as a fast key set. No erase.
class BlockHashMap {
 public:
  static constexpr std::uint32_t kNotFound = 0xffffffffu;

  /// The value stored for `key`, or kNotFound.
  std::uint32_t find(std::uint64_t key) const {
    if (keys_.empty()) return kNotFound;
    for (std::size_t i = mixBlockKey(key) & mask_;; i = (i + 1) & mask_) {
      const std::uint64_t k = keys_[i];
      if (k == key) return values_[i];
      if (k == kEmptyBlockKey) return kNotFound;
    }
  }
  /// Inserts (key, value) unless present. Returns the stored value and whether it was inserted.
  std::pair<std::uint32_t, bool> insert(std::uint64_t key, std::uint32_t value);
  /// Set use: inserts `key` (value 0) unless present; true when it was inserted. Unlike insert,
  /// a hit reads no value.
  bool insertKey(std::uint64_t key);
  /// Asks the cache for the first slot `key` probes (a batch of lookups can run ahead).
  void prefetch(std::uint64_t key) const {
    if (!keys_.empty()) __builtin_prefetch(&keys_[mixBlockKey(key) & mask_]);
  }
  std::size_t size() const { return size_; }
  /// Removes all entries, keeping the table's capacity.
  void clear();
  /// Makes room for `n` entries without rehashing.
  void reserve(std::size_t n);
  /// Bytes held by the table (keys and values arrays).
  std::size_t memoryBytes() const;

 private:
  void rehash(std::size_t capacity);

  // Large tables are mapped whole (LargeAllocator): a growing table's rehash faults in
  // its new arrays one huge page at a time.
  std::vector<std::uint64_t, LargeAllocator<std::uint64_t>> keys_;  // kEmpty: free slot
  std::vector<std::uint32_t, LargeAllocator<std::uint32_t>> values_;
  std::size_t size_ = 0;
  std::size_t mask_ = 0;
};

/// Storage of a volume's blocks in slabs of consecutive blocks whose addresses never change. A
/// new slab holds a quarter of the blocks stored so far (at least 16, at most one huge page,
/// 509 blocks): a growing volume calls the allocator once per slab instead of once per block,
/// its large slabs are faulted in one huge page at a time (LargeAllocator), and the
/// unused tail is at most a quarter of the blocks. Not copyable (TsdfVolume copies blocks).
class BlockSlabs {
 public:
  BlockSlabs() = default;
  BlockSlabs(const BlockSlabs&) = delete;
  BlockSlabs& operator=(const BlockSlabs&) = delete;
  BlockSlabs(BlockSlabs&& other) noexcept;
  BlockSlabs& operator=(BlockSlabs&& other) noexcept;
  ~BlockSlabs();
  /// A new block, all voxels unobserved (a value-initialised TsdfBlock).
  TsdfBlock* create();
  /// Makes room for `n` more blocks in one slab (huge pages from 2 MiB on) when the current one
  /// has less: a volume whose size is known up front (a copy, a loaded map, a region) is not
  /// grown through many small slabs, each page of them a fault.
  void reserve(std::size_t n);
  /// Frees every slab.
  void clear() noexcept;
  /// Bytes the slabs hold (their whole capacity).
  std::size_t bytes() const { return bytes_; }
  /// New slabs are whole chunks of `pool` while it has any (nullptr: none; the default).
  void usePool(std::shared_ptr<HugePagePool> pool) { pool_ = std::move(pool); }
  const std::shared_ptr<HugePagePool>& pool() const { return pool_; }

 private:
  struct Slab {
    TsdfBlock* blocks;
    std::size_t capacity;  ///< blocks
    std::size_t bytes;     ///< requested from allocateLarge
  };
  std::vector<Slab> slabs_;
  std::shared_ptr<HugePagePool> pool_;
  std::size_t used_ = 0;   ///< blocks created in the last slab
  std::size_t total_ = 0;  ///< blocks created in all slabs
  std::size_t bytes_ = 0;
};

}  // namespace detail
}  // namespace planesdf
