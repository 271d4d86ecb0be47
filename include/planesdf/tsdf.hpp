#pragma once
/// \file tsdf.hpp
/// The block-sparse TSDF volume of one PlaneSDF and its fusion (design.md, "Pipeline").
///
/// A volume lives in its plane's LOCAL frame: x = u and y = v span the plane, z = h is the height
/// above the plane along its normal (positive on the free side). Voxels are cubes of side
/// `voxelSize()`; the voxel with global integer index (i, j, k) covers
/// [i, i+1) x [j, j+1) x [k, k+1) voxels and has its centre at ((i, j, k) + 0.5) * voxelSize().
/// Voxels are grouped in blocks of 8^3, allocated on demand and kept in a hash map keyed by the
/// integer block index (block = floor(voxel / 8)).
///
/// SDF values are in metres, clamped to [-truncation, +truncation], positive in free space.
/// A voxel is *observed* when its weight is > 0.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/detail/tsdf_blocks.hpp"
#include "planesdf/memory.hpp"
#include "planesdf/types.hpp"

namespace planesdf {

/// One TSDF voxel: signed distance (m) and accumulated weight (0 = never observed).
struct TsdfVoxel {
  float sdf = 0.0f;
  float weight = 0.0f;
};
static_assert(sizeof(TsdfVoxel) == 8, "TsdfVoxel must stay 8 bytes");

/// Voxels per block side, per block, and the block side as a shift.
constexpr int kTsdfBlockSide = 8;
constexpr int kTsdfBlockShift = 3;
constexpr int kTsdfBlockVoxels = kTsdfBlockSide * kTsdfBlockSide * kTsdfBlockSide;

/// A block of 8^3 voxels, stored x fastest: voxels[x + 8 * (y + 8 * z)].
struct TsdfBlock {
  std::array<TsdfVoxel, kTsdfBlockVoxels> voxels{};
  Eigen::Vector3i index = Eigen::Vector3i::Zero();  ///< integer block index
  std::uint64_t revision = 0;  ///< the volume revision at which a voxel last changed

  /// Global voxel index of the voxel stored at `linear` (0..511).
  Eigen::Vector3i voxelIndex(int linear) const {
    return index * kTsdfBlockSide +
           Eigen::Vector3i(linear & 7, (linear >> kTsdfBlockShift) & 7, linear >> 6);
  }
};

/// True when every coordinate of `b` is in [-2^20, 2^20) (about ±58 km at 7 mm voxels).
inline bool blockIndexInRange(const Eigen::Vector3i& b) {
  const auto ok = [](int c) {
    return c >= -detail::kBlockKeyOffset && c < detail::kBlockKeyOffset;
  };
  return ok(b.x()) && ok(b.y()) && ok(b.z());
}

/// A sample of the TSDF at a continuous point.
struct TsdfSample {
  float sdf = 0.0f;           ///< m
  float weight = 0.0f;        ///< interpolated weight (trilinear case) or the voxel's weight
  bool interpolated = false;  ///< true: trilinear over 8 voxels; false: nearest voxel
};

/// A block-sparse TSDF volume in a plane's local frame. Deep-copyable and movable. Not
/// thread-safe for concurrent modification; concurrent const access is safe.
class TsdfVolume {
 public:
  /// Throws planesdf::Error unless voxel_size and truncation are positive and finite.
  TsdfVolume(double voxel_size, double truncation);
  /// Voxel size and truncation from `cfg` (cfg.voxel_size, cfg.truncation()).
  explicit TsdfVolume(const Config& cfg);
  TsdfVolume(const TsdfVolume& other);
  TsdfVolume& operator=(const TsdfVolume& other);
  TsdfVolume(TsdfVolume&&) noexcept = default;
  TsdfVolume& operator=(TsdfVolume&&) noexcept = default;
  ~TsdfVolume() = default;

  double voxelSize() const { return voxel_size_; }
  double truncation() const { return truncation_; }
  /// Side of a block in metres (8 voxels).
  double blockSize() const { return voxel_size_ * kTsdfBlockSide; }

