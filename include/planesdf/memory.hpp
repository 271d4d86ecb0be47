#pragma once
/// \file memory.hpp
/// Memory for the large arrays of a growing map (TSDF block slabs, hash tables).
///
/// A map that grows frame by frame keeps asking the system for fresh memory, and every 4 KiB
/// page of it costs a page fault on first touch (on a virtual machine, several microseconds
/// each: thousands per frame add milliseconds). Requests of at least kHugePageBytes are
/// therefore mapped whole, 2 MiB-aligned and advised for transparent huge pages, so that one
/// fault maps 2 MiB where the kernel allows it (Linux THP in "madvise" or "always" mode);
/// smaller requests go to operator new. Internal to planesdf (used by its containers), except
/// retainFreedMemory, which applications call once at start-up.

#include <cstddef>
#include <new>
#include <string>
#include <vector>

#include "planesdf/config.hpp"

namespace planesdf {

/// Process-wide allocator setting for real-time use: memory the program frees stays in the
/// process for its next requests instead of going back to the system. With glibc's defaults,
/// freed blocks of more than a few MiB are unmapped (or trimmed off the heap) and the next
/// request faults them in again page by page: a detectChanges call on a room pair allocates
/// about 80 MB of grids (height maps, masks, labels) and took ~19,000 page faults and 110-180 ms
/// of system time per call on this project's 2-core VM, with the same faults again at every
/// call. This sets glibc malloc's trim threshold beyond reach and its mmap threshold to the
/// largest the heap can serve (32 MiB), as real-time pipelines do at start-up; the process
/// then keeps its peak heap. Call it once, before the threads that allocate start; the
/// planesdf command line calls it. Returns false where the allocator does not take the settings
/// (other C libraries; AddressSanitizer's allocator).
bool retainFreedMemory() noexcept;

/// Config::memory_limit_mb in bytes; 0 there gives half the physical memory (8192 MB when the
/// physical memory is unknown).
std::size_t memoryLimitBytes(const Config& cfg);

/// Throws planesdf::Error(input, ...) saying that `what` needs `bytes`, more than the memory
/// limit, unless `bytes` fits in memoryLimitBytes(cfg). Called before large allocations.
void requireMemory(std::size_t bytes, const Config& cfg, const std::string& input,
                   const std::string& what);

/// Bytes of the buffers that loading and fusing one depth frame of `pixels` pixels allocates
/// (decoded image, depth, back-projected points, the per-pixel fusion pass): an estimate.
constexpr std::size_t kDepthFrameBytesPerPixel = 64;

/// Bytes per cell of a height map and the grids detection derives from it (object labels,
/// change masks, the other map's heights, pictures): an estimate.
constexpr std::size_t kHeightMapBytesPerCell = 48;

}  // namespace planesdf

namespace planesdf::detail {

/// Bytes of a transparent huge page on x86-64 and arm64 Linux.
constexpr std::size_t kHugePageBytes = std::size_t{2} << 20;

/// `bytes` of uninitialised memory, aligned to at least alignof(std::max_align_t); mapped whole
/// and huge-page advised from kHugePageBytes on. Throws std::bad_alloc.
void* allocateLarge(std::size_t bytes);
/// Releases memory from allocateLarge(bytes) (the same `bytes`). p may be nullptr.
void freeLarge(void* p, std::size_t bytes) noexcept;

/// The machine's physical memory in bytes, or 0 when unknown.
std::size_t physicalMemoryBytes() noexcept;

/// Advises the whole 2 MiB pages inside [p, p + bytes) for transparent huge pages (memory the
/// caller owns and has not touched yet, e.g. a freshly reserved vector); a no-op elsewhere.
void adviseHugePages(void* p, std::size_t bytes) noexcept;

/// Pre-faulted chunks a map hands to its volumes (src/memory_internal.hpp).
class HugePagePool;

/// A standard allocator over allocateLarge / freeLarge (stateless; all instances are equal).
template <class T>
struct LargeAllocator {
  using value_type = T;
  LargeAllocator() noexcept = default;
  template <class U>
  LargeAllocator(const LargeAllocator<U>& /*other*/) noexcept {}  // NOLINT: rebinding
  T* allocate(std::size_t n) {
    if (n > static_cast<std::size_t>(-1) / sizeof(T)) throw std::bad_alloc();
    return static_cast<T*>(allocateLarge(n * sizeof(T)));
  }
  void deallocate(T* p, std::size_t n) noexcept { freeLarge(p, n * sizeof(T)); }
  template <class U>
  bool operator==(const LargeAllocator<U>& /*other*/) const noexcept {
    return true;
  }
  template <class U>
  bool operator!=(const LargeAllocator<U>& /*other*/) const noexcept {
    return false;
  }
};

}  // namespace planesdf::detail
