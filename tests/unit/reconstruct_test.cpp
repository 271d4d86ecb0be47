// The simulator's reconstruction outputs (SessionData::reconstruction, mesh_triangles,
// reconstruction_gt): a TSDF fused from the frames, its zero-crossing points and marching cubes.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <set>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/ply.hpp"
#include "planesdf/sim.hpp"
#include "test_support.hpp"

namespace planesdf::sim {
namespace {
using Eigen::Vector3d;
using planesdf::test::TempDir;

constexpr double kBoxHalfX = 0.15, kBoxHalfY = 0.10, kBoxHeight = 0.25;
constexpr double kFloorHalf = 1.0 + 0.1;  // a 2 m room: the floor slab reaches 10 cm beyond it

/// A 2 x 2 m floor (no walls) with a 30 x 20 x 25 cm box standing at the origin, seen by 5
/// noise-free 640 x 480 frames from an 80 degree arc on the +x side (1.2 m out, 0.9 to 1.1 m up),
/// so the box's -x face is never seen. The current session (unused) has one frame.
Scene floorAndBox() {
  Scene s;
  s.room.size = Eigen::Vector2d(2.0, 2.0);
  s.sensor.noise = false;
  Object box;
  box.id = 1;
  box.type = ObjectType::Box;
  box.size = Vector3d(2 * kBoxHalfX, 2 * kBoxHalfY, kBoxHeight);
  box.support = "floor";
  s.reference.objects = s.current.objects = {box};
  Orbit o;
  o.target = Vector3d(0, 0, 0.1);
  o.radius = 1.2;
  o.z_min = 0.9;
  o.z_max = 1.1;
  o.height_waves = 1;
  o.start_deg = -40;
  o.end_deg = 40;
  o.frames = 5;
  s.reference.trajectory = {o};
  o.frames = 1;
  s.current.trajectory = {o};
  return s;
}

/// A tabletop preset with few frames at 320 x 240 (as sim_test's smallPreset).
Scene smallTabletop(std::uint32_t seed, ChangeKind change) {
  PresetOptions opt;
  opt.changes = {change};
  opt.frames = 4;
  Scene s = makePreset("tabletop", seed, opt);
  Intrinsics& k = s.sensor.intrinsics;
  k.width = 320;
  k.height = 240;
  k.fx = k.fy = 262.5;
  k.cx = 159.5;
  k.cy = 119.5;
  return s;
}

/// Distance from `p` to the nearest surface of `prims`.
double surfaceDistance(const std::vector<Primitive>& prims, const Vector3d& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const Primitive& prim : prims) best = std::min(best, std::abs(signedDistance(prim, p)));
  return best;
}

/// True when `p` is on a face of the floor-and-box scene at least `margin` away from the face's
/// edges (and the floor point that far from the box): where projective TSDF fusion is exact up to
/// the pixel rounding (near edges the views disagree about what is in front).
bool onFaceInterior(const Vector3d& p, double margin, double voxel) {
  const double ax = std::abs(p.x()), ay = std::abs(p.y());
  const bool near_x = ax < kBoxHalfX - margin, near_y = ay < kBoxHalfY - margin;
  const bool box_height = p.z() > margin && p.z() < kBoxHeight - margin;
  const double h = voxel / 2;
  const bool floor = std::abs(p.z()) < h && ax < kFloorHalf - margin && ay < kFloorHalf - margin &&
                     (ax > kBoxHalfX + margin || ay > kBoxHalfY + margin);
  const bool top = std::abs(p.z() - kBoxHeight) < h && near_x && near_y;
  const bool side_x = std::abs(ax - kBoxHalfX) < h && near_y && box_height;
  const bool side_y = std::abs(ay - kBoxHalfY) < h && near_x && box_height;
  return floor || top || side_x || side_y;
}

/// The largest measured depth of any frame.
double farthestDepth(const SessionData& d) {
  float z_far = 0.0f;
  for (const DepthFrame& f : d.frames)
    for (const float z : f.depth)
      if (DepthFrame::isValidDepth(z)) z_far = std::max(z_far, z);
  return z_far;
}

/// The pixel `p` projects to in a frame seen from `camera_to_world`, and its depth.
struct Projection {
  double u = 0, v = 0, z = 0;
};
Projection project(const Intrinsics& K, const Pose& camera_to_world, const Vector3d& p) {
  const Vector3d q = camera_to_world.inverse() * p;
  return {K.fx * q.x() / q.z() + K.cx, K.fy * q.y() / q.z() + K.cy, q.z()};
}

/// The reconstruction of floorAndBox(), made once for the tests that only look at it.
class FloorAndBox : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new Scene(floorAndBox());
    sim_ = new Simulation(simulate(*scene_));
  }
  static void TearDownTestSuite() {
    delete sim_;
    delete scene_;
  }
  static const Scene& scene() { return *scene_; }
  static const SessionData& data() { return sim_->reference; }
  static double voxel() { return SimulateOptions{}.reconstruction_voxel; }

 private:
  static inline Scene* scene_ = nullptr;
  static inline Simulation* sim_ = nullptr;
};

