#pragma once
/// \file plane.hpp
/// The plane stage (design.md, "Pipeline"): the Plane
/// struct with its fixed local frame, PCA normals, whole-cloud detection (DP-vMF-means normal
/// clustering + offset split), per-frame RANSAC, a tracker merging frame planes into global planes
/// with stable ids, and robust point-to-plane refinement.
///
/// Conventions. A plane is {x : normal·x + offset = 0}; `normal` is unit and points to the free
/// (observed) side, so the signed distance normal·x + offset is the height above the plane. Empty
/// or all-NaN input is not an error: detection returns no planes (and estimateUp falls back to
/// cfg.up). Invalid plane parameters in the Config throw planesdf::Error("config", ...), and a
/// PointCloud whose arrays disagree in length throws through PointCloud::validate.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <cstdint>
#include <optional>
#include <unordered_set>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/types.hpp"

namespace planesdf {

/// A detected plane and its local frame. The frame (`frame_origin`, `frame_axes`) is set when the
/// plane is created and afterwards changes only through updatePlaneGeometry() (refinement), which
/// moves it rigidly with the plane; the plane's TSDF lives in that frame as (u, v, h).
struct Plane {
  enum class Orientation { Horizontal, Vertical };

  int id = -1;                                        ///< stable id; -1 for frame planes
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< unit, toward the free side
  double offset = 0.0;                                ///< normal·x + offset = 0
  Orientation orientation = Orientation::Horizontal;  ///< w.r.t. the up axis
  std::size_t support = 0;                            ///< inliers seen so far
  /// In-plane bounds (u, v) of the inliers seen so far, in the plane frame. Empty when none.
  Eigen::AlignedBox2d extent;
  /// Frame origin in the world: a point on the plane (the inlier centroid at creation).
  Eigen::Vector3d frame_origin = Eigen::Vector3d::Zero();
  /// Frame axes in the world as columns (u, v, normal); right-handed, column 2 == normal.
  Eigen::Matrix3d frame_axes = Eigen::Matrix3d::Identity();

