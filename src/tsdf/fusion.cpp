// Fusion into a TsdfVolume: projective integration of depth frames and splatting of points with
// normals. See tsdf.hpp for the contracts.

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <functional>
#include <limits>
#include <memory>
#include <string>

#include "../numeric.hpp"
#include "planesdf/error.hpp"
#include "planesdf/memory.hpp"
#include "planesdf/tsdf.hpp"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define PLANESDF_AVX2_KERNEL 1
#include <immintrin.h>
#else
#define PLANESDF_AVX2_KERNEL 0
#endif

namespace planesdf {

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

inline int floorToInt(float x) {
  const int i = static_cast<int>(x);
  return i - (x < static_cast<float>(i) ? 1 : 0);
}

int resolveThreads(int requested) {
  return requested > 0 ? requested : std::max(1, omp_get_max_threads());
}

/// Heights (local z) that bound the fusion: points are fused when h is in [pt_lo, pt_hi];
/// voxels are updated when their centre's h is in [vox_lo, vox_hi] (the point band widened by
/// the truncation); allocation covers [alloc_lo, alloc_hi], the extent of those voxels.
struct Band {
  float pt_lo, pt_hi, vox_lo, vox_hi, alloc_lo, alloc_hi;
};

Band makeBand(const Config& cfg, double voxel, double truncation) {
  Band b;
  b.pt_lo = static_cast<float>(-cfg.below_band);
  b.pt_hi = static_cast<float>(cfg.fuse_band);
  b.vox_lo = static_cast<float>(-cfg.below_band - truncation);
  b.vox_hi = static_cast<float>(cfg.fuse_band + truncation);
  // Voxel k has its centre at (k + 0.5) * voxel: the band's first and last voxels.
  const double k_lo = std::ceil(b.vox_lo / voxel - 0.5), k_hi = std::floor(b.vox_hi / voxel - 0.5);
  b.alloc_lo = static_cast<float>(k_lo * voxel + 1e-4 * voxel);
  b.alloc_hi = static_cast<float>((k_hi + 1.0) * voxel - 1e-4 * voxel);
  return b;
}

/// Running-average update with weight 1; returns true when the voxel changed.
inline bool fuseVoxel(TsdfVoxel& v, float sdf, float max_weight) {
  const float w_new = std::min(v.weight + 1.0f, max_weight);
  const float s_new = v.sdf + (sdf - v.sdf) / (v.weight + 1.0f);
  if (s_new == v.sdf && w_new == v.weight) return false;
  v.sdf = s_new;
  v.weight = w_new;
  return true;
}

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
      keys_.push_back(packBlockKey(b));
      return;
    }
    if (!blockIndexInRange(b)) return;
    const std::uint64_t key = packBlockKey(b);
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
          if (vol_.blockSlot(b) < 0 && set_.find(packBlockKey(b)) == BlockHashMap::kNotFound)
            return false;
        }
    return true;
  }

 private:
  const TsdfVolume& vol_;
  BlockGrid& grid_;
  RecentKeys recent_;
  BlockHashMap set_;
  std::vector<std::uint64_t> keys_;
};

/// Allocates the blocks of `per_thread` key lists in key order; returns their indices. Throws
/// planesdf::Error, allocating nothing, when the new blocks exceed the memory limit of `cfg`.
std::vector<Eigen::Vector3i> allocateKeys(TsdfVolume& vol,
                                          const std::vector<std::vector<std::uint64_t>>& per_thread,
                                          const Config& cfg) {
  std::vector<std::uint64_t> keys;
  for (const auto& k : per_thread) keys.insert(keys.end(), k.begin(), k.end());
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  requireMemory(keys.size() * sizeof(TsdfBlock), cfg, "",
                std::to_string(keys.size()) + " new TSDF blocks at voxel_size " +
                    std::to_string(vol.voxelSize()) + " m (fuse_band " +
                    std::to_string(cfg.fuse_band) + " m)");
  std::vector<Eigen::Vector3i> out;
  out.reserve(keys.size());
  for (const std::uint64_t k : keys) {
    out.push_back(unpackBlockKey(k));
    vol.allocateBlock(out.back());
  }
  return out;
}

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

Camera makeCamera(const Intrinsics& K, const Pose& T_local_camera, const Config& cfg) {
  Camera c;
  c.fx = static_cast<float>(K.fx);
  c.fy = static_cast<float>(K.fy);
  c.cx = static_cast<float>(K.cx);
  c.cy = static_cast<float>(K.cy);
  c.width = K.width;
  c.height = K.height;
  c.z_min = static_cast<float>(std::max(cfg.min_depth, 1e-6));
  c.z_max = static_cast<float>(cfg.max_depth);
  c.z_surface = static_cast<float>(cfg.surface_max_depth);
  c.R_lc = T_local_camera.linear().cast<float>();
  c.t_lc = T_local_camera.translation().cast<float>();
  const Pose T_cl = T_local_camera.inverse(Eigen::Isometry);
  c.R_cl_d = T_cl.linear();
  c.t_cl_d = T_cl.translation();
  c.R_cl = c.R_cl_d.cast<float>();
  return c;
}

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

/// Quantises a measurement; `inv_depth_scale` is the number of dq units per metre of depth.
inline PixelMeasurement encodeMeasurement(float nx, float ny, float d, float k, bool carve_only,
                                          float inv_depth_scale) {
  const auto q16 = [](float x, float scale) {
    const float y = std::clamp(x * scale, -32767.0f, 32767.0f);
    // Round half away from zero without a branch (the signs of normals are unpredictable).
    return static_cast<std::int16_t>(y + std::copysign(0.5f, y));
  };
  PixelMeasurement m;
  m.nx = q16(nx, kNormalScale);
  m.ny = q16(ny, kNormalScale);
  m.dq = static_cast<std::uint16_t>(std::clamp(d * inv_depth_scale + 0.5f, 1.0f, 65535.0f));
  const std::int16_t kq = std::max<std::int16_t>(1, q16(k, kCosineScale));
  m.kq = carve_only ? static_cast<std::int16_t>(-kq) : kq;
  return m;
}

/// Surfaces seen more grazing than this (cosine between the ray and the surface normal) are not
/// fused: their points only carve free space (and are edge pixels for the silhouette guard).
constexpr float kMinCosine = 0.2f;
/// Bound on the tangent-plane term of q, |n' . (voxel - its pixel's ray point)|, in pixel
/// footprints at the voxel's depth: |n'| <= 1 / kMinCosine = 5 and the voxel is at most half a
/// pixel diagonal (0.71 px) off its pixel's ray.
constexpr float kTangentSlackPx = 3.6f;
/// Neighbouring depths differing by more than this many pixel footprints (and more than the
/// truncation) are a discontinuity; a surface at acos(kMinCosine) = 78 deg differs by ~5.
constexpr float kMaxJumpFootprints = 6.0f;

/// Depth derivative along one image axis from the two neighbours' depths dm, dp (central
/// difference; one-sided when a neighbour is invalid or across a jump > max_jump). False when
/// both are missing.
inline bool depthDerivative(float dm, float dp, float d, const Camera& cam, float max_jump,
                            float* out) {
  const bool has_m = dm >= cam.z_min && dm <= cam.z_max && std::fabs(dm - d) <= max_jump;
  const bool has_p = dp >= cam.z_min && dp <= cam.z_max && std::fabs(dp - d) <= max_jump;
  if (has_m && has_p)
    *out = 0.5f * (dp - dm);
  else if (has_p)
    *out = dp - d;
  else if (has_m)
    *out = d - dm;
  else
    return false;
  return true;
}

/// The unit tangent-plane normal n (camera frame, facing the camera) of pixel u of row `row`,
/// whose ray is r = (x, y, 1) and depth d; `above`/`below` are the neighbouring rows (or
/// nullptr). For P = D(u, v) r(u, v) the normal is parallel to
/// (fx D_u, fy D_v, -(D + fx x D_u + fy y D_v)), whose dot product with r is -D.
/// Without a usable normal: (0, 0, -1), i.e. the projective distance d - z. The zero vector for
/// surfaces seen more grazing than kMinCosine.
void surfaceNormal(const float* above, const float* row, const float* below, int u, float x,
                   float y, float d, const Camera& cam, float max_jump, float n[3]) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  float du, dv;
  if (!depthDerivative(u > 0 ? row[u - 1] : nan, u + 1 < cam.width ? row[u + 1] : nan, d, cam,
                       max_jump, &du) ||
      !depthDerivative(above ? above[u] : nan, below ? below[u] : nan, d, cam, max_jump, &dv)) {
    n[0] = n[1] = 0.0f;
    n[2] = -1.0f;
    return;
  }
  n[0] = cam.fx * du;
  n[1] = cam.fy * dv;
  n[2] = -(d + cam.fx * x * du + cam.fy * y * dv);
  const float len2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
  // cos(ray, normal) = d / (|n| |r|), compared squared (d > 0): one square root per pixel.
  const float scale = d * d < kMinCosine * kMinCosine * len2 * (x * x + y * y + 1.0f)
                          ? 0.0f
                          : 1.0f / std::sqrt(len2);
  for (int i = 0; i < 3; ++i) n[i] *= scale;
}

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
/// Saturation of the per-pixel edge distance (pixels).
constexpr int kFarEdge = 255;

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

/// True when pixel u of `row` (depth d) has a valid 4-neighbour farther than d + max_jump.
inline bool isForegroundEdge(const float* above, const float* row, const float* below, int u, int W,
                             float d, float max_jump, const Camera& cam) {
  const float far = d + max_jump;
  const auto farther = [&](float dd) { return dd > far && dd <= cam.z_max; };
  return (u > 0 && farther(row[u - 1])) || (u + 1 < W && farther(row[u + 1])) ||
         (above && farther(above[u])) || (below && farther(below[u]));
}

