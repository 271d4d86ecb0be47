// Internal numeric and CPU helpers shared by the stages (not installed).
#pragma once

#include <cmath>

namespace planesdf::detail {

inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kDegToRad = kPi / 180.0;

/// Slabs parallel to a plane (shelf boards, table tops) are thinner than this, m: the reach of
/// the underside rules of the splatting (map) and of the ownership claims (change).
inline constexpr double kMaxSlabThickness = 0.05;

/// floor(x) as an int, without a libm call (the x86-64 baseline has no rounding instruction):
/// truncate, minus one where that rounded up. The same value as static_cast<int>(std::floor(x))
/// for |x| < 2^31; callers check the range (see floorToIntOr).
inline int floorToInt(double x) {
  const int i = static_cast<int>(x);
  return i - (x < static_cast<double>(i) ? 1 : 0);
}

/// floorToInt(x) when |x| < 1e9, else `fallback` (also for NaN).
inline int floorToIntOr(double x, int fallback) {
  return std::abs(x) < 1e9 ? floorToInt(x) : fallback;
}

/// True when this CPU runs AVX2 code (checked once, at the first call). The stages' AVX2 builds
/// (fusion's row kernel, the kept points' band pre-test, the height map's block classification
/// and layer walk, the in-plane refinement's scoring) run when this and cfg.simd are true.
inline bool cpuHasAvx2() {
#if defined(__x86_64__) && defined(__GNUC__)
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
#else
  return false;
#endif
}

}  // namespace planesdf::detail