  /// The plane-local frame, local-to-world: x_world = frame() * (u, v, h).
  Pose frame() const;
  /// Height of `p` above the plane (positive on the free side).
  double signedDistance(const Eigen::Vector3d& p) const { return normal.dot(p) + offset; }
  /// World point -> (u, v, h) in the plane frame.
  Eigen::Vector3d toLocal(const Eigen::Vector3d& p) const {
    return frame_axes.transpose() * (p - frame_origin);
  }
  /// (u, v, h) in the plane frame -> world point.
  Eigen::Vector3d toWorld(const Eigen::Vector3d& uvh) const;
  /// Grows `extent` by the in-plane coordinates of `points` (world; non-finite ones are skipped).
  void extendExtent(const std::vector<Eigen::Vector3f>& points);
};

/// A plane found in one frame by detectPlanesRansac, with its inliers.
struct PlaneObservation {
  Plane plane;                         ///< id -1; support = number of inliers
  std::vector<std::uint32_t> inliers;  ///< indices into the frame's points
  /// The plane is final (a thin panel's front face, fitted together with its back face): its
  /// inliers extend it but a tracker does not refit it to them.
  bool fitted = false;
};

/// Result of whole-cloud detection.
struct PlaneSegmentation {
  std::vector<Plane> planes;  ///< id == index, sorted by decreasing support
  std::vector<int> labels;    ///< per input point: index of its plane, or -1
  /// Per plane: 1 when it is a thin panel's front face (PlaneObservation::fitted).
  std::vector<char> fitted;
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();  ///< the up axis used (cfg.up or estimated)
};

// --- geometry helpers ---------------------------------------------------------------------------

/// Deterministic plane axes (columns u, v, normal) given the normal and the up axis. Vertical-ish
/// planes (|normal·up| < 0.7): v is up projected into the plane. Horizontal-ish planes: u is the
/// world axis least aligned with up, projected into the plane. Both inputs need not be unit.
Eigen::Matrix3d planeAxes(const Eigen::Vector3d& normal, const Eigen::Vector3d& up);

/// A plane with its frame: axes from planeAxes(normal, up), origin = `anchor` projected onto the
/// plane. `normal` is normalised (offset scaled with it). Support 0, empty extent.
Plane makePlane(const Eigen::Vector3d& normal, double offset, const Eigen::Vector3d& anchor,
                const Eigen::Vector3d& up, int id = -1);

/// Sets normal and offset (normal normalised) and moves the frame with the plane: the axes turn by
/// the smallest rotation taking the old normal to the new one and the origin is projected onto the
/// new plane. `extent` is kept.
void updatePlaneGeometry(Plane& plane, const Eigen::Vector3d& normal, double offset);

/// Horizontal when the angle between the normal and ±up is within `tolerance_deg`, Vertical when
/// the angle to the horizontal is within it, otherwise nullopt.
std::optional<Plane::Orientation> classifyOrientation(const Eigen::Vector3d& normal,
                                                      const Eigen::Vector3d& up,
                                                      double tolerance_deg);

/// Total least-squares plane (PCA) through the finite points; the normal's sign is arbitrary.
/// Returns false (outputs untouched) when there are fewer than 3 finite points or they are
/// collinear.
bool fitPlaneLeastSquares(const std::vector<Eigen::Vector3f>& points, Eigen::Vector3d& normal,
                          double& offset);

/// The sensor position when the cloud has one: organised clouds and clouds whose sensor_pose is
/// not the identity (an unorganised cloud with identity pose is a scene without a sensor).
std::optional<Eigen::Vector3d> sensorOrigin(const PointCloud& cloud);

/// Throws planesdf::Error("config", ...) when a plane-stage parameter is out of range.
void validatePlaneConfig(const Config& cfg);

// --- normals ------------------------------------------------------------------------------------

/// Each valid point moved onto the least-squares plane of its cfg.cloud_smooth_knn nearest
/// neighbours (itself included): a one-step moving-least-squares smoothing that collapses the
/// depth noise of an accumulated cloud to about sigma / sqrt(k) while keeping a surface where it
/// is. A point farther from that plane than cfg.cloud_outlier_sigma times the neighbours' RMS
/// distance from it becomes NaN (when that factor is > 0). Invalid points and points with fewer
/// than 3 neighbours are kept as they are; k = 0 copies. Parallel (cfg.threads).
std::vector<Eigen::Vector3f> projectToLocalPlanes(const std::vector<Eigen::Vector3f>& points,
                                                  const Config& cfg);

/// PCA normals, one per point (NaN for invalid points or too few neighbours). Unorganised clouds:
/// the cfg.normal_knn nearest neighbours (hash-grid search), or in a noisy cloud up to
/// cfg.normal_knn_max where those are not flat (cfg.normal_max_curvature). Organised clouds: an
/// image window of about cfg.normal_window metres (integral images; blurred across depth edges,
/// which shows up in the curvature). Oriented toward sensorOrigin(cloud) when there is one, else
/// sign as computed. `curvature`, when given, receives the surface variation λ0/(λ0+λ1+λ2) per
/// point (NaN when the normal is NaN). `spread`, when given, receives per point of an unorganised
/// cloud the RMS distance of the neighbours its normal came from to their plane (the local noise;
/// empty for organised clouds). `noisy`, when given, receives isNoisyCloud of the one-scale spread
/// (false for organised clouds); only noisy clouds get the larger scales. Parallel
/// (cfg.threads; 0 = all CPUs).
std::vector<Eigen::Vector3f> estimateNormals(const PointCloud& cloud, const Config& cfg,
                                             std::vector<float>* curvature = nullptr,
                                             std::vector<float>* spread = nullptr,
                                             bool* noisy = nullptr);

/// Whether an unorganised cloud is a noisy one (raw accumulated frames): at least
/// cfg.noisy_cloud_share of its points have a `spread` (estimateNormals at one scale) beyond
/// one voxel, a noise layer thicker than the map resolves. Reconstructions and meshes, exported
/// from a TSDF at about the voxel size, are thinner everywhere (design.md, "Noisy clouds").
bool isNoisyCloud(const std::vector<float>& spread, const Config& cfg);

// --- whole-cloud detection ----------------------------------------------------------------------

/// The up axis from the data: the normal of the dominant plane (RANSAC on a subsample), oriented
/// toward sensorOrigin(cloud), or toward +cfg.up when the cloud has no sensor. Ignores
/// cfg.up_auto. Returns cfg.up (normalised) when no plane is found (e.g. empty or all-NaN cloud).
Eigen::Vector3d estimateUp(const PointCloud& cloud, const Config& cfg);

/// Whole-cloud plane detection: PCA normals, DP-vMF-means clustering of the normals (axial, angle
/// cfg.vmf_lambda_deg), offset split of each normal cluster (modes of normal·x at least
/// cfg.offset_split apart), inliers within cfg.ransac_inlier_dist, connectivity split
/// (cfg.plane_connect_cell), support >= cfg.min_plane_support, least-squares + robust refinement,
/// then only horizontal / vertical planes w.r.t. up (cfg.up, or estimateUp when cfg.up_auto).
/// Normals point toward the sensor when sensorOrigin(cloud) exists; otherwise horizontal planes
/// along +up and vertical planes toward the centroid of the cloud. Empty / all-NaN: no planes.
PlaneSegmentation segmentPlanes(const PointCloud& world, const Config& cfg);

/// segmentPlanes with the normals of an unorganised cloud already estimated (estimateNormals,
/// one per point), so a caller that also needs them computes them once. `noise`, empty or one per
/// point (estimateNormals' `spread` of a noisy cloud): an accepted plane also claims the points
/// over its footprint (cfg.plane_connect_cell cells; none when 0) within cfg.splat_noise_reach
/// times their noise of it, its noise layer.
PlaneSegmentation segmentPlanes(const PointCloud& world, const Config& cfg,
                                const std::vector<Eigen::Vector3f>& normals,
                                const std::vector<float>& noise = {});

/// segmentPlanes(world, cfg).planes.
std::vector<Plane> detectPlanes(const PointCloud& world, const Config& cfg);

// --- stream detection ---------------------------------------------------------------------------

/// Per-frame sequential RANSAC on a deterministic subsample (cfg.ransac_max_samples) of the valid
/// points: up to cfg.ransac_max_planes_per_frame planes, each with at least
/// cfg.ransac_min_inlier_frac of the valid points within cfg.ransac_inlier_dist (counted on all
/// points, each point going to the first plane within reach). Least-squares refit, normals toward
/// `sensor_origin`; the inliers of a plane are split into spatially connected parts
/// (cfg.plane_connect_cell), each part with enough inliers being one observation; frame from
/// `up`, extent over the part's inliers; only horizontal / vertical planes w.r.t. `up` are
/// returned (largest first). Deterministic for a given input. Empty / all-NaN: no planes.
std::vector<PlaneObservation> detectPlanesRansac(const std::vector<Eigen::Vector3f>& points_world,
                                                 const Eigen::Vector3d& sensor_origin,
                                                 const Config& cfg, const Eigen::Vector3d& up);

/// As above with up = cfg.up, or, when cfg.up_auto, the normal of this frame's largest plane
/// oriented toward the sensor.
std::vector<PlaneObservation> detectPlanesRansac(const std::vector<Eigen::Vector3f>& points_world,
                                                 const Eigen::Vector3d& sensor_origin,
                                                 const Config& cfg);

/// Holds the global planes of a stream. Each frame plane merges into the global plane whose
/// normal agrees within cfg.plane_merge_angle_deg (same free side), whose offset agrees within
/// cfg.plane_merge_offset (distance of the frame plane's inlier centroid) and whose extent overlaps
/// or is within cfg.plane_merge_extent_gap of the frame plane's; the closest such plane wins.
/// Otherwise a new global plane gets the next id. Ids never change and are never reused; global
/// planes are never removed. A global plane keeps a uniform reservoir sample of its inliers
/// (cfg.plane_reservoir_size) and is refined (refinePlane) whenever it has gained
/// cfg.refine_min_new_inliers since its last refinement (also at creation).
class PlaneTracker {
 public:
  /// Throws planesdf::Error("config", ...) on invalid plane parameters.
  explicit PlaneTracker(const Config& cfg);