  // --- blocks ---------------------------------------------------------------------------------
  /// Number of allocated blocks.
  std::size_t numBlocks() const { return blocks_.size(); }
  /// Number of allocated voxels (numBlocks() * 512).
  std::size_t numVoxels() const { return blocks_.size() * kTsdfBlockVoxels; }
  /// Number of voxels with weight > 0 (scans the volume).
  std::size_t numObservedVoxels() const;
  /// Everything the volume holds on the heap and in itself: voxels, block metadata, the block
  /// pointer array, the hash table and an allowance for the allocator's per-block header.
  std::size_t memoryBytes() const;

  /// The block at `b`, or nullptr when it is not allocated.
  const TsdfBlock* findBlock(const Eigen::Vector3i& b) const {
    const std::ptrdiff_t slot = blockSlot(b);
    return slot < 0 ? nullptr : blocks_[static_cast<std::size_t>(slot)];
  }
  TsdfBlock* findBlock(const Eigen::Vector3i& b) {
    const std::ptrdiff_t slot = blockSlot(b);
    return slot < 0 ? nullptr : blocks_[static_cast<std::size_t>(slot)];
  }
  /// The block at `b`, allocated (all voxels unobserved) when missing; `created` tells which.
  /// Throws planesdf::Error when `b` is outside blockIndexInRange().
  TsdfBlock& allocateBlock(const Eigen::Vector3i& b, bool* created = nullptr);
  /// Makes room for `n` more blocks (storage, index, hash table) before allocating them.
  void reserveBlocks(std::size_t n);
  /// Blocks allocated from now on live in chunks of `pool` (memory faulted in up front, see
  /// Map::reserveMemory) while it has any; nullptr: fresh memory only (the default). A copy of
  /// the volume does not share the pool.
  void useHugePagePool(std::shared_ptr<detail::HugePagePool> pool) {
    slabs_.usePool(std::move(pool));
  }
  /// The slot of block `b` (its position in allocation order), or -1.
  std::ptrdiff_t blockSlot(const Eigen::Vector3i& b) const {
    if (!blockIndexInRange(b)) return -1;
    const std::uint32_t slot = map_.find(detail::packBlockKey(b));
    return slot == detail::BlockHashMap::kNotFound ? -1 : static_cast<std::ptrdiff_t>(slot);
  }
  /// Block by slot, slot in [0, numBlocks()). Slots follow allocation order and never change.
  const TsdfBlock& block(std::size_t slot) const { return *blocks_[slot]; }
  TsdfBlock& block(std::size_t slot) { return *blocks_[slot]; }
  /// The index of the block in `slot`, from a compact array (scans over many blocks' indices
  /// read 12 bytes per block instead of one cache line behind each block's voxels).
  const Eigen::Vector3i& blockIndex(std::size_t slot) const { return indices_[slot]; }
  /// Calls f(const TsdfBlock&) for every block, in slot order.
  template <class F>
  void forEachBlock(F&& f) const {
    for (const auto& b : blocks_) f(*b);
  }
  /// Indices of all allocated blocks, in slot order.
  std::vector<Eigen::Vector3i> blockIndices() const;
  /// Indices of the blocks whose revision is > `revision` (changed since that revision).
  std::vector<Eigen::Vector3i> blocksChangedSince(std::uint64_t revision) const;
  /// Inclusive range of allocated block indices; false (and unchanged outputs) when empty.
  bool blockBounds(Eigen::Vector3i* lo, Eigen::Vector3i* hi) const;
  /// Drops every block (revision increments when the volume was not empty).
  void clear();

  /// Calls f(const Eigen::Vector3i& global_voxel_index, const TsdfVoxel&) for each voxel of
  /// `block` with weight > 0 and >= min_weight, in memory order (x fastest).
  template <class F>
  static void forEachObservedVoxel(const TsdfBlock& block, F&& f, float min_weight = 0.0f) {
    const Eigen::Vector3i base = block.index * kTsdfBlockSide;
    int i = 0;
    for (int z = 0; z < kTsdfBlockSide; ++z)
      for (int y = 0; y < kTsdfBlockSide; ++y)
        for (int x = 0; x < kTsdfBlockSide; ++x, ++i) {
          const TsdfVoxel& v = block.voxels[i];
          if (v.weight > 0.0f && v.weight >= min_weight)
            f(Eigen::Vector3i(base.x() + x, base.y() + y, base.z() + z), v);
        }
  }

