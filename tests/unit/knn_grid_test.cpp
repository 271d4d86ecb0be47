// The hashed-grid k-nearest-neighbour search of the plane stage (src/plane/knn_grid.cpp): exact
// neighbours, and cells sized to the bulk of the cloud whatever its far outliers.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <random>
#include <utility>
#include <vector>

#include "plane/knn_grid.hpp"
#include "planesdf/plane.hpp"

namespace planesdf {
namespace {

using detail::KnnGrid;
using Neighbours = std::vector<std::pair<float, std::uint32_t>>;

/// `count` points on the tilted plane z = 0.3 x - 0.2 y + 1 over a 2 x 2 m square, 1 mm noise.
std::vector<Eigen::Vector3f> tiltedPlane(std::size_t count, std::mt19937& rng) {
  std::uniform_real_distribution<float> uni(-1.0f, 1.0f);
  std::normal_distribution<float> noise(0.0f, 0.001f);
  std::vector<Eigen::Vector3f> pts;
  for (std::size_t i = 0; i < count; ++i) {
    const float x = uni(rng), y = uni(rng);
    pts.emplace_back(x, y, 0.3f * x - 0.2f * y + 1.0f + noise(rng));
  }
  return pts;
}

std::vector<std::uint32_t> allIndices(std::size_t n) {
  std::vector<std::uint32_t> idx(n);
  std::iota(idx.begin(), idx.end(), 0u);
  return idx;
}

/// The k nearest of all points to points[query] by brute force, nearest first (as KnnGrid::knn
/// computes distances and orders them).
Neighbours bruteForce(const std::vector<Eigen::Vector3f>& points, std::uint32_t query, int k) {
  Neighbours all;
  for (std::uint32_t j = 0; j < points.size(); ++j)
    all.emplace_back((points[j] - points[query]).squaredNorm(), j);
  std::partial_sort(all.begin(), all.begin() + k, all.end());
  all.resize(static_cast<std::size_t>(k));
  return all;
}

TEST(KnnGrid, AFarOutlierNeitherInflatesTheCellsNorChangesTheNeighbours) {
  // 20,000 points on a plane, then the same with one point at (1e6, 1e6, 1e6). Cells sized from
  // the whole extent would be metres wide (every cell search then scans the whole plane): the
  // cell stays within 25 % of the one without the outlier, and the neighbours stay exact.
  constexpr int k = 20;
  std::mt19937 rng(27);
  const std::vector<Eigen::Vector3f> plane = tiltedPlane(20000, rng);
  std::vector<Eigen::Vector3f> points = plane;
  points.emplace_back(1e6f, 1e6f, 1e6f);
  const auto outlier = static_cast<std::uint32_t>(plane.size());

  const double cell_plane = KnnGrid::suggestCell(plane, allIndices(plane.size()), k);
  const double cell = KnnGrid::suggestCell(points, allIndices(points.size()), k);
  // About 1.3 times the k-th neighbour distance, sqrt(k / (pi * density)) = 3.7 cm for 20,000
  // points on 4.25 m^2: 4.8 cm.
  EXPECT_GT(cell_plane, 0.035);
  EXPECT_LT(cell_plane, 0.065);
  EXPECT_GT(cell, cell_plane / 1.25);
  EXPECT_LT(cell, cell_plane * 1.25);

  const KnnGrid grid(points, allIndices(points.size()), cell);
  Neighbours nb;
  std::vector<std::uint32_t> scratch;
  int checked = 0;
  for (std::size_t c = 0; c < grid.cellCount(); ++c) {
    for (const std::uint32_t* it = grid.cellBegin(c); it != grid.cellEnd(c); ++it) {
      if (*it == outlier) {
        // Nothing within 4 cells: the search stops there with the point itself.
        grid.knn(*it, c, k, 4, nb, scratch);
        ASSERT_EQ(nb.size(), 1u);
        EXPECT_EQ(nb[0].second, outlier);
        continue;
      }
      if (*it % 7 != 0) continue;  // every 7th point against brute force
      grid.knn(*it, c, k, 4, nb, scratch);
      ASSERT_EQ(nb, bruteForce(points, *it, k)) << "point " << *it;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 2858);  // indices 0, 7, ..., 19999

  // PCA normals of the plane's points: the same with the outlier as without (the outlier itself,
  // with no neighbour near, gets none).
  PointCloud with, without;
  with.points = points;
  with.width = static_cast<std::uint32_t>(points.size());
  without.points = plane;
  without.width = static_cast<std::uint32_t>(plane.size());
  Config cfg;
  cfg.normal_knn = k;
  const std::vector<Eigen::Vector3f> n_with = estimateNormals(with, cfg);
  const std::vector<Eigen::Vector3f> n_without = estimateNormals(without, cfg);
  ASSERT_EQ(n_with.size(), points.size());
  for (std::size_t i = 0; i < plane.size(); ++i)
    ASSERT_GT(std::abs(n_with[i].dot(n_without[i])), 1.0f - 1e-5f) << "point " << i;
  EXPECT_FALSE(n_with[outlier].allFinite());
}

}  // namespace
}  // namespace planesdf
