// The depth sensor: camera trajectories and ray-cast depth frames with the Kinect-like noise model
// of SensorModel.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <random>
#include <utility>
#include <vector>

#include "planesdf/sim.hpp"
#include "world.hpp"

namespace planesdf::sim {
namespace {
using detail::kPi;
using Eigen::Vector3d;

/// Uniform and normal numbers from std::mt19937 by our own formulas, so the noise is the same
/// with any standard library.
class Noise {
 public:
  explicit Noise(std::uint64_t seed) {
    std::seed_seq seq{static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(seed >> 32)};
    gen_.seed(seq);
  }
  /// In (0, 1).
  double uniform() { return (static_cast<double>(gen_()) + 0.5) * (1.0 / 4294967296.0); }
  /// Standard normal (Box-Muller, both values used).
  double normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double r = std::sqrt(-2.0 * std::log(uniform()));
    const double a = 2.0 * kPi * uniform();
    spare_ = r * std::sin(a);
    has_spare_ = true;
    return r * std::cos(a);
  }

 private:
  std::mt19937 gen_;
  bool has_spare_ = false;
  double spare_ = 0.0;
};

constexpr int kTile = 16;  ///< pixels per side of a culling tile

}  // namespace

Pose lookAt(const Vector3d& eye, const Vector3d& target) {
  const Vector3d z = (target - eye).normalized();
  Vector3d x = z.cross(Vector3d::UnitZ());
  if (x.norm() < 1e-9) x = z.unitOrthogonal();
  x.normalize();
  const Vector3d y = z.cross(x);
  Pose pose = Pose::Identity();
  pose.linear().col(0) = x;
  pose.linear().col(1) = y;
  pose.linear().col(2) = z;
  pose.translation() = eye;
  return pose;
}

std::vector<Pose> trajectoryPoses(const std::vector<Orbit>& trajectory) {
  std::vector<Pose> poses;
  for (const Orbit& o : trajectory) {
    const double z_mid = 0.5 * (o.z_min + o.z_max);
    for (int i = 0; i < o.frames; ++i) {
      const double f = (i + 0.5) / o.frames;
      const double phi = detail::deg2rad(o.start_deg + (o.end_deg - o.start_deg) * f);
      const double z =
          o.z_min + (o.z_max - o.z_min) * 0.5 * (1.0 - std::cos(2.0 * kPi * o.height_waves * f));
      const Vector3d eye(o.center.x() + o.radius * std::cos(phi),
                         o.center.y() + o.radius * std::sin(phi), z);
      const Vector3d target = o.target + Vector3d(0.0, 0.0, o.target_follow * (z - z_mid));
      poses.push_back(lookAt(eye, target));
    }
  }
  return poses;
}

DepthFrame renderDepth(const Scene& scene, const Session& session, const Pose& camera_to_world,
                       std::uint64_t noise_seed) {
  const detail::World world(sessionPrimitives(scene, session));
  return detail::renderFrame(world, scene.sensor, camera_to_world, noise_seed);
}