  /// Detects the planes of one frame (points in the world frame, NaN allowed) and merges them.
  /// When cfg.up_auto, the first frame with a plane fixes up (its largest plane's normal toward
  /// the sensor). Returns, per merged frame plane, the id of its global plane.
  std::vector<int> integrate(const std::vector<Eigen::Vector3f>& points_world,
                             const Eigen::Vector3d& sensor_origin);

  /// Merges frame planes detected elsewhere (inlier indices refer to `points_world`), largest
  /// first, classified w.r.t. up() (when up is not fixed yet, the first observation's normal
  /// fixes it, as detectPlanesRansac does with cfg.up_auto). Returns the global id of each
  /// observation (-1 for one without inliers, or one that would start a plane whose inliers span
  /// less than `min_extent` along the longer side of their in-plane box or `min_width` along the
  /// shorter, m: integrate passes cfg.plane_min_extent and cfg.plane_min_width).
  std::vector<int> merge(const std::vector<PlaneObservation>& observations,
                         const std::vector<Eigen::Vector3f>& points_world, double min_extent = 0.0,
                         double min_width = 0.0);

  /// Replaces the tracker's state with `planes` (planes[i].id must be i) and, when given, the
  /// up axis: used when a saved map is loaded and keeps integrating. Inlier reservoirs start
  /// empty. Throws planesdf::Error("planes", ...) when the ids are not 0..n-1.
  void restore(std::vector<Plane> planes, std::optional<Eigen::Vector3d> up);