/// The distance (pixels, saturated at kFarEdge) from each pixel of a row of width W to the nearest
/// of the row's edge pixels, whose columns are cols[0..n) in increasing order.
void rowEdgeDistance(const int* cols, int n, int W, std::uint8_t* out) {
  constexpr int kNone = 1 << 20;
  int left = -kNone, x = 0;
  for (int i = 0; i <= n; ++i) {
    const int right = i < n ? cols[i] : W + kNone;
    const int end = std::min(right, W);
    for (; x < end; ++x)
      out[x] = static_cast<std::uint8_t>(std::min(std::min(x - left, right - x), kFarEdge));
    if (i < n) {
      out[right] = 0;
      x = right + 1;
      left = right;
    }
  }
}

/// out = min(out, min(src[x - 1], src[x], src[x + 1]) + 1) over a row (saturating).
inline void edgeDistanceStep(const std::uint8_t* src, std::uint8_t* out, int W) {
  const auto inc = [](std::uint8_t a) {
    return static_cast<std::uint8_t>(a + (a != kFarEdge ? 1 : 0));
  };
  if (W == 1) {
    out[0] = std::min(out[0], inc(src[0]));
    return;
  }
  out[0] = std::min(out[0], inc(std::min(src[0], src[1])));
  for (int x = 1; x + 1 < W; ++x)
    out[x] = std::min(out[x], inc(std::min(std::min(src[x - 1], src[x]), src[x + 1])));
  out[W - 1] = std::min(out[W - 1], inc(std::min(src[W - 2], src[W - 1])));
}

/// Turns per-row edge distances h (rowEdgeDistance) into the exact chessboard distance to the
/// nearest edge pixel of the image (saturated): a downward pass
/// D(y) = min(h(y), min(D(y - 1) at x - 1, x, x + 1) + 1), then the same pass upward. k
/// vertical or diagonal steps reach any column within k of x, so an edge at (x', y') costs
/// |y - y'| + max(0, |x - x'| - |y - y'|) = max(|x - x'|, |y - y'|) and nothing costs less.
/// Vectorises over the row; about 0.1 ms for 640x480.
void columnEdgeDistance(std::uint8_t* d, int W, int H) {
  for (int y = 1; y < H; ++y)
    edgeDistanceStep(d + static_cast<std::size_t>(y - 1) * W, d + static_cast<std::size_t>(y) * W,
                     W);
  for (int y = H - 2; y >= 0; --y)
    edgeDistanceStep(d + static_cast<std::size_t>(y + 1) * W, d + static_cast<std::size_t>(y) * W,
                     W);
}

/// Dilates the tile map by `r` tiles (separable min filter).
void dilateMin(std::vector<float>& map, int w, int h, int r) {
  std::vector<float> tmp(map.size());
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      float m = std::numeric_limits<float>::infinity();
      for (int i = std::max(0, x - r); i <= std::min(w - 1, x + r); ++i)
        m = std::min(m, map[y * w + i]);
      tmp[y * w + x] = m;
    }
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      float m = std::numeric_limits<float>::infinity();
      for (int j = std::max(0, y - r); j <= std::min(h - 1, y + r); ++j)
        m = std::min(m, tmp[j * w + x]);
      map[y * w + x] = m;
    }
}

/// Pass 1a over the pixels (plane-independent), parallel over rows of tiles: fills `fm` (the
/// measurements, with only grazing pixels flagged carve-only; edge and silhouette distances;
/// the guard and largest-depth tiles) and `k_exact` (per pixel k, 0 when the pixel is invalid
/// or grazing).
/// `alongside` (may be null) runs on one thread while the others start the rows; that thread
/// then joins them. Its exception, if any, is rethrown after the pass.
void analysePixels(const DepthFrame& frame, const Camera& cam, float trunc, int threads,
                   FrameMeasurements& fm, std::vector<float>& k_exact,
                   const std::function<void()>* alongside) {
  const int W = cam.width, H = cam.height;
  const float footprint = 1.0f / std::min(cam.fx, cam.fy);  // pixel size at unit depth
  std::vector<float>& xn = fm.xn;
  xn.resize(W);
  // As the voxel kernels compute them (no table gather there): (u - cx) * (1 / fx).
  const float inv_fx = 1.0f / cam.fx, inv_fy = 1.0f / cam.fy;
  for (int u = 0; u < W; ++u) xn[u] = (static_cast<float>(u) - cam.cx) * inv_fx;
  fm.yn.resize(H);
  for (int v = 0; v < H; ++v) fm.yn[v] = (static_cast<float>(v) - cam.cy) * inv_fy;
  fm.pixels.resize(static_cast<std::size_t>(W) * H);
  k_exact.resize(static_cast<std::size_t>(W) * H);
  fm.depth_scale = cam.z_max / 65535.0f;
  const float inv_depth_scale = 1.0f / fm.depth_scale;
  fm.tiles_x = (W + kGuardTile - 1) >> kGuardTileShift;
  fm.tiles_y = (H + kGuardTile - 1) >> kGuardTileShift;
  fm.guard.assign(static_cast<std::size_t>(fm.tiles_x) * fm.tiles_y,
                  std::numeric_limits<float>::infinity());
  fm.tile_max_depth.assign(fm.guard.size(), -std::numeric_limits<float>::infinity());
  fm.edge_dist.resize(static_cast<std::size_t>(W) * H + kGatherPadding);
  fm.silhouette_dist.resize(static_cast<std::size_t>(W) * H + kGatherPadding);
  // Valid pixels and their depth sum per row of tiles, added up in order afterwards (the same
  // mean depth for any thread count and schedule).
  std::vector<std::size_t> row_valid(static_cast<std::size_t>(fm.tiles_y), 0);
  std::vector<double> row_depth(static_cast<std::size_t>(fm.tiles_y), 0.0);
  std::exception_ptr alongside_failure;
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
#pragma omp single nowait
    {
      if (alongside != nullptr) {
        try {
          (*alongside)();
        } catch (...) {
          alongside_failure = std::current_exception();
        }
      }
    }
    std::vector<int> edge_cols, silhouette_cols;
    edge_cols.reserve(static_cast<std::size_t>(W));
    silhouette_cols.reserve(static_cast<std::size_t>(W));
#pragma omp for schedule(dynamic, 1)
    for (int ty = 0; ty < fm.tiles_y; ++ty) {
      std::size_t n_valid = 0;
      double sum_depth = 0.0;
      float* guard_row = fm.guard.data() + static_cast<std::size_t>(ty) * fm.tiles_x;
      float* max_depth_row = fm.tile_max_depth.data() + static_cast<std::size_t>(ty) * fm.tiles_x;
      for (int v = ty * kGuardTile; v < std::min(H, (ty + 1) * kGuardTile); ++v) {
        const float yn = fm.yn[v];
        const float* depth = frame.depth.data() + static_cast<std::size_t>(v) * W;
        const float* above = v > 0 ? depth - W : nullptr;
        const float* below = v + 1 < H ? depth + W : nullptr;
        PixelMeasurement* out = fm.pixels.data() + static_cast<std::size_t>(v) * W;
        float* k_out = k_exact.data() + static_cast<std::size_t>(v) * W;
        edge_cols.clear();
        silhouette_cols.clear();
        for (int u = 0; u < W; ++u) {
          const float d = depth[u];
          k_out[u] = 0.0f;
          if (!(d >= cam.z_min && d <= cam.z_max)) {
            out[u] = {0, 0, 0, 0};
            continue;
          }
          ++n_valid;
          sum_depth += d;
          float& dmax = max_depth_row[u >> kGuardTileShift];
          dmax = std::max(dmax, d);
          const float max_jump = std::max(trunc, kMaxJumpFootprints * d * footprint);
          float n[3];
          surfaceNormal(above, depth, below, u, xn[u], yn, d, cam, max_jump, n);
          const float k = -(n[0] * xn[u] + n[1] * yn + n[2]);  // 0 when grazing
          const bool silhouette = isForegroundEdge(above, depth, below, u, W, d, max_jump, cam);
          if (k == 0.0f || silhouette) {
            float& g = guard_row[u >> kGuardTileShift];
            g = std::min(g, d);
            edge_cols.push_back(u);
            if (silhouette) silhouette_cols.push_back(u);
          }
          if (k == 0.0f) {  // grazing: carve along the optical axis only
            out[u] = encodeMeasurement(0.0f, 0.0f, d, 1.0f, true, inv_depth_scale);
            continue;
          }
          k_out[u] = k;
          const float inv_k = 1.0f / k;
          out[u] = encodeMeasurement(n[0] * inv_k, n[1] * inv_k, d, k, d > cam.z_surface,
                                     inv_depth_scale);
        }
        rowEdgeDistance(edge_cols.data(), static_cast<int>(edge_cols.size()), W,
                        fm.edge_dist.data() + static_cast<std::size_t>(v) * W);
        rowEdgeDistance(silhouette_cols.data(), static_cast<int>(silhouette_cols.size()), W,
                        fm.silhouette_dist.data() + static_cast<std::size_t>(v) * W);
      }
      row_valid[static_cast<std::size_t>(ty)] = n_valid;
      row_depth[static_cast<std::size_t>(ty)] = sum_depth;
    }
  }
  if (alongside_failure) std::rethrow_exception(alongside_failure);
  std::size_t n_valid = 0;
  double sum_depth = 0.0;
  for (int ty = 0; ty < fm.tiles_y; ++ty) {
    n_valid += row_valid[static_cast<std::size_t>(ty)];
    sum_depth += row_depth[static_cast<std::size_t>(ty)];
  }
  columnEdgeDistance(fm.edge_dist.data(), W, H);
  columnEdgeDistance(fm.silhouette_dist.data(), W, H);
  // Lateral reach of the truncation at the frame's mean depth, in tiles.
  if (n_valid > 0) {
    const double reach_px = trunc / (footprint * (sum_depth / static_cast<double>(n_valid)));
    dilateMin(fm.guard, fm.tiles_x, fm.tiles_y, static_cast<int>(std::ceil(reach_px / kGuardTile)));
  }
}

