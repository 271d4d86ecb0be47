#pragma once
// Internal helpers shared by map.cpp and map_io.cpp.
#include <Eigen/Core>

#include <cmath>
#include <cstddef>
#include <cstdint>

#include "planesdf/map.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf::detail {

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