namespace detail {
namespace {

/// Per screen tile of kTile pixels, the primitives that may cover it, nearest first: the screen
/// rectangle of each primitive (its oriented bounding box, clipped to the space in front of the
/// camera, grown by `margin` pixels) goes into the tiles it covers, with the nearest depth of
/// the box, so a pixel tests only the primitives of its tile.
std::vector<std::vector<std::pair<float, int>>> cullTiles(const World& world,
                                                          const SensorModel& sensor, const Pose& T,
                                                          double margin) {
  const Intrinsics& K = sensor.intrinsics;
  const int W = K.width, H = K.height;
  const int tiles_x = (W + kTile - 1) / kTile, tiles_y = (H + kTile - 1) / kTile;
  std::vector<std::vector<std::pair<float, int>>> tiles(static_cast<std::size_t>(tiles_x) *
                                                        tiles_y);
  const auto& prims = world.primitives();
  constexpr double kNear = 1e-3;
  for (std::size_t m = 0; m < prims.size(); ++m) {
    const Vector3d half = localHalfExtent(prims[m]);
    const Pose to_camera = T.inverse(Eigen::Isometry) * prims[m].pose;
    std::array<Vector3d, 8> c;
    for (int k = 0; k < 8; ++k)
      c[static_cast<std::size_t>(k)] =
          to_camera * Vector3d((k & 1) ? half.x() : -half.x(), (k & 2) ? half.y() : -half.y(),
                               (k & 4) ? half.z() : -half.z());
    double z_near = kInf, u0 = kInf, u1 = -kInf, v0 = kInf, v1 = -kInf;
    const auto project = [&](const Vector3d& p) {
      const double u = K.fx * p.x() / p.z() + K.cx, v = K.fy * p.y() / p.z() + K.cy;
      u0 = std::min(u0, u);
      u1 = std::max(u1, u);
      v0 = std::min(v0, v);
      v1 = std::max(v1, v);
    };
    for (int k = 0; k < 8; ++k) {
      const Vector3d& p = c[static_cast<std::size_t>(k)];
      z_near = std::min(z_near, p.z());
      if (p.z() >= kNear) project(p);
      for (const int bit : {1, 2, 4}) {  // edges k -> k | bit, each once
        if (k & bit) continue;
        const Vector3d& q = c[static_cast<std::size_t>(k | bit)];
        if ((p.z() < kNear) != (q.z() < kNear))
          project(p + (q - p) * ((kNear - p.z()) / (q.z() - p.z())));
      }
    }
    if (u0 > u1 || z_near > sensor.max_depth) continue;  // behind the camera or out of range
    if (u1 + margin < 0.0 || v1 + margin < 0.0 || u0 - margin > W - 1 || v0 - margin > H - 1)
      continue;
    const auto clampTile = [](double x, int n) {
      return static_cast<int>(std::clamp(std::floor(x / kTile), 0.0, static_cast<double>(n - 1)));
    };
    const int tx0 = clampTile(u0 - margin, tiles_x), tx1 = clampTile(u1 + margin, tiles_x);
    const int ty0 = clampTile(v0 - margin, tiles_y), ty1 = clampTile(v1 + margin, tiles_y);
    // A lower bound of the depth (float, rounded down) so that sorting and early exit are safe.
    const float near = std::nextafter(static_cast<float>(std::max(0.0, z_near)), 0.0f);
    for (int ty = ty0; ty <= ty1; ++ty)
      for (int tx = tx0; tx <= tx1; ++tx)
        tiles[static_cast<std::size_t>(ty) * tiles_x + tx].emplace_back(near, static_cast<int>(m));
  }
  for (auto& t : tiles) std::sort(t.begin(), t.end());
  return tiles;
}

/// Pass 1: exact depth (z along the optical axis) and incidence of each pixel's (jittered) ray;
/// depth 0 where nothing is hit.
void traceRays(const World& world, const SensorModel& sensor, const Pose& T, Noise& noise,
               std::vector<double>& depth, std::vector<double>& cosine) {
  const Intrinsics& K = sensor.intrinsics;
  const int W = K.width, H = K.height;
  const double sigma_px = sensor.noise ? sensor.lateral_sigma_px : 0.0;
  const double jitter_max = 4.0 * sigma_px;
  const Eigen::Matrix3d R = T.linear();
  const Vector3d origin = T.translation();
  const bool noisy = sensor.noise;
  const int tiles_x = (W + kTile - 1) / kTile;
  const auto tiles = cullTiles(world, sensor, T, std::ceil(jitter_max) + 1.0);
  const std::size_t n = static_cast<std::size_t>(W) * H;
  depth.assign(n, 0.0);
  cosine.assign(n, 1.0);
  const double cos_max = std::cos(deg2rad(sensor.max_incidence_deg));
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      double du = 0.0, dv = 0.0;
      if (sigma_px > 0.0) {
        du = std::clamp(sigma_px * noise.normal(), -jitter_max, jitter_max);
        dv = std::clamp(sigma_px * noise.normal(), -jitter_max, jitter_max);
      }
      const Vector3d ray_cam((u + du - K.cx) / K.fx, (v + dv - K.cy) / K.fy, 1.0);
      const Vector3d ray = R * ray_cam;  // unit z in the camera: the ray parameter is the depth
      int primitive = -1;
      const auto& candidates = tiles[static_cast<std::size_t>(v / kTile) * tiles_x + u / kTile];
      const Hit hit = world.raycast(origin, ray, sensor.max_depth, candidates, primitive);
      if (primitive < 0 || hit.t < sensor.min_depth) continue;
      const double c = std::abs(hit.normal.dot(ray)) / ray.norm();
      if (noisy && c < cos_max) continue;
      const std::size_t i = static_cast<std::size_t>(v) * W + u;
      depth[i] = hit.t;
      cosine[i] = c;
    }
  }
}