/// Pass 1b (per volume), parallel over rows: flags the pixels whose point lies in the band
/// (`in_band`, the others only carve) and allocates the blocks crossed by the ray segments of
/// in-band points within the truncation of their surface (|depth difference| * k <= trunc),
/// clipped to the band's voxels. Returns the in-band count.
/// The local AABB of the frustum between camera depths z0 and z1.
void frustumLocalBox(const Camera& cam, double z0, double z1, Eigen::Vector3d& lo,
                     Eigen::Vector3d& hi) {
  lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  hi = -lo;
  const double us[2] = {-0.5, cam.width - 0.5}, vs[2] = {-0.5, cam.height - 0.5};
  const double zs[2] = {z0, z1};
  for (const double z : zs)
    for (const double u : us)
      for (const double v : vs) {
        const Eigen::Vector3d pc(z * (u - cam.cx) / cam.fx, z * (v - cam.cy) / cam.fy, z);
        const Eigen::Vector3d pl = cam.R_cl_d.transpose() * (pc - cam.t_cl_d);
        lo = lo.cwiseMin(pl);
        hi = hi.cwiseMax(pl);
      }
}

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

/// One pixel of the allocation pass (the reference code; allocateRowAvx2 computes the same
/// values). Returns 1 when the pixel's point is in the band.
inline int allocatePixel(const AllocRow& r, int u, SegmentBlocks& segments) {
  r.flag[u] = 0;
  const float k = r.k[u];
  if (k == 0.0f) return 0;  // no measurement, or grazing (carves only)
  const float d = r.depth[u];
  // The ray in local coordinates per unit depth, and the point's height.
  const float xu = r.xn[u];
  const float dir[3] = {xu * r.dir_col[0] + r.dir_row[0], xu * r.dir_col[1] + r.dir_row[1],
                        xu * r.dir_col[2] + r.dir_row[2]};
  const float pz = r.t[2] + d * dir[2];
  if (!(pz >= r.band.pt_lo && pz <= r.band.pt_hi)) return 0;
  r.flag[u] = 1;
  // Segment over depths d + s of this pixel's ray, for the voxels it fuses: trunc / k in front
  // (distance trunc), behind up to the distance kBehindFraction * trunc and at most trunc in
  // depth; clipped to the band's voxels.
  float s0 = -r.trunc / k, s1 = std::min(r.trunc, -kBehindFraction * s0);
  if (dir[2] != 0.0f) {
    float sa = (r.band.alloc_lo - pz) / dir[2], sb = (r.band.alloc_hi - pz) / dir[2];
    if (sa > sb) std::swap(sa, sb);
    s0 = std::max(s0, sa);
    s1 = std::min(s1, sb);
  }
  if (s0 > s1) return 1;
  const float a0 = (d + s0) * r.inv_bs, a1 = (d + s1) * r.inv_bs;
  segments.add(
      Eigen::Vector3f(r.t_bs[0] + a0 * dir[0], r.t_bs[1] + a0 * dir[1], r.t_bs[2] + a0 * dir[2]),
      Eigen::Vector3f(r.t_bs[0] + a1 * dir[0], r.t_bs[1] + a1 * dir[1], r.t_bs[2] + a1 * dir[2]));
  return 1;
}

#if PLANESDF_AVX2_KERNEL
/// allocatePixel for a row, 8 pixels at a time (AVX2, no FMA: every lane performs the scalar
/// code's operations in the same order, so flags and segments are bit-identical). A group whose
/// segments' block box lies inside a box already known to be allocated skips the segments (they
/// cannot add a block). Returns the in-band count.
__attribute__((target("avx2"))) int allocateRowAvx2(const AllocRow& r, SegmentBlocks& segments) {
  int count = 0, u = 0;
  const __m256 zero = _mm256_setzero_ps();
  for (; u + 8 <= r.W; u += 8) {
    const __m256 k = _mm256_loadu_ps(r.k + u);
    __m256 m = _mm256_cmp_ps(k, zero, _CMP_NEQ_UQ);
    if (_mm256_movemask_ps(m) == 0) {
      std::memset(r.flag + u, 0, 8);
      continue;
    }
    const __m256 d = _mm256_loadu_ps(r.depth + u);
    const __m256 xu = _mm256_loadu_ps(r.xn + u);
    __m256 dir[3];
    for (int i = 0; i < 3; ++i)
      dir[i] = _mm256_add_ps(_mm256_mul_ps(xu, _mm256_set1_ps(r.dir_col[i])),
                             _mm256_set1_ps(r.dir_row[i]));
    const __m256 pz = _mm256_add_ps(_mm256_set1_ps(r.t[2]), _mm256_mul_ps(d, dir[2]));
    m = _mm256_and_ps(m,
                      _mm256_and_ps(_mm256_cmp_ps(pz, _mm256_set1_ps(r.band.pt_lo), _CMP_GE_OQ),
                                    _mm256_cmp_ps(pz, _mm256_set1_ps(r.band.pt_hi), _CMP_LE_OQ)));
    const int in_band = _mm256_movemask_ps(m);
    for (int i = 0; i < 8; ++i) r.flag[u + i] = static_cast<std::uint8_t>((in_band >> i) & 1);
    if (in_band == 0) continue;
    count += __builtin_popcount(static_cast<unsigned>(in_band));
    const __m256 trunc = _mm256_set1_ps(r.trunc);
    __m256 s0 = _mm256_div_ps(_mm256_set1_ps(-r.trunc), k);
    __m256 s1 = _mm256_min_ps(_mm256_mul_ps(_mm256_set1_ps(-kBehindFraction), s0), trunc);
    const __m256 sa = _mm256_div_ps(_mm256_sub_ps(_mm256_set1_ps(r.band.alloc_lo), pz), dir[2]);
    const __m256 sb = _mm256_div_ps(_mm256_sub_ps(_mm256_set1_ps(r.band.alloc_hi), pz), dir[2]);
    const __m256 swap = _mm256_cmp_ps(sa, sb, _CMP_GT_OQ);
    const __m256 lo = _mm256_blendv_ps(sa, sb, swap), hi = _mm256_blendv_ps(sb, sa, swap);
    const __m256 clip = _mm256_cmp_ps(dir[2], zero, _CMP_NEQ_UQ);
    s0 = _mm256_blendv_ps(s0, _mm256_max_ps(lo, s0), clip);
    s1 = _mm256_blendv_ps(s1, _mm256_min_ps(hi, s1), clip);
    const int seg = in_band & ~_mm256_movemask_ps(_mm256_cmp_ps(s0, s1, _CMP_GT_OQ));
    if (seg == 0) continue;
    const __m256 inv_bs = _mm256_set1_ps(r.inv_bs);
    const __m256 a0 = _mm256_mul_ps(_mm256_add_ps(d, s0), inv_bs);
    const __m256 a1 = _mm256_mul_ps(_mm256_add_ps(d, s1), inv_bs);
    alignas(32) float A[3][8], B[3][8];
    alignas(32) int ia[3][8], ib[3][8];
    for (int i = 0; i < 3; ++i) {
      const __m256 tb = _mm256_set1_ps(r.t_bs[i]);
      const __m256 pa = _mm256_add_ps(tb, _mm256_mul_ps(a0, dir[i]));
      const __m256 pb = _mm256_add_ps(tb, _mm256_mul_ps(a1, dir[i]));
      _mm256_store_ps(A[i], pa);
      _mm256_store_ps(B[i], pb);
      // floorToInt: truncate, minus one where that rounded up.
      const __m256i ta = _mm256_cvttps_epi32(pa), tb_ = _mm256_cvttps_epi32(pb);
      _mm256_store_si256(reinterpret_cast<__m256i*>(ia[i]),
                         _mm256_add_epi32(ta, _mm256_castps_si256(_mm256_cmp_ps(
                                                  pa, _mm256_cvtepi32_ps(ta), _CMP_LT_OQ))));
      _mm256_store_si256(reinterpret_cast<__m256i*>(ib[i]),
                         _mm256_add_epi32(tb_, _mm256_castps_si256(_mm256_cmp_ps(
                                                   pb, _mm256_cvtepi32_ps(tb_), _CMP_LT_OQ))));
    }
    Eigen::Vector3i box_lo = Eigen::Vector3i::Constant(std::numeric_limits<int>::max());
    Eigen::Vector3i box_hi = Eigen::Vector3i::Constant(std::numeric_limits<int>::min());
    for (int l = 0; l < 8; ++l) {
      if (!((seg >> l) & 1)) continue;
      for (int i = 0; i < 3; ++i) {
        box_lo[i] = std::min({box_lo[i], ia[i][l], ib[i][l]});
        box_hi[i] = std::max({box_hi[i], ia[i][l], ib[i][l]});
      }
    }
    if (segments.boxKnown(box_lo, box_hi)) continue;
    for (int l = 0; l < 8; ++l)
      if ((seg >> l) & 1)
        segments.add(Eigen::Vector3f(A[0][l], A[1][l], A[2][l]),
                     Eigen::Vector3f(B[0][l], B[1][l], B[2][l]));
    segments.noteBox(box_lo, box_hi);
  }
  for (; u < r.W; ++u) count += allocatePixel(r, u, segments);
  return count;
}
#endif

