// What depth integration and splatting share: the config check, the thread count, the height
// band and the bookkeeping of a pass's outcomes. See tsdf.hpp for the contracts.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "fusion_internal.hpp"
#include "planesdf/error.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {
namespace fusion_detail {

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

}  // namespace fusion_detail

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

}  // namespace planesdf
