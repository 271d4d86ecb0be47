// Point-distance differencing baseline (issue 5, Table I): voxel downsampling, neighbour tests on
// a hashed grid, Euclidean clustering, and outputs in the `planesdf detect` format.

#include "planesdf/baseline.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <numeric>
#include <system_error>
#include <unordered_map>

#include "planesdf/error.hpp"
#include "planesdf/eval.hpp"
#include "planesdf/io/ply.hpp"

namespace planesdf {
namespace {

// 21 bits per axis (cells offset by 2^20 so negative coordinates pack too).
constexpr std::int64_t kBias = std::int64_t{1} << 20;

std::uint64_t packCell(const Eigen::Vector3i& c) {
  const auto u = [](int v) {
    return static_cast<std::uint64_t>(std::clamp<std::int64_t>(v + kBias, 0, 2 * kBias - 1));
  };
  return u(c.x()) | (u(c.y()) << 21) | (u(c.z()) << 42);
}

Eigen::Vector3i cellOf(const Eigen::Vector3f& p, double inv) {
  return Eigen::Vector3i(static_cast<int>(std::floor(p.x() * inv)),
                         static_cast<int>(std::floor(p.y() * inv)),
                         static_cast<int>(std::floor(p.z() * inv)));
}

// Points bucketed into cubic cells of edge `cell` (>= the query radius, so 27 cells suffice).
class HashGrid {
 public:
  HashGrid(const std::vector<Eigen::Vector3f>& points, double cell)
      : points_(points), inv_(1.0 / cell) {
    cells_.reserve(points.size());
    for (std::uint32_t i = 0; i < points.size(); ++i)
      if (points[i].allFinite()) cells_[packCell(cellOf(points[i], inv_))].push_back(i);
  }

  template <class F>
  void forEachNear(const Eigen::Vector3f& p, F&& visit) const {
    const Eigen::Vector3i c = cellOf(p, inv_);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const auto it = cells_.find(packCell(c + Eigen::Vector3i(dx, dy, dz)));
          if (it == cells_.end()) continue;
          for (std::uint32_t j : it->second)
            if (!visit(j)) return;
        }
  }

  const std::vector<Eigen::Vector3f>& points() const { return points_; }

