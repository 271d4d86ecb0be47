#include "planesdf/map.hpp"
#include "planesdf/memory.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <functional>

#include "../memory_internal.hpp"
#include "../numeric.hpp"
#include "../parallel.hpp"
#include "map_internal.hpp"
#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"

#include <unordered_map>

namespace planesdf {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

/// World points of a depth frame into `out`, one per pixel (NaN where the depth is invalid);
/// rows in parallel. `out` is overwritten (reuse it across frames: no allocation per frame).
void backProject(const DepthFrame& f, const Pose& camera_to_world, int threads,
                 std::vector<Eigen::Vector3f>& out) {
  const Intrinsics& k = f.intrinsics;
  const Eigen::Matrix3f R = camera_to_world.linear().cast<float>();
  const Eigen::Vector3f t = camera_to_world.translation().cast<float>();
  const Eigen::Vector3f nan = Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
  out.resize(f.depth.size());
  const float ifx = static_cast<float>(1.0 / k.fx), ify = static_cast<float>(1.0 / k.fy);
  const float cx = static_cast<float>(k.cx), cy = static_cast<float>(k.cy);
  detail::parallelChunks(k.height, threads, 16, [&](int, long long v0, long long v1) {
    for (long long v = v0; v < v1; ++v)
      for (int u = 0; u < k.width; ++u) {
        const std::size_t i = static_cast<std::size_t>(v) * k.width + u;
        const float d = f.depth[i];
        out[i] =
            DepthFrame::isValidDepth(d)
                ? Eigen::Vector3f(R * Eigen::Vector3f((u - cx) * d * ifx,
                                                      (static_cast<float>(v) - cy) * d * ify, d) +
                                  t)
                : nan;
      }
  });
}

/// Makes room for `needed` points in `v` (capacity doubling, as push_back grows). The new array
/// is advised for huge pages before the points move in: a map's kept points grow to tens of
/// megabytes, and 4 KiB page faults on every doubling cost about 1 ms per frame.
void growPoints(std::vector<Eigen::Vector3f>& v, std::size_t needed) {
  if (needed <= v.capacity()) return;
  std::vector<Eigen::Vector3f> bigger;
  bigger.reserve(std::max(needed, 2 * v.capacity()));
  detail::adviseHugePages(bigger.data(), bigger.capacity() * sizeof(Eigen::Vector3f));
  bigger.insert(bigger.end(), v.begin(), v.end());
  v.swap(bigger);
}

/// Every `stride`-th point of every `stride`-th row of a row-major width x height grid.
std::vector<Eigen::Vector3f> gridSubsample(const std::vector<Eigen::Vector3f>& pts, int width,
                                           int height, int stride) {
  if (stride <= 1) return pts;
  std::vector<Eigen::Vector3f> out;
  out.reserve(static_cast<std::size_t>((width + stride - 1) / stride) *
              ((height + stride - 1) / stride));
  for (int v = 0; v < height; v += stride)
    for (int u = 0; u < width; u += stride)
      out.push_back(pts[static_cast<std::size_t>(v) * width + u]);
  return out;
}

std::vector<Eigen::Vector3f> transformPoints(const std::vector<Eigen::Vector3f>& pts,
                                             const Pose& T) {
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  std::vector<Eigen::Vector3f> out(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) out[i] = R * pts[i] + t;  // NaN stays NaN
  return out;
}

// `cfg` with memory_limit_mb lowered to what `used` bytes leave of it (at least 1 MB), so the
// blocks one fusion call adds are checked against the whole map's budget.
Config withMemoryLeft(const Config& cfg, std::size_t used) {
  const std::size_t limit = memoryLimitBytes(cfg);
  Config c = cfg;
  c.memory_limit_mb =
      static_cast<int>(std::max<std::size_t>(1, (limit > used ? limit - used : 0) >> 20));
  return c;
}

void checkFrame(const DepthFrame& frame) {
  frame.intrinsics.validate("depth frame");
  const std::size_t n = static_cast<std::size_t>(frame.intrinsics.width) * frame.intrinsics.height;
  if (frame.depth.size() != n)
    throw Error("depth frame", "holds " + std::to_string(frame.depth.size()) +
                                   " depth values for a " + std::to_string(frame.intrinsics.width) +
                                   "x" + std::to_string(frame.intrinsics.height) + " image");
}

/// Largest deviation of a pose's rotation from orthonormality (and of its determinant from +1)
/// that integrate() accepts: a quaternion or matrix written with a few decimals passes, a scale,
/// shear or reflection does not.
constexpr double kRigidTolerance = 1e-4;

/// Throws Error(what, ...) unless `pose` is finite and rigid (R^T R = I, det R = +1 within
/// kRigidTolerance). A NaN or non-rigid pose would otherwise drop or distort the whole frame.
void checkPose(const Pose& pose, const char* what) {
  const Eigen::Matrix3d R = pose.linear();
  if (!R.allFinite() || !pose.translation().allFinite())
    throw Error(what, "is not finite (NaN or infinite entries)");
  const double skew = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  const double det = R.determinant();
  char text[160];
  if (!(skew <= kRigidTolerance)) {
    std::snprintf(text, sizeof text,
                  "rotation is not orthonormal (|R^T R - I| up to %.3g, tolerance %g): not a "
                  "rigid motion",
                  skew, kRigidTolerance);
    throw Error(what, text);
  }
  if (!(std::abs(det - 1.0) <= kRigidTolerance)) {
    std::snprintf(text, sizeof text,
                  "rotation has determinant %.3g, not +1: a reflection is not a rigid motion", det);
    throw Error(what, text);
  }
}

/// Points of a cloud binned into square columns of a plane grid: their weighted sum and weight.
class ColumnHeights {
 public:
  explicit ColumnHeights(double cell) : cell_(cell) {}
  void add(const Eigen::Vector3f& p, double weight) {
    Acc& a = cells_[key(p.x(), p.y())];
    a.sum += weight * p.cast<double>();
    a.weight += weight;
  }
  struct Acc {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();  ///< weighted sum of the points
    double weight = 0.0;
  };
  /// The column holding (x, y); null when no point fell in it.
  const Acc* at(double x, double y) const {
    const auto it = cells_.find(key(x, y));
    return it == cells_.end() ? nullptr : &it->second;
  }
  double cell() const { return cell_; }