/// Pass 2: edges (dropouts, flying pixels), axial noise, quantisation.
DepthFrame degrade(const SensorModel& sensor, const std::vector<double>& depth,
                   const std::vector<double>& cosine, Noise& noise) {
  const Intrinsics& K = sensor.intrinsics;
  const int W = K.width, H = K.height;
  const std::size_t n = static_cast<std::size_t>(W) * H;
  const bool noisy = sensor.noise;
  DepthFrame frame;
  frame.intrinsics = K;
  frame.depth.assign(n, 0.0f);
  const double steps = sensor.quantisation > 0.0 ? 1.0 / sensor.quantisation : 0.0;
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * W + u;
      double z = depth[i];
      if (z <= 0.0) continue;
      if (noisy) {
        bool behind = false, in_front = false;
        double z_front = z;
        const std::array<std::pair<int, int>, 4> nbs = {
            {{u - 1, v}, {u + 1, v}, {u, v - 1}, {u, v + 1}}};
        for (const auto& [nu, nv] : nbs) {
          if (nu < 0 || nv < 0 || nu >= W || nv >= H) continue;
          const double zn = depth[static_cast<std::size_t>(nv) * W + nu];
          if (zn <= 0.0 || std::abs(zn - z) <= sensor.edge_jump * z) continue;
          if (zn < z) {
            behind = true;
            z_front = std::min(z_front, zn);
          } else {
            in_front = true;
          }
        }
        if (behind) {
          const double p = noise.uniform();
          if (p < sensor.edge_dropout) continue;
          if (p < sensor.edge_dropout + sensor.flying_pixel)
            z = z_front + noise.uniform() * (z - z_front);
        } else if (in_front && noise.uniform() < 0.5 * sensor.edge_dropout) {
          continue;
        }
        const double theta = std::acos(std::clamp(cosine[i], 0.0, 1.0));
        const double grazing = theta / (0.5 * kPi - theta);
        const double sigma = sensor.axial_a +
                             sensor.axial_b * (z - sensor.axial_z0) * (z - sensor.axial_z0) +
                             sensor.axial_incidence / std::sqrt(z) * grazing * grazing;
        z += sigma * noise.normal();
        if (steps > 0.0) z = std::round(z * steps) / steps;
        if (z < sensor.min_depth || z >= sensor.max_depth) continue;
      }
      frame.depth[i] = static_cast<float>(z);
    }
  }
  return frame;
}

}  // namespace

DepthFrame renderFrame(const World& world, const SensorModel& sensor, const Pose& T,
                       std::uint64_t noise_seed) {
  Noise noise(noise_seed);
  std::vector<double> depth, cosine;
  traceRays(world, sensor, T, noise, depth, cosine);
  return degrade(sensor, depth, cosine, noise);
}

}  // namespace detail
}  // namespace planesdf::sim