TEST_F(FloorAndBox, PointsLieOnTheTrueSurface) {
  const SessionData& d = data();
  const std::vector<Primitive> prims = sessionPrimitives(scene(), scene().reference);
  const double v = voxel(), truncation = 4 * v;
  const Intrinsics& K = scene().sensor.intrinsics;
  // With exact depth, the interpolated zero crossing of a plane is exact but for the nearest-pixel
  // lookup: the depth is read up to half a pixel away in u and in v, i.e. up to
  // 0.5 (z / f) (|tan a_u| + |tan a_v|) off in depth, which is at most sqrt(2)/2 z / f along the
  // normal. At the farthest depth seen here (about 2.8 m) that is 3.7 mm, about half a voxel.
  const double face_tolerance = std::sqrt(0.5) * farthestDepth(d) / K.fx;
  EXPECT_LT(face_tolerance, 0.6 * v);
  // Near edges a voxel hidden behind a silhouette takes negative values (less than the truncation
  // behind what its pixel sees, along a ray up to the corner of the image: a factor 1 / cos of
  // the half-diagonal field of view) mixed with the free space other views see there: a crossing
  // can be that far plus its edge (one voxel) plus the pixel rounding off the surface.
  const double half_diagonal = std::hypot(K.width / 2.0, K.height / 2.0);
  const double edge_tolerance =
      truncation * std::hypot(K.fx, half_diagonal) / K.fx + v + face_tolerance;

  ASSERT_GT(d.reconstruction.size(), 50000u);
  std::size_t interior = 0;
  for (const Eigen::Vector3f& pf : d.reconstruction.points) {
    const Vector3d p = pf.cast<double>();
    const double dist = surfaceDistance(prims, p);
    if (onFaceInterior(p, truncation + v, v)) {
      ++interior;
      ASSERT_LE(dist, face_tolerance) << p.transpose();
    } else {
      ASSERT_LE(dist, edge_tolerance) << p.transpose();
    }
  }
  EXPECT_GT(interior, d.reconstruction.size() * 9 / 10);
}

TEST_F(FloorAndBox, FloorPointsCoverTheFloorSeenTwice) {
  const SessionData& d = data();
  const double v = voxel(), margin = 5 * v;
  const Intrinsics& K = scene().sensor.intrinsics;
  // The floor (z = 0) lies halfway between voxel centres: each column of voxels
  // ((i + 0.5) v, (j + 0.5) v) whose two voxels around z = 0 were both observed twice gives
  // exactly one point, at z = 0. A column is expected when the pixel its floor point projects to
  // sees the floor (not the box) in at least 2 frames; the voxels just above and below project
  // to pixels at most a fraction of a pixel away, so they can differ from that only where the
  // count changes between neighbouring columns: the tolerance is the number of columns on the
  // boundary of the expected set. Columns near the box and the floor's edge are left out (edge
  // effects, see PointsLieOnTheTrueSurface).
  const auto in_region = [&](double x, double y) {
    const double ax = std::abs(x), ay = std::abs(y);
    return ax < kFloorHalf - margin && ay < kFloorHalf - margin &&
           (ax > kBoxHalfX + margin || ay > kBoxHalfY + margin);
  };
  const int n = static_cast<int>(std::ceil(kFloorHalf / v));
  const auto centre = [&](int i) { return (i + 0.5) * v; };
  std::map<std::pair<int, int>, bool> expected;  // in-region columns -> seen twice
  for (int i = -n; i < n; ++i)
    for (int j = -n; j < n; ++j) {
      if (!in_region(centre(i), centre(j))) continue;
      const Vector3d p(centre(i), centre(j), 0.0);
      int seen = 0;
      for (std::size_t f = 0; f < d.frames.size(); ++f) {
        const Projection q = project(K, d.reported_poses[f], p);
        const double u = std::floor(q.u + 0.5), w = std::floor(q.v + 0.5);
        if (q.z <= 0 || u < 0 || u >= K.width || w < 0 || w >= K.height) continue;
        const double z = d.frames[f].at(static_cast<int>(u), static_cast<int>(w));
        const Vector3d seen_point =
            d.reported_poses[f] * Vector3d((u - K.cx) / K.fx * z, (w - K.cy) / K.fy * z, z);
        seen += z > 0 && std::abs(seen_point.z()) < 1e-6;
      }
      expected[{i, j}] = seen >= 2;
    }
  std::size_t count = 0, boundary = 0;
  for (const auto& [ij, seen] : expected) {
    if (!seen) continue;
    ++count;
    const auto [i, j] = ij;
    for (const auto& nb : {std::pair{i + 1, j}, {i - 1, j}, {i, j + 1}, {i, j - 1}}) {
      const auto it = expected.find(nb);
      if (it != expected.end() && !it->second) {
        ++boundary;
        break;
      }
    }
  }
  std::size_t floor_points = 0;
  for (const Eigen::Vector3f& p : d.reconstruction.points)
    floor_points += std::abs(p.z()) < v / 4 && in_region(p.x(), p.y());
  // About 3.3 m^2 of floor seen twice: ~68000 columns of 7 mm, a few hundred on the boundary.
  EXPECT_GT(count, 50000u);
  EXPECT_LT(boundary, count / 20);
  EXPECT_LE(std::abs(static_cast<double>(floor_points) - static_cast<double>(count)),
            static_cast<double>(boundary))
      << floor_points << " floor points, " << count << " columns seen twice, " << boundary
      << " on the boundary";
}

