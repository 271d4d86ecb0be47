// Splatting of points with normals (integratePointsWithNormals), for unorganised clouds. See
// tsdf.hpp for the contracts.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "fusion_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {
namespace fusion_detail {
namespace {

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
}  // namespace fusion_detail

// The fusion files' shared helpers, named unqualified as in one anonymous namespace.
using namespace fusion_detail;

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
  detail::BlockHashMap ids;
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
          const std::uint64_t key = detail::packBlockKey(Eigen::Vector3i(x, y, z));
          const auto [id, inserted] = ids.insert(key, static_cast<std::uint32_t>(keys.size()));
          if (inserted) keys.push_back(key);
          touches.emplace_back(id, si);
        }
  }
  res.num_points_fused = splats.size();
  {
    std::vector<std::vector<std::uint64_t>> fresh(1);
    for (const std::uint64_t k : keys)
      if (vol.blockSlot(detail::unpackBlockKey(k)) < 0) fresh[0].push_back(k);
    res.allocated_blocks = allocateKeys(vol, fresh, cfg);
  }

  // Block order = slot order; per block, its splats in input order (counting sort).
  std::vector<std::pair<std::uint32_t, std::uint32_t>> order(keys.size());  // (slot, id)
  for (std::size_t id = 0; id < keys.size(); ++id)
    order[id] = {static_cast<std::uint32_t>(vol.blockSlot(detail::unpackBlockKey(keys[id]))),
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
  parallelChunks(n, threads, 2, [&](int, long long begin, long long end) {
    for (long long i = begin; i < end; ++i) {
      const auto [slot, id] = order[i];
      slots[i] = slot;
      TsdfBlock& blk = vol.block(slot);
      BlockOutcome& o = outcomes[i];
      for (std::uint32_t k = start[id]; k < start[id + 1]; ++k)
        o.updates += applySplat(blk, splats[list[k]], trunc, r2, voxel, cfg.max_weight, &o.changed);
      o.in_view = o.updates > 0;
    }
  });
  finishIntegration(vol, slots, outcomes, res);
  return res;
}

}  // namespace planesdf
