// The voxels a blob is validated on (see voxel_region.hpp).

#include "voxel_region.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace planesdf::detail {

SurfaceSupport surfaceSupport(const TsdfVolume& vol, const HeightMap& hm, const Config& cfg,
                              const std::vector<Eigen::Vector2i>& cells, int ring) {
  Eigen::AlignedBox2i box;
  for (const Eigen::Vector2i& c : cells) box.extend(c);
  if (box.isEmpty()) return {};
  box.min() = (box.min().array() - ring).max(0);
  box.max() = (box.max().array() + ring).min(Eigen::Array2i(hm.width - 1, hm.height - 1));
  const int bw = box.sizes().x() + 1;
  const auto local = [&](int x, int y) {
    return static_cast<std::size_t>((y - box.min().y()) * bw + (x - box.min().x()));
  };
  std::vector<std::uint8_t> in_blob(static_cast<std::size_t>(bw) * (box.sizes().y() + 1), 0);
  for (const Eigen::Vector2i& c : cells) in_blob[local(c.x(), c.y())] = 1;
  const double vs = vol.voxelSize();
  const auto surfaceWeight = [&](int x, int y) {
    const int k = static_cast<int>(std::floor(hm.at(x, y) / vs));
    float w = 0.0f;
    for (int dk = -1; dk <= 1; ++dk)
      if (const TsdfVoxel* v = vol.voxel(Eigen::Vector3i(hm.i0 + x, hm.j0 + y, k + dk)))
        w = std::max(w, v->weight);
    return static_cast<double>(w);
  };
  double sum[2] = {0.0, 0.0};
  int count[2] = {0, 0};
  for (int y = box.min().y(); y <= box.max().y(); ++y)
    for (int x = box.min().x(); x <= box.max().x(); ++x) {
      const float h = hm.at(x, y);
      if (h == kUnobserved) continue;
      const int side = in_blob[local(x, y)] ? 0 : 1;
      if (side == 0 && !(h > cfg.h_obj)) continue;  // a grown cell on the support
      sum[side] += surfaceWeight(x, y);
      ++count[side];
    }
  if (count[0] == 0 || count[1] == 0) return {};
  return {sum[0] / count[0], sum[1] / count[1]};
}