std::size_t allocateInBand(TsdfVolume& vol, const std::vector<float>& depth_img,
                           const std::vector<float>& k_exact, const FrameMeasurements& fm,
                           const Camera& cam, const Band& band, int threads, bool simd,
                           BlockGrid& grid, std::vector<std::uint8_t>& in_band, const Config& cfg,
                           std::vector<Eigen::Vector3i>& allocated) {
  const int W = cam.width, H = cam.height;
  const float trunc = static_cast<float>(vol.truncation());
  const float inv_bs = static_cast<float>(1.0 / vol.blockSize());
  const Eigen::Matrix3f& R = cam.R_lc;
  const Eigen::Vector3f& t = cam.t_lc;
  in_band.resize(static_cast<std::size_t>(W) * H + kGatherPadding);
  std::vector<std::vector<std::uint64_t>> new_keys(threads);
  // The block cells segments can reach: the frustum out to z_max + trunc, the allocation band,
  // one block of margin. (Segments leaving it still work, through hash lookups.)
  {
    Eigen::Vector3d lo, hi;
    frustumLocalBox(cam, cam.z_min, static_cast<double>(cam.z_max) + trunc, lo, hi);
    lo.z() = std::max(lo.z(), static_cast<double>(band.alloc_lo));
    hi.z() = std::min(hi.z(), static_cast<double>(band.alloc_hi));
    const double bs = vol.blockSize();
    const auto cell = [&](double x) {  // clamped well inside int
      return static_cast<int>(std::clamp(std::floor(x / bs), -1e9, 1e9));
    };
    if (lo.allFinite() && hi.allFinite())
      grid.reset(vol, Eigen::Vector3i(cell(lo.x()), cell(lo.y()), cell(lo.z())).array() - 1,
                 Eigen::Vector3i(cell(hi.x()), cell(hi.y()), cell(hi.z())).array() + 1);
    else
      grid.clear();  // a non-finite pose: no grid
  }
  std::size_t count = 0;
#pragma omp parallel num_threads(threads) if (threads > 1) reduction(+ : count)
  {
    SegmentBlocks segments(vol, grid);
#pragma omp for schedule(dynamic, 8)
    for (int v = 0; v < H; ++v) {
      const float yn = fm.yn[v];
      const std::size_t row = static_cast<std::size_t>(v) * W;
      const AllocRow r{depth_img.data() + row,
                       k_exact.data() + row,
                       fm.xn.data(),
                       in_band.data() + row,
                       W,
                       {R(0, 0), R(1, 0), R(2, 0)},
                       {yn * R(0, 1) + R(0, 2), yn * R(1, 1) + R(1, 2), yn * R(2, 1) + R(2, 2)},
                       {t.x(), t.y(), t.z()},
                       {t.x() * inv_bs, t.y() * inv_bs, t.z() * inv_bs},
                       trunc,
                       inv_bs,
                       band};
#if PLANESDF_AVX2_KERNEL
      if (simd) {
        count += static_cast<std::size_t>(allocateRowAvx2(r, segments));
        continue;
      }
#endif
      for (int u = 0; u < W; ++u) count += static_cast<std::size_t>(allocatePixel(r, u, segments));
    }
    new_keys[omp_get_thread_num()] = segments.newKeys();
  }
  allocated = allocateKeys(vol, new_keys, cfg);
  return count;
}

/// Slots of the allocated blocks that may hold a voxel centre in the frustum's local AABB and
/// the voxel band, in slot order. Enumerates the AABB's block cells or scans all blocks,
/// whichever is fewer.
std::vector<std::uint32_t> frustumCandidates(const TsdfVolume& vol, const Camera& cam,
                                             const Band& band, const BlockGrid& grid) {
  std::vector<std::uint32_t> slots;
  Eigen::Vector3i vlo, vhi;
  if (!vol.blockBounds(&vlo, &vhi)) return slots;
  Eigen::Vector3d lo, hi;
  frustumLocalBox(cam, cam.z_min, cam.z_max, lo, hi);
  lo.z() = std::max(lo.z(), static_cast<double>(band.vox_lo));
  hi.z() = std::min(hi.z(), static_cast<double>(band.vox_hi));
  if ((lo.array() > hi.array()).any()) return slots;
  const double bs = vol.blockSize();
  const auto cell = [&](double x) { return static_cast<int>(std::floor(x / bs)); };
  const Eigen::Vector3i blo =
      Eigen::Vector3i(cell(lo.x()), cell(lo.y()), cell(lo.z())).cwiseMax(vlo);
  const Eigen::Vector3i bhi =
      Eigen::Vector3i(cell(hi.x()), cell(hi.y()), cell(hi.z())).cwiseMin(vhi);
  if ((blo.array() > bhi.array()).any()) return slots;
  const Eigen::Vector3d extent = (bhi - blo).cast<double>().array() + 1.0;
  const double cells = extent.prod();
  if (cells <= static_cast<double>(vol.numBlocks())) {
    for (int z = blo.z(); z <= bhi.z(); ++z)
      for (int y = blo.y(); y <= bhi.y(); ++y)
        for (int x = blo.x(); x <= bhi.x(); ++x) {
          const Eigen::Vector3i b(x, y, z);
          // The frame's grid knows every allocated block it covers: no lookup for empty cells.
          const std::ptrdiff_t g = grid.find(b);
          if (g >= 0 && !grid.known(g)) continue;
          const std::ptrdiff_t s = vol.blockSlot(b);
          if (s >= 0) slots.push_back(static_cast<std::uint32_t>(s));
        }
    std::sort(slots.begin(), slots.end());
  } else {
    for (std::size_t s = 0; s < vol.numBlocks(); ++s) {
      const Eigen::Vector3i& b = vol.blockIndex(s);
      if ((b.array() >= blo.array()).all() && (b.array() <= bhi.array()).all())
        slots.push_back(static_cast<std::uint32_t>(s));
    }
  }
  return slots;
}

/// Indices into `slots` ordered by the image tile their block centre projects to (row-major
/// tiles of 32 px; blocks behind the camera last), so that consecutive blocks read nearby pixel
/// measurements from cache. Ties keep slot order (deterministic).
std::vector<std::uint32_t> imageOrder(const TsdfVolume& vol,
                                      const std::vector<std::uint32_t>& slots, const Camera& cam) {
  constexpr double kTile = 32.0;
  const double half = 0.5 * vol.blockSize();
  const int tiles_x = static_cast<int>(std::ceil(cam.width / kTile)) + 2;
  const int tiles_y = static_cast<int>(std::ceil(cam.height / kTile)) + 2;
  const std::int64_t behind = static_cast<std::int64_t>(tiles_y) * tiles_x;  // the last bucket
  std::vector<std::int64_t> keyed(slots.size());
  for (std::size_t i = 0; i < slots.size(); ++i) {
    const Eigen::Vector3d c_local =
        vol.blockIndex(slots[i]).cast<double>() * vol.blockSize() + Eigen::Vector3d::Constant(half);
    const Eigen::Vector3d c = cam.R_cl_d * c_local + cam.t_cl_d;
    std::int64_t key = behind;
    if (c.z() > 1e-6) {
      const double u = cam.fx * c.x() / c.z() + cam.cx, v = cam.fy * c.y() / c.z() + cam.cy;
      const auto tile = [&](double x, int n) {
        return std::clamp(static_cast<int>(std::floor(x / kTile)) + 1, 0, n);
      };
      const int ty = tile(v, tiles_y - 1);
      key = static_cast<std::int64_t>(ty) * tiles_x + tile(u, tiles_x - 1);
    }
    keyed[i] = key;
  }
  // Counting sort by tile (stable: ties keep slot order).
  std::vector<std::uint32_t> start(static_cast<std::size_t>(behind) + 2, 0);
  for (const std::int64_t k : keyed) ++start[static_cast<std::size_t>(k) + 1];
  for (std::size_t b = 1; b < start.size(); ++b) start[b] += start[b - 1];
  std::vector<std::uint32_t> order(slots.size());
  for (std::size_t i = 0; i < keyed.size(); ++i)
    order[start[static_cast<std::size_t>(keyed[i])]++] = static_cast<std::uint32_t>(i);
  return order;
}

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

/// Fuses the row of kTsdfBlockSide voxels whose first centre is (rx, ry, rz) in camera
/// coordinates (the reference implementation; fuseRowAvx2 gives bit-identical results).
inline void fuseRowScalar(const RowKernel& k, float rx, float ry, float rz, TsdfVoxel* voxels,
                          BlockOutcome& out) {
  for (int x = 0; x < kTsdfBlockSide; ++x) {
    const float fxx = static_cast<float>(x);
    const float px = rx + fxx * k.ax_x, py = ry + fxx * k.ax_y, zc = rz + fxx * k.ax_z;
    if (!(zc >= k.z_min && zc <= k.z_max)) continue;
    const float inv = 1.0f / zc;
    const float uf = k.fx * px * inv + k.cx;
    const float vf = k.fy * py * inv + k.cy;
    if (!(uf >= -0.5f && uf < k.w_lim && vf >= -0.5f && vf < k.h_lim)) continue;
    out.in_view = true;
    const int ui = std::min(static_cast<int>(uf + 0.5f), k.W - 1);
    const int vi = std::min(static_cast<int>(vf + 0.5f), k.H - 1);
    const std::size_t pix = static_cast<std::size_t>(vi) * k.W + ui;
    const PixelMeasurement m = k.pixels[pix];
    if (m.dq == 0) continue;
    // The pixel's normalised coordinates, computed as analysePixels tabulates them.
    const float xn = (static_cast<float>(ui) - k.cx) * k.inv_fx;
    const float yn = (static_cast<float>(vi) - k.cy) * k.inv_fy;
    const float q = (m.nx * (px - xn * zc) + m.ny * (py - yn * zc)) * (1.0f / kNormalScale) +
                    (m.dq * k.depth_scale - zc);
    if (q < -k.trunc) continue;  // behind the surface by more than the truncation (in depth)
    const float cos_ray = static_cast<float>(m.kq < 0 ? -m.kq : m.kq) * (1.0f / kCosineScale);
    float sdf = cos_ray * q;
    if (sdf < -k.behind) continue;  // deeper behind the surface than the band behind it
    // Silhouette guard: |sdf| (at most trunc) against the lateral distance to an edge.
    if (k.guard_near && std::fabs(sdf) > k.guard_sdf &&
        k.guard[(vi >> kGuardTileShift) * k.tiles_x + (ui >> kGuardTileShift)] <= zc + k.trunc) {
      if (sdf > 0.0f) {
        if (std::min(sdf, k.trunc) * k.edge_scale > k.edge_dist[pix] * zc) continue;
      } else if (k.guard_behind) {
        // Behind: only a silhouette can put the voxel beyond the object's hidden side, and
        // only if it lies within |sdf| * sin(angle between ray and surface) of the voxel's
        // line of sight (the ray meets the surface |sdf| / cos before the voxel).
        const float sin_ray = std::sqrt(std::max(0.0f, 1.0f - cos_ray * cos_ray));
        const float edge_px = k.silhouette_dist[pix] + kSilhouetteOffsetPx;
        if (std::min(-sdf, k.trunc) * sin_ray * k.edge_scale > edge_px * zc) continue;
      }
    }
    if (sdf >= k.trunc)
      sdf = k.trunc;
    else if (m.kq < 0 || !k.in_band[pix])
      continue;  // grazing or outside the band: carves free space only
    out.changed |= fuseVoxel(voxels[x], sdf, k.max_weight);
    ++out.updates;
  }
}