 private:
  std::uint64_t key(double x, double y) const {
    const auto u = static_cast<std::int64_t>(std::floor(x / cell_)) + (std::int64_t{1} << 30);
    const auto v = static_cast<std::int64_t>(std::floor(y / cell_)) + (std::int64_t{1} << 30);
    return static_cast<std::uint64_t>(u) << 32 | static_cast<std::uint64_t>(v);
  }
  double cell_;
  std::unordered_map<std::uint64_t, Acc> cells_;
};

/// +1 when the points 1.5-3.5 cm from `p` along `dir` (horizontal, unit) stand lower on average
/// than those as far the other way, by at least 1 cm; -1 the other way round; 0 when unclear
/// (a side is empty, or both about as high).
int lowerSide(const ColumnHeights& columns, const Eigen::Vector3f& p, const Eigen::Vector2f& dir) {
  double mean[2] = {0.0, 0.0};
  for (int side = 0; side < 2; ++side) {
    double sum = 0.0, weight = 0.0;
    for (double s = 0.015; s <= 0.0351; s += columns.cell()) {
      const double sign = side == 0 ? 1.0 : -1.0;
      const ColumnHeights::Acc* a =
          columns.at(p.x() + sign * s * dir.x(), p.y() + sign * s * dir.y());
      if (a == nullptr) continue;
      sum += a->sum.z();
      weight += a->weight;
    }
    if (weight <= 0.0) return 0;
    mean[side] = sum / weight;
  }
  constexpr double kClear = 0.01;
  if (mean[0] + kClear <= mean[1]) return 1;
  if (mean[1] + kClear <= mean[0]) return -1;
  return 0;
}

/// Orients splat normals of an unorganised cloud without a sensor (design.md, "Side faces face
/// the lower side"): toward the plane's free side where the surface faces up (|n·N| >= 0.5).
/// A side face faces the side whose nearby points stand lower (outside an object is its
/// support, inside it its top; a ring's inner face looks into the hole); when that is unclear,
/// away from the centroid of the points within 5-10 cm weighted by their height above the plane
/// (the object's mass, not the floor around it).
void orientWithoutSensor(const std::vector<Eigen::Vector3f>& pts_local,
                         std::vector<Eigen::Vector3f>& normals_local) {
  ColumnHeights fine(0.01), coarse(0.05);
  for (const auto& p : pts_local) {
    fine.add(p, 1.0);
    coarse.add(p, std::max(0.0, static_cast<double>(p.z())) + 1e-3);
  }
  for (std::size_t i = 0; i < pts_local.size(); ++i) {
    Eigen::Vector3f& n = normals_local[i];
    if (std::abs(n.z()) >= 0.5f) {
      if (n.z() < 0) n = -n;
      continue;
    }
    const Eigen::Vector3f& p = pts_local[i];
    const Eigen::Vector2f dir = n.head<2>().normalized();
    const int lower = lowerSide(fine, p, dir);
    if (lower != 0) {
      if (lower < 0) n = -n;
      continue;
    }
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double weight = 0.0;
    const double c = coarse.cell();
    for (int du = -1; du <= 1; ++du)
      for (int dv = -1; dv <= 1; ++dv) {
        const ColumnHeights::Acc* a = coarse.at(p.x() + du * c, p.y() + dv * c);
        if (a == nullptr) continue;
        sum += a->sum;
        weight += a->weight;
      }
    if (weight <= 0.0) continue;
    const Eigen::Vector3f centroid = (sum / weight).cast<float>();
    const Eigen::Vector2f d(p.x() - centroid.x(), p.y() - centroid.y());
    if (n.head<2>().dot(d) < 0) n = -n;
  }
}

/// The lower face of a slab parallel to the plane (a shelf board's or a table top's underside,
/// seen from below): orientWithoutSensor turned it to face away from the plane like any top
/// face, which would put a surface with free space above inside the slab. A facing-up point
/// whose next point up its voxel column (nothing between) also faces up and lies 1.5 voxels to
/// kMaxSlabThickness above it is such a face: it faces down.
void orientUndersides(const std::vector<Eigen::Vector3f>& pts_local,
                      std::vector<Eigen::Vector3f>& normals_local, float voxel) {
  std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> columns;
  const auto key = [&](const Eigen::Vector3f& p) {
    const auto u = static_cast<std::int64_t>(std::floor(p.x() / voxel)) + (1 << 30);
    const auto v = static_cast<std::int64_t>(std::floor(p.y() / voxel)) + (1 << 30);
    return static_cast<std::uint64_t>(u) << 32 | static_cast<std::uint64_t>(v);
  };
  for (std::size_t i = 0; i < pts_local.size(); ++i)
    columns[key(pts_local[i])].push_back(static_cast<std::uint32_t>(i));
  std::vector<std::uint32_t> flip;
  for (auto& [k, ids] : columns) {
    if (ids.size() < 2) continue;
    std::sort(ids.begin(), ids.end(), [&](std::uint32_t a, std::uint32_t b) {
      return pts_local[a].z() < pts_local[b].z();
    });
    for (std::size_t j = 0; j + 1 < ids.size(); ++j) {
      const std::uint32_t lo = ids[j], hi = ids[j + 1];
      const float gap = pts_local[hi].z() - pts_local[lo].z();
      if (normals_local[lo].z() >= 0.5f && normals_local[hi].z() >= 0.5f && gap >= 1.5f * voxel &&
          gap <= static_cast<float>(detail::kMaxSlabThickness))
        flip.push_back(lo);
    }
  }
  for (const std::uint32_t i : flip) normals_local[i] = -normals_local[i];
}

/// Heights within a slack of a band pass the pre-test: kBandSlack plus kBandSlackPerMetre of
/// the coordinates' and the offset's magnitudes, several times the rounding error of the
/// single-precision dot product, so that it never drops a point the exact (double) test keeps.
constexpr float kBandSlack = 1e-3f, kBandSlackPerMetre = 4e-7f;

inline float bandSlack(float x, float y, float z, float abs_d) {
  return kBandSlack + kBandSlackPerMetre * (std::abs(x) + std::abs(y) + std::abs(z) + abs_d);
}

/// maybe[i] = 1 when point i of the packed xyz array (m points) may lie in some band, else 0;
/// NaN points give 0. The reference code for bandPretestAvx2.
void bandPretestScalar(const float* xyz, int m, const std::vector<detail::BandF>& bands,
                       std::uint8_t* maybe) {
  for (int i = 0; i < m; ++i) {
    const float x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
    std::uint8_t any = 0;
    for (const detail::BandF& b : bands) {
      const float h = b.nx * x + b.ny * y + b.nz * z + b.d;
      const float slack = bandSlack(x, y, z, std::abs(b.d));
      any = static_cast<std::uint8_t>(any | ((h >= b.lo - slack) & (h <= b.hi + slack)));
    }
    maybe[i] = any;
  }
}

#if defined(__x86_64__) && defined(__GNUC__)
/// bandPretestScalar 8 points at a time (the packed xyz of 8 points de-interleaved by blends
/// and permutes). The margin covers the difference between the two, so both keep every point
/// the exact test keeps.
__attribute__((target("avx2"))) void bandPretestAvx2(const float* xyz, int m,
                                                     const std::vector<detail::BandF>& bands,
                                                     std::uint8_t* maybe) {
  const __m256 sign = _mm256_set1_ps(-0.0f);
  const __m256i px = _mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5);
  const __m256i py = _mm256_setr_epi32(1, 4, 7, 2, 5, 0, 3, 6);
  const __m256i pz = _mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7);
  int i = 0;
  for (; i + 8 <= m; i += 8) {
    const float* p = xyz + 3 * i;
    const __m256 a0 = _mm256_loadu_ps(p), a1 = _mm256_loadu_ps(p + 8), a2 = _mm256_loadu_ps(p + 16);
    const __m256 x =
        _mm256_permutevar8x32_ps(_mm256_blend_ps(_mm256_blend_ps(a0, a1, 0x92), a2, 0x24), px);
    const __m256 y =
        _mm256_permutevar8x32_ps(_mm256_blend_ps(_mm256_blend_ps(a0, a1, 0x24), a2, 0x49), py);
    const __m256 z =
        _mm256_permutevar8x32_ps(_mm256_blend_ps(_mm256_blend_ps(a0, a1, 0x49), a2, 0x92), pz);
    const __m256 mag =
        _mm256_add_ps(_mm256_add_ps(_mm256_andnot_ps(sign, x), _mm256_andnot_ps(sign, y)),
                      _mm256_andnot_ps(sign, z));
    int any = 0;
    for (const detail::BandF& b : bands) {
      const __m256 h =
          _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(b.nx), x),
                                                    _mm256_mul_ps(_mm256_set1_ps(b.ny), y)),
                                      _mm256_mul_ps(_mm256_set1_ps(b.nz), z)),
                        _mm256_set1_ps(b.d));
      const __m256 slack =
          _mm256_add_ps(_mm256_set1_ps(kBandSlack),
                        _mm256_mul_ps(_mm256_set1_ps(kBandSlackPerMetre),
                                      _mm256_add_ps(mag, _mm256_set1_ps(std::abs(b.d)))));
      const __m256 in =
          _mm256_and_ps(_mm256_cmp_ps(h, _mm256_sub_ps(_mm256_set1_ps(b.lo), slack), _CMP_GE_OQ),
                        _mm256_cmp_ps(h, _mm256_add_ps(_mm256_set1_ps(b.hi), slack), _CMP_LE_OQ));
      any |= _mm256_movemask_ps(in);
    }
    for (int l = 0; l < 8; ++l) maybe[i + l] = static_cast<std::uint8_t>((any >> l) & 1);
  }
  if (i < m) bandPretestScalar(xyz + 3 * i, m - i, bands, maybe + i);
}
#endif