  /// Global planes; planes()[i].id == i.
  const std::vector<Plane>& planes() const { return planes_; }
  /// The plane with this id, or nullptr.
  const Plane* plane(int id) const;
  /// The up axis in use (cfg.up, or the estimate once cfg.up_auto has fixed it).
  std::optional<Eigen::Vector3d> up() const { return up_; }
  /// Number of inliers held for refinement by plane `id` (0 for an unknown id).
  std::size_t reservoirSize(int id) const;
  /// Number of refinements plane `id` has had.
  int refinementCount(int id) const;

 private:
  struct Track {
    std::vector<Eigen::Vector3f> reservoir;
    std::size_t seen = 0;          ///< inliers offered to the reservoir
    std::size_t since_refine = 0;  ///< inliers gained since the last refinement
    std::uint64_t rng_state = 0;   ///< deterministic per-plane random stream
    int refinements = 0;
    /// World cells (kOccupancyCell) that sampled inliers fell in: where the plane is, for
    /// merging only spatially connected planes (Config::plane_merge_coplanar).
    std::unordered_set<std::uint64_t> cells;
  };

  /// True when a sampled inlier of `sample` lies in or next to a cell of `track`'s plane (a
  /// restored plane without cells: its extent box within one cell of theirs).
  bool touches(const Track& track, const Plane& plane, const std::vector<Eigen::Vector3f>& points,
               const std::vector<std::uint32_t>& sample) const;
  void occupy(Track& track, const std::vector<Eigen::Vector3f>& points,
              const std::vector<std::uint32_t>& inliers) const;
  /// True when `obs` is horizontal and its inlier centre `centre` lies more than
  /// plane_merge_offset above a plane whose normal agrees within acos(min_cos) and whose extent
  /// holds it: a desk or a board over the floor, whose coplanar patches merge only where
  /// connected (the floor merges across gaps).
  bool standsOnAnotherPlane(const PlaneObservation& obs, const Eigen::Vector3d& centre,
                            double min_cos) const;

  int findMatch(const PlaneObservation& obs, const std::vector<Eigen::Vector3f>& points,
                Eigen::AlignedBox2d& obs_extent) const;
  int addPlane(const PlaneObservation& obs, const std::vector<Eigen::Vector3f>& points);
  void absorb(int id, const PlaneObservation& obs, const std::vector<Eigen::Vector3f>& points,
              const Eigen::AlignedBox2d& obs_extent);
  void offerToReservoir(Track& track, const std::vector<Eigen::Vector3f>& points,
                        const std::vector<std::uint32_t>& indices) const;
  void maybeRefine(int id);

  Config cfg_;
  std::vector<Plane> planes_;
  std::vector<Track> tracks_;
  std::optional<Eigen::Vector3d> up_;
};

// --- refinement ---------------------------------------------------------------------------------

/// Robust point-to-plane least squares (Ceres; residual normal·p + offset, Cauchy loss of scale
/// cfg.refine_loss_scale, normal on the unit sphere, at most cfg.refine_max_points points, evenly
/// subsampled), started from the plane's current parameters. Keeps the normal on the same (free)
/// side and moves the frame with updatePlaneGeometry. Returns false and leaves the plane untouched
/// when there are fewer than 3 finite points or the solve fails.
bool refinePlane(const std::vector<Eigen::Vector3f>& inliers, Plane& plane, const Config& cfg);

}  // namespace planesdf
