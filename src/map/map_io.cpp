// Map save/load: a versioned little-endian binary format.
//
//   header  : magic "PSDFMAP\0" (8 bytes), u32 format version, u32 flags (bit 0: splatted;
//             other bits 0; written 0 before the flag existed),
//             u64 payload size
//   payload : config as JSON (u32 length + bytes), u64 frames, u8 has_up + 3 f64 up,
//             u32 plane count, then per plane: i32 id, 3 f64 normal, f64 offset,
//             u8 orientation, u64 support, u8 extent_empty + 4 f64 extent (min u, min v,
//             max u, max v), 3 f64 frame origin, 9 f64 frame axes (column-major),
//             f64 voxel size, f64 truncation, u32 block count, per block 3 i32 index +
//             512 x (f32 sdf, f32 weight); u64 point count + 3 f32 per point
//   trailer : u64 checksum of the payload: version 2, checksum64 (FNV-1a steps over 8-byte
//             words in 4 interleaved lanes, then the tail bytes, folded); version 1 (read
//             only), byte-wise FNV-1a, which reads under 1 GB/s
//
// Every count is checked against the bytes left before anything is allocated.
#include <cstring>
#include <type_traits>

#if defined(__linux__)
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
#endif

#include "../binary.hpp"
#include "map_checksum.hpp"
#include "map_internal.hpp"
#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/map.hpp"

namespace planesdf {
namespace {

using detail::checksum64;
using detail::fnv1a;

constexpr char kMagic[8] = {'P', 'S', 'D', 'F', 'M', 'A', 'P', '\0'};
constexpr std::uint32_t kVersion = 2;
constexpr std::uint32_t kOldestReadableVersion = 1;  // same layout, byte-wise FNV-1a checksum
constexpr std::size_t kHeaderSize = 8 + 4 + 4 + 8;
constexpr std::uint32_t kFlagSplatted = 1;  ///< header flags: Map::splatted()
constexpr std::size_t kBlockBytes = 3 * 4 + kTsdfBlockVoxels * 8;

using detail::Reader;
using detail::Writer;

class MappedFile {
 public:
  explicit MappedFile(const std::string& path) {
#if defined(__linux__)
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return;
    struct stat st {};
    if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) {
      const auto size = static_cast<std::size_t>(st.st_size);
      void* p = ::mmap(nullptr, size, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
      if (p != MAP_FAILED) {
        data_ = p;
        size_ = size;
      }
    }
    ::close(fd);
#else
    (void)path;
#endif
  }
  ~MappedFile() {
#if defined(__linux__)
    if (data_ != nullptr) ::munmap(data_, size_);
#endif
  }
  MappedFile(const MappedFile&) = delete;
  MappedFile& operator=(const MappedFile&) = delete;
  bool ok() const {
    return data_ != nullptr;
  }
  const char* data() const {
    return static_cast<const char*>(data_);
  }
  std::size_t size() const {
    return size_;
  }

