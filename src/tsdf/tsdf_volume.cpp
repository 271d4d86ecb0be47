// TsdfVolume: block storage, the block hash map and voxel queries.

#include <algorithm>
#include <cmath>
#include <new>
#include <string>
#include <type_traits>
#include <utility>

#include "../memory_internal.hpp"
#include "../numeric.hpp"
#include "planesdf/error.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {

namespace {

constexpr std::uint64_t kEmptyKey = detail::kEmptyBlockKey;
// Slab sizes of BlockSlabs: at least this many blocks, at most one huge page.
constexpr std::size_t kMinSlabBlocks = 16;
constexpr std::size_t kMaxSlabBlocks = detail::kHugePageBytes / sizeof(TsdfBlock);

}  // namespace

// ---- detail::BlockHashMap
// ---------------------------------------------------------------------------

std::pair<std::uint32_t, bool> detail::BlockHashMap::insert(std::uint64_t key,
                                                            std::uint32_t value) {
  if ((size_ + 1) * 2 > keys_.size()) rehash(std::max<std::size_t>(16, keys_.size() * 2));
  for (std::size_t i = detail::mixBlockKey(key) & mask_;; i = (i + 1) & mask_) {
    const std::uint64_t k = keys_[i];
    if (k == key) return {values_[i], false};
    if (k == kEmptyKey) {
      keys_[i] = key;
      values_[i] = value;
      ++size_;
      return {value, true};
    }
  }
}

bool detail::BlockHashMap::insertKey(std::uint64_t key) {
  if ((size_ + 1) * 2 > keys_.size()) rehash(std::max<std::size_t>(16, keys_.size() * 2));
  for (std::size_t i = detail::mixBlockKey(key) & mask_;; i = (i + 1) & mask_) {
    const std::uint64_t k = keys_[i];
    if (k == key) return false;
    if (k == kEmptyKey) {
      keys_[i] = key;
      values_[i] = 0;
      ++size_;
      return true;
    }
  }
}

void detail::BlockHashMap::clear() {
  std::fill(keys_.begin(), keys_.end(), kEmptyKey);
  size_ = 0;
}

void detail::BlockHashMap::reserve(std::size_t n) {
  std::size_t cap = 16;
  while (cap < 2 * n) cap *= 2;
  if (cap > keys_.size()) rehash(cap);
}

std::size_t detail::BlockHashMap::memoryBytes() const {
  return keys_.capacity() * sizeof(std::uint64_t) + values_.capacity() * sizeof(std::uint32_t);
}

void detail::BlockHashMap::rehash(std::size_t capacity) {
  const auto old_keys = std::move(keys_);
  const auto old_values = std::move(values_);
  keys_.assign(capacity, kEmptyKey);
  values_.assign(capacity, kNotFound);
  mask_ = capacity - 1;
  size_ = 0;
  for (std::size_t i = 0; i < old_keys.size(); ++i)
    if (old_keys[i] != kEmptyKey) insert(old_keys[i], old_values[i]);
}

// ---- BlockSlabs ------------------------------------------------------------------------------

