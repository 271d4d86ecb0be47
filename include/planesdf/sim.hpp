#pragma once
/// \file sim.hpp
/// The synthetic scene simulator behind `planesdf simulate` (design.md, "Formats", issue 5): a room
/// with tables, a shelf and small objects seen in two sessions (reference, current) that differ by
/// known changes, rendered by exact ray casting with a Kinect-like depth noise model, plus the
/// ground truth of which points belong to changed objects. Each session is given as frames with
/// poses, as a whole-scene cloud and as the whole-scene reconstruction a mapper would export (TSDF
/// surface points and mesh), each form with its ground truth.
///
/// World frame: z up, the floor is z = 0, the room is centred on the origin. Lengths in metres.
/// Camera poses are camera-to-world in the OpenCV optical frame (x right, y down, z forward).
///
/// Everything is deterministic: a preset is a function of its name, seed and options (one
/// std::mt19937 seeded explicitly), the sensor noise of frame i of a session comes from its own
/// generator seeded from (Scene::seed, session, i), so the outputs are byte-identical for the same
/// scene whatever the thread count.
///
/// Typical use:
/// \code
///   planesdf::sim::Scene scene = planesdf::sim::makePreset("tabletop", 7);
///   planesdf::sim::Simulation sim = planesdf::sim::simulate(scene);
///   planesdf::sim::writeSimulation("out", scene, sim);   // the `planesdf simulate` folder
/// \endcode

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "planesdf/types.hpp"