#if PLANESDF_AVX2_KERNEL
/// fuseRowScalar for the 8 voxels of a row at once (AVX2, no FMA: every lane performs the
/// scalar code's operations in the same order, so the results are bit-identical). Lanes that
/// the scalar code leaves by `continue` are masked out; gathers read only active lanes.
__attribute__((target("avx2"), always_inline)) inline void fuseRowAvx2(const RowKernel& k, float rx,
                                                                       float ry, float rz,
                                                                       TsdfVoxel* voxels,
                                                                       BlockOutcome& out) {
  static_assert(kTsdfBlockSide == 8, "one AVX2 vector per row of voxels");
  const __m256 xi = _mm256_setr_ps(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
  const __m256 px = _mm256_add_ps(_mm256_set1_ps(rx), _mm256_mul_ps(xi, _mm256_set1_ps(k.ax_x)));
  const __m256 py = _mm256_add_ps(_mm256_set1_ps(ry), _mm256_mul_ps(xi, _mm256_set1_ps(k.ax_y)));
  const __m256 zc = _mm256_add_ps(_mm256_set1_ps(rz), _mm256_mul_ps(xi, _mm256_set1_ps(k.ax_z)));
  __m256 m = _mm256_and_ps(_mm256_cmp_ps(zc, _mm256_set1_ps(k.z_min), _CMP_GE_OQ),
                           _mm256_cmp_ps(zc, _mm256_set1_ps(k.z_max), _CMP_LE_OQ));
  if (_mm256_movemask_ps(m) == 0) return;
  const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), zc);
  const __m256 uf = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(k.fx), px), inv),
                                  _mm256_set1_ps(k.cx));
  const __m256 vf = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(k.fy), py), inv),
                                  _mm256_set1_ps(k.cy));
  const __m256 lo = _mm256_set1_ps(-0.5f);
  m = _mm256_and_ps(m, _mm256_and_ps(_mm256_cmp_ps(uf, lo, _CMP_GE_OQ),
                                     _mm256_cmp_ps(uf, _mm256_set1_ps(k.w_lim), _CMP_LT_OQ)));
  m = _mm256_and_ps(m, _mm256_and_ps(_mm256_cmp_ps(vf, lo, _CMP_GE_OQ),
                                     _mm256_cmp_ps(vf, _mm256_set1_ps(k.h_lim), _CMP_LT_OQ)));
  if (_mm256_movemask_ps(m) == 0) return;
  out.in_view = true;
  const __m256 half = _mm256_set1_ps(0.5f);
  __m256i mi = _mm256_castps_si256(m);
  // Pixel indices (inactive lanes: 0, so that no index is ever out of range).
  const __m256i ui = _mm256_and_si256(
      mi,
      _mm256_min_epi32(_mm256_cvttps_epi32(_mm256_add_ps(uf, half)), _mm256_set1_epi32(k.W - 1)));
  const __m256i vi = _mm256_and_si256(
      mi,
      _mm256_min_epi32(_mm256_cvttps_epi32(_mm256_add_ps(vf, half)), _mm256_set1_epi32(k.H - 1)));
  const __m256i pix = _mm256_add_epi32(_mm256_mullo_epi32(vi, _mm256_set1_epi32(k.W)), ui);
  // PixelMeasurement as two 32-bit words: (nx | ny << 16) and (dq | kq << 16).
  const int* words = reinterpret_cast<const int*>(static_cast<const void*>(k.pixels));
  const __m256i pix2 = _mm256_slli_epi32(pix, 1);
  const __m256i zero = _mm256_setzero_si256();
  const __m256i w0 = _mm256_mask_i32gather_epi32(zero, words, pix2, mi, 4);
  const __m256i w1 = _mm256_mask_i32gather_epi32(zero, words + 1, pix2, mi, 4);
  const __m256i dq = _mm256_and_si256(w1, _mm256_set1_epi32(0xffff));
  const __m256i kq = _mm256_srai_epi32(w1, 16);
  mi = _mm256_andnot_si256(_mm256_cmpeq_epi32(dq, zero), mi);
  m = _mm256_castsi256_ps(mi);
  if (_mm256_movemask_ps(m) == 0) return;
  const __m256 nx = _mm256_cvtepi32_ps(_mm256_srai_epi32(_mm256_slli_epi32(w0, 16), 16));
  const __m256 ny = _mm256_cvtepi32_ps(_mm256_srai_epi32(w0, 16));
  const __m256 xn = _mm256_mul_ps(_mm256_sub_ps(_mm256_cvtepi32_ps(ui), _mm256_set1_ps(k.cx)),
                                  _mm256_set1_ps(k.inv_fx));
  const __m256 yn = _mm256_mul_ps(_mm256_sub_ps(_mm256_cvtepi32_ps(vi), _mm256_set1_ps(k.cy)),
                                  _mm256_set1_ps(k.inv_fy));
  const __m256 tangent = _mm256_add_ps(_mm256_mul_ps(nx, _mm256_sub_ps(px, _mm256_mul_ps(xn, zc))),
                                       _mm256_mul_ps(ny, _mm256_sub_ps(py, _mm256_mul_ps(yn, zc))));
  const __m256 q = _mm256_add_ps(
      _mm256_mul_ps(tangent, _mm256_set1_ps(1.0f / kNormalScale)),
      _mm256_sub_ps(_mm256_mul_ps(_mm256_cvtepi32_ps(dq), _mm256_set1_ps(k.depth_scale)), zc));
  const __m256 trunc = _mm256_set1_ps(k.trunc);
  m = _mm256_and_ps(m, _mm256_cmp_ps(q, _mm256_set1_ps(-k.trunc), _CMP_NLT_UQ));
  const __m256 cos_ray =
      _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_abs_epi32(kq)), _mm256_set1_ps(1.0f / kCosineScale));
  __m256 sdf = _mm256_mul_ps(cos_ray, q);
  m = _mm256_and_ps(m, _mm256_cmp_ps(sdf, _mm256_set1_ps(-k.behind), _CMP_NLT_UQ));
  if (_mm256_movemask_ps(m) == 0) return;
  // Silhouette guard.
  const __m256 abs_sdf = _mm256_andnot_ps(_mm256_set1_ps(-0.0f), sdf);
  __m256 g = _mm256_and_ps(m, _mm256_cmp_ps(abs_sdf, _mm256_set1_ps(k.guard_sdf), _CMP_GT_OQ));
  if (k.guard_near && _mm256_movemask_ps(g) != 0) {
    const __m256i tile = _mm256_add_epi32(
        _mm256_mullo_epi32(_mm256_srli_epi32(vi, kGuardTileShift), _mm256_set1_epi32(k.tiles_x)),
        _mm256_srli_epi32(ui, kGuardTileShift));
    const __m256 edge_depth = _mm256_mask_i32gather_ps(_mm256_setzero_ps(), k.guard, tile, g, 4);
    g = _mm256_and_ps(g, _mm256_cmp_ps(edge_depth, _mm256_add_ps(zc, trunc), _CMP_LE_OQ));
    const __m256 front = _mm256_and_ps(g, _mm256_cmp_ps(sdf, _mm256_setzero_ps(), _CMP_GT_OQ));
    const __m256i bytes = _mm256_set1_epi32(0xff);
    const __m256 edge_scale = _mm256_set1_ps(k.edge_scale);
    if (_mm256_movemask_ps(front) != 0) {
      const __m256i ed = _mm256_and_si256(
          bytes, _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(k.edge_dist), pix,
                                             _mm256_castps_si256(front), 1));
      const __m256 skip = _mm256_cmp_ps(_mm256_mul_ps(_mm256_min_ps(sdf, trunc), edge_scale),
                                        _mm256_mul_ps(_mm256_cvtepi32_ps(ed), zc), _CMP_GT_OQ);
      m = _mm256_andnot_ps(_mm256_and_ps(front, skip), m);
    }
    const __m256 behind = _mm256_andnot_ps(front, g);
    if (k.guard_behind && _mm256_movemask_ps(behind) != 0) {
      const __m256 sin_ray = _mm256_sqrt_ps(
          _mm256_max_ps(_mm256_sub_ps(_mm256_set1_ps(1.0f), _mm256_mul_ps(cos_ray, cos_ray)),
                        _mm256_setzero_ps()));
      const __m256i sd = _mm256_and_si256(
          bytes, _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(k.silhouette_dist),
                                             pix, _mm256_castps_si256(behind), 1));
      const __m256 edge_px =
          _mm256_add_ps(_mm256_cvtepi32_ps(sd), _mm256_set1_ps(kSilhouetteOffsetPx));
      const __m256 neg_sdf = _mm256_xor_ps(sdf, _mm256_set1_ps(-0.0f));
      const __m256 skip = _mm256_cmp_ps(
          _mm256_mul_ps(_mm256_mul_ps(_mm256_min_ps(neg_sdf, trunc), sin_ray), edge_scale),
          _mm256_mul_ps(edge_px, zc), _CMP_GT_OQ);
      m = _mm256_andnot_ps(_mm256_and_ps(behind, skip), m);
    }
  }
  // Free space clamps to trunc; nearer values need a fused (not grazing), in-band pixel.
  const __m256 free_space = _mm256_cmp_ps(sdf, trunc, _CMP_GE_OQ);
  sdf = _mm256_blendv_ps(sdf, trunc, free_space);
  const __m256 near = _mm256_andnot_ps(free_space, m);
  if (_mm256_movemask_ps(near) != 0) {
    const __m256i in_band =
        _mm256_and_si256(_mm256_set1_epi32(0xff),
                         _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(k.in_band),
                                                     pix, _mm256_castps_si256(near), 1));
    const __m256i fused = _mm256_andnot_si256(
        _mm256_or_si256(_mm256_cmpgt_epi32(zero, kq), _mm256_cmpeq_epi32(in_band, zero)),
        _mm256_castps_si256(near));
    m = _mm256_or_ps(_mm256_and_ps(m, free_space), _mm256_castsi256_ps(fused));
  }
  const int bits = _mm256_movemask_ps(m);
  if (bits == 0) return;
  // fuseVoxel on the active lanes. The row's 8 voxels (sdf, weight pairs) load as two vectors;
  // within 128-bit lanes, shuffling gives sdf and weight in voxel order 0 1 4 5 2 3 6 7, and
  // unpacking puts them back. The new values and the mask are permuted to that order.
  float* raw = &voxels[0].sdf;
  const __m256 v0 = _mm256_loadu_ps(raw), v1 = _mm256_loadu_ps(raw + 8);
  const __m256 old_s = _mm256_shuffle_ps(v0, v1, 0x88);
  const __m256 old_w = _mm256_shuffle_ps(v0, v1, 0xdd);
  const __m256i order = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
  const __m256 obs = _mm256_permutevar8x32_ps(sdf, order);
  const __m256 act = _mm256_permutevar8x32_ps(m, order);
  const __m256 w_plus = _mm256_add_ps(old_w, _mm256_set1_ps(1.0f));
  const __m256 new_w = _mm256_min_ps(w_plus, _mm256_set1_ps(k.max_weight));
  const __m256 new_s = _mm256_add_ps(old_s, _mm256_div_ps(_mm256_sub_ps(obs, old_s), w_plus));
  const __m256 differs = _mm256_or_ps(_mm256_cmp_ps(new_s, old_s, _CMP_NEQ_UQ),
                                      _mm256_cmp_ps(new_w, old_w, _CMP_NEQ_UQ));
  out.changed |= _mm256_movemask_ps(_mm256_and_ps(differs, act)) != 0;
  out.updates += static_cast<std::uint32_t>(__builtin_popcount(static_cast<unsigned>(bits)));
  const __m256 s_out = _mm256_blendv_ps(old_s, new_s, act);
  const __m256 w_out = _mm256_blendv_ps(old_w, new_w, act);
  _mm256_storeu_ps(raw, _mm256_unpacklo_ps(s_out, w_out));
  _mm256_storeu_ps(raw + 8, _mm256_unpackhi_ps(s_out, w_out));
}

