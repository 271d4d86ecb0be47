#pragma once
/// \file config.hpp
/// One plain struct with every parameter of the pipeline (design.md, "Pipeline"). Values from the
/// paper are the defaults (δn, δd, δh, bins, σ, α, δ_blob, voxel, band); the others are ours.
/// Passed down explicitly; there are no globals.

#include <Eigen/Core>

#include <string>

namespace planesdf {

/// Largest Config::threads accepted: a parallel stage starts up to that many worker threads, and
/// a huge count exhausts memory before it starts (validateConfig refuses more).
inline constexpr int kMaxThreads = 1024;

/// Largest Config::memory_limit_mb accepted (16 TB).
inline constexpr int kMaxMemoryLimitMb = 1 << 24;

struct Config {
  // --- up axis -------------------------------------------------------------------------------
  /// Gravity "up" in the world frame. Ignored when `up_auto` is true.
  Eigen::Vector3d up{0.0, 0.0, 1.0};
  /// Estimate up as the dominant plane's normal oriented toward the sensor (`--up auto`).
  bool up_auto = false;

  // --- plane detection, streams (per-frame RANSAC)
  // ------------------------------------------------
  double ransac_inlier_dist = 0.015;  ///< m
  /// Of the frame's valid points (plane_min_extent keeps the object faces this lets through
  /// from becoming planes).
  double ransac_min_inlier_frac = 0.03;
  /// ... and for horizontal frame planes: a shelf board near eye height is seen foreshortened
  /// and fills 1-3 % of a frame (design.md, "Planes"). The extent minimums below still apply.
  double ransac_min_horizontal_frac = 0.015;
  int ransac_iterations = 200;
  int ransac_max_planes_per_frame = 8;
  /// Merge a frame plane into a global plane when normals agree within this angle ...
  double plane_merge_angle_deg = 10.0;
  /// ... and offsets agree within this distance (m) ...
  double plane_merge_offset = 0.05;
  /// ... and, when the offsets differ by more than this (m), the frame plane's inliers come within
  /// about 10 cm of the global plane's: two desks a few cm apart in height are two planes (one
  /// plane fitted to both would tilt and raise one desk's top into the other's band), while the
  /// floor seen in separate patches stays one plane. The default is RANSAC's inlier distance:
  /// closer surfaces are one surface to the per-frame fit anyway.
  double plane_merge_coplanar = 0.015;
  /// ... and their in-plane extents overlap or are at most this far apart (m). Large by default:
  /// a PlaneSDF fuses the whole (unbounded) band of its plane, so two coplanar planes would hold
  /// duplicate volumes; coplanar patches (a floor seen around a table) are one plane.
  double plane_merge_extent_gap = 1000.0;
  /// Frame streams: a new global plane needs inliers spanning at least this much (m, the longer
  /// side of their in-plane box) in the frame that starts it: shelf boards (0.8 m and wider) and
  /// desks are planes, the faces of the objects on them (at most ~0.4 m) are not, whatever
  /// fraction of a frame they fill. Later observations of any size merge into existing planes.
  /// Whole clouds keep min_plane_support instead (design.md, "Planes").
  double plane_min_extent = 0.5;
  /// ... and at least this much along the shorter side (m): shelf boards are 0.25 m deep and more,
  /// a table leg's face (5 cm) or a table top's edge (3 cm) is no support.
  double plane_min_width = 0.12;
  /// Points RANSAC scores hypotheses on (a deterministic subsample of the frame's valid points).
  int ransac_max_samples = 2000;
  /// Inliers kept per global plane for refinement (a uniform reservoir sample; bounds memory).
  int plane_reservoir_size = 20000;
  /// Map::integrate(DepthFrame): plane tracking sees every n-th pixel of every n-th row (plane
  /// parameters need far fewer points than fusion, which always reads every pixel).
  int track_pixel_stride = 1;

