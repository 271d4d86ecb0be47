#pragma once
/// \file memory.hpp
/// Memory for the large arrays of a growing map (TSDF block slabs, hash tables).
///
/// A map that grows frame by frame keeps asking the system for fresh memory, and every 4 KiB
/// page of it costs a page fault on first touch (on a virtual machine, several microseconds
/// each: thousands per frame add milliseconds). Requests of at least kHugePageBytes are
/// therefore mapped whole, 2 MiB-aligned and advised for transparent huge pages, so that one
/// fault maps 2 MiB where the kernel allows it (Linux THP in "madvise" or "always" mode);
/// smaller requests go to operator new. Internal to planesdf (used by its containers).

#include <cstddef>
#include <new>

namespace planesdf::detail {

/// Bytes of a transparent huge page on x86-64 and arm64 Linux.
constexpr std::size_t kHugePageBytes = std::size_t{2} << 20;

/// `bytes` of uninitialised memory, aligned to at least alignof(std::max_align_t); mapped whole
/// and huge-page advised from kHugePageBytes on. Throws std::bad_alloc.
void* allocateLarge(std::size_t bytes);
/// Releases memory from allocateLarge(bytes) (the same `bytes`). p may be nullptr.
void freeLarge(void* p, std::size_t bytes) noexcept;

/// Advises the whole 2 MiB pages inside [p, p + bytes) for transparent huge pages (memory the
/// caller owns and has not touched yet, e.g. a freshly reserved vector); a no-op elsewhere.
void adviseHugePages(void* p, std::size_t bytes) noexcept;

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
