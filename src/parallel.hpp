// Internal: a parallel loop over indices with OpenMP (not installed).
#pragma once

#include <omp.h>

#include <algorithm>
#include <exception>
#include <functional>

namespace planesdf::detail {

/// Runs f(0..n-1) on up to `threads` threads (0: all cores), dynamically scheduled; the first
/// exception thrown by any f is rethrown once all have finished.
inline void parallelFor(int n, int threads, const std::function<void(int)>& f) {
  const int t = threads > 0 ? threads : std::max(1, omp_get_max_threads());
  std::exception_ptr error;
#pragma omp parallel for num_threads(t) if (t > 1 && n > 1) schedule(dynamic, 1)
  for (int i = 0; i < n; ++i) {
    try {
      f(i);
    } catch (...) {
#pragma omp critical(planesdf_parallel_for_error)
      if (!error) error = std::current_exception();
    }
  }
  if (error) std::rethrow_exception(error);
}

}  // namespace planesdf::detail
