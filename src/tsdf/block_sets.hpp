#pragma once
// The per-frame block sets of the allocation pass: the frustum's block grid and the per-thread
// collection of the blocks crossed by truncation segments (header-only, for the row kernels).

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <utility>
#include <vector>

#include "fusion_internal.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf::fusion_detail {

/// Small ring of recently seen block keys: neighbouring pixels' segments cross the same blocks.
class RecentKeys {
 public:
  RecentKeys() { keys_.fill(detail::kEmptyBlockKey); }
  /// True when `key` was seen among the last 8; else remembers it.
  bool seen(std::uint64_t key) {
    for (const std::uint64_t k : keys_)
      if (k == key) return true;
    keys_[next_] = key;
    next_ = (next_ + 1) & 7;
    return false;
  }

 private:
  std::array<std::uint64_t, 8> keys_;
  int next_ = 0;
};

/// A dense grid of the block cells around the frame's frustum (per frame, per volume): 1 where a
/// block is allocated or was collected for allocation by any thread, else 0. Lookups that would
/// hash a block key become one byte read, with relaxed atomic builtins: threads may both see 0 and
/// both collect a block (their key lists are merged without duplicates).
class BlockGrid {
 public:
  /// Covers the blocks of [lo, hi] that have keys (blockIndexInRange) when they are at most
  /// kMaxCells; else empty() (callers fall back to the volume's hash map).
  void reset(const TsdfVolume& vol, Eigen::Vector3i lo, Eigen::Vector3i hi) {
    size_ = 0;
    lo = lo.cwiseMax(Eigen::Vector3i::Constant(-detail::kBlockKeyOffset));
    hi = hi.cwiseMin(Eigen::Vector3i::Constant(detail::kBlockKeyOffset - 1));
    if ((lo.array() > hi.array()).any()) return;
    const Eigen::Vector3i dims = hi - lo + Eigen::Vector3i::Ones();
    const double cells = dims.cast<double>().prod();
    if (cells > static_cast<double>(kMaxCells)) return;
    lo_ = lo;
    dims_ = dims;
    size_ = static_cast<std::size_t>(cells);
    if (capacity_ < size_) {
      cells_.reset(new std::uint8_t[size_]);
      capacity_ = size_;
    }
    std::memset(cells_.get(), 0, size_);  // before any thread reads the grid
    if (cells <= static_cast<double>(vol.numBlocks())) {
      for (int z = lo.z(); z <= hi.z(); ++z)
        for (int y = lo.y(); y <= hi.y(); ++y)
          for (int x = lo.x(); x <= hi.x(); ++x) {
            const Eigen::Vector3i b(x, y, z);
            if (vol.blockSlot(b) >= 0) cells_[index(b)] = 1;
          }
    } else {
      for (std::size_t sl = 0; sl < vol.numBlocks(); ++sl) {
        const std::ptrdiff_t i = find(vol.blockIndex(sl));
        if (i >= 0) cells_[i] = 1;
      }
    }
  }
  void clear() { size_ = 0; }
  bool empty() const { return size_ == 0; }
  /// The cell of block b, or -1 outside the grid.
  std::ptrdiff_t find(const Eigen::Vector3i& b) const {
    if (size_ == 0) return -1;
    const Eigen::Vector3i r = b - lo_;
    if (static_cast<unsigned>(r.x()) >= static_cast<unsigned>(dims_.x()) ||
        static_cast<unsigned>(r.y()) >= static_cast<unsigned>(dims_.y()) ||
        static_cast<unsigned>(r.z()) >= static_cast<unsigned>(dims_.z()))
      return -1;
    return index(b);
  }
  bool known(std::ptrdiff_t i) const { return __atomic_load_n(&cells_[i], __ATOMIC_RELAXED) != 0; }
  void mark(std::ptrdiff_t i) { __atomic_store_n(&cells_[i], std::uint8_t{1}, __ATOMIC_RELAXED); }