/// Adds what one plane volume's integration did to the call's stats.
void addResult(IntegrateStats& stats, int plane_id, const IntegrationResult& r) {
  if (!r.updated_blocks.empty()) stats.updated_planes.push_back(plane_id);
  if (r.changed()) stats.changed_planes.push_back(plane_id);
  stats.blocks_updated += r.updated_blocks.size();
  stats.blocks_allocated += r.allocated_blocks.size();
  stats.points_fused += r.num_points_fused;
}

}  // namespace

void detail::bandPretest(const float* xyz, int m, const std::vector<BandF>& bands,
                         std::uint8_t* maybe, bool simd) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (simd && cpuHasAvx2()) return bandPretestAvx2(xyz, m, bands, maybe);
#endif
  bandPretestScalar(xyz, m, bands, maybe);
}

detail::PointCellSetsPtr::PointCellSetsPtr() noexcept = default;
detail::PointCellSetsPtr::~PointCellSetsPtr() = default;
detail::PointCellSetsPtr::PointCellSetsPtr(const PointCellSetsPtr& other)
    : p_(other.p_ ? std::make_unique<PointCellSets>(*other.p_) : nullptr) {}
detail::PointCellSetsPtr& detail::PointCellSetsPtr::operator=(const PointCellSetsPtr& other) {
  if (this != &other) p_ = other.p_ ? std::make_unique<PointCellSets>(*other.p_) : nullptr;
  return *this;
}
detail::PointCellSetsPtr::PointCellSetsPtr(PointCellSetsPtr&& other) noexcept = default;
detail::PointCellSetsPtr& detail::PointCellSetsPtr::operator=(PointCellSetsPtr&& other) noexcept =
    default;