/// fuseRowAvx2 for the kTsdfBlockSide rows of one slice of a block: the row's first centre
/// moves by `ay` from (sx, sy, sz); `voxels` is the slice's first voxel. One function, so that
/// the rows' independent work overlaps.
__attribute__((target("avx2"))) void fuseSliceAvx2(const RowKernel& k, float sx, float sy, float sz,
                                                   float ay_x, float ay_y, float ay_z,
                                                   TsdfVoxel* voxels, BlockOutcome& out) {
  for (int y = 0; y < kTsdfBlockSide; ++y)  // the next slice's rows (one cache line each)
    __builtin_prefetch(voxels + (kTsdfBlockSide + y) * kTsdfBlockSide, 1);
  for (int y = 0; y < kTsdfBlockSide; ++y) {
    const float fyy = static_cast<float>(y);
    fuseRowAvx2(k, sx + fyy * ay_x, sy + fyy * ay_y, sz + fyy * ay_z, voxels + y * kTsdfBlockSide,
                out);
  }
}
#endif

/// Pass 2 for one block (integer index `index`, from the volume's index array: reading
/// blk.index would miss the cache on the line after the voxels): projects its voxel centres
/// (memory order) and fuses them.
BlockOutcome updateBlockFromDepth(TsdfBlock& blk, const Eigen::Vector3i& index, const Camera& cam,
                                  const FrustumCull& cull, const DepthUpdateParams& prm) {
  BlockOutcome out;
  const double vs = prm.voxel;
  const Eigen::Vector3d c0_local = (index.cast<double>() * kTsdfBlockSide).array() * vs + 0.5 * vs;
  const Eigen::Vector3f c0 = (cam.R_cl_d * c0_local + cam.t_cl_d).cast<float>();
  const Eigen::Vector3f ax = cam.R_cl.col(0) * prm.voxel;
  const Eigen::Vector3f ay = cam.R_cl.col(1) * prm.voxel;
  const Eigen::Vector3f az = cam.R_cl.col(2) * prm.voxel;
  const float half = 0.5f * (kTsdfBlockSide - 1);
  const float radius = std::sqrt(3.0f) * half * prm.voxel * 1.0001f + 1e-6f;
  if (!cull.mayIntersect(c0 + half * (ax + ay + az), radius)) return out;

  const float w_lim = cam.width - 0.5f, h_lim = cam.height - 0.5f;
  const int W = cam.width, H = cam.height;
  const FrameMeasurements& fm = *prm.fm;
  const float fx = cam.fx, fy = cam.fy, cx = cam.cx, cy = cam.cy;
  const float trunc = prm.trunc;
  // Pixels per metre of lateral distance at unit depth (the smaller focal length: the lateral
  // distance is never overestimated).
  const float edge_scale = std::min(fx, fy);
  RowKernel kernel{fm.pixels.data(),
                   fm.guard.data(),
                   fm.edge_dist.data(),
                   fm.silhouette_dist.data(),
                   prm.in_band,
                   W,
                   H,
                   fm.tiles_x,
                   ax.x(),
                   ax.y(),
                   ax.z(),
                   fx,
                   fy,
                   cx,
                   cy,
                   1.0f / fx,
                   1.0f / fy,
                   cam.z_min,
                   cam.z_max,
                   w_lim,
                   h_lim,
                   trunc,
                   kBehindFraction * trunc,
                   kGuardSdf * prm.voxel,
                   edge_scale,
                   fm.depth_scale,
                   prm.max_weight,
                   prm.guard_behind};

  // Occlusion bound. Over the pixels the block's voxel centres can project to (nearest pixel,
  // inside the projected box of its corner centres), the largest measured depth dmax. A voxel
  // deeper than dmax + trunc + the tangent-plane term (|n'| * the voxel's lateral offset from its
  // pixel's ray, at most kTangentSlackPx pixel footprints) has q < -trunc: untouched. Slices of
  // the block beyond that are skipped whole (the result is identical).
  const float near_dz = (kTsdfBlockSide - 1) * (std::min(0.0f, ax.z()) + std::min(0.0f, ay.z()));
  float occluded_from = kInf;
  // Slice z of the block holds band voxels / lies wholly beyond the occlusion bound.
  const auto sliceInBand = [&](int z) {
    const float h = static_cast<float>(c0_local.z() + z * vs);
    return h >= prm.band.vox_lo && h <= prm.band.vox_hi;
  };
  {  // the first band slice's rows (one cache line each) are requested before the work below
    int z0 = 0;
    while (z0 < kTsdfBlockSide && !sliceInBand(z0)) ++z0;
    if (z0 < kTsdfBlockSide)
      for (int y = 0; y < kTsdfBlockSide; ++y)
        __builtin_prefetch(&blk.voxels[(z0 * kTsdfBlockSide + y) * kTsdfBlockSide], 1);
  }
  const auto sliceOccluded = [&](int z) {
    return c0.z() + static_cast<float>(z) * az.z() + near_dz > occluded_from;
  };
  {
    const float e = static_cast<float>(kTsdfBlockSide - 1);
    float umin = kInf, umax = -kInf, vmin = kInf, vmax = -kInf, zmax = -kInf;
    bool in_front = true;
    for (int i = 0; i < 8; ++i) {
      const Eigen::Vector3f p =
          c0 + ((i & 1) ? e : 0.0f) * ax + ((i & 2) ? e : 0.0f) * ay + ((i & 4) ? e : 0.0f) * az;
      if (!(p.z() > 1e-3f)) {
        in_front = false;
        break;
      }
      const float u = fx * p.x() / p.z() + cx, v = fy * p.y() / p.z() + cy;
      umin = std::min(umin, u);
      umax = std::max(umax, u);
      vmin = std::min(vmin, v);
      vmax = std::max(vmax, v);
      zmax = std::max(zmax, p.z());
    }
    if (in_front) {
      if (umax < -0.5f || umin >= w_lim || vmax < -0.5f || vmin >= h_lim) return out;
      const auto pixel = [](float x, int n) {
        return static_cast<int>(std::clamp(x + 0.5f, 0.0f, static_cast<float>(n - 1)));
      };
      const int tx0 = pixel(umin, W) >> kGuardTileShift, tx1 = pixel(umax, W) >> kGuardTileShift;
      const int ty0 = pixel(vmin, H) >> kGuardTileShift, ty1 = pixel(vmax, H) >> kGuardTileShift;
      float dmax = -kInf, gmin = kInf;
      for (int ty = ty0; ty <= ty1; ++ty)
        for (int tx = tx0; tx <= tx1; ++tx) {
          const std::size_t t = static_cast<std::size_t>(ty) * fm.tiles_x + tx;
          dmax = std::max(dmax, fm.tile_max_depth[t]);
          gmin = std::min(gmin, fm.guard[t]);
        }
      // The guard acts where its tile's edge depth <= zc + trunc; zc <= zmax (plus rounding).
      kernel.guard_near = gmin <= zmax + trunc + 1e-3f;
      occluded_from = dmax + trunc + kTangentSlackPx * zmax / edge_scale + 1e-3f;
      // The measurements the voxel loop will gather, requested ahead (one cache line = 8 px),
      // unless every slice of the block is occluded (see below).
      bool any_slice = false;
      for (int z = 0; z < kTsdfBlockSide && !any_slice; ++z)
        any_slice = sliceInBand(z) && !sliceOccluded(z);
      if (any_slice) {
        const int u0 = pixel(umin, W), u1 = pixel(umax, W);
        for (int v = pixel(vmin, H); v <= pixel(vmax, H); ++v)
          for (int u = u0; u <= u1 + 7; u += 8)
            __builtin_prefetch(fm.pixels.data() + static_cast<std::size_t>(v) * W +
                               std::min(u, u1));
      }
    }
  }
  // True when a voxel centre of slice z projects into the image within the depth range.
  const auto sliceInView = [&](int z) {
    for (int y = 0; y < kTsdfBlockSide; ++y)
      for (int x = 0; x < kTsdfBlockSide; ++x) {
        const Eigen::Vector3f p = c0 + static_cast<float>(x) * ax + static_cast<float>(y) * ay +
                                  static_cast<float>(z) * az;
        if (!(p.z() >= cam.z_min && p.z() <= cam.z_max)) continue;
        const float uf = fx * p.x() / p.z() + cx, vf = fy * p.y() / p.z() + cy;
        if (uf >= -0.5f && uf < w_lim && vf >= -0.5f && vf < h_lim) return true;
      }
    return false;
  };

  for (int z = 0; z < kTsdfBlockSide; ++z) {
    if (!sliceInBand(z)) continue;
    if (sliceOccluded(z)) {
      if (!out.in_view) out.in_view = sliceInView(z);
      continue;
    }
    const float fz = static_cast<float>(z);
    const float sx = c0.x() + fz * az.x(), sy = c0.y() + fz * az.y(), sz = c0.z() + fz * az.z();
    TsdfVoxel* slice = &blk.voxels[z * kTsdfBlockSide * kTsdfBlockSide];
#if PLANESDF_AVX2_KERNEL
    if (prm.simd) {
      fuseSliceAvx2(kernel, sx, sy, sz, ay.x(), ay.y(), ay.z(), slice, out);
      continue;
    }
#endif
    for (int y = 0; y < kTsdfBlockSide; ++y) {
      const float fyy = static_cast<float>(y);
      fuseRowScalar(kernel, sx + fyy * ay.x(), sy + fyy * ay.y(), sz + fyy * ay.z(),
                    slice + y * kTsdfBlockSide, out);
    }
  }
  return out;
}

