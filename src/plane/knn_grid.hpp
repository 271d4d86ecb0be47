#pragma once
// k-nearest-neighbour search on a hashed voxel grid (internal to the plane stage).

#include <Eigen/Core>

#include <cstdint>
#include <utility>
#include <vector>

namespace planesdf::detail {

/// Buckets points into cubic cells (sorted by cell key, cells found through an open-addressing
/// hash table) and answers exact k-nearest-neighbour queries by searching growing shells of cells.
class KnnGrid {
 public:
  /// Indexes points[indices]; `cell` > 0 (m).
  KnnGrid(const std::vector<Eigen::Vector3f>& points, const std::vector<std::uint32_t>& indices,
          double cell);

  /// A cell size about 1.3 times the median k-th neighbour distance (estimated from the cell
  /// occupancy, then calibrated on exact k-NN queries of ~256 points). The first estimate comes
  /// from the extent of the bulk of the points (per-axis percentiles), so far outliers do not
  /// inflate the cells.
  static double suggestCell(const std::vector<Eigen::Vector3f>& points,
                            const std::vector<std::uint32_t>& indices, int k);

  double cell() const { return cell_; }
  std::size_t cellCount() const { return cells_.size(); }

  /// Calls visit(cell_index, begin, end) style access: the point indices of cell `c`.
  const std::uint32_t* cellBegin(std::size_t c) const { return order_.data() + cells_[c].begin; }
  const std::uint32_t* cellEnd(std::size_t c) const { return order_.data() + cells_[c].end; }

  /// Point indices of the cells within `radius` cells (Chebyshev) of cell `c`, appended to `out`.
  void gatherAround(std::size_t c, int radius, std::vector<std::uint32_t>& out) const;

  /// The k nearest indexed points of points[query] (including itself), nearest first, written to
  /// `out` as (squared distance, index). Fewer when the grid holds fewer than k points within
  /// `max_radius` cells.
  void knn(std::uint32_t query, std::size_t c, int k, int max_radius,
           std::vector<std::pair<float, std::uint32_t>>& out,
           std::vector<std::uint32_t>& scratch) const;

  /// Selects the k nearest of the `candidates` within squared distance `bound2` of points[query]
  /// into `out` (unsorted). Returns the squared distance of the k-th, or +inf when fewer than k
  /// are within the bound (then `out` holds those that are).
  float selectNearest(std::uint32_t query, const std::vector<std::uint32_t>& candidates, int k,
                      float bound2, std::vector<std::pair<float, std::uint32_t>>& out) const;

 private:
  struct CellRange {
    std::uint64_t key;
    std::uint32_t begin;
    std::uint32_t end;
    Eigen::Vector3i coord;
  };

  Eigen::Vector3i coordOf(const Eigen::Vector3f& p) const;
  static std::uint64_t keyOf(const Eigen::Vector3i& c);
  /// Index into cells_, or -1.
  long long find(std::uint64_t key) const;

  const std::vector<Eigen::Vector3f>& points_;
  double cell_;
  std::vector<std::uint32_t> order_;  // point indices sorted by cell
  std::vector<CellRange> cells_;
  std::vector<std::uint32_t> table_;  // open addressing: cell index + 1, 0 = empty
  std::uint64_t mask_ = 0;
};

}  // namespace planesdf::detail