  // --- plane detection, whole cloud ------------------------------------------------------------
  int normal_knn = 20;  ///< k for PCA normals
  /// An unorganised cloud is noisy (raw accumulated frames, not a reconstruction) when at least
  /// this share of its points lie in layers thicker than a voxel: their normal_knn neighbours'
  /// RMS distance from their plane exceeds voxel_size (isNoisyCloud; design.md, "Noisy clouds").
  /// Only noisy clouds get the normals and splat options below. 0: every cloud is noisy.
  double noisy_cloud_share = 0.01;
  /// Noisy clouds: where the normal_knn nearest neighbours are not flat (surface variation above
  /// normal_max_curvature) and at least normal_rough_share of 4 or 16 times as many neighbours
  /// are not flat either, the normal is taken from those, up to normal_knn_max, at the flattest
  /// scale (design.md, "Noisy clouds"). normal_knn_max = normal_knn keeps one scale.
  int normal_knn_max = 320;
  /// Most neighbours one normal fit reads: a larger scale fits that many from a subsample of
  /// the cloud (one point in scale / normal_fit_points) over the same extent. Lower is faster
  /// and noisier (design.md, "Noisy clouds"); the default fits every scale on all its points.
  int normal_fit_points = 320;
  double normal_max_curvature = 0.05;
  double normal_rough_share = 0.0;
  double vmf_lambda_deg = 10.0;  ///< DP-vMF-means cluster angle λ
  double offset_split = 0.05;    ///< split a normal cluster into planes by offset (m)
  int min_plane_support = 2000;  ///< points needed to keep a plane
  /// Organised clouds: normals from an image window about this wide (m); the window in pixels
  /// adapts to the depth and is never smaller than about sqrt(normal_knn) pixels.
  double normal_window = 0.03;
  /// Split a plane into its spatially connected parts on a grid of this cell size (m); parts
  /// below min_plane_support are dropped. 0 disables the split.
  double plane_connect_cell = 0.05;

  // --- plane filter ------------------------------------------------------------------------------
  double orientation_tolerance_deg = 10.0;  ///< horizontal / vertical w.r.t. up

  // --- plane refinement (Ceres) ---------------------------------------------------------------
  double refine_loss_scale = 0.01;  ///< robust loss scale (m)
  /// Re-run when a plane gained this many inliers (of the points tracking sees, see
  /// track_pixel_stride), and at least half as many as it had at its last refinement
  /// (refinements thin out geometrically as the reservoir settles).
  int refine_min_new_inliers = 1000;
  int refine_max_points = 10000;  ///< refinement uses at most this many points (subsampled)

  // --- PlaneSDF fusion
  // ----------------------------------------------------------------------------
  double voxel_size = 0.007;  ///< m
  double fuse_band = 0.30;    ///< m above the plane (free side)
  double below_band = 0.03;   ///< m below the plane also fused (thin band)
  int truncation_voxels = 4;  ///< TSDF truncation in voxels
  double max_depth = 4.0;     ///< m; depth beyond this is ignored
  /// m; depth beyond this only carves free space in front of it (docs/design.md, "Far depth"):
  /// fusion shifts a surface toward the camera once the depth noise nears the truncation (the
  /// band behind a surface is shorter than the one in front). With a Kinect-class sensor
  /// (sigma = 1.2 mm + 1.9 mm (z - 0.4 m)^2) that starts past 3 m, where sigma is half the 2.8 cm
  /// truncation. A value >= max_depth fuses every surface.
  double surface_max_depth = 3.0;
  double min_depth = 0.2;     ///< m
  float max_weight = 100.0f;  ///< weight cap per voxel
  /// Threads of every parallel stage, the calling thread included; 0 = every CPU the process may
  /// run on. Idle workers block, never spin (docs/design.md, "Threads"). At most kMaxThreads.
  int threads = 0;
  /// Memory budget (MB) of the large arrays: a depth frame's buffers, the TSDF blocks a frame or
  /// cloud adds to a map, a height map and the grids derived from it are estimated before they
  /// are allocated and refused (planesdf::Error) beyond it. 0 = half the physical memory (8192
  /// when unknown); at most kMaxMemoryLimitMb.
  int memory_limit_mb = 0;
  /// Fuse rows of voxels with the AVX2 kernel when the CPU has AVX2 (checked at run time); also
  /// the AVX2 builds of the kept points' band pre-test, of the height map's block
  /// classification and layer walk and of the in-plane refinement's scoring. The results are
  /// bit-identical to the scalar code, which runs when this is off or on CPUs without AVX2 (the
  /// refinement's mean |diff| sums in another order: the last bits may differ).
  bool simd = true;
  /// Projective fusion skips "inside" values behind a surface near a silhouette, where the
  /// object may already have ended (integrateDepth). Right when other views fill in what is
  /// skipped (frame streams); Map::fromCloud of an organised cloud, a single view, turns it off
  /// for its fusion, since nothing could replace the object rims it drops.
  bool silhouette_guard_behind = true;
  /// Lateral radius (in voxels) of the cylinder a point with a normal updates when an
  /// unorganised cloud is splatted (integratePointsWithNormals).
  double splat_radius_voxels = 1.0;
  /// A splatted point of a noisy cloud also marks free space up to this many times its local
  /// noise (the RMS distance of its normal's neighbours to their plane) beyond the truncation in
  /// front of it, at most two truncations more: what a ray would have carved through the noise
  /// layer of a surface (design.md, "Noisy clouds"). A plane of a noisy cloud claims the points
  /// over it within as many times their noise. 0: the truncation only, and no layer claimed.
  double splat_noise_reach = 3.0;
  /// A point of a noisy cloud whose local noise (as above) exceeds this fraction of the
  /// truncation is not splatted: its surface is placed no better than a measurement beyond
  /// surface_max_depth, whose noise is half the truncation (design.md, "Noisy clouds"). 0 keeps
  /// all.
  double splat_max_noise = 0.5;
  /// Unorganised clouds are first smoothed by projecting each point onto the plane of its this
  /// many nearest neighbours (projectToLocalPlanes); 0 keeps the points as given. Opt-in for raw
  /// accumulated frame points (docs/accuracy.md: more F1, fewer missed, more wrong clusters).
  int cloud_smooth_knn = 0;
  /// With smoothing, a point farther from its neighbours' plane than this many times their RMS
  /// distance from it is dropped (flying pixels, far-range noise); 0 keeps every point.
  double cloud_outlier_sigma = 2.5;

