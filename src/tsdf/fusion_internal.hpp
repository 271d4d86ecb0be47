#pragma once
// Internal declarations shared by the fusion translation units (fusion.cpp, depth_analysis.cpp,
// block_allocation*.cpp, voxel_kernel*.cpp, integration.cpp, splatting.cpp); not installed.

#include <Eigen/Core>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "../parallel.hpp"
#include "planesdf/tsdf.hpp"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define PLANESDF_AVX2_KERNEL 1
#include <immintrin.h>
#else
#define PLANESDF_AVX2_KERNEL 0
#endif

namespace planesdf {
namespace fusion_detail {

constexpr float kInf = std::numeric_limits<float>::infinity();

inline int floorToInt(float x) {
  const int i = static_cast<int>(x);
  return i - (x < static_cast<float>(i) ? 1 : 0);
}

using detail::parallelChunks;
using detail::resolveThreads;

/// Heights (local z) that bound the fusion: points are fused when h is in [pt_lo, pt_hi];
/// voxels are updated when their centre's h is in [vox_lo, vox_hi] (the point band widened by
/// the truncation); allocation covers [alloc_lo, alloc_hi], the extent of those voxels.
struct Band {
  float pt_lo, pt_hi, vox_lo, vox_hi, alloc_lo, alloc_hi;
};

/// The band of `cfg` for a volume of the given voxel size and truncation (fusion.cpp).
Band makeBand(const Config& cfg, double voxel, double truncation);

/// Running-average update with weight 1; returns true when the voxel changed.
inline bool fuseVoxel(TsdfVoxel& v, float sdf, float max_weight) {
  const float w_new = std::min(v.weight + 1.0f, max_weight);
  const float s_new = v.sdf + (sdf - v.sdf) / (v.weight + 1.0f);
  if (s_new == v.sdf && w_new == v.weight) return false;
  v.sdf = s_new;
  v.weight = w_new;
  return true;
}

// ---- depth frames ---------------------------------------------------------------------------

/// The camera in float, with both transforms.
struct Camera {
  float fx, fy, cx, cy;
  int width, height;
  float z_min, z_max;    // depth range (z_min > 0)
  float z_surface;       // beyond this depth a measurement only carves free space
  Eigen::Matrix3f R_lc;  // camera -> local
  Eigen::Vector3f t_lc;
  Eigen::Matrix3d R_cl_d;  // local -> camera (double, for block origins)
  Eigen::Vector3d t_cl_d;
  Eigen::Matrix3f R_cl;
};

/// The camera of intrinsics K at pose T_local_camera, depth range from `cfg` (depth_analysis.cpp).
Camera makeCamera(const Intrinsics& K, const Pose& T_local_camera, const Config& cfg);

/// A pixel's measurement for pass 2. With r = (xp, yp, 1) the pixel's ray and P = d r its point,
/// the tangent plane through P is written as n' . x + d = 0 with n' = n / k, n the unit normal
/// facing the camera and k = -n . r, so that n' . r = -1. For a voxel at x (camera frame),
/// q = n' . x + d is its depth difference to the tangent plane along the pixel's viewing
/// direction (sub-pixel exact; d - z on the pixel's ray) and k * q its distance to the plane.
/// Stored in 8 bytes (the image is read at random in pass 2, so its size matters): n'x, n'y
/// and k as 16-bit fixed point, d as 16-bit fixed point of the depth range; n'z = -1 - n'x xp -
/// n'y yp. dq = 0: no measurement; k < 0: the point is outside the band (or grazing) and only
/// carves free space.
struct PixelMeasurement {
  std::int16_t nx, ny;
  std::uint16_t dq;
  std::int16_t kq;
};

/// Fixed-point scales: |n'| <= 1 / kMinCosine = 5 < 6; k <= |r| < 4 (fields of view < 150 deg).
constexpr float kNormalScale = 32767.0f / 6.0f;
constexpr float kCosineScale = 32767.0f / 4.0f;

/// Surfaces seen more grazing than this (cosine between the ray and the surface normal) are not
/// fused: their points only carve free space (and are edge pixels for the silhouette guard).
constexpr float kMinCosine = 0.2f;

/// Behind the surface a measurement says how deep a voxel is only as far as the object is thick
/// along the ray, which the frame cannot see. Voxels farther behind the tangent plane than this
/// fraction of the truncation are not updated: thin structures (a 3 cm table top at 7 mm voxels)
/// then keep no inside values near their unseen back faces, and views from opposite sides of a
/// thin object stop averaging each other's behind-surface values into its front surface.
constexpr float kBehindFraction = 0.5f;

/// Silhouette guard. Near a silhouette, a projective measurement misjudges distances on both
/// sides of the surface:
///  * in front: a voxel beside a foreground object whose pixel sees the background gets a large
///    positive distance from that background although the object is near (the classic silhouette
///    bias of projective fusion);
///  * behind: a voxel behind a surface near its silhouette may lie beyond the object's hidden
///    side (the far rim of a table or box seen from above: just past the rim and below its top,
///    the tangent plane says "inside" although the voxel is in free space).
/// "Edge" pixels are surface points the frame sees but does not fuse: the near side of a depth
/// discontinuity, and surfaces seen too grazing to be fused (beyond acos(kMinCosine)), whose
/// points still bound the distance of the voxels near them. A measurement that puts a voxel at
/// |sdf| > kGuardSdf voxels from the surface is not trusted, and the voxel is not updated by this
/// frame, when an edge pixel lies laterally closer than min(|sdf|, trunc) to the voxel's line of
/// sight (the chessboard pixel distance to the nearest edge pixel, scaled to the voxel's depth:
/// never more than the Euclidean distance, so the test errs on the side of skipping) and the
/// edges near its pixel are not more than one truncation behind the voxel (an edge far behind it
/// is a surface out of its truncation band). Per tile of kGuardTile^2 pixels the guard map holds
/// the smallest edge depth within the lateral reach of the truncation (dilated): the depth test,
/// and a cheap filter before the per-pixel distance (FrameMeasurements::edge_dist) is read.
constexpr int kGuardTileShift = 3;
constexpr int kGuardTile = 1 << kGuardTileShift;
constexpr float kGuardSdf = 0.5f;  // voxels
/// A silhouette lies between an edge pixel's centre and its background neighbour's centre: seen
/// from a voxel behind the foreground surface (whose own pixel is on the foreground side), half
/// a pixel beyond the edge pixel on average. Added to the edge distance of such voxels.
constexpr float kSilhouetteOffsetPx = 0.5f;

/// Bytes after the last pixel of the per-pixel byte images: the AVX2 kernel reads a byte as
/// the low byte of a 32-bit gather.
constexpr std::size_t kGatherPadding = 4;

/// Everything pass 2 reads from the frame.
struct FrameMeasurements {
  std::vector<PixelMeasurement> pixels;  ///< row-major, one per pixel
  std::vector<float> xn, yn;             ///< normalised coordinates of columns / rows
  float depth_scale = 0.0f;              ///< metres per unit of PixelMeasurement::dq
  std::vector<float> guard;              ///< per tile: nearby edge depth (+inf: none)
  std::vector<float> tile_max_depth;     ///< per tile: largest measured depth (-inf: none)
  int tiles_x = 0, tiles_y = 0;
  /// Per pixel: chessboard distance (pixels, saturated at kFarEdge) to the nearest edge pixel.
  std::vector<std::uint8_t> edge_dist;
  /// The same to the nearest depth-discontinuity edge only (silhouettes; no grazing pixels).
  std::vector<std::uint8_t> silhouette_dist;
};

// ---- pass 1b: block allocation (block_allocation.cpp, block_allocation_avx2.cpp) ------------

class BlockGrid;
class SegmentBlocks;

/// Allocates the blocks of `per_thread` key lists in key order (see block_allocation.cpp).
std::vector<Eigen::Vector3i> allocateKeys(TsdfVolume& vol,
                                          const std::vector<std::vector<std::uint64_t>>& per_thread,
                                          const Config& cfg);

/// The local AABB of the frustum between camera depths z0 and z1.
void frustumLocalBox(const Camera& cam, double z0, double z1, Eigen::Vector3d& lo,
                     Eigen::Vector3d& hi);

/// What the allocation pass reads for one row of pixels.
struct AllocRow {
  const float* depth;
  const float* k;
  const float* xn;
  std::uint8_t* flag;
  int W;
  float dir_col[3];  ///< the ray's change per unit xn (camera x axis in local coordinates)
  float dir_row[3];  ///< the ray at xn = 0 for this row
  float t[3];        ///< camera centre (local)
  float t_bs[3];     ///< camera centre in block units
  float trunc, inv_bs;
  Band band;
};

/// One pixel of the allocation pass; 1 when its point is in the band (block_allocation.cpp).
int allocatePixel(const AllocRow& r, int u, SegmentBlocks& segments);

#if PLANESDF_AVX2_KERNEL
/// allocatePixel for a row, 8 pixels at a time (block_allocation_avx2.cpp).
__attribute__((target("avx2"))) int allocateRowAvx2(const AllocRow& r, SegmentBlocks& segments);
#endif

/// Pass 1b (per volume): flags the in-band pixels and allocates the blocks their truncation
/// segments cross; returns the in-band count (block_allocation.cpp).
std::size_t allocateInBand(TsdfVolume& vol, const std::vector<float>& depth_img,
                           const std::vector<float>& k_exact, const FrameMeasurements& fm,
                           const Camera& cam, const Band& band, int threads, bool simd,
                           BlockGrid& grid, std::vector<std::uint8_t>& in_band, const Config& cfg,
                           std::vector<Eigen::Vector3i>& allocated);

// ---- pass 2: voxel update (voxel_kernel.cpp, voxel_kernel_avx2.cpp) ------------------------

/// Frustum side planes through the camera centre (inside: n . p >= 0), plus the depth range;
/// tests a sphere in camera coordinates.
struct FrustumCull {
  Eigen::Vector3f n[4];
  float z_min, z_max;