 private:
  void* data_ = nullptr;
  std::size_t size_ = 0;
};

}  // namespace

std::string Map::serialize() const {
  Writer w;
  std::size_t blocks = 0;
  for (const auto& ps : planes_) blocks += ps.volume.numBlocks();
  w.out.reserve(4096 + planes_.size() * 256 + blocks * kBlockBytes + points_.size() * 12);
  const std::string cfg_json = configToJson(cfg_);
  w.put<std::uint32_t>(static_cast<std::uint32_t>(cfg_json.size()));
  w.putBytes(cfg_json.data(), cfg_json.size());
  w.put<std::uint64_t>(frames_);
  const auto up = tracker_.up();
  w.put<std::uint8_t>(up ? 1 : 0);
  w.putVec(up.value_or(Eigen::Vector3d::Zero()));
  w.put<std::uint32_t>(static_cast<std::uint32_t>(planes_.size()));
  for (const PlaneSdf& ps : planes_) {
    const Plane& p = ps.plane;
    w.put<std::int32_t>(p.id);
    w.putVec(p.normal);
    w.put<double>(p.offset);
    w.put<std::uint8_t>(p.orientation == Plane::Orientation::Horizontal ? 0 : 1);
    w.put<std::uint64_t>(p.support);
    w.put<std::uint8_t>(p.extent.isEmpty() ? 1 : 0);
    for (int i = 0; i < 2; ++i) w.put<double>(p.extent.min()[i]);
    for (int i = 0; i < 2; ++i) w.put<double>(p.extent.max()[i]);
    w.putVec(p.frame_origin);
    for (int i = 0; i < 9; ++i) w.put<double>(p.frame_axes.data()[i]);
    w.put<double>(ps.volume.voxelSize());
    w.put<double>(ps.volume.truncation());
    w.put<std::uint32_t>(static_cast<std::uint32_t>(ps.volume.numBlocks()));
    ps.volume.forEachBlock([&](const TsdfBlock& b) {
      for (int i = 0; i < 3; ++i) w.put<std::int32_t>(b.index[i]);
      w.putBytes(b.voxels.data(), sizeof(TsdfVoxel) * kTsdfBlockVoxels);
    });
  }
  w.put<std::uint64_t>(points_.size());
  std::vector<float> xyz(points_.size() * 3);
  for (std::size_t i = 0; i < points_.size(); ++i)
    for (int k = 0; k < 3; ++k) xyz[3 * i + k] = points_[i][k];
  w.putBytes(xyz.data(), xyz.size() * sizeof(float));

  Writer file;
  file.putBytes(kMagic, sizeof(kMagic));
  file.put<std::uint32_t>(kVersion);
  file.put<std::uint32_t>(splatted_ ? kFlagSplatted : 0u);
  file.put<std::uint64_t>(w.out.size());
  file.out += w.out;
  file.put<std::uint64_t>(checksum64(w.out.data(), w.out.size()));
  return std::move(file.out);
}

Map Map::deserialize(const std::string& bytes, const std::string& name) {
  return deserializeBytes(bytes.data(), bytes.size(), name);
}

Map Map::deserializeBytes(const char* data, std::size_t size, const std::string& name) {
  if (size < kHeaderSize + 8 || std::memcmp(data, kMagic, sizeof(kMagic)) != 0)
    throw Error(name, "not a planesdf map (no PSDFMAP header)");
  Reader head(data, 8, kHeaderSize, name);
  const auto version = head.get<std::uint32_t>("version");
  if (version < kOldestReadableVersion || version > kVersion)
    throw Error(name, "map format version " + std::to_string(version) +
                          " is not supported (this build reads versions " +
                          std::to_string(kOldestReadableVersion) + " to " +
                          std::to_string(kVersion) + ")");
  const auto flags = head.get<std::uint32_t>("flags");
  const auto payload = head.get<std::uint64_t>("payload size");
  if (payload != size - kHeaderSize - 8)
    throw Error(name, "corrupt map: header declares " + std::to_string(payload) +
                          " payload bytes, the file holds " +
                          std::to_string(size - kHeaderSize - 8) + " (truncated?)");
  std::uint64_t stored = 0;
  std::memcpy(&stored, data + size - 8, 8);
  const char* body = data + kHeaderSize;
  if (stored != (version == 1 ? fnv1a(body, payload) : checksum64(body, payload)))
    throw Error(name, "corrupt map: checksum mismatch");

  Reader r(data, kHeaderSize, kHeaderSize + payload, name);
  const auto cfg_len = r.get<std::uint32_t>("config length");
  r.needItems(cfg_len, 1, "config");
  const std::string cfg_json(r.take(cfg_len, "config"), cfg_len);
  const Config cfg = parseConfigJson(cfg_json, name + " (embedded config)");
  Map m(cfg);
  m.frames_ = r.get<std::uint64_t>("frames");
  m.splatted_ = (flags & kFlagSplatted) != 0;
  const bool has_up = r.get<std::uint8_t>("up flag") != 0;
  const Eigen::Vector3d up = r.getVec("up");

  const auto n_planes = r.get<std::uint32_t>("plane count");
  r.needItems(n_planes, 4 + 8 * 4 + 1 + 8 + 1 + 8 * 4 + 8 * 12 + 8 * 2 + 4, "plane");
  std::vector<Plane> planes;
  for (std::uint32_t i = 0; i < n_planes; ++i) {
    Plane p;
    p.id = r.get<std::int32_t>("plane id");
    if (p.id != static_cast<std::int32_t>(i)) r.fail("plane ids are not 0..n-1");
    p.normal = r.getVec("plane normal");
    p.offset = r.get<double>("plane offset");
    p.orientation = r.get<std::uint8_t>("orientation") == 0 ? Plane::Orientation::Horizontal
                                                            : Plane::Orientation::Vertical;
    p.support = r.get<std::uint64_t>("support");
    const bool empty = r.get<std::uint8_t>("extent flag") != 0;
    Eigen::Vector2d lo, hi;
    for (int k = 0; k < 2; ++k) lo[k] = r.get<double>("extent");
    for (int k = 0; k < 2; ++k) hi[k] = r.get<double>("extent");
    p.extent = empty ? Eigen::AlignedBox2d() : Eigen::AlignedBox2d(lo, hi);
    p.frame_origin = r.getVec("frame origin");
    for (int k = 0; k < 9; ++k) p.frame_axes.data()[k] = r.get<double>("frame axes");
    if (!p.normal.allFinite() || std::abs(p.normal.norm() - 1.0) > 1e-6 ||
        !p.frame_axes.allFinite())
      r.fail("plane " + std::to_string(i) + " has an invalid normal or frame");
    const double voxel = r.get<double>("voxel size");
    const double trunc = r.get<double>("truncation");
    if (!(voxel > 0.0 && std::isfinite(voxel) && trunc > 0.0 && std::isfinite(trunc)))
      r.fail("plane " + std::to_string(i) + " has an invalid voxel size or truncation");
    TsdfVolume vol(voxel, trunc);
    const auto n_blocks = r.get<std::uint32_t>("block count");
    r.needItems(n_blocks, kBlockBytes, "block");
    vol.reserveBlocks(n_blocks);
    for (std::uint32_t b = 0; b < n_blocks; ++b) {
      Eigen::Vector3i idx;
      for (int k = 0; k < 3; ++k) idx[k] = r.get<std::int32_t>("block index");
      if (!blockIndexInRange(idx)) r.fail("block index out of range");
      bool created = false;
      TsdfBlock& blk = vol.allocateBlock(idx, &created);
      if (!created) r.fail("duplicate block");
      std::memcpy(blk.voxels.data(), r.take(sizeof(TsdfVoxel) * kTsdfBlockVoxels, "voxels"),
                  sizeof(TsdfVoxel) * kTsdfBlockVoxels);
    }
    planes.push_back(p);
    m.planes_.push_back(PlaneSdf{std::move(p), std::move(vol)});
  }
  const auto n_points = r.get<std::uint64_t>("point count");
  r.needItems(n_points, 12, "point");
  std::vector<float> xyz(n_points * 3);
  if (n_points > 0) std::memcpy(xyz.data(), r.take(n_points * 12, "points"), n_points * 12);
  m.points_.resize(n_points);
  for (std::size_t i = 0; i < n_points; ++i)
    m.points_[i] = Eigen::Vector3f(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
  if (r.remaining() != 0) r.fail("unexpected bytes after the points");
  m.tracker_.restore(std::move(planes), has_up ? std::optional<Eigen::Vector3d>(up) : std::nullopt);
  if (m.cfg_.point_cell > 0.0)
    for (const auto& p : m.points_) {
      const std::uint64_t key = detail::cellKeyOf(p, m.cfg_.point_cell);
      m.point_cells_.get().sets[detail::pointCellSet(key)].insert(key);
    }
  return m;
}

void Map::save(const std::string& path) const {
  const std::string bytes = serialize();
  io::writeFileAtomic(path, [&](std::ostream& o) {
    o.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  });
}

Map Map::load(const std::string& path) {
  io::requireRegularFile(path);  // open() of a FIFO would block
  const MappedFile file(path);
  if (file.ok()) return deserializeBytes(file.data(), file.size(), path);
  return deserialize(io::readFile(path), path);
}

}  // namespace planesdf