namespace planesdf::sim {

// ---- scene description ------------------------------------------------------------------------

/// What an object is made of. The first five are single primitives, the last four composites.
enum class ObjectType { Box, Cylinder, Sphere, Cone, Torus, Mug, BookStack, Bottle, ToyCar };

/// "box", "cylinder", "sphere", "cone", "torus", "mug", "book_stack", "bottle", "toy_car".
const char* toString(ObjectType type);
/// The type named `name` (as toString writes it), or nullopt.
std::optional<ObjectType> objectTypeFromString(const std::string& name);

/// A small object standing on (or hung from) a support plane. Its local frame has the origin at
/// the centre of its base, on the support, and z along the support normal (up on tables, out of
/// the wall for hung objects); `size` is its bounding box in that frame (x, y, z = height).
///   box: the box; cylinder / cone: diameter min(x, y), apex of the cone up; sphere: diameter
///   min(x, y, z); torus: lying flat, outer diameter min(x, y), tube diameter z (needs
///   min(x, y) >= 2 z); mug: body of diameter y with a handle reaching to x (needs
///   y + 0.01 <= x <= 2 y); book_stack: round(z / 35 mm) books (1 to 5), slightly offset and
///   rotated; bottle: body, shoulder and neck; toy_car: body, cabin and four wheels, along x.
struct Object {
  int id = 1;  ///< >= 1, unique within a session; the same id in both sessions = same object
  ObjectType type = ObjectType::Box;
  Eigen::Vector3d size{0.1, 0.1, 0.1};                 ///< m, each in [0.01, 2]
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  ///< world position of the base centre
  /// Object-to-world rotation (normalised when used).
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  std::string support;  ///< name of the SupportPlane it rests on (see supportPlanes)
};

/// Object-to-world pose of `object` (from position and the normalised orientation).
Pose objectPose(const Object& object);

/// The room: a floor at z = 0 of size.x by size.y centred on the origin, optionally four walls.
struct Room {
  Eigen::Vector2d size{5.0, 5.0};  ///< m, each in [1, 50]
  double wall_height = 2.5;        ///< m
  bool walls = false;
};

/// A table: a 3 cm top on four legs. Local frame: origin on the floor under the centre of the top,
/// rotated by yaw about z.
struct Table {
  int id = 1;  ///< >= 1, unique; its top is the support plane "table<id>"
  Eigen::Vector2d center = Eigen::Vector2d::Zero();
  double yaw_deg = 0.0;
  Eigen::Vector3d size{1.2, 0.8, 0.75};  ///< top length (x), width (y), height of the top (z)
};

/// A shelf standing against a wall: two sides, a back and `boards` horizontal boards from 10 cm
/// above the floor up to the top (size.z). Local frame as for tables; the open front faces local
/// -y. Board k (1 = lowest) is the support plane "shelf<id>.board<k>".
struct Shelf {
  int id = 1;
  Eigen::Vector2d center = Eigen::Vector2d::Zero();
  double yaw_deg = 0.0;
  Eigen::Vector3d size{1.0, 0.32, 1.8};  ///< width (x), depth (y), height of the top board (z)
  int boards = 4;                        ///< in [2, 10]
};

/// A horizontal or vertical rectangle objects rest on or hang from: the floor ("floor"), a wall
/// ("wall+x", "wall-x", "wall+y", "wall-y": the wall at x = +size.x / 2, ...), a table top
/// ("table<id>") or a shelf board ("shelf<id>.board<k>").
struct SupportPlane {
  std::string name;
  /// Plane-to-world: origin at the centre of the rectangle, z the normal toward the free side,
  /// for walls x horizontal along the wall and y up.
  Pose frame = Pose::Identity();
  Eigen::Vector2d half_extent = Eigen::Vector2d::Zero();  ///< m, along the frame's x and y
  double clearance = 0.0;  ///< free space above the plane (m): shelf boards are limited
};

/// A camera path: `frames` views from a circle of `radius` around `center` (world xy), camera i
/// at the angle start + (end - start) (i + 0.5) / frames, at a height going `height_waves` times
/// between z_min and z_max (starting at z_min), looking at `target`. The look-at point moves up
/// and down with the camera by the fraction `target_follow` of its height offset (0: fixed
/// target; 1: the camera keeps its pitch, to scan a shelf). An arc shorter than 360 degrees is a
/// partial-coverage trajectory.
struct Orbit {
  Eigen::Vector3d target = Eigen::Vector3d::Zero();
  Eigen::Vector2d center = Eigen::Vector2d::Zero();
  double radius = 1.5;
  double z_min = 1.0;
  double z_max = 1.4;
  int height_waves = 2;
  double start_deg = 0.0;
  double end_deg = 360.0;
  int frames = 30;
  double target_follow = 0.0;
};

/// The rigid error of a session's reported camera poses (a localisation / map-alignment error
/// between sessions): reported = E * true with E = translate(pivot + translation) *
/// rotate(rotation_deg) * translate(-pivot), `rotation_deg` an axis-angle vector in degrees. The
/// presets rotate about the vertical (visual-inertial drift leaves roll and pitch observable).
struct LocalisationError {
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Vector3d rotation_deg = Eigen::Vector3d::Zero();
  Eigen::Vector3d pivot = Eigen::Vector3d::Zero();
};

/// E of `error` (see LocalisationError).
Pose localisationErrorPose(const LocalisationError& error);

/// One session: the objects present, the camera trajectory and the error of its reported poses.
struct Session {
  std::vector<Object> objects;
  std::vector<Orbit> trajectory;  ///< orbits, concatenated in order
  LocalisationError localisation_error;
};

/// A change scenario. Move is >= 10 cm, SmallMove exactly 3 cm; Swap exchanges the places of two
/// objects; Replace puts a new object in place of a removed one.
enum class ChangeKind { None, Add, Remove, Move, SmallMove, Swap, Replace };

/// "none", "add", "remove", "move", "small_move", "swap", "replace".
const char* toString(ChangeKind kind);
std::optional<ChangeKind> changeKindFromString(const std::string& name);

/// A record of one change that was made (documentation for people and benchmarks; the ground
/// truth is computed from the two sessions' object lists, see changedObjects).
struct Change {
  ChangeKind kind = ChangeKind::None;
  std::vector<int> reference_ids;  ///< objects of the reference session involved
  std::vector<int> current_ids;    ///< objects of the current session involved
};

/// The depth sensor and its noise (Nguyen, Izadi & Lovell 2012, Kinect v1): axial
/// sigma = a + b (z - z0)^2 + c / sqrt(z) * theta^2 / (pi/2 - theta)^2 (theta: angle of
/// incidence), lateral noise as a Gaussian jitter of each pixel's ray, depth quantised to
/// `quantisation`, no return beyond `max_incidence_deg`, and at depth edges (a 4-neighbour more
/// than edge_jump * z nearer or farther) dropouts and flying pixels (a depth between the two
/// surfaces).
struct SensorModel {
  Intrinsics intrinsics;  ///< 640x480, fx = fy = 525, cx = 319.5, cy = 239.5
  double min_depth = 0.4;
  double max_depth = 4.0;
  bool noise = true;  ///< false: an ideal sensor (exact depth, no jitter, no dropouts)
  double axial_a = 0.0012;
  double axial_b = 0.0019;
  double axial_z0 = 0.4;
  double axial_incidence = 0.0001;  ///< c of the incidence term
  double lateral_sigma_px = 0.8;    ///< ray jitter (pixels)
  double quantisation = 0.001;      ///< m (0: none)
  double max_incidence_deg = 80.0;
  double edge_jump = 0.03;     ///< relative depth jump that marks an edge
  double edge_dropout = 0.3;   ///< P(drop) of a pixel behind an edge (half of it in front)
  double flying_pixel = 0.05;  ///< P(flying pixel) of a pixel behind an edge
  double frame_rate = 30.0;    ///< Hz; frame i has the timestamp i / frame_rate
};

/// A whole scene description: the static structure, the sensor and both sessions. This is what
/// `scene.json` holds and `planesdf simulate --scene FILE.json` reads.
struct Scene {
  std::string name = "custom";  ///< the preset it came from, or anything
  std::uint32_t seed = 1;       ///< seeds the sensor noise (and, for presets, the layout)
  Room room;
  std::vector<Table> tables;
  std::vector<Shelf> shelves;
  SensorModel sensor;
  Session reference;
  Session current;
  std::vector<Change> changes;
};

/// The support planes of the scene's structure, in a fixed order: floor, walls (when present),
/// table tops, shelf boards.
std::vector<SupportPlane> supportPlanes(const Scene& scene);

/// Throws planesdf::Error naming `what` and the element (e.g. "current.objects[2].size") when the
/// scene is not usable: sizes outside their ranges or not finite, an unknown support, duplicate
/// ids, a trajectory without frames (or more than 5000 in all), bad intrinsics or noise values.
void validateScene(const Scene& scene, const std::string& what = "scene");

// ---- presets ------------------------------------------------------------------------------------

struct PresetOptions {
  /// Changes to make, in order, each on objects no earlier change touched. Empty: the preset's
  /// default (tabletop: add, remove, move; room: add, remove, move, replace).
  std::vector<ChangeKind> changes;
  /// Frames per session: tabletop 30 (one orbit), room about 14 per table + 12 for the shelf + 6
  /// for the wall; a positive value scales the room's split to this total.
  int frames = 0;
  /// Fraction of a full orbit each session covers, in (0, 1]. A partial arc is centred on the
  /// changed objects, so the changes stay in view.
  double reference_coverage = 1.0;
  double current_coverage = 1.0;
  /// Localisation error of the current session: a random horizontal direction of this length (m)
  /// and a rotation of this angle about the vertical through the scene centre (random sign).
  double localisation_translation = 0.01;
  double localisation_rotation_deg = 1.0;
};

/// A generated scene. "tabletop": a floor and one table with 5 to 7 objects, the camera orbiting
/// the table. "room": floor, four walls, 1 to 3 tables with 3 to 5 objects each, a shelf with 3 or
/// 4 boards and objects on them, an object hung on a wall, cameras orbiting each table, scanning
/// the shelf and looking at the wall. Objects are 4 to 35 cm tall. Throws
/// planesdf::Error("--scene") for another name or when the changes cannot be placed.
Scene makePreset(const std::string& name, std::uint32_t seed, const PresetOptions& options = {});

// ---- JSON ---------------------------------------------------------------------------------------

/// The scene as JSON (every field written, doubles in shortest round-trip form, so
/// parseSceneJson(sceneToJson(s)) reproduces `s` exactly).
std::string sceneToJson(const Scene& scene);

/// Parses a scene. Optional keys (sensor, shelves, tables, changes, localisation_error and the
/// fields of sensor / orbits / room) take the defaults above; unknown keys are errors. Throws
/// planesdf::Error naming `name` and the element when the JSON is malformed, a key is unknown, a
/// type name is unknown or validateScene rejects it.
Scene parseSceneJson(const std::string& text, const std::string& name);

/// Reads a scene file (parseSceneJson of its contents).
Scene loadSceneJson(const std::string& path);

/// Writes sceneToJson atomically.
void saveSceneJson(const std::string& path, const Scene& scene);

// ---- ground truth -------------------------------------------------------------------------------

/// The ids of changed objects, sorted: `reference` = objects of the reference session that are
/// gone from the current one or are there with another pose or shape (removed, moved away,
/// replaced); `current` = objects of the current session that are new or have another pose or
/// shape (added, moved in, replacing). A pose differs when the base moved more than 1 mm or
/// turned more than 0.1 degree.
struct ChangedIds {
  std::vector<int> reference;
  std::vector<int> current;
};
ChangedIds changedObjects(const Scene& scene);

// ---- geometry -----------------------------------------------------------------------------------

enum class PrimitiveKind { Box, Cylinder, Sphere, Cone, Torus };

/// A solid primitive in its own frame (centred, axis z), placed by `pose` (primitive-to-world).
/// `size` per kind: box (half extents); cylinder (radius, -, half height); sphere (radius, -, -);
/// cone, a capped cone / frustum (radius at z = -h, radius at z = +h, h); torus lying in the
/// local xy plane (major radius, tube radius, -).
struct Primitive {
  PrimitiveKind kind = PrimitiveKind::Box;
  Pose pose = Pose::Identity();
  Eigen::Vector3d size = Eigen::Vector3d::Zero();
  int owner = 0;  ///< the object id (>= 1), or < 0 for the room and furniture
};

/// The primitives of an object, in world coordinates, owner = object.id.
std::vector<Primitive> objectPrimitives(const Object& object);
/// The primitives of the room and furniture (floor, walls, tables, shelves), owners < 0.
std::vector<Primitive> structurePrimitives(const Scene& scene);
/// Structure plus the objects of `session`.
std::vector<Primitive> sessionPrimitives(const Scene& scene, const Session& session);

/// Smallest t > 0 at which origin + t * direction is on the primitive's surface (exact; the torus
/// by sphere tracing its exact distance to 1e-7 m), or +infinity. `direction` need not be unit.
double raycast(const Primitive& primitive, const Eigen::Vector3d& origin,
               const Eigen::Vector3d& direction);

/// Exact signed distance (negative inside) from `p` to the primitive's surface.
double signedDistance(const Primitive& primitive, const Eigen::Vector3d& p);

// ---- sensor -------------------------------------------------------------------------------------

/// The true camera-to-world poses along `trajectory` (see Orbit), orbits in order.
std::vector<Pose> trajectoryPoses(const std::vector<Orbit>& trajectory);

/// Camera-to-world pose (OpenCV optical frame, no roll) of a camera at `eye` looking at `target`.
Pose lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target);

