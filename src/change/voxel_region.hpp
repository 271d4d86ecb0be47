#pragma once
// The voxels a plane pair's blob is validated on: its columns' voxels, the region completed with
// the free space its height map knows, the boxes, and how many measurements a surface rests on
// (see comparePlanePair).

#include <Eigen/Core>

#include <cstdint>
#include <utility>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/tsdf.hpp"
#include "planesdf/types.hpp"

namespace planesdf::detail {

/// How many measurements a surface rests on: the mean TSDF weight of the voxels at the height
/// map's surface (the largest of the three around it per column), over `cells` above the
/// object threshold (`blob`) and over the other observed cells of their box grown by `ring`
/// (`around`). A splat adds one to each voxel it reaches, so the weight counts the points within
/// a splat radius (design.md, "Thin support"). Both 0 when either set of cells is empty.
struct SurfaceSupport {
  double blob = 0.0, around = 0.0;
};

SurfaceSupport surfaceSupport(const TsdfVolume& vol, const HeightMap& hm, const Config& cfg,
                              const std::vector<Eigen::Vector2i>& cells, int ring);

/// Observed voxels of column (i, j) with centre height in [lo, hi].
void columnVoxels(const TsdfVolume& vol, int i, int j, double lo, double hi, float w_min,
                  std::vector<Eigen::Vector3i>& out);

/// The voxels of `vol` in [lo, hi] (global indices) as a new volume, where an unobserved voxel
/// above the surface of an observed height-map column gets its vertical distance to that surface
/// (capped at the truncation) with weight w_min: fusion allocates blocks only around surfaces and
/// a single view leaves voxels near silhouettes unobserved, but the height map knows the space
/// above an observed surface is empty (its 2.5D premise), and the 3D validation needs that free
/// space to tell "gone" from "unobserved".
/// Only the columns (i, j) of the box flagged in `need` (row-major over the box's x-y extent)
/// are filled: the validation reads the voxels near the blob only, and a thin blob's box can
/// span metres.
TsdfVolume completedRegion(const TsdfVolume& vol, const HeightMap& hm, const Eigen::Vector3i& lo,
                           const Eigen::Vector3i& hi, const std::vector<std::uint8_t>& need,
                           float w_min);

/// Flags the columns of the box [lo, hi] (row-major over its x-y extent) within `margin`
/// (Chebyshev) of one of `columns`.
std::vector<std::uint8_t> columnsNear(std::vector<Eigen::Vector2i> columns,
                                      const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                                      int margin);

/// Voxel bounding box of `voxels` grown by `margin`.
std::pair<Eigen::Vector3i, Eigen::Vector3i> voxelBox(const std::vector<Eigen::Vector3i>& voxels,
                                                     int margin);

/// The target voxel box covering the source box [lo, hi] mapped by T, grown by `margin`.
std::pair<Eigen::Vector3i, Eigen::Vector3i> mappedBox(const Eigen::Vector3i& lo,
                                                      const Eigen::Vector3i& hi, const Pose& T,
                                                      double vs, int margin);

}  // namespace planesdf::detail