  explicit FrustumCull(const Camera& c) : z_min(c.z_min), z_max(c.z_max) {
    const float aL = (-0.5f - c.cx) / c.fx, aR = (c.width - 0.5f - c.cx) / c.fx;
    const float aT = (-0.5f - c.cy) / c.fy, aB = (c.height - 0.5f - c.cy) / c.fy;
    n[0] = Eigen::Vector3f(1.0f, 0.0f, -aL).normalized();
    n[1] = Eigen::Vector3f(-1.0f, 0.0f, aR).normalized();
    n[2] = Eigen::Vector3f(0.0f, 1.0f, -aT).normalized();
    n[3] = Eigen::Vector3f(0.0f, -1.0f, aB).normalized();
  }
  bool mayIntersect(const Eigen::Vector3f& c, float r) const {
    if (c.z() < z_min - r || c.z() > z_max + r) return false;
    for (const auto& ni : n)
      if (ni.dot(c) < -r) return false;
    return true;
  }
};

struct BlockOutcome {
  bool in_view = false;
  bool changed = false;
  std::uint32_t updates = 0;
};

struct DepthUpdateParams {
  const FrameMeasurements* fm;
  const std::uint8_t* in_band;  ///< per pixel: the point is in the band (else it only carves)
  float trunc;
  float max_weight;
  float voxel;
  Band band;
  bool guard_behind;  ///< cfg.silhouette_guard_behind
  bool simd;          ///< use the AVX2 row kernel (cfg.simd and the CPU has AVX2)
};

/// What the voxel loop of one block reads: the frame's measurements, the camera and the
/// block's x axis in camera coordinates (one row of voxels runs along it).
struct RowKernel {
  const PixelMeasurement* pixels;
  const float* guard;
  const std::uint8_t* edge_dist;
  const std::uint8_t* silhouette_dist;
  const std::uint8_t* in_band;
  int W, H, tiles_x;
  float ax_x, ax_y, ax_z;
  float fx, fy, cx, cy, inv_fx, inv_fy, z_min, z_max, w_lim, h_lim;
  float trunc, behind, guard_sdf, edge_scale, depth_scale, max_weight;
  bool guard_behind;
  /// False when no tile the block's voxels project to has an edge near enough for the
  /// silhouette guard (it cannot skip a voxel of this block; its gathers are left out).
  bool guard_near = true;
};

#if PLANESDF_AVX2_KERNEL
/// The AVX2 kernel for the rows of one slice of a block (voxel_kernel_avx2.cpp).
__attribute__((target("avx2"))) void fuseSliceAvx2(const RowKernel& k, float sx, float sy, float sz,
                                                   float ay_x, float ay_y, float ay_z,
                                                   TsdfVoxel* voxels, BlockOutcome& out);
#endif

/// Pass 2 for one block (voxel_kernel.cpp).
BlockOutcome updateBlockFromDepth(TsdfBlock& blk, const Eigen::Vector3i& index, const Camera& cam,
                                  const FrustumCull& cull, const DepthUpdateParams& prm);

/// Gathers per-block outcomes into `res`, bumps the revision and stamps changed blocks
/// (fusion.cpp).
void finishIntegration(TsdfVolume& vol, const std::vector<std::uint32_t>& slots,
                       const std::vector<BlockOutcome>& outcomes, IntegrationResult& res);

}  // namespace fusion_detail

struct DepthFrameAnalysis::Impl {
  fusion_detail::FrameMeasurements fm;
  std::vector<float> depth;  ///< the frame's depths (exact, for allocation)
  std::vector<float> k;      ///< per pixel k (0: invalid or grazing)
  Intrinsics intrinsics;
  float truncation = 0.0f;
  float z_min = 0.0f, z_max = 0.0f;
  float z_surface = 0.0f;  ///< cfg.surface_max_depth it was made for
  int threads = 1;
};

}  // namespace planesdf
