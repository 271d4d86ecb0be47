// Internal: the pre-faulted chunks of Map::reserveMemory (not installed).
#pragma once

#include <cstddef>
#include <mutex>
#include <vector>

#include "planesdf/memory.hpp"

namespace planesdf::detail {

/// Chunks of kHugePageBytes from allocateLarge, mapped and touched up front (fill), that a map
/// hands to its volumes' block slabs (Map::reserveMemory): the first touch of fresh memory
/// (a page fault and the zeroing of the page: on a virtual machine whose host has not backed
/// the memory yet, about 3 ms per 2 MiB) then happens before fusion instead of during it.
/// Thread-safe. Chunks taken are the taker's (freeLarge(p, kHugePageBytes)).
class HugePagePool {
 public:
  HugePagePool() = default;
  HugePagePool(const HugePagePool&) = delete;
  HugePagePool& operator=(const HugePagePool&) = delete;
  ~HugePagePool();
  /// Maps and touches `chunks` more chunks (take() waits meanwhile). Throws std::bad_alloc;
  /// the pool keeps the chunks mapped before.
  void fill(std::size_t chunks);
  /// A chunk, or nullptr when the pool is empty.
  void* take() noexcept;
  /// Bytes of the chunks not taken yet.
  std::size_t bytes() const;

 private:
  mutable std::mutex mutex_;
  std::vector<void*> chunks_;
};

}  // namespace planesdf::detail
