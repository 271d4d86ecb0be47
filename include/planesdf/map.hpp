#pragma once
/// \file map.hpp
/// The map of one session (paper §III-A): a set of PlaneSDFs — detected horizontal / vertical
/// planes, each owning a block-sparse TSDF of the band above it in the plane's local frame —
/// plus the input points that fell into some band (the change outputs report them).
///
/// Single-threaded ownership: one thread at a time calls the non-const members; const members
/// may run on several threads at once. Fusion parallelises internally on the calling thread's
/// workers (Config::threads; docs/design.md, "Threads"). Copyable (deep) and movable.

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/plane.hpp"
#include "planesdf/tsdf.hpp"
#include "planesdf/types.hpp"

namespace planesdf {

/// One plane and its TSDF volume (in plane.frame() coordinates: u, v in-plane, h height).
struct PlaneSdf {
  Plane plane;
  TsdfVolume volume;

  PlaneSdf(const Plane& p, TsdfVolume v) : plane(p), volume(std::move(v)) {}
  PlaneSdf(const PlaneSdf&) = default;
  PlaneSdf& operator=(const PlaneSdf&) = default;
  /// noexcept (Eigen's fixed-size types in Plane do not say so): a growing vector of planes
  /// moves its volumes instead of copying them.
  PlaneSdf(PlaneSdf&& o) noexcept : plane(o.plane), volume(std::move(o.volume)) {}
  PlaneSdf& operator=(PlaneSdf&& o) noexcept {
    plane = o.plane;
    volume = std::move(o.volume);
    return *this;
  }
  ~PlaneSdf() = default;
};
static_assert(std::is_nothrow_move_constructible<PlaneSdf>::value,
              "vectors of PlaneSdf must move, not copy, their volumes");

/// What one integrate() call did.
struct IntegrateStats {
  std::vector<int> new_planes;      ///< ids of the planes this call created
  std::vector<int> updated_planes;  ///< ids of the planes whose volume the frame reached
  std::vector<int> changed_planes;  ///< ids of the planes whose volume changed
  std::size_t blocks_updated = 0;   ///< over all planes (frustum-limited)
  std::size_t blocks_allocated = 0;
  std::size_t points_fused = 0;  ///< measurements inside some plane's band
  double milliseconds = 0.0;     ///< wall time of the call
  /// Wall times of the call's stages (ms). For depth frames, tracking (plane tracking, its
  /// refinements included) and then points (the object points kept for the change outputs) run
  /// on one thread beside the frame's per-pixel pass, so they overlap it; fusion is the TSDF
  /// update of every plane volume after it. For clouds the three run one after the other
  /// (fusion includes the normals of an unorganised cloud).
  double tracking_ms = 0.0;
  double points_ms = 0.0;
  double fusion_ms = 0.0;
};

namespace detail {
struct PointCellSets;  // src/map/map_internal.hpp

/// Owns a map's point-cell sets (created on first use) and copies them deeply; defined where
/// they are complete, so the header need not show them.
class PointCellSetsPtr {
 public:
  PointCellSetsPtr() noexcept;
  ~PointCellSetsPtr();
  PointCellSetsPtr(const PointCellSetsPtr& other);
  PointCellSetsPtr& operator=(const PointCellSetsPtr& other);
  PointCellSetsPtr(PointCellSetsPtr&& other) noexcept;
  PointCellSetsPtr& operator=(PointCellSetsPtr&& other) noexcept;
  /// The sets, empty ones created on first use.
  PointCellSets& get();

 private:
  std::unique_ptr<PointCellSets> p_;
};
}  // namespace detail

class Map {
 public:
  /// An empty map. Throws planesdf::Error("config", ...) on invalid parameters.
  explicit Map(const Config& cfg = Config{});

  /// Fuses one depth frame (camera-to-world pose, OpenCV optical camera frame): per-frame RANSAC
  /// planes merged into the map's planes (stable ids), then projective fusion into every plane
  /// volume, touching only blocks inside the camera frustum and depth range.
  /// Throws planesdf::Error on a malformed frame (bad intrinsics, wrong buffer size) and on a
  /// pose that is not finite or not rigid (rotation orthonormal with determinant +1 within 1e-4).
  IntegrateStats integrate(const DepthFrame& frame, const Pose& camera_to_world);

  /// Fuses a point cloud whose points are in its own frame; `cloud_to_world` places that frame.
  /// Organised clouds (height > 1) are a frame seen from cloud.sensor_pose: fused projectively
  /// (free space carved) with intrinsics estimated from the pixel grid. Unorganised clouds get
  /// PCA normals (oriented toward the sensor when known) and are splatted along them; their planes
  /// come from whole-cloud detection. Throws planesdf::Error on an inconsistent cloud and when
  /// `cloud_to_world` or cloud.sensor_pose is not finite or not rigid (as above).
  IntegrateStats integrate(const PointCloud& cloud, const Pose& cloud_to_world);