 private:
  const std::vector<Eigen::Vector3f>& points_;
  double inv_;
  std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> cells_;
};

int findRoot(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

void checkParams(const BaselineParams& p) {
  const auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (!positive(p.voxel)) throw Error("baseline", "voxel must be positive and finite");
  if (!positive(p.distance)) throw Error("baseline", "distance must be positive and finite");
  if (!positive(p.cluster_distance))
    throw Error("baseline", "cluster_distance must be positive and finite");
  if (p.min_cluster_cells < 1) throw Error("baseline", "min_cluster_cells must be at least 1");
}

}  // namespace

DownsampledCloud voxelDownsample(const std::vector<Eigen::Vector3f>& points, double voxel) {
  if (!(std::isfinite(voxel) && voxel > 0.0))
    throw Error("baseline", "voxel must be positive and finite");
  const double inv = 1.0 / voxel;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;
  keyed.reserve(points.size());
  for (std::uint32_t i = 0; i < points.size(); ++i)
    if (points[i].allFinite()) keyed.emplace_back(packCell(cellOf(points[i], inv)), i);
  std::sort(keyed.begin(), keyed.end());
  DownsampledCloud out;
  for (std::size_t a = 0; a < keyed.size();) {
    std::size_t b = a;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    std::vector<std::uint32_t> members;
    while (b < keyed.size() && keyed[b].first == keyed[a].first) {
      sum += points[keyed[b].second].cast<double>();
      members.push_back(keyed[b].second);
      ++b;
    }
    out.centroids.push_back((sum / static_cast<double>(b - a)).cast<float>());
    out.members.push_back(std::move(members));
    a = b;
  }
  return out;
}

std::vector<bool> hasNeighbourWithin(const std::vector<Eigen::Vector3f>& query,
                                     const std::vector<Eigen::Vector3f>& other, double distance) {
  std::vector<bool> found(query.size(), false);
  if (other.empty()) return found;
  const HashGrid grid(other, distance);
  const float d2 = static_cast<float>(distance * distance);
  for (std::size_t i = 0; i < query.size(); ++i) {
    if (!query[i].allFinite()) continue;
    bool hit = false;
    grid.forEachNear(query[i], [&](std::uint32_t j) {
      hit = (other[j] - query[i]).squaredNorm() <= d2;
      return !hit;
    });
    found[i] = hit;
  }
  return found;
}

std::vector<int> euclideanClusters(const std::vector<Eigen::Vector3f>& points, double distance,
                                   int min_points) {
  const int n = static_cast<int>(points.size());
  std::vector<int> parent(static_cast<std::size_t>(n));
  std::iota(parent.begin(), parent.end(), 0);
  const HashGrid grid(points, distance);
  const float d2 = static_cast<float>(distance * distance);
  for (int i = 0; i < n; ++i) {
    if (!points[i].allFinite()) continue;
    grid.forEachNear(points[i], [&](std::uint32_t j) {
      if (static_cast<int>(j) > i && (points[j] - points[i]).squaredNorm() <= d2) {
        const int a = findRoot(parent, i), b = findRoot(parent, static_cast<int>(j));
        if (a != b) parent[std::max(a, b)] = std::min(a, b);
      }
      return true;
    });
  }
  std::vector<int> size(static_cast<std::size_t>(n), 0);
  for (int i = 0; i < n; ++i)
    if (points[i].allFinite()) ++size[findRoot(parent, i)];
  std::vector<int> label(static_cast<std::size_t>(n), -1), number(static_cast<std::size_t>(n), -1);
  int next = 0;
  for (int i = 0; i < n; ++i) {
    if (!points[i].allFinite()) continue;
    const int r = findRoot(parent, i);
    if (size[r] < min_points) continue;
    if (number[r] < 0) number[r] = next++;
    label[i] = number[r];
  }
  return label;
}

int clusterChanges(const std::vector<Eigen::Vector3f>& source, const DownsampledCloud& cloud,
                   const std::vector<bool>& flagged, const BaselineParams& params, int first_id,
                   const std::array<std::uint8_t, 3>& color, PointCloud& out) {
  std::vector<Eigen::Vector3f> pts;
  std::vector<std::size_t> cell_of;
  for (std::size_t c = 0; c < cloud.centroids.size(); ++c)
    if (flagged[c]) {
      pts.push_back(cloud.centroids[c]);
      cell_of.push_back(c);
    }
  const std::vector<int> label =
      euclideanClusters(pts, params.cluster_distance, params.min_cluster_cells);
  ScalarField* ids = out.field(kChangeIdField);
  if (ids == nullptr) {
    out.fields.push_back({kChangeIdField, ScalarType::Int32, {}});
    ids = &out.fields.back();
  }
  int clusters = 0;
  for (std::size_t k = 0; k < pts.size(); ++k) {
    if (label[k] < 0) continue;
    clusters = std::max(clusters, label[k] + 1);
    for (std::uint32_t i : cloud.members[cell_of[k]]) {
      out.points.push_back(source[i]);
      out.colors.push_back(color);
      ids->values.push_back(first_id + label[k]);
    }
  }
  out.width = static_cast<std::uint32_t>(out.points.size());
  out.height = 1;
  return clusters;
}

BaselineResult pointDistanceBaseline(const PointCloud& reference, const PointCloud& current,
                                     const BaselineParams& params) {
  checkParams(params);
  const auto t0 = std::chrono::steady_clock::now();
  const DownsampledCloud ref = voxelDownsample(reference.points, params.voxel);
  const DownsampledCloud cur = voxelDownsample(current.points, params.voxel);
  std::vector<bool> gone = hasNeighbourWithin(ref.centroids, cur.centroids, params.distance);
  std::vector<bool> fresh = hasNeighbourWithin(cur.centroids, ref.centroids, params.distance);
  gone.flip();
  fresh.flip();
  BaselineResult r;
  r.removed_clusters =
      clusterChanges(reference.points, ref, gone, params, 1, {40, 90, 230}, r.removed);
  r.added_clusters = clusterChanges(current.points, cur, fresh, params, 1 + r.removed_clusters,
                                    {230, 40, 40}, r.added);
  r.milliseconds =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

void writeBaselineOutputs(const std::string& dir, const BaselineResult& result) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw Error(dir, "cannot create the output folder: " + ec.message());
  const auto withField = [](PointCloud c) {
    if (c.field(kChangeIdField) == nullptr)
      c.fields.push_back({kChangeIdField, ScalarType::Int32, {}});
    c.width = static_cast<std::uint32_t>(c.size());
    c.height = 1;
    return c;
  };
  io::writePly(dir + "/removed_points.ply", withField(result.removed));
  io::writePly(dir + "/added_points.ply", withField(result.added));
}

}  // namespace planesdf