detail::PointCellSets& detail::PointCellSetsPtr::get() {
  if (!p_) p_ = std::make_unique<PointCellSets>();
  return *p_;
}

bool detail::CellBitSet::insert(std::uint64_t key) {
  const std::uint64_t brick = brickOf(key);
  if (brick != last_brick_) {
    std::uint32_t slot = bricks_.find(brick);
    if (slot == detail::BlockHashMap::kNotFound) {
      masks_.push_back({});  // first: a failed insert below leaves only an unused mask
      slot = static_cast<std::uint32_t>(masks_.size() - 1);
      bricks_.insert(brick, slot);
    }
    last_brick_ = brick;
    last_mask_ = slot;
  }
  const unsigned bit =
      static_cast<unsigned>((key & 7) | ((key >> 21) & 7) << 3 | ((key >> 42) & 7) << 6);
  std::uint64_t& word = masks_[last_mask_][bit >> 6];
  const std::uint64_t b = std::uint64_t{1} << (bit & 63);
  if (word & b) return false;
  word |= b;
  ++cells_;
  return true;
}

Map::Map(const Config& cfg) : cfg_(cfg), tracker_(cfg) {
  validateConfig(cfg_);
}

const PlaneSdf* Map::findPlane(int id) const {
  return id >= 0 && static_cast<std::size_t>(id) < planes_.size() ? &planes_[id] : nullptr;
}

Eigen::Vector3d Map::up() const {
  return tracker_.up().value_or(cfg_.up.normalized());
}

std::size_t Map::memoryBytes() const {
  std::size_t b = points_.capacity() * sizeof(Eigen::Vector3f) + reservedBytes();
  for (const auto& p : planes_) b += p.volume.memoryBytes();
  return b;
}