/// Renders one depth frame of `session` seen from `camera_to_world` with scene.sensor (noise from a
/// generator seeded with `noise_seed`). Depth is z in metres, 0 where there is no return.
DepthFrame renderDepth(const Scene& scene, const Session& session, const Pose& camera_to_world,
                       std::uint64_t noise_seed = 0);

// ---- simulation ---------------------------------------------------------------------------------

/// One rendered session.
struct SessionData {
  std::vector<DepthFrame> frames;    ///< noisy depth, timestamps i / frame_rate
  std::vector<Pose> true_poses;      ///< where the camera was
  std::vector<Pose> reported_poses;  ///< what the session reports (E * true, see LocalisationError)
  /// The whole-scene cloud, in the reported frame: the points of every frame fused into one
  /// point (the centroid) per cell. Cells are kVoxel wide for points measured at most 2 m deep and
  /// twice as wide per doubling of the depth beyond (the sensor's own resolution: a pixel is
  /// 3.8 mm wide at 2 m); a cell is dropped where a finer cell lies inside it, and when it belongs
  /// to a noise shell (a face neighbour holds more than twice its points). Ordered by cell.
  PointCloud cloud;
  /// The points of `cloud` (same coordinates) on this side's changed objects, with an Int32 field
  /// "object_id": a point belongs to an object when the object's surface is within
  /// kLabelDistance of it and nearer than any other surface of the scene.
  PointCloud gt;
  /// The whole-scene reconstruction a mapper would export (Open3D, voxblox, KinectFusion), in the
  /// reported frame: the frames fused with the reported poses into a projective TSDF of
  /// SimulateOptions::reconstruction_voxel (truncation 4 voxels, weight 1 per observation, depth
  /// up to the sensor's max_depth), and its surface extracted as Open3D's extract_point_cloud
  /// does: one point at the linear zero crossing of each voxel edge (voxel centre to its +x, +y or
  /// +z neighbour) whose two voxels were both observed by at least 2 frames and differ in sign.
  /// Points only: no normals, colours or sensor pose. Ordered by TSDF block, then voxel, then axis.
  PointCloud reconstruction;
  /// The marching-cubes mesh of the same TSDF over the cubes whose 8 voxels were observed by at
  /// least 2 frames: triangles indexing `reconstruction.points` (its vertices are exactly those
  /// points; a point on no observed cube is an unused vertex), counter-clockwise seen from the
  /// free side.
  std::vector<Triangle> mesh_triangles;
  /// The points of `reconstruction` on this side's changed objects, labelled as `gt` is (each
  /// point mapped back to the true frame with E^-1 for the distance queries); also the ground
  /// truth of the mesh, whose vertices are the same points.
  PointCloud reconstruction_gt;
};

