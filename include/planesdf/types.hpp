#pragma once
/// \file types.hpp
/// Small data structs shared by every stage: poses, camera intrinsics, depth frames and point
/// clouds. Plain structs with public members; no OpenCV, PCL or MRPT types.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

// planesdf's structs hold fixed-size Eigen members, laid out for 16-byte alignment; the CMake
// target planesdf::planesdf defines it for its users. Without it, -mavx or -march=native give
// them another layout than the library's and corrupt memory.
static_assert(EIGEN_MAX_STATIC_ALIGN_BYTES == 16,
              "planesdf: compile with -DEIGEN_MAX_STATIC_ALIGN_BYTES=16 (link the CMake target "
              "planesdf::planesdf, which sets it)");

namespace planesdf {

/// A rigid transform. Camera poses are camera-to-world (x_world = pose * x_camera), camera frame
/// in the OpenCV optical convention (x right, y down, z forward).
using Pose = Eigen::Isometry3d;

/// Pinhole intrinsics of a depth camera, in pixels.
struct Intrinsics {
  double fx = 525.0;
  double fy = 525.0;
  double cx = 319.5;
  double cy = 239.5;
  int width = 640;
  int height = 480;

  /// Throws planesdf::Error (naming `what`) unless focal lengths are positive and finite, the
  /// image size is in [1, 16384] and the principal point is finite.
  void validate(const std::string& what = "intrinsics") const;
};

/// One depth image with its intrinsics. Depth in metres, row-major, width*height values;
/// invalid pixels are 0 or non-finite.
struct DepthFrame {
  Intrinsics intrinsics;
  std::vector<float> depth;
  double timestamp = 0.0;

  float at(int u, int v) const { return depth[static_cast<std::size_t>(v) * intrinsics.width + u]; }
  static bool isValidDepth(float d) {
    return d > 0.0f && d < std::numeric_limits<float>::infinity();
  }
};

/// The binary type a scalar field was stored with, kept so files round-trip with their types.
enum class ScalarType : std::uint8_t {
  Int8,
  UInt8,
  Int16,
  UInt16,
  Int32,
  UInt32,
  Float32,
  Float64
};

/// Size in bytes of one value of `t`.
int scalarTypeSize(ScalarType t);

/// An extra per-point property read or written by name (e.g. `object_id`, `change_id`, `label`).
/// Values are held as double, which represents every supported type exactly.
struct ScalarField {
  std::string name;
  ScalarType type = ScalarType::Float32;
  std::vector<double> values;
};

/// A point cloud. Points are in the cloud's own frame; `sensor_pose` is the sensor pose in that
/// frame (PCD VIEWPOINT; identity when unknown). A point with a non-finite coordinate is invalid
/// and kept in place, so organised clouds (height > 1) keep their pixel grid.
struct PointCloud {
  std::vector<Eigen::Vector3f> points;
  std::vector<Eigen::Vector3f> normals;             ///< empty, or one per point
  std::vector<std::array<std::uint8_t, 3>> colors;  ///< empty, or RGB per point
  std::vector<ScalarField> fields;                  ///< extra properties, one value per point
  std::uint32_t width = 0;                          ///< points per row (== size() when unorganised)
  std::uint32_t height = 1;  ///< rows; > 1 means organised (row-major pixel grid)
  Pose sensor_pose = Pose::Identity();

  std::size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  bool isOrganized() const { return height > 1; }
  bool hasNormals() const { return !normals.empty(); }
  bool hasColors() const { return !colors.empty(); }
  static bool isValid(const Eigen::Vector3f& p) { return p.allFinite(); }
  bool isValid(std::size_t i) const { return isValid(points[i]); }
  /// Number of points with finite coordinates.
  std::size_t countValid() const;

  /// The field called `name`, or nullptr.
  const ScalarField* field(const std::string& name) const;
  ScalarField* field(const std::string& name);
  /// Adds (or replaces) a field of `size()` values.
  ScalarField& addField(const std::string& name, ScalarType type, double fill = 0.0);

  /// Throws planesdf::Error (naming `what`) when the per-point arrays disagree in length or
  /// width*height != size().
  void validate(const std::string& what = "point cloud") const;
};

/// A mesh triangle: three indices into a point cloud's points (a PLY face).
using Triangle = std::array<std::uint32_t, 3>;

}  // namespace planesdf