std::size_t Map::reservedBytes() const {
  return block_pool_ ? block_pool_->bytes() : 0;
}

void Map::reserveMemory(std::size_t block_bytes, std::size_t points) {
  // Touching more than the machine holds would end in the kernel's OOM killer, not bad_alloc.
  const std::size_t physical = detail::physicalMemoryBytes();
  const double wanted =
      static_cast<double>(block_bytes) + static_cast<double>(points) * sizeof(Eigen::Vector3f);
  if (physical > 0 && wanted > static_cast<double>(physical))
    throw Error("", "Map::reserveMemory: " + std::to_string(block_bytes) + " bytes of blocks and " +
                        std::to_string(points) + " points exceed this machine's " +
                        std::to_string(physical) + " bytes of memory");
  if (block_bytes > 0) {
    if (!block_pool_) {
      block_pool_ = std::make_shared<detail::HugePagePool>();
      for (auto& ps : planes_) ps.volume.useHugePagePool(block_pool_);
    }
    block_pool_->fill((block_bytes + detail::kHugePageBytes - 1) / detail::kHugePageBytes);
  }
  if (points > points_.capacity()) {
    growPoints(points_, points);
    // Written once (then the size restored) so that its pages are faulted in now.
    const std::size_t size = points_.size();
    points_.resize(points_.capacity(), Eigen::Vector3f::Zero());
    points_.resize(size);
  }
}

void Map::syncPlanes(IntegrateStats& stats) {
  const auto& tp = tracker_.planes();
  for (std::size_t i = 0; i < tp.size(); ++i) {
    if (i < planes_.size()) {
      planes_[i].plane = tp[i];  // geometry may have been refined; the frame moves with it
    } else {
      planes_.push_back(PlaneSdf{tp[i], TsdfVolume(cfg_)});
      if (block_pool_) planes_.back().volume.useHugePagePool(block_pool_);
      stats.new_planes.push_back(tp[i].id);
    }
  }
}

namespace {

/// (input index, cell key) of the points kept by keepPoints, one list per part of the input.
using KeptList = std::vector<std::pair<std::uint32_t, std::uint64_t>>;

/// The points of `pts` that may belong to an object (h_lo to fuse_band above some plane), in
/// `lists`: the band test and the cell keys (`dedup`) in parallel, each part listing its
/// contiguous share of the input in order, so that the lists concatenated in part order are in
/// input order. A single-precision pre-test per chunk (bandPretest, 8 points at a time with AVX2)
/// marks the points that may be in some band; only those take the exact test, and its margin
/// never drops a point the exact test keeps.
void bandPoints(const std::vector<Eigen::Vector3f>& pts, const std::vector<PlaneSdf>& planes,
                const Config& cfg, bool dedup, int threads, std::vector<KeptList>& lists) {
  const double h_lo = 0.5 * cfg.h_obj;
  const auto n = static_cast<std::ptrdiff_t>(pts.size());
  constexpr std::ptrdiff_t kChunk = 512;
  const std::ptrdiff_t chunks = (n + kChunk - 1) / kChunk;
  // A few parts per thread, so a thread the host's work delays holds back little.
  const int parts =
      static_cast<int>(std::max<std::ptrdiff_t>(1, std::min<std::ptrdiff_t>(chunks, 4 * threads)));
  lists.resize(static_cast<std::size_t>(parts));
  for (auto& l : lists) l.clear();
  std::vector<detail::BandF> bands;
  for (const auto& ps : planes) {
    const Eigen::Vector3f nf = ps.plane.normal.cast<float>();
    bands.push_back({nf.x(), nf.y(), nf.z(), static_cast<float>(ps.plane.offset),
                     static_cast<float>(h_lo), static_cast<float>(cfg.fuse_band)});
  }
  detail::parallelChunks(parts, threads, 1, [&](int, long long part, long long) {
    auto& mine = lists[static_cast<std::size_t>(part)];
    alignas(64) std::uint8_t maybe[kChunk];
    long long c0 = 0, c1 = 0;
    detail::staticShare(chunks, parts, static_cast<int>(part), c0, c1);
    for (std::ptrdiff_t c = c0; c < c1; ++c) {
      const std::ptrdiff_t begin = c * kChunk;
      const int m = static_cast<int>(std::min(kChunk, n - begin));
      const float* xyz = pts[static_cast<std::size_t>(begin)].data();
      detail::bandPretest(xyz, m, bands, maybe, cfg.simd);
      for (int i = 0; i < m; ++i) {
        if (!maybe[i]) continue;  // NaN (invalid) points fail both comparisons
        const std::size_t idx = static_cast<std::size_t>(begin + i);
        const Eigen::Vector3f& p = pts[idx];
        if (!PointCloud::isValid(p)) continue;
        for (const auto& ps : planes) {
          const double h = ps.plane.signedDistance(p.cast<double>());
          if (h >= h_lo && h <= cfg.fuse_band) {
            mine.emplace_back(static_cast<std::uint32_t>(idx),
                              dedup ? detail::cellKeyOf(p, cfg.point_cell) : 0);
            break;
          }
        }
      }
    }
  });
}

/// De-duplication: marks in `accepted` the list entries whose cell holds no point yet, adding
/// their cells to `cells`. The cells are split in sets by key, each owned by one thread (the
/// same entries for any thread count). The sets are large and their lookups miss the cache:
/// each thread requests its slots some points ahead. A point in the same cell as the set's
/// point before it is a duplicate whatever the set holds.
void acceptNewCells(const std::vector<KeptList>& lists, detail::PointCellSets& cells, int threads,
                    std::vector<std::vector<std::uint8_t>>& accepted) {
  accepted.resize(lists.size());
  for (std::size_t l = 0; l < lists.size(); ++l) accepted[l].assign(lists[l].size(), 0);
  constexpr std::size_t kAhead = 16;
  const int owners = std::min(threads, static_cast<int>(detail::kPointCellSets));
  detail::parallelChunks(owners, owners, 1, [&](int, long long owner, long long) {
    const auto part = static_cast<std::size_t>(owner);
    const auto step = static_cast<std::size_t>(owners);
    std::uint64_t last[detail::kPointCellSets];
    std::fill(std::begin(last), std::end(last), detail::kEmptyBlockKey);
    for (std::size_t l = 0; l < lists.size(); ++l) {
      const auto& list = lists[l];
      for (std::size_t j = 0; j < list.size(); ++j) {
        if (j + kAhead < list.size()) {
          const std::uint64_t ahead = list[j + kAhead].second;
          const std::size_t s = detail::pointCellSet(ahead);
          if (s % step == part) cells.sets[s].prefetch(ahead);
        }
        const std::uint64_t key = list[j].second;
        const std::size_t s = detail::pointCellSet(key);
        if (s % step != part || key == last[s]) continue;
        last[s] = key;
        if (cells.sets[s].insert(key)) accepted[l][j] = 1;
      }
    }
  });
}

}  // namespace

