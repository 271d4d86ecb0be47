// Internal: the library's parallel loops (not installed). design.md, "Threads".
//
// Each host thread that calls into planesdf gets its own small pool of worker threads, created on
// first use, grown to the largest thread count asked for and joined when the host thread exits.
// Idle workers block on a condition variable; they never spin, so a busy host keeps its cores.
// A call made from inside a parallel loop (a worker, or the caller while it takes part) runs on
// the calling thread.
#pragma once

#include <functional>

namespace planesdf::detail {

/// Threads a stage uses: `requested` (Config::threads) or, at 0, the CPUs this process may run
/// on (its affinity mask; at least 1).
int resolveThreads(int requested);

/// Indices per claim of a loop over points or pixels with little work each.
inline constexpr long long kPointGrain = 4096;

/// The body of a loop: body(worker, begin, end) handles indices [begin, end); `worker` is in
/// [0, threads) and no two chunks run at once with the same worker (for per-worker scratch).
using ChunkBody = std::function<void(int, long long, long long)>;

/// Runs `body` over [0, n) in chunks of `grain` indices (the last may be shorter), claimed in
/// order by up to `threads` threads, the caller's included, and returns when all are done. The
/// first exception thrown by the body is rethrown; chunks not yet started are then skipped.
void parallelChunks(long long n, int threads, long long grain, const ChunkBody& body);

/// Runs f(0..n-1) on up to `threads` threads (0: all CPUs), one index per claim; the first
/// exception thrown by any f is rethrown once the running ones have finished.
inline void parallelFor(int n, int threads, const std::function<void(int)>& f) {
  parallelChunks(n, resolveThreads(threads), 1, [&](int, long long begin, long long end) {
    for (long long i = begin; i < end; ++i) f(static_cast<int>(i));
  });
}

/// The contiguous share [begin, end) of [0, n) of part `part` of `parts` (as a static schedule
/// gives each thread): part order is index order.
inline void staticShare(long long n, int parts, int part, long long& begin, long long& end) {
  const long long q = n / parts, r = n % parts;
  begin = part * q + (part < r ? part : r);
  end = begin + q + (part < r ? 1 : 0);
}

}  // namespace planesdf::detail