TEST_F(FloorAndBox, NoPointWhereNothingWasObserved) {
  const SessionData& d = data();
  const double v = voxel(), margin = 5 * v;
  const Intrinsics& K = scene().sensor.intrinsics;
  for (const Eigen::Vector3f& pf : d.reconstruction.points) {
    const Vector3d p = pf.cast<double>();
    // The box's -x face faces away from every camera; the floor slab's underside and the box's
    // inside are never seen either.
    ASSERT_FALSE(std::abs(p.x() + kBoxHalfX) < v && std::abs(p.y()) < kBoxHalfY - margin &&
                 p.z() > margin && p.z() < kBoxHeight - margin)
        << p.transpose();
    // (Up to a voxel plus half a pixel: a voxel just inside a silhouette can read the background.)
    const bool under_floor = std::abs(p.x()) < kFloorHalf - v && std::abs(p.y()) < kFloorHalf - v;
    ASSERT_FALSE(under_floor && p.z() < -v) << p.transpose();
    ASSERT_FALSE(std::abs(p.x()) < kBoxHalfX - 2 * v && std::abs(p.y()) < kBoxHalfY - 2 * v &&
                 p.z() > 2 * v && p.z() < kBoxHeight - 2 * v)
        << p.transpose();
    // Its two voxels were each seen by at least 2 frames: the point itself projects into at least
    // 2 images, up to the voxel it may be away from them (v f / z pixels).
    int views = 0;
    for (const Pose& T : d.reported_poses) {
      const Projection q = project(K, T, p);
      const double slack = 0.5 + v * K.fx / q.z;
      views += q.z > 0 && q.u > -slack && q.u < K.width - 1 + slack && q.v > -slack &&
               q.v < K.height - 1 + slack && q.z <= scene().sensor.max_depth + v;
    }
    ASSERT_GE(views, 2) << p.transpose();
  }
}

