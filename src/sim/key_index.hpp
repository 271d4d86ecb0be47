#pragma once
// Internal to the simulator: an open-addressing hash map from 64-bit cell / block keys to dense
// indices 0, 1, 2, ... in insertion order (the whole-scene cloud's cells, the TSDF's blocks).

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace planesdf::sim::detail {

/// Keys are any 64-bit values except ~0. find() is const and safe to call from many threads
/// while no thread inserts.
class KeyIndex {
 public:
  static constexpr std::uint32_t kNone = ~std::uint32_t{0};

  explicit KeyIndex(std::size_t expected = 1024) {
    std::size_t cap = 1024;
    while (cap < 2 * expected) cap *= 2;
    keys_.assign(cap, kEmpty);
    index_.assign(cap, kNone);
  }

  std::size_t size() const { return count_; }

  /// The index of `key`, inserting it (as index size()) when new.
  std::uint32_t insert(std::uint64_t key) {
    if (2 * (count_ + 1) > keys_.size()) grow();
    const std::size_t i = slot(key);
    if (keys_[i] == kEmpty) {
      keys_[i] = key;
      index_[i] = static_cast<std::uint32_t>(count_++);
    }
    return index_[i];
  }

  /// The index of `key`, or kNone.
  std::uint32_t find(std::uint64_t key) const { return index_[slot(key)]; }

  /// Bytes held by the table.
  std::size_t bytes() const {
    return keys_.capacity() * sizeof(std::uint64_t) + index_.capacity() * sizeof(std::uint32_t);
  }

 private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};

  std::size_t slot(std::uint64_t key) const {
    const std::uint64_t h = key * 0x9E3779B97F4A7C15ull;
    std::size_t i = static_cast<std::size_t>(h >> 24) & (keys_.size() - 1);
    while (keys_[i] != kEmpty && keys_[i] != key) i = (i + 1) & (keys_.size() - 1);
    return i;
  }

  void grow() {
    const std::vector<std::uint64_t> old_keys = std::move(keys_);
    const std::vector<std::uint32_t> old_index = std::move(index_);
    keys_.assign(old_keys.size() * 2, kEmpty);
    index_.assign(old_keys.size() * 2, kNone);
    for (std::size_t j = 0; j < old_keys.size(); ++j)
      if (old_keys[j] != kEmpty) {
        const std::size_t i = slot(old_keys[j]);
        keys_[i] = old_keys[j];
        index_[i] = old_index[j];
      }
  }

  std::vector<std::uint64_t> keys_;
  std::vector<std::uint32_t> index_;
  std::size_t count_ = 0;
};

}  // namespace planesdf::sim::detail