 private:
  static constexpr std::size_t kMaxCells = std::size_t{1} << 22;
  std::ptrdiff_t index(const Eigen::Vector3i& b) const {
    const Eigen::Vector3i r = b - lo_;
    return (static_cast<std::ptrdiff_t>(r.z()) * dims_.y() + r.y()) * dims_.x() + r.x();
  }
  Eigen::Vector3i lo_ = Eigen::Vector3i::Zero(), dims_ = Eigen::Vector3i::Zero();
  std::size_t size_ = 0, capacity_ = 0;
  /// Accessed with relaxed atomic builtins while threads share the grid (plain writes in
  /// reset, before they do).
  std::unique_ptr<std::uint8_t[]> cells_;
};

/// Collects, per thread, the keys of blocks that are not in the volume yet (looked up in the
/// frame's block grid where it covers them, else in the volume and a per-thread set).
class NewBlockCollector {
 public:
  NewBlockCollector(const TsdfVolume& vol, BlockGrid& grid) : vol_(vol), grid_(grid) {}
  void add(const Eigen::Vector3i& b) {
    const std::ptrdiff_t i = grid_.find(b);
    if (i >= 0) {
      if (grid_.known(i)) return;
      grid_.mark(i);
      keys_.push_back(detail::packBlockKey(b));
      return;
    }
    if (!blockIndexInRange(b)) return;
    const std::uint64_t key = detail::packBlockKey(b);
    if (recent_.seen(key) || vol_.blockSlot(b) >= 0) return;
    if (set_.insert(key, 0).second) keys_.push_back(key);
  }
  const std::vector<std::uint64_t>& keys() const { return keys_; }
  /// True when every block of the box [lo, hi] is allocated or collected (by this thread, or by
  /// any thread within the grid).
  bool allKnown(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi) const {
    for (int z = lo.z(); z <= hi.z(); ++z)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int x = lo.x(); x <= hi.x(); ++x) {
          const Eigen::Vector3i b(x, y, z);
          const std::ptrdiff_t i = grid_.find(b);
          if (i >= 0) {
            if (!grid_.known(i)) return false;
            continue;
          }
          if (!blockIndexInRange(b)) return false;
          if (vol_.blockSlot(b) < 0 &&
              set_.find(detail::packBlockKey(b)) == detail::BlockHashMap::kNotFound)
            return false;
        }
    return true;
  }

 private:
  const TsdfVolume& vol_;
  BlockGrid& grid_;
  RecentKeys recent_;
  detail::BlockHashMap set_;
  std::vector<std::uint64_t> keys_;
};

/// Calls f(block index) for each block crossed by the segment A-B, given in block units, whose
/// ends lie in blocks `start` and `end` (3D DDA). Visits exactly |dx|+|dy|+|dz|+1 blocks.
template <class F>
void visitBlocksOnSegment(const Eigen::Vector3f& A, const Eigen::Vector3f& B,
                          const Eigen::Vector3i& start, const Eigen::Vector3i& end, F&& f) {
  Eigen::Vector3i cur = start;
  f(cur);
  int remaining = (end - cur).cwiseAbs().sum();
  if (remaining == 0) return;
  if (remaining == 1) {
    f(end);
    return;
  }
  const Eigen::Vector3f D = B - A;
  float t_max[3], t_delta[3];
  int step[3];
  for (int i = 0; i < 3; ++i) {
    step[i] = end[i] > cur[i] ? 1 : (end[i] < cur[i] ? -1 : 0);
    if (step[i] == 0) {
      t_max[i] = t_delta[i] = kInf;
      continue;
    }
    const float boundary = static_cast<float>(cur[i] + (step[i] > 0 ? 1 : 0));
    t_max[i] = (boundary - A[i]) / D[i];
    t_delta[i] = static_cast<float>(step[i]) / D[i];
  }
  while (remaining-- > 0) {
    int axis = -1;
    float best = kInf;
    for (int i = 0; i < 3; ++i)
      if (cur[i] != end[i] && (axis < 0 || t_max[i] < best)) {
        best = t_max[i];
        axis = i;
      }
    cur[axis] += step[axis];
    t_max[axis] += t_delta[axis];
    f(cur);
  }
}