  /// Frame streams keep at most one input point per cell of this size (m) for the change
  /// outputs; 0 keeps every in-band point. Whole clouds (Map::fromCloud) keep every point.
  double point_cell = 0.0035;

  // --- height map / object map ---------------------------------------------------------------
  float w_min = 1.0f;   ///< minimum TSDF weight for a surface / observed cell
  double h_obj = 0.01;  ///< m; cells above this height belong to objects
  /// m; a plane's height-map cells farther than this outside its extent (the box of its inliers)
  /// are unknown: a PlaneSDF fuses the whole unbounded band of its plane, but what stands beyond
  /// the plane (a wall or a shelf in a table's band, across the room) is not on it. A large value
  /// (1000) disables the limit.
  double support_margin = 0.10;
  /// Ownership of a band between planes (design.md, "Ownership"). Planes whose normals' |cosine|
  /// is below ownership_parallel_cos are not parallel: a height-map surface within
  /// ownership_surface_distance (m) of such a plane, inside its extent grown by
  /// ownership_extent_margin (m), lies on that plane and is unknown here.
  double ownership_parallel_cos = 0.7;
  double ownership_surface_distance = 0.02;
  double ownership_extent_margin = 0.03;
  /// A vertical plane whose extent is at least structure_min_extent (m) long is room structure
  /// (a wall, a shelf's side; not a box's face): its surface is unknown in other bands from
  /// structure_behind (m) behind it to structure_front (m) in front, the back half of a far
  /// wall's noisy surface (3 sigma of a Kinect's depth noise is 6 cm at 3.5 m) and the
  /// truncation band behind it, which the height walk reads as objects standing in the wall.
  /// A plane farther than structure_behind behind another was seen through it.
  double structure_min_extent = 1.0;
  double structure_behind = 0.10;
  double structure_front = 0.06;
  /// m; room structure at least this long is a wall: its surface is structure at any height
  /// (the planes of frame streams stop near 1.8 m) and along its whole line, beyond the ends of
  /// its extent (a patch of it cut off from the rest by what hid the wall between).
  double wall_min_length = 2.0;
  /// Speckle filter of the object map (computeObjectMap). A connected component of cells above
  /// h_obj in which fewer than this fraction of the cells have their whole 3x3 neighbourhood above
  /// h_obj is sensor noise percolating over a far or grazing surface (single noisy cells a few
  /// mm above h_obj, touching diagonally), not a solid object: only its opening (the cells of
  /// the 3x3 squares inside it) stays. Solid objects, 3x3 cells (2 cm) and wider, have a third
  /// or more of such cells and stay whole. 0 keeps every component (the brief's plain components).
  double object_min_solidity = 0.02;

  // --- registration ------------------------------------------------------------------------------
  double delta_n = 0.95;       ///< minimum cosine between normals
  double delta_d = 0.20;       ///< m; maximum offset gap
  bool refine_inplane = true;  ///< refine (u, v, yaw) from static height-map structure
  /// Search window of the in-plane refinement (refineInPlane), both ways along u and v (m) and in
  /// yaw (degrees): a frame error of t metres and r radians moves points at distance D from its
  /// centre by up to t + r D in the plane (3 cm and 2 degrees at 1.2 m).
  double inplane_max_shift = 0.08;
  double inplane_max_yaw_deg = 4.0;
  /// Steps of the fine search: m (0: the target map's cell) and degrees.
  double inplane_shift_step = 0.0;
  double inplane_yaw_step_deg = 0.5;
  int inplane_max_cells = 40000;  ///< source cells scored per candidate (evenly subsampled)
  int inplane_min_compared = 50;  ///< fewer cells observed in both maps: no refinement
  /// A refinement is applied only when it removes at least inplane_min_gain_cells mismatching
  /// cells and either inplane_min_gain_fraction of the initial mismatches or
  /// inplane_min_gain_sigmas standard deviations of their count (design.md, "In-plane
  /// refinement").
  int inplane_min_gain_cells = 20;
  double inplane_min_gain_fraction = 0.2;
  double inplane_min_gain_sigmas = 3.0;

