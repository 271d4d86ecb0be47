#pragma once
// Internal to the simulator: a whole-scene reconstruction as a mapper exports it (Open3D,
// voxblox, KinectFusion): depth frames fused into a sparse projective TSDF, its surface
// extracted as points at the zero crossings of voxel edges (Open3D's extract_point_cloud) and as
// a marching-cubes mesh whose vertices are those points.

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "key_index.hpp"
#include "planesdf/types.hpp"

namespace planesdf::sim::detail {

/// The surface of a TSDF: one point per voxel edge whose two ends are observed (weight >= the
/// minimum) and differ in sign, and the marching-cubes triangles over the cubes whose eight
/// corners are observed. Every triangle corner is one of `points` (the mesh is welded), the
/// triangles wind counter-clockwise seen from the free side (positive SDF).
struct TsdfSurface {
  std::vector<Eigen::Vector3d> points;
  std::vector<Triangle> triangles;
};

/// A sparse projective TSDF: blocks of 8^3 voxels in a hash map, allocated around each valid
/// pixel's point within the truncation. Voxel (i, j, k) is centred on ((i, j, k) + 0.5) * voxel,
/// so a plane through round coordinates (the floor z = 0) lies halfway between voxel centres.
/// The SDF is the projective distance (measured depth - the voxel's depth along the optical axis)
/// truncated to +truncation in front; voxels more than `truncation` behind the surface are left
/// alone. Each observation has weight 1 (a running mean).
class SparseTsdf {
 public:
  static constexpr int kBlockSide = 8;
  static constexpr int kBlockVoxels = kBlockSide * kBlockSide * kBlockSide;

  /// 8^3 voxels, x fastest: the mean SDF (m) and the number of observations.
  struct Block {
    std::array<float, kBlockVoxels> sdf{};
    std::array<std::uint16_t, kBlockVoxels> weight{};
  };
  /// A block and its +x / +y / +z neighbours (2 x 2 x 2 blocks, index dx + 2 dy + 4 dz): block
  /// indices (KeyIndex::kNone where none is allocated) and the blocks (nullptr there).
  struct Neighbourhood {
    std::array<std::uint32_t, 8> ids{};
    std::array<const Block*, 8> blocks{};
  };

  /// `voxel` and `truncation` in metres; pixels deeper than `max_depth` are ignored.
  SparseTsdf(double voxel, double truncation, double max_depth);

  /// Fuses one frame seen from `camera_to_world`: allocates the blocks within the truncation of
  /// its points, then updates each of those blocks' voxels (in parallel over blocks on `threads`
  /// threads; the result does not depend on the thread count).
  void integrate(const DepthFrame& frame, const Pose& camera_to_world, int threads);

  /// The surface of the voxels observed at least `min_weight` times, blocks in key order.
  TsdfSurface extractSurface(int min_weight, int threads) const;

  std::size_t blockCount() const { return blocks_.size(); }
  /// Bytes held by the blocks and the hash map.
  std::size_t bytes() const;

 private:
  struct BlockSurface;

  std::vector<std::uint64_t> touchedBlocks(const DepthFrame& frame, const Pose& camera_to_world,
                                           int threads) const;
  void updateBlock(Block& block, std::uint64_t key, const DepthFrame& frame,
                   const Pose& world_to_camera) const;
  std::vector<std::uint32_t> blocksInKeyOrder() const;
  Neighbourhood neighbourhood(std::uint32_t b) const;
  BlockSurface blockPoints(std::uint32_t b, int min_weight) const;
  std::vector<Triangle> blockTriangles(std::uint32_t b, int min_weight,
                                       const std::vector<BlockSurface>& surfaces) const;

  double voxel_;
  double truncation_;
  double max_depth_;
  KeyIndex index_;
  std::vector<std::uint64_t> keys_;  ///< block keys, by block index
  std::vector<std::unique_ptr<Block>> blocks_;
};

}  // namespace planesdf::sim::detail
