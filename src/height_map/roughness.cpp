// Local roughness of a height map per tile (see height_map.hpp, computeRoughness).

#include <algorithm>
#include <cmath>
#include <vector>

#include "planesdf/height_map.hpp"

namespace planesdf {
namespace {

constexpr int kLag = 2;                    ///< cells between the two cells of a pair
constexpr double kQuantile = 0.75;         ///< of the pairs' absolute differences
constexpr double kMinPairFraction = 0.25;  ///< of a tile's possible pairs, for an estimate

/// The pairs' quantile of one tile [x0, x1) x [y0, y1), or 0 with too few pairs.
float tileRoughness(const HeightMap& hm, int x0, int x1, int y0, int y1, float cap,
                    std::vector<float>& diffs) {
  diffs.clear();
  const auto usable = [&](int x, int y) {
    const float h = hm.at(x, y);
    return h != kUnobserved && h <= cap;
  };
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      if (!usable(x, y)) continue;
      const float h = hm.at(x, y);
      if (x + kLag < x1 && usable(x + kLag, y)) diffs.push_back(std::abs(h - hm.at(x + kLag, y)));
      if (y + kLag < y1 && usable(x, y + kLag)) diffs.push_back(std::abs(h - hm.at(x, y + kLag)));
    }
  const int w = x1 - x0, h = y1 - y0;
  const int possible = std::max(0, w - kLag) * h + std::max(0, h - kLag) * w;
  if (possible == 0 || static_cast<double>(diffs.size()) < kMinPairFraction * possible) return 0.0f;
  const auto k = static_cast<std::size_t>(kQuantile * static_cast<double>(diffs.size() - 1));
  std::nth_element(diffs.begin(), diffs.begin() + static_cast<std::ptrdiff_t>(k), diffs.end());
  return diffs[k];
}

}  // namespace

RoughnessMap computeRoughness(const HeightMap& hm, const Config& cfg) {
  RoughnessMap r;
  if (cfg.roughness_tile <= 0 || hm.empty()) return r;
  r.tile = cfg.roughness_tile;
  r.tiles_x = (hm.width + r.tile - 1) / r.tile;
  r.tiles_y = (hm.height + r.tile - 1) / r.tile;
  r.sigma.assign(static_cast<std::size_t>(r.tiles_x) * static_cast<std::size_t>(r.tiles_y), 0.0f);
  const auto cap = static_cast<float>(2.0 * cfg.delta_h);
  std::vector<float> diffs;
  for (int ty = 0; ty < r.tiles_y; ++ty)
    for (int tx = 0; tx < r.tiles_x; ++tx) {
      const int x0 = tx * r.tile, y0 = ty * r.tile;
      r.sigma[static_cast<std::size_t>(ty) * static_cast<std::size_t>(r.tiles_x) +
              static_cast<std::size_t>(tx)] =
          tileRoughness(hm, x0, std::min(hm.width, x0 + r.tile), y0,
                        std::min(hm.height, y0 + r.tile), cap, diffs);
    }
  return r;
}

}  // namespace planesdf
