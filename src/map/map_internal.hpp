#pragma once
// Internal helpers shared by map.cpp and map_io.cpp.
#include <Eigen/Core>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "planesdf/map.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf::detail {

/// Heights n . p + d in [lo, hi] (a plane's band), in single precision for bandPretest.
struct BandF {
  float nx, ny, nz, d, lo, hi;
};

/// The pre-test of Map's kept points: maybe[i] = 1 when point i of `xyz` (m packed x y z
/// points) may lie in some band, else 0 (also for NaN points). Its margin, 1 mm plus 4e-7 of
/// the magnitudes of the coordinates and of d, is several times the rounding error of the
/// single-precision height, so a point whose exact height (double) is inside a band is never
/// given 0. 8 points at a time with AVX2 when `simd` and the CPU has it.
void bandPretest(const float* xyz, int m, const std::vector<BandF>& bands, std::uint8_t* maybe,
                 bool simd = true);

/// Key of the cube of side `cell` holding `p` (21 bits per axis, wraps beyond ±7 km at 3.5 mm).
/// Defined for every coordinate: cell indices beyond ±2^40 (and NaN) are clamped before the
/// conversion to an integer, which would otherwise be undefined (a loaded map's points are not
/// checked to be finite or near).
inline std::uint64_t cellKeyOf(const Eigen::Vector3f& p, double cell) {
  auto q = [&](float x) {
    constexpr double kLimit = 1099511627776.0;  // 2^40
    double c = std::floor(x / cell);
    if (!(c > -kLimit)) c = -kLimit;
    if (c > kLimit) c = kLimit;
    return static_cast<std::uint64_t>(static_cast<std::int64_t>(c) + (std::int64_t{1} << 20)) &
           0x1fffffu;
  };
  return q(p.x()) | (q(p.y()) << 21) | (q(p.z()) << 42);
}

/// Which of the map's kPointCellSets sets holds cell `key`: a high bit of its mixed brick key
/// (every cell of a brick in the same set; the sets' tables stay evenly used).
constexpr std::size_t kPointCellSets = 2;
inline std::size_t pointCellSet(std::uint64_t key) {
  return static_cast<std::size_t>(mixBlockKey(CellBitSet::brickOf(key)) >> 47) % kPointCellSets;
}

}  // namespace planesdf::detail