void Map::keepPoints(const std::vector<Eigen::Vector3f>& pts, bool deduplicate) {
  // Only points that can belong to an object are kept: above some plane by at least half the
  // object threshold and inside its band (plane surfaces themselves never change). The lists
  // are reused.
  const bool dedup = deduplicate && cfg_.point_cell > 0.0;
  const int threads = detail::resolveThreads(cfg_.threads);
  thread_local std::vector<KeptList> lists;
  bandPoints(pts, planes_, cfg_, dedup, threads, lists);
  if (!dedup) {
    std::size_t total = points_.size();
    for (const auto& list : lists) total += list.size();
    growPoints(points_, total);
    for (const auto& list : lists)
      for (const auto& entry : list) points_.push_back(pts[entry.first]);
    return;
  }
  // A point is kept when its cell holds none yet; the kept points are appended in input order.
  thread_local std::vector<std::vector<std::uint8_t>> accepted;
  acceptNewCells(lists, point_cells_.get(), threads, accepted);
  std::size_t total = points_.size();
  for (const auto& a : accepted)
    total += static_cast<std::size_t>(std::count(a.begin(), a.end(), 1));
  growPoints(points_, total);
  for (std::size_t l = 0; l < lists.size(); ++l)
    for (std::size_t j = 0; j < lists[l].size(); ++j)
      if (accepted[l][j]) points_.push_back(pts[lists[l][j].first]);
}

IntegrateStats Map::fuseDepth(const DepthFrameAnalysis& analysis, const Pose& camera_to_world,
                              const Config& fuse_cfg) {
  IntegrateStats stats;
  for (auto& ps : planes_) {
    const Pose T_local_camera = ps.plane.frame().inverse() * camera_to_world;
    const IntegrationResult r = integrateDepth(ps.volume, analysis, T_local_camera,
                                               withMemoryLeft(fuse_cfg, memoryBytes()));
    addResult(stats, ps.plane.id, r);
  }
  return stats;
}