/// Gathers per-block outcomes into `res`, bumps the revision and stamps changed blocks.
void finishIntegration(TsdfVolume& vol, const std::vector<std::uint32_t>& slots,
                       const std::vector<BlockOutcome>& outcomes, IntegrationResult& res) {
  std::vector<std::uint32_t> changed;
  for (std::size_t i = 0; i < slots.size(); ++i) {
    const BlockOutcome& o = outcomes[i];
    res.num_voxel_updates += o.updates;
    if (o.in_view) res.updated_blocks.push_back(vol.blockIndex(slots[i]));
    if (o.changed) changed.push_back(slots[i]);
  }
  if (changed.empty() && res.allocated_blocks.empty()) return;
  const std::uint64_t rev = vol.bumpRevision();
  for (const std::uint32_t s : changed) {
    vol.block(s).revision = rev;
    res.changed_blocks.push_back(vol.blockIndex(s));
  }
  for (const Eigen::Vector3i& b : res.allocated_blocks) vol.findBlock(b)->revision = rev;
}

void validateFrame(const DepthFrame& frame) {
  frame.intrinsics.validate("depth frame");
  const std::size_t expected =
      static_cast<std::size_t>(frame.intrinsics.width) * frame.intrinsics.height;
  if (frame.depth.size() != expected)
    throw Error("", "depth frame: " + std::to_string(frame.depth.size()) + " depth values for a " +
                        std::to_string(frame.intrinsics.width) + "x" +
                        std::to_string(frame.intrinsics.height) + " image");
}

// ---- splatting ------------------------------------------------------------------------------

struct Splat {
  Eigen::Vector3f p, n;
  float front = 0.0f;        // how far in front of p (along n) voxels are updated, >= trunc
  Eigen::Vector3i vlo, vhi;  // inclusive global voxel range the splat may touch
};

/// The splat of point i, or false when the point is skipped (invalid, zero normal, out of band).
bool makeSplat(const Eigen::Vector3f& p, const Eigen::Vector3f& n_raw, float trunc, float front,
               float r_lat, float voxel, const Band& band, Splat* s) {
  if (!p.allFinite() || !n_raw.allFinite()) return false;
  const float len = n_raw.norm();
  if (!(len > 1e-12f)) return false;
  if (!(p.z() >= band.pt_lo && p.z() <= band.pt_hi)) return false;
  s->p = p;
  s->n = n_raw / len;
  s->front = std::isfinite(front) ? std::max(front, trunc) : trunc;
  const Eigen::Vector3f e = s->front * s->n.cwiseAbs() + Eigen::Vector3f::Constant(r_lat);
  Eigen::Vector3f lo = p - e, hi = p + e;
  lo.z() = std::max(lo.z(), band.vox_lo);
  hi.z() = std::min(hi.z(), band.vox_hi);
  for (int i = 0; i < 3; ++i) {
    s->vlo[i] = -floorToInt(-(lo[i] / voxel - 0.5f));  // ceil
    s->vhi[i] = floorToInt(hi[i] / voxel - 0.5f);
  }
  return (s->vlo.array() <= s->vhi.array()).all() &&
         blockIndexInRange(TsdfVolume::blockOfVoxel(s->vlo)) &&
         blockIndexInRange(TsdfVolume::blockOfVoxel(s->vhi));
}

/// Applies splat `s` to the voxels of `blk`; returns the number of voxel updates.
std::uint32_t applySplat(TsdfBlock& blk, const Splat& s, float trunc, float r2, float voxel,
                         float max_weight, bool* changed) {
  const Eigen::Vector3i b0 = blk.index * kTsdfBlockSide;
  const Eigen::Vector3i lo = s.vlo.cwiseMax(b0);
  const Eigen::Vector3i hi = s.vhi.cwiseMin(b0 + Eigen::Vector3i::Constant(kTsdfBlockSide - 1));
  std::uint32_t updates = 0;
  for (int z = lo.z(); z <= hi.z(); ++z)
    for (int y = lo.y(); y <= hi.y(); ++y)
      for (int x = lo.x(); x <= hi.x(); ++x) {
        const Eigen::Vector3f d =
            (Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)) +
             Eigen::Vector3f::Constant(0.5f)) *
                voxel -
            s.p;
        const float t = s.n.dot(d);
        if (t < -trunc || t > s.front || d.squaredNorm() - t * t > r2) continue;
        TsdfVoxel& v = blk.voxels[TsdfVolume::linearIndexInBlock(Eigen::Vector3i(x, y, z))];
        *changed |= fuseVoxel(v, std::min(t, trunc), max_weight);
        ++updates;
      }
  return updates;
}

}  // namespace

void validateFusionConfig(const Config& cfg) {
  const auto bad = [](const std::string& m) { throw Error("", "fusion config: " + m); };
  if (!(std::isfinite(cfg.fuse_band) && cfg.fuse_band >= 0.0)) bad("fuse_band must be >= 0");
  if (!(std::isfinite(cfg.below_band) && cfg.below_band >= 0.0)) bad("below_band must be >= 0");
  if (!(std::isfinite(cfg.min_depth) && cfg.min_depth >= 0.0)) bad("min_depth must be >= 0");
  if (!(std::isfinite(cfg.max_depth) && cfg.max_depth > cfg.min_depth))
    bad("max_depth must be finite and > min_depth");
  if (!(cfg.surface_max_depth > cfg.min_depth)) bad("surface_max_depth must be > min_depth");
  if (!(std::isfinite(cfg.max_weight) && cfg.max_weight >= 1.0f)) bad("max_weight must be >= 1");
}

struct DepthFrameAnalysis::Impl {
  FrameMeasurements fm;
  std::vector<float> depth;  ///< the frame's depths (exact, for allocation)
  std::vector<float> k;      ///< per pixel k (0: invalid or grazing)
  Intrinsics intrinsics;
  float truncation = 0.0f;
  float z_min = 0.0f, z_max = 0.0f;
  float z_surface = 0.0f;  ///< cfg.surface_max_depth it was made for
  int threads = 1;
};