namespace detail {

BlockSlabs::BlockSlabs(BlockSlabs&& other) noexcept
    : slabs_(std::exchange(other.slabs_, {})),
      pool_(std::exchange(other.pool_, {})),
      used_(std::exchange(other.used_, 0)),
      total_(std::exchange(other.total_, 0)),
      bytes_(std::exchange(other.bytes_, 0)) {}

BlockSlabs& BlockSlabs::operator=(BlockSlabs&& other) noexcept {
  if (this != &other) {
    clear();
    slabs_ = std::exchange(other.slabs_, {});
    pool_ = std::exchange(other.pool_, {});
    used_ = std::exchange(other.used_, 0);
    total_ = std::exchange(other.total_, 0);
    bytes_ = std::exchange(other.bytes_, 0);
  }
  return *this;
}

BlockSlabs::~BlockSlabs() {
  clear();
}

TsdfBlock* BlockSlabs::create() {
  static_assert(std::is_trivially_destructible_v<TsdfBlock>, "slabs never run destructors");
  if (slabs_.empty() || used_ == slabs_.back().capacity) {
    if (slabs_.size() == slabs_.capacity())  // cannot throw after the allocation below
      slabs_.reserve(std::max<std::size_t>(8, 2 * slabs_.capacity()));
    // A reserved chunk (already faulted in) when the pool has one, else fresh memory.
    void* chunk = pool_ ? pool_->take() : nullptr;
    if (chunk != nullptr) {
      slabs_.push_back({static_cast<TsdfBlock*>(chunk), kMaxSlabBlocks, kHugePageBytes});
    } else {
      const std::size_t capacity = std::clamp(total_ / 4, kMinSlabBlocks, kMaxSlabBlocks);
      // A full-size slab asks for the whole huge page (its tail is a few bytes).
      const std::size_t bytes =
          capacity == kMaxSlabBlocks ? kHugePageBytes : capacity * sizeof(TsdfBlock);
      slabs_.push_back({static_cast<TsdfBlock*>(allocateLarge(bytes)), capacity, bytes});
    }
    bytes_ += slabs_.back().bytes;
    used_ = 0;
  }
  TsdfBlock* b = new (slabs_.back().blocks + used_) TsdfBlock();
  ++used_;
  ++total_;
  return b;
}

void BlockSlabs::reserve(std::size_t n) {
  if (n == 0 || (!slabs_.empty() && slabs_.back().capacity - used_ >= n)) return;
  // Whole huge pages from one on: the tail of the last page holds blocks too.
  std::size_t bytes = n * sizeof(TsdfBlock);
  if (bytes >= kHugePageBytes)
    bytes = (bytes + kHugePageBytes - 1) / kHugePageBytes * kHugePageBytes;
  if (slabs_.size() == slabs_.capacity())
    slabs_.reserve(std::max<std::size_t>(8, 2 * slabs_.capacity()));
  auto* memory = static_cast<TsdfBlock*>(allocateLarge(bytes));
  slabs_.push_back({memory, bytes / sizeof(TsdfBlock), bytes});
  bytes_ += bytes;
  used_ = 0;
}

void BlockSlabs::clear() noexcept {
  for (const Slab& s : slabs_) freeLarge(s.blocks, s.bytes);
  slabs_.clear();
  used_ = total_ = bytes_ = 0;
}

}  // namespace detail

// ---- TsdfVolume -----------------------------------------------------------------------------

TsdfVolume::TsdfVolume(double voxel_size, double truncation)
    : voxel_size_(voxel_size), truncation_(truncation) {
  if (!(std::isfinite(voxel_size) && voxel_size > 0.0))
    throw Error("", "tsdf volume: voxel_size must be positive and finite (got " +
                        std::to_string(voxel_size) + ")");
  if (!(std::isfinite(truncation) && truncation > 0.0))
    throw Error("", "tsdf volume: truncation must be positive and finite (got " +
                        std::to_string(truncation) + ")");
}

TsdfVolume::TsdfVolume(const Config& cfg) : TsdfVolume(cfg.voxel_size, cfg.truncation()) {}

TsdfVolume::TsdfVolume(const TsdfVolume& other)
    : voxel_size_(other.voxel_size_),
      truncation_(other.truncation_),
      map_(other.map_),
      lo_(other.lo_),
      hi_(other.hi_),
      revision_(other.revision_) {
  blocks_.reserve(other.blocks_.size());
  slabs_.reserve(other.blocks_.size());
  for (const TsdfBlock* b : other.blocks_) {
    TsdfBlock* copy = slabs_.create();
    *copy = *b;
    blocks_.push_back(copy);
  }
  indices_ = other.indices_;
}

TsdfVolume& TsdfVolume::operator=(const TsdfVolume& other) {
  if (this != &other) *this = TsdfVolume(other);
  return *this;
}

std::size_t TsdfVolume::numObservedVoxels() const {
  std::size_t n = 0;
  for (const auto& b : blocks_)
    for (const TsdfVoxel& v : b->voxels) n += v.weight > 0.0f ? 1 : 0;
  return n;
}

std::size_t TsdfVolume::memoryBytes() const {
  return sizeof(*this) + blocks_.capacity() * sizeof(blocks_[0]) +
         indices_.capacity() * sizeof(indices_[0]) + slabs_.bytes() + map_.memoryBytes();
}

TsdfBlock& TsdfVolume::allocateBlock(const Eigen::Vector3i& b, bool* created) {
  if (!blockIndexInRange(b))
    throw Error("", "tsdf volume: block index (" + std::to_string(b.x()) + ", " +
                        std::to_string(b.y()) + ", " + std::to_string(b.z()) +
                        ") is out of the representable range");
  const std::uint64_t key = detail::packBlockKey(b);
  const std::uint32_t found = map_.find(key);
  if (created) *created = found == detail::BlockHashMap::kNotFound;
  if (found != detail::BlockHashMap::kNotFound) return *blocks_[found];
  // Everything that can throw happens before the block is entered anywhere.
  if (blocks_.size() == blocks_.capacity())
    blocks_.reserve(std::max<std::size_t>(64, 2 * blocks_.capacity()));
  if (indices_.size() == indices_.capacity())
    indices_.reserve(std::max<std::size_t>(64, 2 * indices_.capacity()));
  map_.reserve(map_.size() + 1);
  TsdfBlock* block = slabs_.create();
  block->index = b;
  map_.insert(key, static_cast<std::uint32_t>(blocks_.size()));
  blocks_.push_back(block);
  indices_.push_back(b);
  if (blocks_.size() == 1) {
    lo_ = hi_ = b;
  } else {
    lo_ = lo_.cwiseMin(b);
    hi_ = hi_.cwiseMax(b);
  }
  return *blocks_.back();
}