IntegrateStats Map::integrate(const DepthFrame& frame, const Pose& camera_to_world) {
  const auto t0 = Clock::now();
  checkFrame(frame);
  checkPose(camera_to_world, "camera pose");
  const Intrinsics& k = frame.intrinsics;
  requireMemory(static_cast<std::size_t>(k.width) * k.height * kDepthFrameBytesPerPixel, cfg_,
                "depth frame",
                "fusing a " + std::to_string(k.width) + "x" + std::to_string(k.height) + " frame");
  thread_local std::vector<Eigen::Vector3f> points_scratch;
  std::vector<Eigen::Vector3f>& pts = points_scratch;  // this thread's buffer, reused per frame
  backProject(frame, camera_to_world, detail::resolveThreads(cfg_.threads), pts);
  const auto track = [&] {
    if (cfg_.track_pixel_stride <= 1) {
      tracker_.integrate(pts, camera_to_world.translation());  // every pixel: no copy
    } else {
      tracker_.integrate(gridSubsample(pts, frame.intrinsics.width, frame.intrinsics.height,
                                       cfg_.track_pixel_stride),
                         camera_to_world.translation());
    }
  };
  // The per-pixel pass of fusion (scratch reused per thread) does not depend on the planes.
  // Plane tracking, which is serial, and then the object points of the frame, which need the
  // tracked planes, run on one thread while the others start the pass; that thread joins the
  // pass when done (same results for any thread count: all of them only read the frame).
  thread_local DepthFrameAnalysis scratch;
  DepthFrameAnalysis& analysis = scratch;  // the caller's (see keepPoints)
  IntegrateStats created;
  double tracking_ms = 0.0, points_ms = 0.0;
  const std::function<void()> before_fusion = [&] {
    const auto tt = Clock::now();
    track();
    syncPlanes(created);
    tracking_ms = msSince(tt);
    const auto tp = Clock::now();
    keepPoints(pts, true);
    points_ms = msSince(tp);
  };
  analysis.analyse(frame, cfg_.truncation(), cfg_, before_fusion);
  const auto tf = Clock::now();
  IntegrateStats stats;
  if (!planes_.empty()) stats = fuseDepth(analysis, camera_to_world, cfg_);
  stats.fusion_ms = msSince(tf);
  stats.tracking_ms = tracking_ms;
  stats.points_ms = points_ms;
  stats.new_planes = std::move(created.new_planes);
  ++frames_;
  stats.milliseconds = msSince(t0);
  return stats;
}

namespace {

/// Whole-cloud plane detection results as observations a PlaneTracker can merge.
std::vector<PlaneObservation> observationsOf(const PlaneSegmentation& seg) {
  std::vector<PlaneObservation> obs(seg.planes.size());
  for (std::size_t i = 0; i < seg.planes.size(); ++i) {
    obs[i].plane = seg.planes[i];
    obs[i].plane.id = -1;
    obs[i].fitted = i < seg.fitted.size() && seg.fitted[i] != 0;
  }
  for (std::size_t p = 0; p < seg.labels.size(); ++p)
    if (seg.labels[p] >= 0) obs[seg.labels[p]].inliers.push_back(static_cast<std::uint32_t>(p));
  return obs;
}

/// The splats of one plane volume: points in its band (plane-local), their normals and the free
/// space each one carves in front of it (design.md, "Noisy clouds").
struct BandSplats {
  std::vector<Eigen::Vector3f> points, normals;
  std::vector<float> front;
};

/// The points of `world` in the band of the plane whose frame `to_local` maps into, with their
/// PCA normals. A noisy point's free space reaches `reach_sigma` times its local noise further,
/// and points noisier than `max_noise` are left out (0: none). Without a sensor the normals are
/// oriented from the points (orientWithoutSensor, orientUndersides): a slab's top face up to
/// kMaxSlabThickness above the band tells its underside in the band, then is dropped.
BandSplats bandSplats(const PointCloud& world, const std::vector<Eigen::Vector3f>& normals,
                      const std::vector<float>& spread, const Pose& to_local, bool has_sensor,
                      float reach_sigma, float max_noise, const Config& cfg) {
  const auto trunc = static_cast<float>(cfg.truncation());
  const double top = cfg.fuse_band + (has_sensor ? 0.0 : detail::kMaxSlabThickness);
  const Eigen::Matrix3f R = to_local.linear().cast<float>();
  const Eigen::Vector3f t = to_local.translation().cast<float>();
  BandSplats b;
  for (std::size_t i = 0; i < world.points.size(); ++i) {
    if (!world.isValid(i) || !normals[i].allFinite()) continue;
    const Eigen::Vector3f q = R * world.points[i] + t;
    if (q.z() < -cfg.below_band || q.z() > top) continue;
    const float noise = std::isfinite(spread[i]) ? spread[i] : 0.0f;
    if (max_noise > 0.0f && noise > max_noise) continue;
    b.points.push_back(q);
    b.normals.push_back(R * normals[i]);
    b.front.push_back(trunc + std::min(reach_sigma * noise, 2.0f * trunc));
  }
  if (has_sensor || b.points.empty()) return b;
  orientWithoutSensor(b.points, b.normals);
  orientUndersides(b.points, b.normals, static_cast<float>(cfg.voxel_size));
  std::size_t kept = 0;
  for (std::size_t i = 0; i < b.points.size(); ++i)
    if (b.points[i].z() <= cfg.fuse_band) {
      b.points[kept] = b.points[i];
      b.front[kept] = b.front[i];
      b.normals[kept++] = b.normals[i];
    }
  b.points.resize(kept);
  b.normals.resize(kept);
  b.front.resize(kept);
  return b;
}

}  // namespace