DepthFrameAnalysis::DepthFrameAnalysis() = default;
DepthFrameAnalysis::~DepthFrameAnalysis() = default;
DepthFrameAnalysis::DepthFrameAnalysis(DepthFrameAnalysis&&) noexcept = default;
DepthFrameAnalysis& DepthFrameAnalysis::operator=(DepthFrameAnalysis&&) noexcept = default;
DepthFrameAnalysis::DepthFrameAnalysis(const DepthFrameAnalysis& o)
    : impl_(o.impl_ ? std::make_unique<Impl>(*o.impl_) : nullptr) {}
DepthFrameAnalysis& DepthFrameAnalysis::operator=(const DepthFrameAnalysis& o) {
  if (this != &o) impl_ = o.impl_ ? std::make_unique<Impl>(*o.impl_) : nullptr;
  return *this;
}

void DepthFrameAnalysis::analyse(const DepthFrame& frame, double truncation, const Config& cfg) {
  analyseImpl(frame, truncation, cfg, nullptr);
}

void DepthFrameAnalysis::analyse(const DepthFrame& frame, double truncation, const Config& cfg,
                                 const std::function<void()>& alongside) {
  analyseImpl(frame, truncation, cfg, &alongside);
}

void DepthFrameAnalysis::analyseImpl(const DepthFrame& frame, double truncation, const Config& cfg,
                                     const std::function<void()>* alongside) {
  validateFrame(frame);
  validateFusionConfig(cfg);
  if (!(std::isfinite(truncation) && truncation > 0.0))
    throw Error("", "depth frame analysis: truncation must be > 0");
  if (!impl_) impl_ = std::make_unique<Impl>();
  Impl& a = *impl_;
  a.intrinsics = frame.intrinsics;
  a.truncation = static_cast<float>(truncation);
  a.threads = resolveThreads(cfg.threads);
  const Camera cam = makeCamera(frame.intrinsics, Pose::Identity(), cfg);
  a.z_min = cam.z_min;
  a.z_max = cam.z_max;
  a.z_surface = cam.z_surface;
  a.depth = frame.depth;
  analysePixels(frame, cam, a.truncation, a.threads, a.fm, a.k, alongside);
}

bool DepthFrameAnalysis::empty() const {
  return !impl_;
}

IntegrationResult integrateDepth(TsdfVolume& vol, const DepthFrameAnalysis& analysis,
                                 const Pose& T_local_camera, const Config& cfg) {
  if (!analysis.impl_) throw Error("", "depth frame analysis: analyse() was not called");
  validateFusionConfig(cfg);
  const DepthFrameAnalysis::Impl& a = *analysis.impl_;
  const Camera cam = makeCamera(a.intrinsics, T_local_camera, cfg);
  if (static_cast<float>(vol.truncation()) != a.truncation || cam.z_min != a.z_min ||
      cam.z_max != a.z_max || cam.z_surface != a.z_surface)
    throw Error("", "depth frame analysis: made for truncation " + std::to_string(a.truncation) +
                        " m and depths [" + std::to_string(a.z_min) + ", " +
                        std::to_string(a.z_max) + "] m, used with truncation " +
                        std::to_string(vol.truncation()) + " m and depths [" +
                        std::to_string(cam.z_min) + ", " + std::to_string(cam.z_max) +
                        "] m (or another surface_max_depth)");
  IntegrationResult res;
  const int threads = resolveThreads(cfg.threads);
  const Band band = makeBand(cfg, vol.voxelSize(), vol.truncation());
  // Per-thread scratch reused across calls (every entry is rewritten): no large allocation and
  // page faulting per call.
  thread_local std::vector<std::uint8_t> in_band;
  thread_local BlockGrid grid;  // the block cells around the frustum (see allocateInBand)
  const bool simd = cfg.simd && detail::cpuHasAvx2();
  res.num_points_fused = allocateInBand(vol, a.depth, a.k, a.fm, cam, band, threads, simd, grid,
                                        in_band, cfg, res.allocated_blocks);
  const std::vector<std::uint32_t> slots = frustumCandidates(vol, cam, band, grid);
  std::vector<BlockOutcome> outcomes(slots.size());
  const FrustumCull cull(cam);
  DepthUpdateParams prm{&a.fm,
                        in_band.data(),
                        static_cast<float>(vol.truncation()),
                        cfg.max_weight,
                        static_cast<float>(vol.voxelSize()),
                        band,
                        cfg.silhouette_guard_behind,
                        simd};
  const std::vector<std::uint32_t> order = imageOrder(vol, slots, cam);
  const int n = static_cast<int>(order.size());
#pragma omp parallel for num_threads(threads) if (threads > 1) schedule(dynamic, 4)
  for (int i = 0; i < n; ++i) {
    const std::uint32_t j = order[i];
    outcomes[j] =
        updateBlockFromDepth(vol.block(slots[j]), vol.blockIndex(slots[j]), cam, cull, prm);
  }
  finishIntegration(vol, slots, outcomes, res);
  return res;
}

IntegrationResult integrateDepth(TsdfVolume& vol, const DepthFrame& frame,
                                 const Pose& T_local_camera, const Config& cfg) {
  // Per-thread scratch reused across calls: no large allocation and page faulting per frame.
  thread_local DepthFrameAnalysis analysis;
  analysis.analyse(frame, vol.truncation(), cfg);
  return integrateDepth(vol, analysis, T_local_camera, cfg);
}

IntegrationResult integratePointsWithNormals(TsdfVolume& vol,
                                             const std::vector<Eigen::Vector3f>& points_local,
                                             const std::vector<Eigen::Vector3f>& normals_local,
                                             const Config& cfg,
                                             const std::vector<float>* front_local) {
  if (points_local.size() != normals_local.size() ||
      (front_local && front_local->size() != points_local.size()))
    throw Error("", "splat integration: " + std::to_string(points_local.size()) + " points but " +
                        std::to_string(normals_local.size()) + " normals" +
                        (front_local ? " and " + std::to_string(front_local->size()) + " reaches"
                                     : std::string()));
  validateFusionConfig(cfg);
  if (!(std::isfinite(cfg.splat_radius_voxels) && cfg.splat_radius_voxels > 0.0))
    throw Error("", "fusion config: splat_radius_voxels must be > 0");
  IntegrationResult res;
  const Band band = makeBand(cfg, vol.voxelSize(), vol.truncation());
  const float trunc = static_cast<float>(vol.truncation());
  const float voxel = static_cast<float>(vol.voxelSize());
  const float r_lat = static_cast<float>(cfg.splat_radius_voxels) * voxel;

  // Pass 1: splats, the blocks each may touch (local block ids), and allocation.
  std::vector<Splat> splats;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> touches;  // (local block id, splat)
  BlockHashMap ids;
  std::vector<std::uint64_t> keys;
  for (std::size_t i = 0; i < points_local.size(); ++i) {
    Splat s;
    const float front = front_local ? (*front_local)[i] : trunc;
    if (!makeSplat(points_local[i], normals_local[i], trunc, front, r_lat, voxel, band, &s))
      continue;
    const auto si = static_cast<std::uint32_t>(splats.size());
    splats.push_back(s);
    const Eigen::Vector3i blo = TsdfVolume::blockOfVoxel(s.vlo);
    const Eigen::Vector3i bhi = TsdfVolume::blockOfVoxel(s.vhi);
    for (int z = blo.z(); z <= bhi.z(); ++z)
      for (int y = blo.y(); y <= bhi.y(); ++y)
        for (int x = blo.x(); x <= bhi.x(); ++x) {
          const std::uint64_t key = packBlockKey(Eigen::Vector3i(x, y, z));
          const auto [id, inserted] = ids.insert(key, static_cast<std::uint32_t>(keys.size()));
          if (inserted) keys.push_back(key);
          touches.emplace_back(id, si);
        }
  }
  res.num_points_fused = splats.size();
  {
    std::vector<std::vector<std::uint64_t>> fresh(1);
    for (const std::uint64_t k : keys)
      if (vol.blockSlot(unpackBlockKey(k)) < 0) fresh[0].push_back(k);
    res.allocated_blocks = allocateKeys(vol, fresh, cfg);
  }

  // Block order = slot order; per block, its splats in input order (counting sort).
  std::vector<std::pair<std::uint32_t, std::uint32_t>> order(keys.size());  // (slot, id)
  for (std::size_t id = 0; id < keys.size(); ++id)
    order[id] = {static_cast<std::uint32_t>(vol.blockSlot(unpackBlockKey(keys[id]))),
                 static_cast<std::uint32_t>(id)};
  std::sort(order.begin(), order.end());
  std::vector<std::uint32_t> start(keys.size() + 1, 0), list(touches.size());
  for (const auto& t : touches) ++start[t.first + 1];
  for (std::size_t i = 0; i < keys.size(); ++i) start[i + 1] += start[i];
  {
    std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
    for (const auto& t : touches) list[fill[t.first]++] = t.second;
  }

  // Pass 2: parallel over blocks.
  std::vector<std::uint32_t> slots(order.size());
  std::vector<BlockOutcome> outcomes(order.size());
  const float r2 = r_lat * r_lat;
  const int threads = resolveThreads(cfg.threads);
  const int n = static_cast<int>(order.size());
#pragma omp parallel for num_threads(threads) if (threads > 1) schedule(dynamic, 2)
  for (int i = 0; i < n; ++i) {
    const auto [slot, id] = order[i];
    slots[i] = slot;
    TsdfBlock& blk = vol.block(slot);
    BlockOutcome& o = outcomes[i];
    for (std::uint32_t k = start[id]; k < start[id + 1]; ++k)
      o.updates += applySplat(blk, splats[list[k]], trunc, r2, voxel, cfg.max_weight, &o.changed);
    o.in_view = o.updates > 0;
  }
  finishIntegration(vol, slots, outcomes, res);
  return res;
}

}  // namespace planesdf