  /// The map of one whole scene cloud in the world frame: planes by whole-cloud detection (PCA
  /// normals, normal clustering, offset split), then fusion as integrate(cloud, identity). All
  /// in-band points are kept. An organised cloud is one view: it is fused with
  /// cfg.silhouette_guard_behind off.
  static Map fromCloud(const PointCloud& world, const Config& cfg);

  const Config& config() const { return cfg_; }
  /// The PlaneSDFs; planes()[i].plane.id == i.
  const std::vector<PlaneSdf>& planes() const { return planes_; }
  /// The PlaneSDF with this id, or nullptr.
  const PlaneSdf* findPlane(int id) const;
  /// The up axis in use (cfg.up, or the estimate once `--up auto` has fixed it).
  Eigen::Vector3d up() const;
  /// Number of integrate() calls so far.
  std::uint64_t frames() const { return frames_; }
  /// True once an unorganised cloud was fused (splatted along PCA normals): such surfaces are
  /// placed only to within the splat radius, which the height comparison allows for
  /// (surfaceRimCells). Saved with the map.
  bool splatted() const { return splatted_; }
  /// Input points (world frame) that may belong to objects — at least h_obj/2 above some plane
  /// and inside its band: every one for fromCloud(), at most one per cfg.point_cell cell for
  /// frame streams. The change outputs report these points.
  const std::vector<Eigen::Vector3f>& points() const { return points_; }
  /// Bytes held by all volumes, the kept points and the reserve not used yet.
  std::size_t memoryBytes() const;
  /// Faults in memory up front, as real-time pipelines do at start-up: `block_bytes` (rounded
  /// up to 2 MiB chunks) for the TSDF blocks of every plane volume, present and future, and
  /// room for `points` kept points. A growing map otherwise touches fresh memory during
  /// integrate(): a page fault and the zeroing of each page, which on a virtual machine can
  /// cost milliseconds per frame (about 3 ms per 2 MiB the first time the host backs it; the
  /// bench frames allocate up to ~5 MiB of blocks per frame). Blocks use the reserve before
  /// any fresh memory; the unused reserve is counted by memoryBytes(). Can be called again to
  /// add more. Throws planesdf::Error, reserving nothing, when the request exceeds the machine's
  /// physical memory, and std::bad_alloc when the memory cannot be mapped.
  void reserveMemory(std::size_t block_bytes, std::size_t points = 0);
  /// Bytes of the block reserve not used yet.
  std::size_t reservedBytes() const;

  /// Writes the map atomically: magic "PSDFMAP", format version, config, planes, blocks, points
  /// and a checksum. Throws planesdf::Error naming the path on failure.
  void save(const std::string& path) const;
  /// Reads a map written by save(). A truncated, corrupted or foreign file throws
  /// planesdf::Error naming it. The loaded map can keep integrating frames.
  static Map load(const std::string& path);
  /// save()/load() through memory; `name` is used in error messages.
  std::string serialize() const;
  static Map deserialize(const std::string& bytes, const std::string& name);

 private:
  static Map deserializeBytes(const char* data, std::size_t size, const std::string& name);
  void syncPlanes(IntegrateStats& stats);
  IntegrateStats integrateCloud(const PointCloud& cloud, const Pose& cloud_to_world,
                                bool whole_cloud);
  void keepPoints(const std::vector<Eigen::Vector3f>& points_world, bool deduplicate);
  /// Splats an unorganised cloud (world frame, with its PCA normals and local noise) into every
  /// plane volume.
  IntegrateStats splatCloud(const PointCloud& world, const std::vector<Eigen::Vector3f>& normals,
                            const std::vector<float>& spread, bool noisy);
  /// Fuses an analysed depth frame into every plane volume.
  IntegrateStats fuseDepth(const DepthFrameAnalysis& analysis, const Pose& camera_to_world,
                           const Config& fuse_cfg);

  Config cfg_;
  PlaneTracker tracker_;
  std::vector<PlaneSdf> planes_;
  std::vector<Eigen::Vector3f> points_;
  /// Cells already holding a kept point, split in sets by brick so that threads can
  /// de-duplicate a frame's points side by side.
  detail::PointCellSetsPtr point_cells_;
  /// Map::reserveMemory's chunks, shared by the plane volumes (nullptr until then).
  std::shared_ptr<detail::HugePagePool> block_pool_;
  std::uint64_t frames_ = 0;
  bool splatted_ = false;
};

}  // namespace planesdf