struct Simulation {
  SessionData reference;
  SessionData current;
};

inline constexpr double kVoxel = 0.0035;        ///< finest whole-cloud cell size (m)
inline constexpr double kLabelDistance = 0.01;  ///< ground-truth labelling distance (m)
/// The range of SimulateOptions::reconstruction_voxel (m).
inline constexpr double kMinReconstructionVoxel = 0.005;
inline constexpr double kMaxReconstructionVoxel = 0.010;

struct SimulateOptions {
  int threads = 0;  ///< rendering / labelling / reconstruction threads; 0 = all cores
  /// Voxel size of the reconstruction's TSDF (m), in [kMinReconstructionVoxel,
  /// kMaxReconstructionVoxel] (what mappers export scenes at).
  double reconstruction_voxel = 0.007;
  /// Called with one-line progress messages (e.g. to print on stderr); may be empty.
  std::function<void(const std::string&)> progress;
};

/// Renders both sessions, builds the whole-scene clouds, the reconstructions and their ground
/// truth. Validates the scene first (planesdf::Error naming "scene") and
/// options.reconstruction_voxel (planesdf::Error naming it).
Simulation simulate(const Scene& scene, const SimulateOptions& options = {});

/// Writes the `planesdf simulate` folder (design.md, "Formats"), binary little-endian PLYs:
///   reference/, current/                  TUM folders with the reported poses
///   reference.ply, current.ply            whole-scene clouds (SessionData::cloud)
///   reference_recon.ply, current_recon.ply  reconstructions (SessionData::reconstruction)
///   reference_mesh.ply, current_mesh.ply  meshes: the reconstruction's points as vertices and
///                                         SessionData::mesh_triangles as faces
///   gt/reference.ply, gt/current.ply      ground truth of the clouds (SessionData::gt)
///   gt/reference_recon.ply, gt/current_recon.ply  ground truth of the reconstructions and meshes
///   scene.json
/// Every file is written atomically; folders are created.
void writeSimulation(const std::string& dir, const Scene& scene, const Simulation& simulation);

}  // namespace planesdf::sim
