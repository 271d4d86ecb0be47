// Large-array memory: whole mappings advised for transparent huge pages (see memory.hpp).

#include "planesdf/memory.hpp"
#include "memory_internal.hpp"

#include <cstdint>
#include <limits>

#include "planesdf/error.hpp"

#if defined(__linux__)
#include <sys/mman.h>
#include <unistd.h>
#endif
#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace planesdf {

bool retainFreedMemory() noexcept {
#if defined(__GLIBC__) && defined(M_TRIM_THRESHOLD) && defined(M_MMAP_THRESHOLD)
  // The largest mmap threshold glibc accepts on 64-bit systems: half its 64 MiB heap size
  // (requests above it are still mapped, and unmapped when freed).
  constexpr int kMmapThreshold = sizeof(void*) == 8 ? 32 << 20 : 512 << 10;
  const bool trim = mallopt(M_TRIM_THRESHOLD, std::numeric_limits<int>::max()) == 1;
  const bool mmap_ok = mallopt(M_MMAP_THRESHOLD, kMmapThreshold) == 1;
  return trim && mmap_ok;
#else
  return false;
#endif
}

std::size_t memoryLimitBytes(const Config& cfg) {
  constexpr std::size_t kMb = std::size_t{1} << 20;
  if (cfg.memory_limit_mb > 0) return static_cast<std::size_t>(cfg.memory_limit_mb) * kMb;
  const std::size_t physical = detail::physicalMemoryBytes();
  return physical > 0 ? physical / 2 : std::size_t{8192} * kMb;
}

void requireMemory(std::size_t bytes, const Config& cfg, const std::string& input,
                   const std::string& what) {
  const std::size_t limit = memoryLimitBytes(cfg);
  if (bytes <= limit) return;
  const auto mb = [](std::size_t b) { return std::to_string((b + (1 << 20) - 1) >> 20); };
  throw Error(input, what + " needs about " + mb(bytes) + " MB, more than the memory limit of " +
                         mb(limit) + " MB (memory_limit_mb, --memory-limit-mb)");
}

}  // namespace planesdf

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

HugePagePool::~HugePagePool() {
  for (void* c : chunks_) freeLarge(c, kHugePageBytes);
}

void HugePagePool::fill(std::size_t chunks) {
  // Each 4 KiB page written once: one fault per huge page where THP applies, else one per page,
  // all of them here. Holds the lock throughout (take() waits; fill runs at start-up).
  constexpr std::size_t kPage = 4096;
  const std::lock_guard<std::mutex> lock(mutex_);
  chunks_.reserve(chunks_.size() + chunks);  // no throw below once a chunk is mapped
  for (std::size_t i = 0; i < chunks; ++i) {
    auto* c = static_cast<unsigned char*>(allocateLarge(kHugePageBytes));
    for (std::size_t o = 0; o < kHugePageBytes; o += kPage) c[o] = 0;
    chunks_.push_back(c);
  }
}

void* HugePagePool::take() noexcept {
  const std::lock_guard<std::mutex> lock(mutex_);
  if (chunks_.empty()) return nullptr;
  void* c = chunks_.back();
  chunks_.pop_back();
  return c;
}

std::size_t HugePagePool::bytes() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return chunks_.size() * kHugePageBytes;
}

std::size_t physicalMemoryBytes() noexcept {
#if defined(__linux__)
  const long pages = sysconf(_SC_PHYS_PAGES);
  const long page = sysconf(_SC_PAGESIZE);
  if (pages > 0 && page > 0)
    return static_cast<std::size_t>(pages) * static_cast<std::size_t>(page);
#endif
  return 0;
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