void TsdfVolume::reserveBlocks(std::size_t n) {
  if (blocks_.capacity() < blocks_.size() + n) blocks_.reserve(blocks_.size() + n);
  if (indices_.capacity() < indices_.size() + n) indices_.reserve(indices_.size() + n);
  map_.reserve(map_.size() + n);
  slabs_.reserve(n);
}

std::vector<Eigen::Vector3i> TsdfVolume::blockIndices() const {
  return indices_;
}

std::vector<Eigen::Vector3i> TsdfVolume::blocksChangedSince(std::uint64_t revision) const {
  std::vector<Eigen::Vector3i> out;
  for (const auto& b : blocks_)
    if (b->revision > revision) out.push_back(b->index);
  return out;
}

bool TsdfVolume::blockBounds(Eigen::Vector3i* lo, Eigen::Vector3i* hi) const {
  if (blocks_.empty()) return false;
  if (lo) *lo = lo_;
  if (hi) *hi = hi_;
  return true;
}

void TsdfVolume::clear() {
  if (blocks_.empty()) return;
  blocks_.clear();
  blocks_.shrink_to_fit();
  indices_.clear();
  indices_.shrink_to_fit();
  slabs_.clear();
  map_ = detail::BlockHashMap();
  lo_.setZero();
  hi_.setConstant(-1);
  ++revision_;
}

Eigen::Vector3i TsdfVolume::voxelIndexAt(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d g = p / voxel_size_;
  return Eigen::Vector3i(detail::floorToInt(g.x()), detail::floorToInt(g.y()),
                         detail::floorToInt(g.z()));
}

Eigen::Vector3i TsdfVolume::blockIndexAt(const Eigen::Vector3d& p) const {
  return blockOfVoxel(voxelIndexAt(p));
}

std::optional<TsdfSample> TsdfVolume::sample(const Eigen::Vector3d& p, float min_weight) const {
  const auto qualifies = [&](const TsdfVoxel* v) {
    return v && v->weight > 0.0f && v->weight >= min_weight;
  };
  // Voxel centres sit at (i + 0.5) * voxel_size: the 8 neighbours of p start at floor(g).
  const Eigen::Vector3d g = p / voxel_size_ - Eigen::Vector3d::Constant(0.5);
  const Eigen::Vector3i base(detail::floorToInt(g.x()), detail::floorToInt(g.y()),
                             detail::floorToInt(g.z()));
  const Eigen::Vector3d f = g - base.cast<double>();
  std::array<const TsdfVoxel*, 8> n{};
  const bool one_block = (base.x() & 7) < 7 && (base.y() & 7) < 7 && (base.z() & 7) < 7;
  const TsdfBlock* blk = one_block ? findBlock(blockOfVoxel(base)) : nullptr;
  bool all = !one_block || blk;
  for (int c = 0; c < 8 && all; ++c) {
    const Eigen::Vector3i v = base + Eigen::Vector3i(c & 1, (c >> 1) & 1, c >> 2);
    n[c] = blk ? &blk->voxels[linearIndexInBlock(v)] : voxel(v);
    all = qualifies(n[c]);
  }
  if (all) {
    TsdfSample s;
    s.interpolated = true;
    double sdf = 0.0, w = 0.0;
    for (int c = 0; c < 8; ++c) {
      const double wx = (c & 1) ? f.x() : 1.0 - f.x();
      const double wy = ((c >> 1) & 1) ? f.y() : 1.0 - f.y();
      const double wz = (c >> 2) ? f.z() : 1.0 - f.z();
      sdf += wx * wy * wz * n[c]->sdf;
      w += wx * wy * wz * n[c]->weight;
    }
    s.sdf = static_cast<float>(sdf);
    s.weight = static_cast<float>(w);
    return s;
  }
  const TsdfVoxel* nearest = voxel(voxelIndexAt(p));
  if (!qualifies(nearest)) return std::nullopt;
  TsdfSample s;
  s.sdf = nearest->sdf;
  s.weight = nearest->weight;
  return s;
}

}  // namespace planesdf