  // --- height comparison -------------------------------------------------------------------------
  double delta_h = 0.02;      ///< m
  int min_change_cells = 20;  ///< drop changed components smaller than this
  int dilation_cells = 1;
  /// A changed blob grows to the whole object-map component it overlaps, except into a
  /// component of at least blob_large_area (m², larger than one movable object: a shelf with
  /// its back panel in a wall's band, a noisy stretch of a far wall) of which the change covers
  /// less than blob_min_overlap: of that, only the changed cells join, and such a blob is a
  /// change only on 3D evidence. blob_min_overlap = 0 always grows (the brief's blobs).
  double blob_min_overlap = 0.5;
  double blob_large_area = 0.1;  ///< m²
  /// A blob without 3D evidence (verdict not Changed) of which at least through_band_top of the
  /// cells reach the band's top, and whose top cells land on or next to top cells of the other map
  /// for at least through_band_fraction, is a structure passing through the band (a table leg on
  /// the floor) seen from other sides in the two sessions, not an object standing in the band
  /// (docs/design.md, "Structure through the band"). An overlap above 1 disables the rule.
  double through_band_top = 0.2;
  double through_band_fraction = 1.0 / 3.0;
  /// Maps splatted from clouds without a pixel grid: a blob whose surface rests on fewer points
  /// (TSDF weight) than this fraction of what the surfaces within 10 cm of it rest on is noise
  /// (flying pixels, a far layer's spikes), not an object (design.md, "Thin support"). 0 keeps
  /// every blob.
  double thin_support_ratio = 0.5;
  /// Noise-aware height test (docs/design.md, "rough surfaces"): a cell changes only when its
  /// height differs by more than max(delta_h, roughness_factor * r), r the larger roughness of
  /// the two maps there (computeRoughness over tiles of roughness_tile cells). A far wall fused
  /// from depth noise of 1-2 cm, or reconstructed from it, is bumpy by that much in both
  /// sessions at different places. roughness_tile = 0 keeps the plain delta_h test.
  int roughness_tile = 16;
  double roughness_factor = 3.0;

  // --- 3D validation ----------------------------------------------------------------------------
  int bins_theta = 5;
  int bins_phi = 5;
  int bins_lambda = 6;
  double sdf_sigma_voxels = 2.0;
  double alpha = 2.0;
  double delta_blob = 0.9;
  /// Key voxels need |det(H / voxel_size)| >= this (Hessian in voxel units). Extrema of pure
  /// noise reach about 1e-3 at 1 mm of SDF noise and 7 mm voxels (det grows as the noise cubed);
  /// those of object edges and corners 1e-3 .. 5e-2.
  double key_min_abs_det = 2e-3;
  int key_max_voxels = 200;  ///< at most this many key voxels per blob, the largest |det|
  /// A 3D verdict (Changed or Unchanged) needs at least this many scored key voxels, else the
  /// blob is Unknown: the only key voxels of static table legs (on rims seen from other
  /// viewpoints) scored "changed", while real changes score 16 to 30 (design.md, "3D verdicts").
  int verdict_min_scored = 3;
  /// ... where either map was splatted from a cloud without a pixel grid: its SDF carries the
  /// points' noise, and static objects scored "changed" from 3-11 key voxels.
  int verdict_min_scored_splatted = 12;

  // --- events (design.md, "Moved and replaced") --------------------------------------------------
  /// Two footprints are the same object when their shapeDistance is below this: a removed and an
  /// added one pair into a move, a blob and the other map's object under it are "in place".
  double moved_shape_distance = 0.3;
  /// The same object in place: the two footprints' IoU is at least in_place_min_overlap and their
  /// centroids are at most in_place_shift_fraction of the smaller box diagonal apart.
  double in_place_min_overlap = 0.5;
  double in_place_shift_fraction = 0.15;
  /// A removal whose footprint lands on current objects covering at least this share of it is a
  /// replacement.
  double replaced_min_overlap = 0.5;

  // --- incremental detection (ChangeDetector) ----------------------------------------------------
  /// A change is announced once the updates over at least this many frames of the current
  /// session found it with the same type; an announced change is updated (new type, extent or
  /// confidence) or retracted only once the updates over as many frames agree (design.md,
  /// "Stable events"). 0 announces every result at once. ChangeDetector::finish settles all.
  int event_settle_frames = 10;
  /// As event_settle_frames, for a result the 3D validation could not check on either side (no
  /// side scored enough key voxels with an observed counterpart: the height test alone decided,
  /// the other session has not seen the object's surfaces closely enough yet; design.md,
  /// "Stable events").
  int event_unscored_settle_frames = 30;

  /// Truncation distance in metres.
  double truncation() const { return truncation_voxels * voxel_size; }
};

}  // namespace planesdf
