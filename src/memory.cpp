// Large-array memory: whole mappings advised for transparent huge pages (see memory.hpp).

#include "planesdf/memory.hpp"

#include <cstdint>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace planesdf::detail {

namespace {

std::size_t roundUpToHugePage(std::size_t bytes) {
  return (bytes + kHugePageBytes - 1) & ~(kHugePageBytes - 1);
}

}  // namespace

void* allocateLarge(std::size_t bytes) {
#if defined(__linux__)
  if (bytes >= kHugePageBytes) {
    if (bytes > static_cast<std::size_t>(-1) - 2 * kHugePageBytes) throw std::bad_alloc();
    const std::size_t size = roundUpToHugePage(bytes);
    // Map one huge page more than needed and trim both ends to a 2 MiB boundary.
    void* raw = mmap(nullptr, size + kHugePageBytes, PROT_READ | PROT_WRITE,
                     MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (raw == MAP_FAILED) throw std::bad_alloc();
    const auto start = reinterpret_cast<std::uintptr_t>(raw);
    const std::uintptr_t aligned = (start + kHugePageBytes - 1) & ~(kHugePageBytes - 1);
    const std::size_t head = aligned - start;
    if (head > 0) munmap(raw, head);
    const std::size_t tail = kHugePageBytes - head;
    if (tail > 0) munmap(reinterpret_cast<void*>(aligned + size), tail);
    void* p = reinterpret_cast<void*>(aligned);
#if defined(MADV_HUGEPAGE)
    madvise(p, size, MADV_HUGEPAGE);  // advice only: without THP the pages stay 4 KiB
#endif
    return p;
  }
#endif
  return ::operator new(bytes);
}

void adviseHugePages(void* p, std::size_t bytes) noexcept {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  const auto start = reinterpret_cast<std::uintptr_t>(p);
  const std::uintptr_t lo = (start + kHugePageBytes - 1) & ~(kHugePageBytes - 1);
  const std::uintptr_t hi = (start + bytes) & ~(kHugePageBytes - 1);
  if (p != nullptr && hi > lo) madvise(reinterpret_cast<void*>(lo), hi - lo, MADV_HUGEPAGE);
#else
  (void)p;
  (void)bytes;
#endif
}

void freeLarge(void* p, std::size_t bytes) noexcept {
  if (p == nullptr) return;
#if defined(__linux__)
  if (bytes >= kHugePageBytes) {
    munmap(p, roundUpToHugePage(bytes));
    return;
  }
#endif
  ::operator delete(p);
}

}  // namespace planesdf::detail