IntegrateStats Map::integrateCloud(const PointCloud& cloud, const Pose& cloud_to_world,
                                   bool whole_cloud) {
  const auto t0 = Clock::now();
  cloud.validate("point cloud");
  checkPose(cloud_to_world, "cloud pose");
  checkPose(cloud.sensor_pose, "point cloud sensor_pose");
  // The cloud in the world frame (positions, normals and sensor pose moved together).
  PointCloud world;
  world.points = transformPoints(cloud.points, cloud_to_world);
  world.width = cloud.width;
  world.height = cloud.height;
  world.sensor_pose = cloud_to_world * cloud.sensor_pose;

  // Unorganised clouds: planes and surfaces from the smoothed points (Config::cloud_smooth_knn);
  // the change outputs keep the points as given.
  std::vector<Eigen::Vector3f> given;
  if (!cloud.isOrganized() && cfg_.cloud_smooth_knn > 0) {
    given = world.points;
    world.points = projectToLocalPlanes(given, cfg_);
  }

  IntegrateStats created;
  const auto tt = Clock::now();
  // Unorganised clouds: one set of normals for the planes and the splats; a noisy cloud's
  // points also carry their local noise (design.md, "Noisy clouds").
  std::vector<Eigen::Vector3f> normals;
  std::vector<float> spread;
  bool noisy = false;
  if (!cloud.isOrganized()) normals = estimateNormals(world, cfg_, nullptr, &spread, &noisy);
  if (whole_cloud || !cloud.isOrganized()) {
    // Without a pixel grid, supports and walls only, as in streams; a single organised view keeps
    // object faces (design.md, "Shelf boards are planes, object faces are not").
    const bool grid = cloud.isOrganized();
    const std::vector<float> kNoNoise;  // a clean cloud's planes claim their inliers only
    tracker_.merge(
        observationsOf(grid ? segmentPlanes(world, cfg_)
                            : segmentPlanes(world, cfg_, normals, noisy ? spread : kNoNoise)),
        world.points, grid ? 0.0 : cfg_.plane_min_extent, grid ? 0.0 : cfg_.plane_min_width);
  } else {
    tracker_.integrate(world.points, world.sensor_pose.translation());
  }
  syncPlanes(created);
  const double tracking_ms = msSince(tt);

  const auto tf = Clock::now();
  IntegrateStats stats;
  if (cloud.isOrganized()) {
    const Intrinsics k = estimateIntrinsics(cloud);
    const DepthFrame depth = depthFromOrganizedCloud(cloud, k);
    // A whole scene given as one organised cloud is a single view: keep the rims (Config).
    Config fuse_cfg = cfg_;
    if (whole_cloud) fuse_cfg.silhouette_guard_behind = false;
    if (!planes_.empty()) {
      thread_local DepthFrameAnalysis analysis;
      analysis.analyse(depth, fuse_cfg.truncation(), fuse_cfg);
      stats = fuseDepth(analysis, world.sensor_pose, fuse_cfg);
    }
  } else {
    stats = splatCloud(world, normals, spread, noisy);
  }
  stats.fusion_ms = msSince(tf);
  stats.tracking_ms = tracking_ms;
  stats.new_planes = std::move(created.new_planes);
  const auto tp = Clock::now();
  if (!given.empty()) world.points = std::move(given);
  keepPoints(world.points, !whole_cloud);
  stats.points_ms = msSince(tp);
  ++frames_;
  stats.milliseconds = msSince(t0);
  return stats;
}

IntegrateStats Map::splatCloud(const PointCloud& world, const std::vector<Eigen::Vector3f>& normals,
                               const std::vector<float>& spread, bool noisy) {
  // No pixel grid: splat each point along its PCA normal.
  splatted_ = true;
  const auto trunc = static_cast<float>(cfg_.truncation());
  const auto reach_sigma = noisy ? static_cast<float>(cfg_.splat_noise_reach) : 0.0f;
  const auto max_noise = noisy ? static_cast<float>(cfg_.splat_max_noise) * trunc : 0.0f;
  const bool has_sensor = sensorOrigin(world).has_value();
  IntegrateStats stats;
  for (auto& ps : planes_) {
    const BandSplats b = bandSplats(world, normals, spread, ps.plane.frame().inverse(), has_sensor,
                                    reach_sigma, max_noise, cfg_);
    if (b.points.empty()) continue;
    const IntegrationResult r = integratePointsWithNormals(ps.volume, b.points, b.normals,
                                                           withMemoryLeft(cfg_, memoryBytes()),
                                                           reach_sigma > 0.0f ? &b.front : nullptr);
    addResult(stats, ps.plane.id, r);
  }
  return stats;
}

IntegrateStats Map::integrate(const PointCloud& cloud, const Pose& cloud_to_world) {
  return integrateCloud(cloud, cloud_to_world, false);
}

Map Map::fromCloud(const PointCloud& world, const Config& cfg) {
  Map m(cfg);
  m.integrateCloud(world, Pose::Identity(), true);
  return m;
}

}  // namespace planesdf
