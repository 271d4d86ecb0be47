// Pass 1a: the plane- and pose-independent analysis of a depth frame (DepthFrameAnalysis):
// per-pixel measurements, edge and silhouette distances, the guard tiles.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "fusion_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {
namespace fusion_detail {

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

namespace {

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

/// Saturation of the per-pixel edge distance (pixels).
constexpr int kFarEdge = 255;

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

/// The scratch of one worker of pass 1a: the edge and silhouette columns of the row at hand.
struct RowScratch {
  std::vector<int> edge_cols, silhouette_cols;
};

/// Valid pixels and the sum of their depths.
struct DepthSum {
  std::size_t valid = 0;
  double depth = 0.0;
};

/// Pixel row v of pass 1a (analysePixels): its measurements, k, edge and silhouette distances,
/// and its tile row's guard and largest depth. Adds its valid pixels and their depths to `sum`.
void analyseRow(const DepthFrame& frame, const Camera& cam, float trunc, int v,
                FrameMeasurements& fm, std::vector<float>& k_exact, RowScratch& s, DepthSum& sum) {
  const int W = cam.width, H = cam.height;
  const float footprint = 1.0f / std::min(cam.fx, cam.fy);  // pixel size at unit depth
  const float inv_depth_scale = 1.0f / fm.depth_scale;
  const std::vector<float>& xn = fm.xn;
  const int ty = v >> kGuardTileShift;
  float* guard_row = fm.guard.data() + static_cast<std::size_t>(ty) * fm.tiles_x;
  float* max_depth_row = fm.tile_max_depth.data() + static_cast<std::size_t>(ty) * fm.tiles_x;
  const float yn = fm.yn[v];
  const float* depth = frame.depth.data() + static_cast<std::size_t>(v) * W;
  const float* above = v > 0 ? depth - W : nullptr;
  const float* below = v + 1 < H ? depth + W : nullptr;
  PixelMeasurement* out = fm.pixels.data() + static_cast<std::size_t>(v) * W;
  float* k_out = k_exact.data() + static_cast<std::size_t>(v) * W;
  s.edge_cols.clear();
  s.silhouette_cols.clear();
  for (int u = 0; u < W; ++u) {
    const float d = depth[u];
    k_out[u] = 0.0f;
    if (!(d >= cam.z_min && d <= cam.z_max)) {
      out[u] = {0, 0, 0, 0};
      continue;
    }
    ++sum.valid;
    sum.depth += d;
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
      s.edge_cols.push_back(u);
      if (silhouette) s.silhouette_cols.push_back(u);
    }
    if (k == 0.0f) {  // grazing: carve along the optical axis only
      out[u] = encodeMeasurement(0.0f, 0.0f, d, 1.0f, true, inv_depth_scale);
      continue;
    }
    k_out[u] = k;
    const float inv_k = 1.0f / k;
    out[u] =
        encodeMeasurement(n[0] * inv_k, n[1] * inv_k, d, k, d > cam.z_surface, inv_depth_scale);
  }
  rowEdgeDistance(s.edge_cols.data(), static_cast<int>(s.edge_cols.size()), W,
                  fm.edge_dist.data() + static_cast<std::size_t>(v) * W);
  rowEdgeDistance(s.silhouette_cols.data(), static_cast<int>(s.silhouette_cols.size()), W,
                  fm.silhouette_dist.data() + static_cast<std::size_t>(v) * W);
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
  std::vector<RowScratch> scratch(static_cast<std::size_t>(threads));
  const auto tileRow = [&](int ty, RowScratch& s) {
    DepthSum sum;
    for (int v = ty * kGuardTile; v < std::min(H, (ty + 1) * kGuardTile); ++v)
      analyseRow(frame, cam, trunc, v, fm, k_exact, s, sum);
    row_valid[static_cast<std::size_t>(ty)] = sum.valid;
    row_depth[static_cast<std::size_t>(ty)] = sum.depth;
  };
  // Index 0 runs `alongside` (claimed first, so it starts at once); 1.. the rows of tiles.
  const int first = alongside != nullptr ? 1 : 0;
  parallelChunks(fm.tiles_y + first, threads, 1, [&](int worker, long long begin, long long end) {
    for (long long i = begin; i < end; ++i) {
      if (i < first) {
        try {
          (*alongside)();
        } catch (...) {
          alongside_failure = std::current_exception();
        }
        continue;
      }
      tileRow(static_cast<int>(i - first), scratch[static_cast<std::size_t>(worker)]);
    }
  });
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

void validateFrame(const DepthFrame& frame) {
  frame.intrinsics.validate("depth frame");
  const std::size_t expected =
      static_cast<std::size_t>(frame.intrinsics.width) * frame.intrinsics.height;
  if (frame.depth.size() != expected)
    throw Error("", "depth frame: " + std::to_string(frame.depth.size()) + " depth values for a " +
                        std::to_string(frame.intrinsics.width) + "x" +
                        std::to_string(frame.intrinsics.height) + " image");
}

}  // namespace
}  // namespace fusion_detail

// The fusion files' shared helpers, named unqualified as in one anonymous namespace.
using namespace fusion_detail;

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

}  // namespace planesdf