inline Eigen::Vector3i floorVec(const Eigen::Vector3f& p) {
  return Eigen::Vector3i(floorToInt(p.x()), floorToInt(p.y()), floorToInt(p.z()));
}

/// Per-thread collection of the blocks crossed by truncation segments. Pixels mostly give
/// segments between a few recurring pairs of blocks a and b; once every block of the box spanned
/// by a and b is known (allocated or collected), no path between them can add anything, so such
/// segments are skipped without walking them (exact, not an approximation). Known pairs are
/// remembered in a direct-mapped cache; a box found to hold an unknown block is not checked
/// again while the same (a, b) repeats.
class SegmentBlocks {
 public:
  SegmentBlocks(const TsdfVolume& vol, BlockGrid& grid) : collector_(vol, grid) {
    done_.fill({Eigen::Vector3i::Zero(), Eigen::Vector3i::Constant(-1)});  // never matches
  }
  /// The segment A-B in block units.
  void add(const Eigen::Vector3f& A, const Eigen::Vector3f& B) {
    const Eigen::Vector3i a = floorVec(A), b = floorVec(B);
    auto& slot = done_[slotOf(a, b)];
    if (slot.first == a && slot.second == b) return;
    visitBlocksOnSegment(A, B, a, b, [&](const Eigen::Vector3i& blk) { collector_.add(blk); });
    if (a == failed_.first && b == failed_.second) return;
    if (collector_.allKnown(a.cwiseMin(b), a.cwiseMax(b)))
      slot = {a, b};
    else
      failed_ = {a, b};
  }
  /// True when every block of the box [lo, hi] is known to be allocated or collected: it lies
  /// in the last box found so, or a lookup finds it so (it then becomes that box). Segments
  /// within such a box cannot add a block. A box that failed noteBox is not looked up again.
  bool boxKnown(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi) {
    if ((lo.array() >= known_box_.first.array()).all() &&
        (hi.array() <= known_box_.second.array()).all())
      return true;
    if ((lo == failed_box_.first && hi == failed_box_.second) || !collector_.allKnown(lo, hi))
      return false;
    known_box_ = {lo, hi};
    return true;
  }
  /// Checks the box [lo, hi] again after its segments were added (they may have collected its
  /// unknown blocks) and remembers it as known, or as failed so that it is not looked up again
  /// while it repeats.
  void noteBox(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi) {
    if (lo == failed_box_.first && hi == failed_box_.second) return;
    if (collector_.allKnown(lo, hi))
      known_box_ = {lo, hi};
    else
      failed_box_ = {lo, hi};
  }
  const std::vector<std::uint64_t>& newKeys() const { return collector_.keys(); }

 private:
  static constexpr std::size_t kDoneSlots = 1024;
  static std::size_t slotOf(const Eigen::Vector3i& a, const Eigen::Vector3i& b) {
    const auto u = [](int v) { return static_cast<std::uint32_t>(v); };
    std::uint32_t h = u(a.x()) * 73856093u ^ u(a.y()) * 19349663u ^ u(a.z()) * 83492791u;
    h ^= (u(b.x() - a.x()) + 2u) * 3u + (u(b.y() - a.y()) + 2u) * 15u +
         (u(b.z() - a.z()) + 2u) * 75u;
    h ^= h >> 13;
    return (h * 0x9E3779B1u >> 22) & (kDoneSlots - 1);
  }
  NewBlockCollector collector_;
  std::array<std::pair<Eigen::Vector3i, Eigen::Vector3i>, kDoneSlots> done_;
  std::pair<Eigen::Vector3i, Eigen::Vector3i> failed_{Eigen::Vector3i::Zero(),
                                                      Eigen::Vector3i::Constant(-1)};
  std::pair<Eigen::Vector3i, Eigen::Vector3i> known_box_{Eigen::Vector3i::Zero(),
                                                         Eigen::Vector3i::Constant(-1)};
  std::pair<Eigen::Vector3i, Eigen::Vector3i> failed_box_{Eigen::Vector3i::Zero(),
                                                          Eigen::Vector3i::Constant(-1)};
};

}  // namespace planesdf::fusion_detail