  // --- coordinates ----------------------------------------------------------------------------
  /// The block holding global voxel `v` (floor division by 8).
  static Eigen::Vector3i blockOfVoxel(const Eigen::Vector3i& v) {
    // Arithmetic right shift (guaranteed by GCC/Clang, and by C++20) = floor division by 8.
    return Eigen::Vector3i(v.x() >> kTsdfBlockShift, v.y() >> kTsdfBlockShift,
                           v.z() >> kTsdfBlockShift);
  }
  /// Position of global voxel `v` inside its block's voxel array.
  static int linearIndexInBlock(const Eigen::Vector3i& v) {
    return (v.x() & 7) + ((v.y() & 7) << kTsdfBlockShift) + ((v.z() & 7) << 6);
  }
  /// Global index of the voxel containing local point `p`.
  Eigen::Vector3i voxelIndexAt(const Eigen::Vector3d& p) const;
  /// Index of the block containing local point `p`.
  Eigen::Vector3i blockIndexAt(const Eigen::Vector3d& p) const;
  /// Centre of global voxel `v` in local coordinates.
  Eigen::Vector3d voxelCenter(const Eigen::Vector3i& v) const {
    return (v.cast<double>().array() + 0.5).matrix() * voxel_size_;
  }

  // --- queries --------------------------------------------------------------------------------
  /// The voxel with global index `v`, or nullptr when its block is not allocated.
  const TsdfVoxel* voxel(const Eigen::Vector3i& v) const {
    const TsdfBlock* b = findBlock(blockOfVoxel(v));
    return b ? &b->voxels[linearIndexInBlock(v)] : nullptr;
  }
  TsdfVoxel* voxel(const Eigen::Vector3i& v) {
    TsdfBlock* b = findBlock(blockOfVoxel(v));
    return b ? &b->voxels[linearIndexInBlock(v)] : nullptr;
  }
  /// The TSDF at local point `p`: trilinear over the 8 surrounding voxel centres when all have
  /// weight > 0 and >= min_weight, else the voxel containing `p` if it qualifies, else nullopt.
  std::optional<TsdfSample> sample(const Eigen::Vector3d& p, float min_weight = 0.0f) const;

  // --- change tracking ------------------------------------------------------------------------
  /// Increments whenever an integration or clear() changes the volume.
  std::uint64_t revision() const { return revision_; }
  /// Increments the revision and returns the new value; for code that edits voxels directly
  /// (e.g. a loader), which should also stamp the edited blocks' `revision` with it.
  std::uint64_t bumpRevision() { return ++revision_; }

 private:
  double voxel_size_;
  double truncation_;
  std::vector<TsdfBlock*> blocks_;        ///< by slot, into slabs_
  std::vector<Eigen::Vector3i> indices_;  ///< by slot: blocks_[slot]->index
  detail::BlockSlabs slabs_;
  detail::BlockHashMap map_;
  Eigen::Vector3i lo_ = Eigen::Vector3i::Zero();
  Eigen::Vector3i hi_ = Eigen::Vector3i::Constant(-1);
  std::uint64_t revision_ = 0;
};

/// What one integration call did.
struct IntegrationResult {
  /// Blocks the call processed: for depth frames, every allocated block with at least one voxel
  /// centre inside the camera frustum, the depth range [min_depth, max_depth] and the voxel band
  /// (see integrateDepth); for splats, every block a splat reached. In slot order.
  std::vector<Eigen::Vector3i> updated_blocks;
  /// The subset of updated_blocks in which at least one voxel changed, in slot order.
  std::vector<Eigen::Vector3i> changed_blocks;
  /// Blocks allocated by this call, in packed-key order.
  std::vector<Eigen::Vector3i> allocated_blocks;
  std::size_t num_points_fused = 0;   ///< valid measurements inside the band
  std::size_t num_voxel_updates = 0;  ///< voxel updates applied (surface and free space)
  /// True when the volume changed (its revision was incremented).
  bool changed() const { return !changed_blocks.empty() || !allocated_blocks.empty(); }
};

/// Throws planesdf::Error ("fusion config: ...") when a fusion parameter is out of range.
void validateFusionConfig(const Config& cfg);

class DepthFrameAnalysis;
IntegrationResult integrateDepth(TsdfVolume& vol, const DepthFrameAnalysis& analysis,
                                 const Pose& T_local_camera, const Config& cfg);

/// The plane-independent first pass of integrateDepth over a depth frame: per pixel the
/// measurement (depth and tangent plane), depth discontinuities and grazing surfaces, the
/// distances to them (silhouette guard) and per-tile depth bounds. Computed once per frame and
/// shared by every volume the frame is fused into (Map fuses one frame into all its planes);
/// the result is identical to integrateDepth(vol, frame, ...). Holds a copy of the depths, so
/// the frame need not outlive it. analyse() reuses the buffers of earlier calls.
class DepthFrameAnalysis {
 public:
  DepthFrameAnalysis();
  ~DepthFrameAnalysis();
  DepthFrameAnalysis(const DepthFrameAnalysis& other);
  DepthFrameAnalysis& operator=(const DepthFrameAnalysis& other);
  DepthFrameAnalysis(DepthFrameAnalysis&&) noexcept;
  DepthFrameAnalysis& operator=(DepthFrameAnalysis&&) noexcept;