TEST_F(FloorAndBox, MeshIsWeldedConsistentlyWoundAndCoversTheFloor) {
  const SessionData& d = data();
  const std::vector<Eigen::Vector3f>& pts = d.reconstruction.points;
  const double v = voxel();
  ASSERT_GT(d.mesh_triangles.size(), pts.size());
  std::set<std::pair<std::uint32_t, std::uint32_t>> directed;
  // Floor points are within the pixel rounding of z = 0 (see PointsLieOnTheTrueSurface), crossings
  // of the box's sides exactly at voxel centre heights ((k + 0.5) v).
  const auto on_floor = [&](double z) { return std::abs(z) < 0.45 * v; };
  double floor_area = 0.0;  // projected on the xy plane
  std::size_t floor_triangles = 0, top_triangles = 0;
  for (const Triangle& t : d.mesh_triangles) {
    for (const std::uint32_t i : t) ASSERT_LT(i, pts.size());
    ASSERT_TRUE(t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
    // Corners of a triangle are on edges of one cube.
    for (int k = 0; k < 3; ++k)
      ASSERT_LE((pts[t[k]] - pts[t[(k + 1) % 3]]).norm(), std::sqrt(3.0) * v + 1e-6);
    // Each directed edge once: no edge is shared by more than two triangles, and neighbours wind
    // the same way.
    for (int k = 0; k < 3; ++k)
      ASSERT_TRUE(directed.insert({t[k], t[(k + 1) % 3]}).second) << "edge used twice";
    const Vector3d a = pts[t[0]].cast<double>(), b = pts[t[1]].cast<double>(),
                   c = pts[t[2]].cast<double>();
    const Vector3d normal = (b - a).cross(c - a);
    // Counter-clockwise seen from the free side: up on the floor and on the box top.
    if (on_floor(a.z()) && on_floor(b.z()) && on_floor(c.z())) {
      ASSERT_GT(normal.z(), 0.0);
      floor_area += 0.5 * normal.z();
      ++floor_triangles;
    }
    if (on_floor(a.z() - kBoxHeight) && on_floor(b.z() - kBoxHeight) &&
        on_floor(c.z() - kBoxHeight)) {
      ASSERT_GT(normal.z(), 0.0);
      ++top_triangles;
    }
  }
  EXPECT_GT(top_triangles, 2000u);  // the 30 x 20 cm top: ~1200 cubes, two triangles each
  // A cube whose four z edges cross the floor holds two triangles whose projections tile its
  // v x v square: the area is v^2 per cube, a little less than one per floor point (a column on
  // the observed area's boundary has no complete cube beside it).
  std::size_t floor_points = 0;
  for (const Eigen::Vector3f& p : pts) floor_points += on_floor(p.z());
  EXPECT_GT(floor_triangles, floor_points);
  EXPECT_LE(floor_area, floor_points * v * v);
  EXPECT_GT(floor_area, 0.9 * floor_points * v * v);
}

TEST_F(FloorAndBox, WrittenFilesReadBack) {
  TempDir tmp;
  writeSimulation(tmp.path(), scene(), Simulation{data(), data()});
  const SessionData& d = data();
  const PointCloud recon = io::readPly(tmp.file("reference_recon.ply"));
  EXPECT_EQ(recon.points, d.reconstruction.points);
  EXPECT_TRUE(recon.fields.empty());
  EXPECT_FALSE(recon.hasNormals() || recon.hasColors());
  EXPECT_EQ(io::readPly(tmp.file("reference_mesh.ply")).points, d.reconstruction.points);
  const PointCloud gt = io::readPly(tmp.file("gt/reference_recon.ply"));
  EXPECT_EQ(gt.points, d.reconstruction_gt.points);
  ASSERT_NE(gt.field("object_id"), nullptr);
  EXPECT_EQ(gt.field("object_id")->type, ScalarType::Int32);

  // The mesh file: binary little-endian vertices (3 floats), then one uchar 3 + 3 ints per face.
  const std::string bytes = io::readFile(tmp.file("current_mesh.ply"));
  const std::string faces_line = "element face " + std::to_string(d.mesh_triangles.size()) +
                                 "\nproperty list uchar int vertex_indices\nend_header\n";
  const std::size_t body = bytes.find(faces_line);
  ASSERT_NE(body, std::string::npos);
  const std::size_t first_face = body + faces_line.size() + 12 * d.reconstruction.size();
  ASSERT_EQ(bytes.size(), first_face + 13 * d.mesh_triangles.size());
  for (std::size_t i = 0; i < d.mesh_triangles.size(); i += 997) {
    const char* record = bytes.data() + first_face + 13 * i;
    ASSERT_EQ(record[0], 3);
    for (int k = 0; k < 3; ++k) {
      std::uint32_t index = 0;  // little-endian int
      for (int b = 3; b >= 0; --b)
        index = (index << 8) | static_cast<unsigned char>(record[1 + 4 * k + b]);
      EXPECT_EQ(index, d.mesh_triangles[i][static_cast<std::size_t>(k)]);
    }
  }
}

// ---- presets --------------------------------------------------------------------------------

TEST(SimReconstruction, OutputDoesNotDependOnTheThreadCount) {
  const Scene s = smallTabletop(11, ChangeKind::Move);
  SimulateOptions one, two;
  one.threads = 1;
  two.threads = 2;
  const Simulation a = simulate(s, one), b = simulate(s, two);
  for (const auto& [x, y] : {std::pair{&a.reference, &b.reference}, {&a.current, &b.current}}) {
    ASSERT_GT(x->reconstruction.size(), 10000u);
    ASSERT_EQ(x->reconstruction.size(), y->reconstruction.size());
    EXPECT_EQ(std::memcmp(x->reconstruction.points.data(), y->reconstruction.points.data(),
                          x->reconstruction.size() * sizeof(Eigen::Vector3f)),
              0);
    EXPECT_EQ(x->mesh_triangles, y->mesh_triangles);
    EXPECT_EQ(x->reconstruction_gt.points, y->reconstruction_gt.points);
    EXPECT_EQ(x->reconstruction_gt.field("object_id")->values,
              y->reconstruction_gt.field("object_id")->values);
  }
}

TEST(SimReconstruction, GroundTruthLabelsTheReconstructionInTheTrueFrame) {
  // The current session's poses are off by 1 cm and 1 degree: its reconstruction is in the
  // reported frame, its labels come from the true geometry.
  const Scene s = smallTabletop(4, ChangeKind::Move);
  const Simulation sim = simulate(s);
  const ChangedIds changed = changedObjects(s);
  for (int side = 0; side < 2; ++side) {
    const Session& session = side == 0 ? s.reference : s.current;
    const SessionData& d = side == 0 ? sim.reference : sim.current;
    const std::vector<int>& ids = side == 0 ? changed.reference : changed.current;
    const Pose to_true = localisationErrorPose(session.localisation_error).inverse();
    EXPECT_EQ(side == 0, to_true.isApprox(Pose::Identity()));
    std::map<int, std::vector<Primitive>> by_owner;
    for (const Primitive& p : sessionPrimitives(s, session)) by_owner[p.owner].push_back(p);
    std::set<std::tuple<float, float, float>> labelled;
    const ScalarField* object_id = d.reconstruction_gt.field("object_id");
    ASSERT_NE(object_id, nullptr);
    for (std::size_t i = 0; i < d.reconstruction_gt.size(); ++i) {
      const Eigen::Vector3f& p = d.reconstruction_gt.points[i];
      labelled.insert({p.x(), p.y(), p.z()});
      const int id = static_cast<int>(object_id->values[i]);
      ASSERT_TRUE(std::find(ids.begin(), ids.end(), id) != ids.end()) << id;
      EXPECT_LE(surfaceDistance(by_owner[id], to_true * p.cast<double>()), kLabelDistance + 1e-6);
    }
    EXPECT_GT(labelled.size(), 100u) << "side " << side;
    // Every 10th unlabelled point: not within kLabelDistance of a changed object, or another
    // surface is nearer (brute force; the few points on a decision boundary skipped).
    for (std::size_t i = 0; i < d.reconstruction.size(); i += 10) {
      const Eigen::Vector3f& pf = d.reconstruction.points[i];
      if (labelled.count({pf.x(), pf.y(), pf.z()})) continue;
      const Vector3d p = to_true * pf.cast<double>();
      double changed_dist = 1e9, other_dist = 1e9;
      for (const auto& [owner, prims] : by_owner) {
        const bool is_changed = std::find(ids.begin(), ids.end(), owner) != ids.end();
        double& best = is_changed ? changed_dist : other_dist;
        best = std::min(best, surfaceDistance(prims, p));
      }
      if (std::abs(changed_dist - kLabelDistance) < 1e-5 ||
          std::abs(changed_dist - other_dist) < 1e-5)
        continue;
      ASSERT_TRUE(changed_dist > kLabelDistance || other_dist < changed_dist) << p.transpose();
    }
  }
}

TEST(SimReconstruction, VoxelSizeIsValidated) {
  const Scene s = smallTabletop(3, ChangeKind::None);
  for (const double bad : {0.0049, 0.0101, std::numeric_limits<double>::quiet_NaN()}) {
    SimulateOptions opt;
    opt.reconstruction_voxel = bad;
    try {
      simulate(s, opt);
      ADD_FAILURE() << "no error for " << bad;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("reconstruction_voxel"), std::string::npos) << e.what();
    }
  }
  // Both ends of the range work; a finer voxel gives more points.
  SimulateOptions fine, coarse;
  fine.reconstruction_voxel = kMinReconstructionVoxel;
  coarse.reconstruction_voxel = kMaxReconstructionVoxel;
  EXPECT_GT(simulate(s, fine).reference.reconstruction.size(),
            simulate(s, coarse).reference.reconstruction.size());
}

}  // namespace
}  // namespace planesdf::sim
