// The sparse projective TSDF behind the simulator's reconstruction outputs: integration (blocks
// allocated around each frame's points, voxels updated by projecting their centres into the
// frame, as Open3D and voxblox do), zero-crossing points and marching cubes.
#include "reconstruct.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string_view>

#include "../numeric.hpp"
#include "../parallel.hpp"

namespace planesdf::sim::detail {
namespace {
using Eigen::Vector3d;
using Eigen::Vector3i;
using planesdf::detail::floorToIntOr;
using planesdf::detail::parallelFor;

constexpr int kSide = SparseTsdf::kBlockSide;

// ---- block keys ---------------------------------------------------------------------------------

// Block coordinates packed 21 bits per axis (+-2^20 blocks: +-5800 km at 7 mm voxels).
constexpr int kKeyBits = 21;
constexpr int kKeyOffset = 1 << (kKeyBits - 1);
constexpr std::uint64_t kKeyMask = (std::uint64_t{1} << kKeyBits) - 1;
// Block coordinates beyond this are not allocated (far outside any scene; keeps +1 in range).
constexpr int kMaxBlock = kKeyOffset - 2;

std::uint64_t packBlock(const Vector3i& b) {
  const auto axis = [](int v) { return static_cast<std::uint64_t>(v + kKeyOffset); };
  return (axis(b.x()) << (2 * kKeyBits)) | (axis(b.y()) << kKeyBits) | axis(b.z());
}

Vector3i unpackBlock(std::uint64_t key) {
  const auto axis = [](std::uint64_t v) { return static_cast<int>(v & kKeyMask) - kKeyOffset; };
  return {axis(key >> (2 * kKeyBits)), axis(key >> kKeyBits), axis(key)};
}

/// Block coordinates of `p` (metres) with blocks `block_size` wide; false when out of range.
bool blockOf(const Vector3d& p, double block_size, Vector3i& b) {
  for (int k = 0; k < 3; ++k) {
    b[k] = floorToIntOr(p[k] / block_size, kMaxBlock + 1);
    if (std::abs(b[k]) > kMaxBlock) return false;
  }
  return true;
}

// ---- voxel addressing ---------------------------------------------------------------------------

/// Which block of a SparseTsdf::Neighbourhood holds voxel (x, y, z) relative to its first block
/// (each in [0, 2 kSide)).
inline int blockSlot(int x, int y, int z) {
  return (x / kSide) | ((y / kSide) << 1) | ((z / kSide) << 2);
}

/// The voxel's index inside its block (x fastest).
inline int voxelIndex(int x, int y, int z) {
  return (x % kSide) + kSide * ((y % kSide) + kSide * (z % kSide));
}

// ---- marching cubes -----------------------------------------------------------------------------

// Corners of a cube in Paul Bourke's order (http://paulbourke.net/geometry/polygonise/).
constexpr int kCorner[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0},
                               {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
// Bourke's edge k runs from corner kEdgeCorner[k] along axis kEdgeAxis[k] (0 = x, 1 = y, 2 = z).
constexpr int kEdgeCorner[12] = {0, 1, 3, 0, 4, 5, 7, 4, 0, 1, 2, 3};
constexpr int kEdgeAxis[12] = {0, 1, 0, 1, 0, 1, 0, 1, 2, 2, 2, 2};

// Bourke's triangle table: for each cube configuration (bit k set when corner k is inside, SDF
// < 0), the edges of its triangles, three hex digits per triangle. His winding is
// counter-clockwise seen from the inside; triangles are emitted reversed.
// clang-format off
constexpr std::string_view kCases[256] = {
    /*   0 */ "",                "083",             "019",             "183981",
    /*   4 */ "12a",             "08312a",          "92a029",          "2832a8a98",
    /*   8 */ "3b2",             "0b28b0",          "19023b",          "1b219b98b",
    /*  12 */ "3a1ba3",          "0a108a8ba",       "3903b9ba9",       "98aa8b",
    /*  16 */ "478",             "430734",          "019847",          "419471731",
    /*  20 */ "12a847",          "34730412a",       "92a902847",       "2a9297273794",
    /*  24 */ "8473b2",          "b47b24204",       "90184723b",       "47b94b9b2921",
    /*  28 */ "3a13ba784",       "1ba14b1047b4",    "47890b9bab03",    "47b4b99ba",
    /*  32 */ "954",             "954083",          "054150",          "854835315",
    /*  36 */ "12a954",          "30812a495",       "52a542402",       "2a5325354348",
    /*  40 */ "95423b",          "0b208b495",       "05401523b",       "21525828b485",
    /*  44 */ "a3ba13954",       "4950818a18ba",    "54050b5bab03",    "54858aa8b",
    /*  48 */ "978579",          "930953573",       "078017157",       "153357",
    /*  52 */ "978957a12",       "a12950530573",    "802825857a52",    "2a5253357",
    /*  56 */ "7957893b2",       "95797292027b",    "23b018178157",    "b21b17715",
    /*  60 */ "958857a13a3b",    "5705097b010aba0", "ba0b03a50807570", "ba57b5",
    /*  64 */ "a65",             "0835a6",          "9015a6",          "1831985a6",
    /*  68 */ "165261",          "165126308",       "965906026",       "598582526328",
    /*  72 */ "23ba65",          "b08b20a65",       "01923b5a6",       "5a61929b298b",
    /*  76 */ "63b653513",       "08b0b50515b6",    "3b6036065059",    "65969bb98",
    /*  80 */ "5a6478",          "43047365a",       "1905a6847",       "a65197173794",
    /*  84 */ "612651478",       "125526304347",    "847905065026",    "739794329596269",
    /*  88 */ "3b2784a65",       "5a647242027b",    "01947823b5a6",    "9219b294b7b45a6",
    /*  92 */ "8473b53515b6",    "51b5b610b7b404b", "059065036b63847", "65969b4797b9",
    /*  96 */ "a4964a",          "4a649a083",       "a01a60640",       "83181686461a",
    /* 100 */ "149124264",       "308129249264",    "024426",          "832824426",
    /* 104 */ "a49a64b23",       "08228b49a4a6",    "3b201606461a",    "64161a48121b8b1",
    /* 108 */ "964936913b63",    "8b1810b61914641", "3b6360064",       "648b68",
    /* 112 */ "7a678a89a",       "0730a709a67a",    "a671a7178180",    "a67a71173",
    /* 116 */ "126168189867",    "269291679093739", "780706602",       "732672",
    /* 120 */ "23ba68a89867",    "20727b09767a9a7", "1801781a767a23b", "b21b17a61671",
    /* 124 */ "896867916b63136", "091b67",          "7807063b0b60",    "7b6",
    /* 128 */ "76b",             "308b76",          "019b76",          "819831b76",
    /* 132 */ "a126b7",          "12a3086b7",       "2902a96b7",       "6b72a3a83a98",
    /* 136 */ "723627",          "708760620",       "276237019",       "162186198876",
    /* 140 */ "a76a17137",       "a7617a187108",    "03707a0a96a7",    "76a7a88a9",
    /* 144 */ "684b86",          "36b306046",       "86b846901",       "946963931b36",
    /* 148 */ "6846b82a1",       "12a30b06b046",    "4b846b0292a9",    "a93a32943b36463",
    /* 152 */ "823842462",       "042462",          "190234246438",    "194142246",
    /* 156 */ "8138618466a1",    "a10a06604",       "4634386a3039a93", "a946a4",
    /* 160 */ "49576b",          "083495b76",       "50154076b",       "b76834354315",
    /* 164 */ "954a1276b",       "6b712a083495",    "76b54a42a402",    "348354325a52b76",
    /* 168 */ "723762549",       "954086062687",    "362376150540",    "628687218485158",
    /* 172 */ "954a16176137",    "16a176107870954", "40a4a503a6a737a", "76a7a854a48a",
    /* 176 */ "6956b9b89",       "36b063056095",    "0b805b01556b",    "6b3635531",
    /* 180 */ "12a95b9b8b56",    "0b306b09656912a", "b85b56805a52025", "6b36352a3a53",
    /* 184 */ "589528562382",    "956960062",       "158180568382628", "156216",
    /* 188 */ "13616a386569896", "a10a06950560",    "03856a",          "a56",
    /* 192 */ "b5a75b",          "b5ab75830",       "5b75ab190",       "a75ab7981831",
    /* 196 */ "b12b71751",       "08312717572b",    "9759279022b7",    "75272b592328982",
    /* 200 */ "25a235375",       "820852875a25",    "9015a35373a2",    "982921872a25752",
    /* 204 */ "135375",          "087071175",       "903935537",       "987597",
    /* 208 */ "5845a8ab8",       "5045b05abb30",    "01984a8aba45",    "ab4a45b34941314",
    /* 212 */ "2512852b8458",    "04b0b345b2b151b", "0250592b5458b85", "9452b3",
    /* 216 */ "25a352345384",    "5a2524420",       "3a235a385458019", "5a2524192942",
    /* 220 */ "845853351",       "045105",          "845853905035",    "945",
    /* 224 */ "4b749b9ab",       "0834979b79ab",    "1ab1b414074b",    "3143481a474bab4",
    /* 228 */ "4b79b492b912",    "9749b791b2b1083", "b74b42240",       "b74b42834324",
    /* 232 */ "29a279237749",    "9a7974a27870207", "37a3a274a1a040a", "1a2874",
    /* 236 */ "491417713",       "491417081871",    "403743",          "487",
    /* 240 */ "9a8ab8",          "30939bb9a",       "01a0a88ab",       "31ab3a",
    /* 244 */ "12b1b99b8",       "30939b1292b9",    "02b80b",          "32b",
    /* 248 */ "23828aa89",       "9a2092",          "23828a0181a8",    "1a2",
    /* 252 */ "138918",          "091",             "038",             "",
};
// clang-format on

int hexDigit(char c) {
  return c <= '9' ? c - '0' : c - 'a' + 10;
}

}  // namespace

// ---- integration --------------------------------------------------------------------------------

SparseTsdf::SparseTsdf(double voxel, double truncation, double max_depth)
    : voxel_(voxel), truncation_(truncation), max_depth_(max_depth) {}

std::size_t SparseTsdf::bytes() const {
  return blocks_.size() * sizeof(Block) + blocks_.capacity() * sizeof(blocks_[0]) +
         keys_.capacity() * sizeof(std::uint64_t) + index_.bytes();
}

std::vector<std::uint64_t> SparseTsdf::touchedBlocks(const DepthFrame& frame,
                                                     const Pose& camera_to_world,
                                                     int threads) const {
  const Intrinsics& K = frame.intrinsics;
  const double block_size = kSide * voxel_;
  const int t = std::max(1, threads);
  std::vector<std::vector<std::uint64_t>> found(static_cast<std::size_t>(t));
  // Neighbouring pixels touch the same blocks: a small direct-mapped cache of recent keys per
  // worker keeps most repeats out of its list.
  std::vector<std::vector<std::uint64_t>> recents(static_cast<std::size_t>(t));
  planesdf::detail::parallelChunks(K.height, t, 8, [&](int worker, long long v0, long long v1) {
    std::vector<std::uint64_t>& out = found[static_cast<std::size_t>(worker)];
    std::vector<std::uint64_t>& recent = recents[static_cast<std::size_t>(worker)];
    if (recent.empty()) recent.assign(4096, ~std::uint64_t{0});
    for (int v = static_cast<int>(v0); v < v1; ++v)
      for (int u = 0; u < K.width; ++u) {
        const float z = frame.at(u, v);
        if (!DepthFrame::isValidDepth(z) || z > max_depth_) continue;
        const Vector3d p =
            camera_to_world * Vector3d((u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z);
        Vector3i lo, hi;
        if (!blockOf(p.array() - truncation_, block_size, lo) ||
            !blockOf(p.array() + truncation_, block_size, hi))
          continue;
        for (int bz = lo.z(); bz <= hi.z(); ++bz)
          for (int by = lo.y(); by <= hi.y(); ++by)
            for (int bx = lo.x(); bx <= hi.x(); ++bx) {
              const std::uint64_t key = packBlock({bx, by, bz});
              std::uint64_t& slot = recent[(key * 0x9E3779B97F4A7C15ull) >> 52];
              if (slot == key) continue;
              slot = key;
              out.push_back(key);
            }
      }
  });
  std::vector<std::uint64_t> keys;
  for (const std::vector<std::uint64_t>& f : found) keys.insert(keys.end(), f.begin(), f.end());
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  return keys;
}

void SparseTsdf::updateBlock(Block& block, std::uint64_t key, const DepthFrame& frame,
                             const Pose& world_to_camera) const {
  const Intrinsics& K = frame.intrinsics;
  const Vector3d first_centre = ((unpackBlock(key) * kSide).cast<double>().array() + 0.5) * voxel_;
  const Vector3d origin = world_to_camera * first_centre;
  const Eigen::Matrix3d step = world_to_camera.linear() * voxel_;  // column k: one voxel along k
  constexpr std::uint16_t kMaxWeight = std::numeric_limits<std::uint16_t>::max();
  for (int z = 0; z < kSide; ++z)
    for (int y = 0; y < kSide; ++y)
      for (int x = 0; x < kSide; ++x) {
        const Vector3d q = origin + step.col(0) * x + step.col(1) * y + step.col(2) * z;
        if (q.z() <= 0.0) continue;
        // The nearest pixel (Open3D rounds too) is floor(u), floor(v), which is the truncation
        // once they are known to be >= 0; the range test also rejects NaN.
        const double inv_z = 1.0 / q.z();
        const double u = K.fx * q.x() * inv_z + K.cx + 0.5;
        const double v = K.fy * q.y() * inv_z + K.cy + 0.5;
        if (!(u >= 0.0 && u < K.width && v >= 0.0 && v < K.height)) continue;
        const float d = frame.at(static_cast<int>(u), static_cast<int>(v));
        if (!DepthFrame::isValidDepth(d) || d > max_depth_) continue;
        const double sdf = d - q.z();
        if (sdf < -truncation_) continue;  // hidden behind the surface: unknown
        const int i = voxelIndex(x, y, z);
        const std::uint16_t w = block.weight[static_cast<std::size_t>(i)];
        if (w == kMaxWeight) continue;
        float& mean = block.sdf[static_cast<std::size_t>(i)];
        mean = static_cast<float>((mean * w + std::min(sdf, truncation_)) / (w + 1.0));
        block.weight[static_cast<std::size_t>(i)] = static_cast<std::uint16_t>(w + 1);
      }
}

void SparseTsdf::integrate(const DepthFrame& frame, const Pose& camera_to_world, int threads) {
  const std::vector<std::uint64_t> keys = touchedBlocks(frame, camera_to_world, threads);
  std::vector<std::uint32_t> ids(keys.size());
  for (std::size_t i = 0; i < keys.size(); ++i) {
    ids[i] = index_.insert(keys[i]);
    if (ids[i] == blocks_.size()) {
      keys_.push_back(keys[i]);
      blocks_.push_back(std::make_unique<Block>());
    }
  }
  const Pose world_to_camera = camera_to_world.inverse();
  parallelFor(static_cast<int>(ids.size()), threads, [&](int i) {
    const auto k = static_cast<std::size_t>(i);
    updateBlock(*blocks_[ids[k]], keys[k], frame, world_to_camera);
  });
}

// ---- surface ------------------------------------------------------------------------------------

/// The zero-crossing points of one block's voxels toward their +x / +y / +z neighbours, in voxel
/// then axis order, each with its edge code (voxel index * 3 + axis, ascending); `first` is the
/// index of its first point in the whole surface.
struct SparseTsdf::BlockSurface {
  std::vector<Vector3d> points;
  std::vector<std::uint16_t> edges;
  std::size_t first = 0;
};

std::vector<std::uint32_t> SparseTsdf::blocksInKeyOrder() const {
  std::vector<std::uint32_t> order(blocks_.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<std::uint32_t>(i);
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return keys_[a] < keys_[b]; });
  return order;
}

SparseTsdf::Neighbourhood SparseTsdf::neighbourhood(std::uint32_t b) const {
  Neighbourhood n;
  const Vector3i first = unpackBlock(keys_[b]);
  for (int slot = 0; slot < 8; ++slot) {
    const Vector3i offset(slot & 1, (slot >> 1) & 1, slot >> 2);
    const std::uint32_t id = slot == 0 ? b : index_.find(packBlock(first + offset));
    n.ids[static_cast<std::size_t>(slot)] = id;
    n.blocks[static_cast<std::size_t>(slot)] = id == KeyIndex::kNone ? nullptr : blocks_[id].get();
  }
  return n;
}

namespace {

/// False when voxel (x, y, z) of `n` (relative to its first block, each in [0, 2 kSide)) is not
/// allocated or was observed fewer than `min_weight` times; else its SDF.
bool readVoxel(const SparseTsdf::Neighbourhood& n, int x, int y, int z, int min_weight,
               float& sdf) {
  const SparseTsdf::Block* b = n.blocks[static_cast<std::size_t>(blockSlot(x, y, z))];
  if (!b) return false;
  const auto i = static_cast<std::size_t>(voxelIndex(x, y, z));
  if (b->weight[i] < min_weight) return false;
  sdf = b->sdf[i];
  return true;
}

}  // namespace

SparseTsdf::BlockSurface SparseTsdf::blockPoints(std::uint32_t b, int min_weight) const {
  const Neighbourhood n = neighbourhood(b);
  BlockSurface out;
  const Vector3d first_centre =
      ((unpackBlock(keys_[b]) * kSide).cast<double>().array() + 0.5) * voxel_;
  for (int z = 0; z < kSide; ++z)
    for (int y = 0; y < kSide; ++y)
      for (int x = 0; x < kSide; ++x) {
        float s = 0.0f;
        if (!readVoxel(n, x, y, z, min_weight, s)) continue;
        const Vector3d centre = first_centre + voxel_ * Vector3d(x, y, z);
        for (int axis = 0; axis < 3; ++axis) {
          float s1 = 0.0f;
          if (!readVoxel(n, x + (axis == 0), y + (axis == 1), z + (axis == 2), min_weight, s1))
            continue;
          if ((s < 0.0f) == (s1 < 0.0f)) continue;
          // Linear zero crossing; s - s1 is nonzero since exactly one of them is negative.
          const double t = static_cast<double>(s) / (static_cast<double>(s) - s1);
          Vector3d p = centre;
          p[axis] += t * voxel_;
          out.points.push_back(p);
          out.edges.push_back(static_cast<std::uint16_t>(voxelIndex(x, y, z) * 3 + axis));
        }
      }
  return out;
}

std::vector<Triangle> SparseTsdf::blockTriangles(std::uint32_t b, int min_weight,
                                                 const std::vector<BlockSurface>& surfaces) const {
  const Neighbourhood n = neighbourhood(b);
  // The surface point on edge `axis` from voxel (x, y, z) of the neighbourhood.
  const auto vertex = [&](int x, int y, int z, int axis, std::uint32_t& index) {
    const std::uint32_t id = n.ids[static_cast<std::size_t>(blockSlot(x, y, z))];
    const BlockSurface& s = surfaces[id];
    const auto code = static_cast<std::uint16_t>(voxelIndex(x, y, z) * 3 + axis);
    const auto it = std::lower_bound(s.edges.begin(), s.edges.end(), code);
    if (it == s.edges.end() || *it != code) return false;
    index = static_cast<std::uint32_t>(s.first + static_cast<std::size_t>(it - s.edges.begin()));
    return true;
  };
  std::vector<Triangle> out;
  for (int z = 0; z < kSide; ++z)
    for (int y = 0; y < kSide; ++y)
      for (int x = 0; x < kSide; ++x) {
        int config = 0;
        bool observed = true;
        for (int c = 0; c < 8 && observed; ++c) {
          float s = 0.0f;
          observed =
              readVoxel(n, x + kCorner[c][0], y + kCorner[c][1], z + kCorner[c][2], min_weight, s);
          if (s < 0.0f) config |= 1 << c;
        }
        if (!observed || config == 0 || config == 255) continue;
        const std::string_view edges = kCases[config];
        for (std::size_t k = 0; k + 3 <= edges.size(); k += 3) {
          Triangle t{};
          bool found = true;
          for (std::size_t j = 0; j < 3 && found; ++j) {
            const int e = hexDigit(edges[k + j]);
            const int* c = kCorner[kEdgeCorner[e]];
            found = vertex(x + c[0], y + c[1], z + c[2], kEdgeAxis[e], t[j]);
          }
          // Every edge of an observed cube with a sign change has its point; reversed winding:
          // counter-clockwise seen from the positive side.
          if (found) out.push_back({t[0], t[2], t[1]});
        }
      }
  return out;
}

TsdfSurface SparseTsdf::extractSurface(int min_weight, int threads) const {
  const std::vector<std::uint32_t> order = blocksInKeyOrder();
  const int n = static_cast<int>(order.size());
  std::vector<BlockSurface> surfaces(blocks_.size());
  parallelFor(n, threads, [&](int r) {
    const std::uint32_t b = order[static_cast<std::size_t>(r)];
    surfaces[b] = blockPoints(b, min_weight);
  });
  TsdfSurface out;
  std::size_t total = 0;
  for (const std::uint32_t b : order) {
    surfaces[b].first = total;
    total += surfaces[b].points.size();
  }
  out.points.reserve(total);
  for (const std::uint32_t b : order) {
    out.points.insert(out.points.end(), surfaces[b].points.begin(), surfaces[b].points.end());
    std::vector<Vector3d>().swap(surfaces[b].points);  // only the edge codes are needed now
  }

  std::vector<std::vector<Triangle>> triangles(order.size());
  parallelFor(n, threads, [&](int r) {
    const auto k = static_cast<std::size_t>(r);
    triangles[k] = blockTriangles(order[k], min_weight, surfaces);
  });
  for (std::vector<Triangle>& t : triangles) {
    out.triangles.insert(out.triangles.end(), t.begin(), t.end());
    std::vector<Triangle>().swap(t);
  }
  return out;
}

}  // namespace planesdf::sim::detail