  /// Analyses `frame` for volumes of truncation `truncation` (m), with cfg's depth range and
  /// threads. Throws planesdf::Error on invalid intrinsics, a depth buffer of the wrong size, an
  /// invalid fusion configuration or truncation <= 0.
  void analyse(const DepthFrame& frame, double truncation, const Config& cfg);
  /// The same analysis, running `alongside` on one of cfg's threads while the others start the
  /// per-pixel pass; that thread joins the pass when `alongside` returns. For the caller's own
  /// per-frame work that needs nothing of the analysis (Map::integrate tracks planes so): both
  /// share the threads without either waiting for the other. `alongside` runs once, unless the
  /// frame or the configuration is rejected first; an exception it throws is rethrown after
  /// the pass. The analysis is the same as analyse(frame, truncation, cfg) for any thread count.
  void analyse(const DepthFrame& frame, double truncation, const Config& cfg,
               const std::function<void()>& alongside);
  /// True before the first analyse().
  bool empty() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  void analyseImpl(const DepthFrame& frame, double truncation, const Config& cfg,
                   const std::function<void()>* alongside);
  friend IntegrationResult integrateDepth(TsdfVolume& vol, const DepthFrameAnalysis& analysis,
                                          const Pose& T_local_camera, const Config& cfg);
};

/// Fuses a depth frame into `vol` (projective TSDF with point-to-plane distances).
///
/// `T_local_camera` maps camera coordinates (OpenCV optical frame) into the volume's local frame
/// (world-to-local * camera-to-world). The volume's own voxel size and truncation are used; from
/// `cfg` come the band (below_band, fuse_band), the depth range, max_weight and threads.
///
/// 1. A pixel is a measurement when its depth d is finite and in [min_depth, max_depth]; others
///    (0, NaN, inf, out of range) never update anything. Its point P is *in the band* when its
///    height is in [-below_band, fuse_band]. Its surface normal comes from the depth gradient
///    (central differences, one-sided at depth jumps).
/// 2. Allocation: for each in-band point, the blocks crossed by its ray segment from the depth
///    where the distance reaches +truncation in front of the surface to where it reaches
///    -truncation / 2 behind it (but at most truncation in depth), clipped to the voxel band,
///    are allocated.
/// 3. Update: only allocated blocks are visited, and within them only voxels whose centre lies in
///    the voxel band h in [-below_band - trunc, fuse_band + trunc], has camera depth z in
///    [min_depth, max_depth] and projects (nearest pixel) into the image. With q the voxel's
///    depth difference to the pixel's tangent plane along the viewing direction (d - z on the
///    pixel's own ray), sdf = cos(ray, normal) * q: the distance to the tangent plane, in metres.
///    q < -trunc or sdf < -trunc / 2: untouched (occluded: how far the object extends behind
///    its visible surface is unknown, so only half the truncation behind it is fused; a thin
///    object keeps no wrong inside values near its unseen back face); sdf >= trunc: free
///    space, fused as +trunc (any measurement carves, in band or not); otherwise fused only when
///    P is in the band. Surfaces seen at more than 78 deg from their normal only carve (along
///    the optical axis).
///    Silhouette guard: pixels on the near side of a depth jump, and pixels of surfaces too
///    grazing to be fused, are edge pixels (seen but not fused surface points). A voxel with
///    |sdf| > half a voxel is skipped when the nearest edge pixel lies laterally closer than
///    min(|sdf|, trunc) to its line of sight (chessboard pixel distance in the image, plus half a
///    pixel behind the surface, scaled to the voxel's depth) and the edges around its pixel
///    (8x8-pixel tiles within the truncation's lateral reach) are at most one truncation behind
///    it. In front, this removes the silhouette bias of projective fusion (a voxel beside an
///    object, seeing the background, would get the background's distance) while keeping the free
///    space around small objects observed. Behind the surface (cfg.silhouette_guard_behind), only
///    depth-jump edges count, within min(|sdf|, trunc) * sin(ray, normal): the ray meets the
///    surface that far (laterally) before the voxel, so an object rim closer than that may put
///    the voxel past the object's hidden side ("inside" values past a far rim).
///    Fusion is a running average with weight 1 per observation, capped at max_weight.
///
/// Candidate blocks are the allocated blocks of the frustum's local AABB (clipped to the band and
/// to the volume's block bounds; enumerated cell by cell or by scanning the blocks, whichever is
/// fewer), culled by their bounding sphere against the frustum planes; a block counts as updated
/// when one of its voxel centres passes the per-voxel view test above (even if no measurement
/// changes it). Parallel over blocks (cfg.threads, 0 = all CPUs); the result is
/// bit-identical for any thread count.
///
/// Throws planesdf::Error on invalid intrinsics, a depth buffer of the wrong size or an invalid
/// fusion configuration.
IntegrationResult integrateDepth(TsdfVolume& vol, const DepthFrame& frame,
                                 const Pose& T_local_camera, const Config& cfg);

// integrateDepth(vol, analysis, T_local_camera, cfg) (declared above): the same from a frame
// analysed once (DepthFrameAnalysis); throws planesdf::Error when the analysis is empty or was
// made for another truncation or depth range than the volume's and cfg's.

/// Least-squares pinhole intrinsics of an organised cloud (e.g. a 640x480 Kinect cloud): fits
/// u = fx * x / z + cx and v = fy * y / z + cy over its valid points (in the sensor frame,
/// i.e. after undoing cloud.sensor_pose), with (u, v) the pixel of each point in the grid.
/// width/height are the cloud's. `rms_px`, when given, receives the RMS reprojection residual.
/// Throws planesdf::Error when the cloud is not organised or has too few valid points (or they
/// are degenerate, e.g. all in one column).
Intrinsics estimateIntrinsics(const PointCloud& organized, double* rms_px = nullptr);

/// The depth image of an organised cloud: each valid point's z in the sensor frame (after undoing
/// cloud.sensor_pose), written at its own grid pixel; invalid points and z <= 0 give 0.
/// Throws planesdf::Error unless the cloud is organised with the intrinsics' width and height.
DepthFrame depthFromOrganizedCloud(const PointCloud& organized, const Intrinsics& intrinsics);

/// Fuses an organised cloud as one depth frame seen from its sensor: `T_local_cloud` maps the
/// cloud's frame into the volume's local frame, so the camera pose is T_local_cloud *
/// cloud.sensor_pose. Intrinsics are estimated with estimateIntrinsics() unless given.
IntegrationResult integrateOrganizedCloud(TsdfVolume& vol, const PointCloud& organized,
                                          const Pose& T_local_cloud, const Config& cfg,
                                          const Intrinsics* intrinsics = nullptr);

/// Fuses an unorganised cloud with oriented normals (no sensor): each point p with unit normal
/// n (pointing to free space, local frame) and height in [-below_band, fuse_band] updates the
/// voxels whose centre v lies within the cylinder around p + t n, |t| <= truncation, of radius
/// cfg.splat_radius_voxels voxels, with sdf = n . (v - p) and weight 1 (running average, capped
/// at max_weight); voxels outside the voxel band are left alone. Points or normals that are
/// non-finite or zero are skipped. `front_local`, when given, extends each point's cylinder in
/// front of it (along n) to that distance where larger than the truncation, with the sdf there
/// clamped to the truncation: the free space in front of a noisy surface (design.md, "Normals
/// of noisy clouds"). Deterministic for any thread count.
/// Throws planesdf::Error when the arrays differ in length.
IntegrationResult integratePointsWithNormals(TsdfVolume& vol,
                                             const std::vector<Eigen::Vector3f>& points_local,
                                             const std::vector<Eigen::Vector3f>& normals_local,
                                             const Config& cfg,
                                             const std::vector<float>* front_local = nullptr);

}  // namespace planesdf
