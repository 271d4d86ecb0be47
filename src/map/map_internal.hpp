#pragma once
// Internal helpers shared by map.cpp and map_io.cpp.
#include <Eigen/Core>

#include <array>
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

/// A set of grid cells keyed as detail::cellKeyOf packs them (21 bits per axis): bricks of 8^3
/// cells in a hash map, each a 512-bit mask. Neighbouring cells share a brick, so a frame's
/// points look up a small table (and mostly the brick of the point before) instead of one large
/// table entry per cell.
class CellBitSet {
 public:
  /// Inserts cell `key`; true when the set did not hold it.
  bool insert(std::uint64_t key);
  /// Asks the cache for the table slot of the brick of cell `key`.
  void prefetch(std::uint64_t key) const { bricks_.prefetch(brickOf(key)); }
  /// Number of cells in the set.
  std::size_t size() const { return cells_; }
  /// The brick key of cell `key` (also what decides which of a map's sets holds it).
  static std::uint64_t brickOf(std::uint64_t key) {
    constexpr std::uint64_t m = (std::uint64_t{1} << 21) - 1;
    return ((key & m) >> 3) | (((key >> 21) & m) >> 3) << 21 | (((key >> 42) & m) >> 3) << 42;
  }

 private:
  detail::BlockHashMap bricks_;  ///< brick key -> index into masks_
  std::vector<std::array<std::uint64_t, 8>, LargeAllocator<std::array<std::uint64_t, 8>>> masks_;
  std::size_t cells_ = 0;
  std::uint64_t last_brick_ = detail::kEmptyBlockKey;  ///< the brick of the previous insert ...
  std::uint32_t last_mask_ = 0;                        ///< ... and its mask
};

/// Which of the map's kPointCellSets sets holds cell `key`: a high bit of its mixed brick key
/// (every cell of a brick in the same set; the sets' tables stay evenly used).
constexpr std::size_t kPointCellSets = 2;
inline std::size_t pointCellSet(std::uint64_t key) {
  return static_cast<std::size_t>(mixBlockKey(CellBitSet::brickOf(key)) >> 47) % kPointCellSets;
}

/// A map's point-cell sets (Map::point_cells_).
struct PointCellSets {
  std::array<CellBitSet, kPointCellSets> sets;
};

}  // namespace planesdf::detail