void columnVoxels(const TsdfVolume& vol, int i, int j, double lo, double hi, float w_min,
                  std::vector<Eigen::Vector3i>& out) {
  const double vs = vol.voxelSize();
  const int k0 = static_cast<int>(std::ceil(lo / vs - 0.5));
  const int k1 = static_cast<int>(std::floor(hi / vs - 0.5));
  for (int k = k0; k <= k1; ++k) {
    const Eigen::Vector3i v(i, j, k);
    const TsdfVoxel* vox = vol.voxel(v);
    if (vox != nullptr && vox->weight > 0.0f && vox->weight >= w_min) out.push_back(v);
  }
}
TsdfVolume completedRegion(const TsdfVolume& vol, const HeightMap& hm, const Eigen::Vector3i& lo,
                           const Eigen::Vector3i& hi, const std::vector<std::uint8_t>& need,
                           float w_min) {
  TsdfVolume out(vol.voxelSize(), vol.truncation());
  const double vs = vol.voxelSize();
  const double trunc = vol.truncation();
  const float w_fill = std::max(w_min, 1.0f);
  const int nx = hi.x() - lo.x() + 1;
  // Block by block: one lookup of the source block and, on the first voxel written, one
  // allocation of the output block; voxels in storage order (x fastest, then y, then z).
  const Eigen::Vector3i blo = TsdfVolume::blockOfVoxel(lo), bhi = TsdfVolume::blockOfVoxel(hi);
  // At most the blocks of the block columns holding a needed column, reserved at once.
  std::size_t columns_needed = 0;
  for (int by = blo.y(); by <= bhi.y(); ++by)
    for (int bx = blo.x(); bx <= bhi.x(); ++bx) {
      bool any = false;
      for (int j = std::max(lo.y(), by * kTsdfBlockSide);
           !any && j <= std::min(hi.y(), (by + 1) * kTsdfBlockSide - 1); ++j)
        for (int i = std::max(lo.x(), bx * kTsdfBlockSide);
             !any && i <= std::min(hi.x(), (bx + 1) * kTsdfBlockSide - 1); ++i)
          any = need[static_cast<std::size_t>(j - lo.y()) * nx + (i - lo.x())] != 0;
      columns_needed += any ? 1 : 0;
    }
  out.reserveBlocks(columns_needed * static_cast<std::size_t>(bhi.z() - blo.z() + 1));
  for (int bz = blo.z(); bz <= bhi.z(); ++bz)
    for (int by = blo.y(); by <= bhi.y(); ++by)
      for (int bx = blo.x(); bx <= bhi.x(); ++bx) {
        const Eigen::Vector3i b(bx, by, bz);
        const TsdfBlock* src_block = vol.findBlock(b);
        TsdfBlock* out_block = nullptr;
        const Eigen::Vector3i v0 = b * kTsdfBlockSide;
        for (int k = std::max(lo.z(), v0.z()); k <= std::min(hi.z(), v0.z() + kTsdfBlockSide - 1);
             ++k)
          for (int j = std::max(lo.y(), v0.y()); j <= std::min(hi.y(), v0.y() + kTsdfBlockSide - 1);
               ++j)
            for (int i = std::max(lo.x(), v0.x());
                 i <= std::min(hi.x(), v0.x() + kTsdfBlockSide - 1); ++i) {
              if (!need[static_cast<std::size_t>(j - lo.y()) * nx + (i - lo.x())]) continue;
              const Eigen::Vector3i v(i, j, k);
              const auto li = static_cast<std::size_t>(TsdfVolume::linearIndexInBlock(v));
              TsdfVoxel val = src_block != nullptr ? src_block->voxels[li] : TsdfVoxel{};
              if (!(val.weight > 0.0f && val.weight >= w_min)) {
                const int x = i - hm.i0, y = j - hm.j0;
                const bool col_known = hm.inBounds(x, y) && hm.observed(x, y);
                const double above =
                    (k + 0.5) * vs - (col_known ? static_cast<double>(hm.at(x, y)) : 0.0);
                if (col_known && above > 0.0) {
                  val = TsdfVoxel{static_cast<float>(std::min(above, trunc)), w_fill};
                } else if (val.weight <= 0.0f) {
                  continue;
                }
              }
              if (out_block == nullptr) out_block = &out.allocateBlock(b);
              out_block->voxels[li] = val;
            }
      }
  return out;
}
std::vector<std::uint8_t> columnsNear(std::vector<Eigen::Vector2i> columns,
                                      const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                                      int margin) {
  const int nx = hi.x() - lo.x() + 1, ny = hi.y() - lo.y() + 1;
  std::vector<std::uint8_t> need(static_cast<std::size_t>(nx) * ny, 0);
  std::sort(columns.begin(), columns.end(), [](const Eigen::Vector2i& a, const Eigen::Vector2i& b) {
    return a.x() != b.x() ? a.x() < b.x() : a.y() < b.y();
  });
  columns.erase(std::unique(columns.begin(), columns.end()), columns.end());
  for (const Eigen::Vector2i& c : columns)
    for (int y = std::max(0, c.y() - lo.y() - margin);
         y <= std::min(ny - 1, c.y() - lo.y() + margin); ++y)
      for (int x = std::max(0, c.x() - lo.x() - margin);
           x <= std::min(nx - 1, c.x() - lo.x() + margin); ++x)
        need[static_cast<std::size_t>(y) * nx + x] = 1;
  return need;
}
std::pair<Eigen::Vector3i, Eigen::Vector3i> voxelBox(const std::vector<Eigen::Vector3i>& voxels,
                                                     int margin) {
  Eigen::Vector3i lo = voxels.front(), hi = voxels.front();
  for (const auto& v : voxels) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  return {lo.array() - margin, hi.array() + margin};
}
std::pair<Eigen::Vector3i, Eigen::Vector3i> mappedBox(const Eigen::Vector3i& lo,
                                                      const Eigen::Vector3i& hi, const Pose& T,
                                                      double vs, int margin) {
  Eigen::Vector3d mn = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d mx = -mn;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3d corner(((c & 1) ? hi.x() + 1 : lo.x()) * vs,
                                 ((c & 2) ? hi.y() + 1 : lo.y()) * vs,
                                 ((c & 4) ? hi.z() + 1 : lo.z()) * vs);
    const Eigen::Vector3d q = T * corner;
    mn = mn.cwiseMin(q);
    mx = mx.cwiseMax(q);
  }
  const Eigen::Vector3i a((mn / vs).array().floor().cast<int>() - margin);
  const Eigen::Vector3i b((mx / vs).array().floor().cast<int>() + margin);
  return {a, b};
}

}  // namespace planesdf::detail
