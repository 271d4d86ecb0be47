#include "planesdf/sim.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/ply.hpp"
#include "planesdf/io/tum.hpp"
#include "test_support.hpp"

namespace planesdf::sim {
namespace {
namespace fs = std::filesystem;
using Eigen::Vector2d;
using Eigen::Vector3d;
using planesdf::test::TempDir;

using test::kPi;

/// A preset with few frames at 320x240 (same field of view), so a whole simulation takes about a
/// second.
Scene smallPreset(const std::string& name, std::uint32_t seed, std::vector<ChangeKind> changes,
                  int frames = 6) {
  PresetOptions opt;
  opt.changes = std::move(changes);
  opt.frames = frames;
  Scene s = makePreset(name, seed, opt);
  Intrinsics& k = s.sensor.intrinsics;
  k.width = 320;
  k.height = 240;
  k.fx = k.fy = 262.5;
  k.cx = 159.5;
  k.cy = 119.5;
  return s;
}

/// An empty 4 x 4 m room with walls and one orbit (for rendering single frames).
Scene emptyRoom() {
  Scene s;
  s.room.size = Vector2d(4.0, 4.0);
  s.room.walls = true;
  Orbit o;
  o.target = Vector3d(0, 0, 0.5);
  o.frames = 1;
  s.reference.trajectory = s.current.trajectory = {o};
  return s;
}

std::set<int> idsOf(const PointCloud& gt) {
  std::set<int> ids;
  const ScalarField* f = gt.field("object_id");
  if (!f) return ids;
  for (const double v : f->values) ids.insert(static_cast<int>(v));
  return ids;
}

const Object* findObject(const Session& s, int id) {
  for (const Object& o : s.objects)
    if (o.id == id) return &o;
  return nullptr;
}

// ---- geometry -------------------------------------------------------------------------------

TEST(SimGeometry, RaycastToABoxFaceIsExact) {
  Primitive box;
  box.kind = PrimitiveKind::Box;
  box.pose.translation() = Vector3d(2.0, 0.0, 0.0);
  box.size = Vector3d(0.5, 1.0, 1.0);
  // Face x = 1.5: along the axis and obliquely (non-unit direction with x component 1).
  EXPECT_EQ(raycast(box, Vector3d::Zero(), Vector3d::UnitX()), 1.5);
  EXPECT_DOUBLE_EQ(raycast(box, Vector3d::Zero(), Vector3d(1.0, 0.2, -0.1)), 1.5);
  EXPECT_DOUBLE_EQ(raycast(box, Vector3d::Zero(), Vector3d(2.0, 0.0, 0.0)), 0.75);
  EXPECT_TRUE(std::isinf(raycast(box, Vector3d::Zero(), -Vector3d::UnitX())));
  EXPECT_TRUE(std::isinf(raycast(box, Vector3d::Zero(), Vector3d(1.0, 0.8, 0.0))));  // passes by

  // A rotated box seen along its face normal from 2 m: distance 2 - 0.25.
  box.pose.linear() = Eigen::AngleAxisd(0.5, Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  box.size = Vector3d(0.25, 0.4, 0.3);
  const Vector3d n = box.pose.linear().col(0);
  const Vector3d eye = box.pose.translation() + 2.0 * n;
  EXPECT_NEAR(raycast(box, eye, -n), 1.75, 1e-12);
  EXPECT_NEAR(signedDistance(box, eye), 1.75, 1e-12);

  // Rendered without noise: a wall 1.2 m in front of the camera has depth 1.2 at every pixel.
  Scene s = emptyRoom();
  s.sensor.noise = false;
  const Pose cam = lookAt(Vector3d(0.8, 0.0, 1.2), Vector3d(3.0, 0.0, 1.2));
  const DepthFrame f = renderDepth(s, s.reference, cam);
  ASSERT_EQ(f.depth.size(), 640u * 480u);
  for (const float z : f.depth) ASSERT_NEAR(z, 1.2, 1e-6);
}

TEST(SimGeometry, RaycastHitsLieOnTheSurfaceOfEveryPrimitive) {
  std::vector<Primitive> prims(5);
  prims[0].kind = PrimitiveKind::Box;
  prims[0].size = Vector3d(0.1, 0.2, 0.15);
  prims[1].kind = PrimitiveKind::Cylinder;
  prims[1].size = Vector3d(0.08, 0.08, 0.12);
  prims[2].kind = PrimitiveKind::Sphere;
  prims[2].size = Vector3d(0.1, 0.1, 0.1);
  prims[3].kind = PrimitiveKind::Cone;
  prims[3].size = Vector3d(0.1, 0.03, 0.12);
  prims[4].kind = PrimitiveKind::Torus;
  prims[4].size = Vector3d(0.1, 0.03, 0.0);
  for (std::size_t k = 0; k < prims.size(); ++k) {
    Primitive& p = prims[k];
    p.pose.linear() =
        Eigen::AngleAxisd(0.3 + k, Vector3d(1, -1, 2).normalized()).toRotationMatrix();
    p.pose.translation() = Vector3d(0.1 * k, -0.2, 0.4);
    int hits = 0;
    for (int i = 0; i < 400; ++i) {
      // Rays from a sphere of 1 m around the primitive toward points near its centre.
      const double a = 0.37 * i, b = 0.11 * i;
      const Vector3d eye = p.pose.translation() + Vector3d(std::cos(a) * std::cos(b),
                                                           std::sin(a) * std::cos(b), std::sin(b));
      const Vector3d aim = p.pose.translation() +
                           0.12 * Vector3d(std::sin(1.7 * i), std::cos(2.3 * i), std::sin(0.9 * i));
      const Vector3d d = 1.7 * (aim - eye);  // not unit
      const double t = raycast(p, eye, d);
      if (std::isinf(t)) continue;
      ++hits;
      ASSERT_NEAR(signedDistance(p, eye + t * d), 0.0, 2e-6) << "primitive " << k << " ray " << i;
      // The segment before the hit is outside.
      for (const double f : {0.25, 0.5, 0.9, 0.999})
        ASSERT_GT(signedDistance(p, eye + f * t * d), 0.0) << "primitive " << k << " ray " << i;
    }
    EXPECT_GT(hits, 50) << "primitive " << k;
  }
}

TEST(SimGeometry, ObjectsStandOnTheirBaseInsideTheirSize) {
  const std::map<ObjectType, Vector3d> sizes = {
      {ObjectType::Box, {0.2, 0.1, 0.15}},         {ObjectType::Cylinder, {0.1, 0.1, 0.2}},
      {ObjectType::Sphere, {0.12, 0.12, 0.12}},    {ObjectType::Cone, {0.15, 0.15, 0.2}},
      {ObjectType::Torus, {0.2, 0.2, 0.06}},       {ObjectType::Mug, {0.12, 0.09, 0.1}},
      {ObjectType::BookStack, {0.24, 0.16, 0.12}}, {ObjectType::Bottle, {0.08, 0.08, 0.3}},
      {ObjectType::ToyCar, {0.2, 0.1, 0.08}}};
  for (const auto& [type, size] : sizes) {
    Object o;
    o.type = type;
    o.size = size;
    const std::vector<Primitive> parts = objectPrimitives(o);
    ASSERT_FALSE(parts.empty());
    // Lowest and highest surface points, found by casting rays straight down and up.
    double lowest = 1e9, highest = -1e9;
    for (double x = -size.x() / 2; x <= size.x() / 2; x += size.x() / 40)
      for (double y = -size.y() / 2; y <= size.y() / 2; y += size.y() / 40)
        for (const Primitive& p : parts) {
          const double up = raycast(p, Vector3d(x, y, -1.0), Vector3d::UnitZ());
          const double down = raycast(p, Vector3d(x, y, 2.0), -Vector3d::UnitZ());
          if (!std::isinf(up)) lowest = std::min(lowest, -1.0 + up);
          if (!std::isinf(down)) highest = std::max(highest, 2.0 - down);
        }
    EXPECT_NEAR(lowest, 0.0, 0.003) << toString(type);  // stands on z = 0 (a sphere touches it)
    EXPECT_LE(highest, size.z() + 1e-9) << toString(type);
    EXPECT_GE(highest, 0.95 * size.z()) << toString(type);
  }
}

// ---- sensor ---------------------------------------------------------------------------------

TEST(SimSensor, AxialNoiseOfAFlatWallAtOneMetreMatchesTheModel) {
  Scene s = emptyRoom();
  const Pose cam = lookAt(Vector3d(1.0, 0.0, 1.2), Vector3d(3.0, 0.0, 1.2));  // wall x = 2
  const DepthFrame f = renderDepth(s, s.reference, cam, 42);
  // Central 200 x 200 pixels: incidence below 15 degrees, so the incidence term is negligible.
  double sum = 0.0, sum2 = 0.0;
  int n = 0;
  for (int v = 140; v < 340; ++v)
    for (int u = 220; u < 420; ++u) {
      const double z = f.at(u, v);
      ASSERT_GT(z, 0.0);
      ASSERT_NEAR(std::round(z * 1000.0), z * 1000.0, 1e-3) << "quantised to 1 mm";
      sum += z;
      sum2 += z * z;
      ++n;
    }
  const double mean = sum / n;
  const double sigma = std::sqrt(sum2 / n - mean * mean);
  const double model = 0.0012 + 0.0019 * 0.6 * 0.6;  // 1.884 mm at z = 1 m
  EXPECT_NEAR(mean, 1.0, 0.0002);
  EXPECT_NEAR(sigma, model, 0.2 * model) << "measured sigma " << sigma;
  // Same seed, same frame; another seed, other noise.
  EXPECT_EQ(renderDepth(s, s.reference, cam, 42).depth, f.depth);
  EXPECT_NE(renderDepth(s, s.reference, cam, 43).depth, f.depth);
}

TEST(SimSensor, DepthEdgesDropPixelsAndMakeFlyingPixels) {
  Scene s = emptyRoom();
  Object box;
  box.id = 1;
  box.size = Vector3d(0.3, 0.3, 0.3);
  box.position = Vector3d(0.5, 0.0, 0.0);
  box.support = "floor";
  s.reference.objects = {box};
  const Pose cam = lookAt(Vector3d(-0.5, 0.0, 0.6), Vector3d(0.6, 0.0, 0.15));
  s.sensor.noise = false;
  const DepthFrame exact = renderDepth(s, s.reference, cam);
  s.sensor.noise = true;
  const DepthFrame noisy = renderDepth(s, s.reference, cam, 7);
  int edge = 0, dropped = 0, flying = 0;
  for (int v = 1; v < 479; ++v)
    for (int u = 1; u < 639; ++u) {
      const float z = exact.at(u, v);
      if (z <= 0.0f) continue;
      float nearest = z;
      for (const auto& [du, dv] : {std::pair{-1, 0}, {1, 0}, {0, -1}, {0, 1}}) {
        const float zn = exact.at(u + du, v + dv);
        if (zn > 0.0f) nearest = std::min(nearest, zn);
      }
      if (z - nearest < 0.1f) continue;  // not behind a clear edge
      ++edge;
      const float zn = noisy.at(u, v);
      if (zn == 0.0f) ++dropped;
      if (zn > nearest + 0.02f && zn < z - 0.02f) ++flying;
    }
  ASSERT_GT(edge, 100);
  EXPECT_GT(dropped, edge / 10);
  EXPECT_GT(flying, 0);
}

TEST(SimTrajectory, OrbitCamerasLookAtTheTargetAtVariedHeights) {
  Orbit o;
  o.target = Vector3d(0.2, -0.1, 0.8);
  o.center = Vector2d(0.2, -0.1);
  o.radius = 1.3;
  o.z_min = 1.1;
  o.z_max = 1.6;
  o.height_waves = 2;
  o.start_deg = 30.0;
  o.end_deg = 150.0;  // a partial arc
  o.frames = 24;
  const std::vector<Pose> poses = trajectoryPoses({o});
  ASSERT_EQ(poses.size(), 24u);
  double z_lo = 1e9, z_hi = -1e9;
  for (const Pose& T : poses) {
    const Vector3d eye = T.translation();
    EXPECT_NEAR((eye.head<2>() - o.center).norm(), o.radius, 1e-12);
    const double az = std::atan2(eye.y() - o.center.y(), eye.x() - o.center.x()) * 180.0 / kPi;
    EXPECT_GE(az, 30.0);
    EXPECT_LE(az, 150.0);
    z_lo = std::min(z_lo, eye.z());
    z_hi = std::max(z_hi, eye.z());
    EXPECT_GE(eye.z(), o.z_min - 1e-12);
    EXPECT_LE(eye.z(), o.z_max + 1e-12);
    // Optical axis (z) toward the target, image x horizontal (no roll), image y pointing down.
    EXPECT_NEAR(T.linear().col(2).dot((o.target - eye).normalized()), 1.0, 1e-12);
    EXPECT_NEAR(T.linear().col(0).z(), 0.0, 1e-12);
    EXPECT_LT(T.linear().col(1).z(), 0.0);
    EXPECT_NEAR(T.linear().determinant(), 1.0, 1e-12);
  }
  EXPECT_GT(z_hi - z_lo, 0.8 * (o.z_max - o.z_min));
}

// ---- scenes ---------------------------------------------------------------------------------

TEST(SimScene, PresetsAreDeterministicAndFollowTheSpec) {
  for (const std::string name : {"tabletop", "room"}) {
    for (const std::uint32_t seed : {1u, 2u, 3u, 4u}) {
      const Scene s = makePreset(name, seed);
      EXPECT_EQ(sceneToJson(s), sceneToJson(makePreset(name, seed))) << name << " " << seed;
      EXPECT_NE(sceneToJson(s), sceneToJson(makePreset(name, seed + 100))) << name << " " << seed;
      EXPECT_GE(s.tables.size(), 1u);
      EXPECT_LE(s.tables.size(), 3u);
      for (const Session* session : {&s.reference, &s.current})
        for (const Object& o : session->objects) {
          if (o.support.rfind("wall", 0) == 0) continue;  // hung: z is how far it sticks out
          EXPECT_GE(o.size.z(), 0.04 - 1e-12) << name << " " << seed << " object " << o.id;
          EXPECT_LE(o.size.z(), 0.35 + 1e-12) << name << " " << seed << " object " << o.id;
        }
      int frames = 0;
      for (const Orbit& o : s.reference.trajectory) frames += o.frames;
      if (name == "tabletop") {
        EXPECT_EQ(frames, 30);
        EXPECT_FALSE(s.room.walls);
        EXPECT_EQ(s.changes.size(), 3u);
      } else {
        EXPECT_TRUE(s.room.walls);
        EXPECT_EQ(s.shelves.size(), 1u);
        EXPECT_GE(s.shelves[0].boards, 3);
        EXPECT_EQ(std::count_if(s.reference.objects.begin(), s.reference.objects.end(),
                                [](const Object& o) { return o.support == "wall+x"; }),
                  1);
        EXPECT_EQ(s.changes.size(), 4u);
      }
      // The current session's reported poses are off by 1 cm and 1 degree at the pivot.
      const Pose E = localisationErrorPose(s.current.localisation_error);
      const Vector3d pivot = s.current.localisation_error.pivot;
      EXPECT_NEAR((E * pivot - pivot).norm(), 0.01, 1e-12);
      EXPECT_NEAR(Eigen::AngleAxisd(E.linear()).angle() * 180.0 / kPi, 1.0, 1e-9);
      EXPECT_TRUE(localisationErrorPose(s.reference.localisation_error).isApprox(Pose::Identity()));
    }
  }
  EXPECT_THROW(makePreset("kitchen", 1), Error);
}

TEST(SimScene, PresetsCanMakeEveryChangeKindForManySeeds) {
  const std::vector<ChangeKind> kinds = {
      ChangeKind::None,      ChangeKind::Add,  ChangeKind::Remove, ChangeKind::Move,
      ChangeKind::SmallMove, ChangeKind::Swap, ChangeKind::Replace};
  for (const std::string name : {"tabletop", "room"})
    for (std::uint32_t seed = 1; seed <= 40; ++seed) {
      for (const ChangeKind k : kinds) {
        PresetOptions opt;
        opt.changes = {k};
        EXPECT_NO_THROW(makePreset(name, seed, opt)) << name << " " << seed << " " << toString(k);
      }
      EXPECT_NO_THROW(makePreset(name, seed)) << name << " " << seed;
    }
}

TEST(SimScene, PartialCoverageArcsAreCentredOnTheChanges) {
  PresetOptions opt;
  opt.changes = {ChangeKind::Move};
  opt.current_coverage = 0.4;
  const Scene s = makePreset("tabletop", 2, opt);
  const Orbit& ref = s.reference.trajectory.at(0);
  const Orbit& cur = s.current.trajectory.at(0);
  EXPECT_DOUBLE_EQ(ref.end_deg - ref.start_deg, 360.0);
  EXPECT_NEAR(cur.end_deg - cur.start_deg, 144.0, 1e-9);
  // The arc's middle faces the mean of the moved object's two places, seen from the table.
  const int id = changedObjects(s).reference.at(0);
  const Vector2d mean =
      0.5 * (findObject(s.reference, id)->position + findObject(s.current, id)->position).head<2>();
  const Vector2d dir = mean - s.tables[0].center;
  const double mid = 0.5 * (cur.start_deg + cur.end_deg) * kPi / 180.0;
  EXPECT_NEAR(std::cos(mid), dir.normalized().x(), 1e-9);
  EXPECT_NEAR(std::sin(mid), dir.normalized().y(), 1e-9);
}

TEST(SimScene, JsonRoundTripIsExact) {
  for (const std::string name : {"tabletop", "room"}) {
    Scene s = makePreset(name, 11);
    s.sensor.lateral_sigma_px = 0.1 + 1.0 / 3.0;  // a double with no short decimal form
    const std::string text = sceneToJson(s);
    const Scene back = parseSceneJson(text, "scene.json");
    EXPECT_EQ(sceneToJson(back), text);
    EXPECT_EQ(back.sensor.lateral_sigma_px, s.sensor.lateral_sigma_px);
    ASSERT_EQ(back.reference.objects.size(), s.reference.objects.size());
    for (std::size_t i = 0; i < s.reference.objects.size(); ++i) {
      EXPECT_EQ(back.reference.objects[i].position, s.reference.objects[i].position);
      EXPECT_EQ(back.reference.objects[i].orientation.coeffs(),
                s.reference.objects[i].orientation.coeffs());
      EXPECT_EQ(back.reference.objects[i].type, s.reference.objects[i].type);
    }
    const std::vector<Pose> a = trajectoryPoses(s.current.trajectory);
    const std::vector<Pose> b = trajectoryPoses(back.current.trajectory);
    ASSERT_EQ(a.size(), b.size());
    for (std::size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].matrix(), b[i].matrix());
  }
  // A minimal hand-written scene takes the defaults.
  const Scene minimal = parseSceneJson(
      R"({"tables": [{"id": 1, "center": [0, 0], "size": [1, 0.7, 0.75]}],
          "reference": {"objects": [{"id": 1, "type": "mug", "size": [0.12, 0.09, 0.1],
                                     "position": [0, 0, 0.75], "support": "table1"}],
                        "trajectory": [{"target": [0, 0, 0.8], "radius": 1.2}]},
          "current": {"objects": [], "trajectory": [{"target": [0, 0, 0.8], "radius": 1.2}]}})",
      "minimal.json");
  EXPECT_EQ(minimal.reference.trajectory[0].frames, 30);
  EXPECT_EQ(minimal.sensor.intrinsics.fx, 525.0);
  EXPECT_EQ(changedObjects(minimal).reference, std::vector<int>{1});
}

TEST(SimScene, BadSceneJsonNamesTheFileAndTheProblem) {
  const std::string good = sceneToJson(makePreset("tabletop", 3));
  const auto expectError = [](const std::string& text, const std::string& what) {
    try {
      parseSceneJson(text, "bad.json");
      ADD_FAILURE() << "no error for " << what;
    } catch (const Error& e) {
      EXPECT_EQ(e.path(), "bad.json");
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  const auto replaced = [&](const std::string& from, const std::string& to) {
    std::string s = good;
    const std::size_t at = s.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return s.replace(at, from.size(), to);
  };
  expectError(good.substr(0, good.size() / 2), "invalid JSON");
  expectError("[1, 2]", "expected a JSON object");
  expectError(replaced("\"seed\": ", "\"seed\": 1, \"seed\": "), "key 'seed' appears twice");
  expectError(std::string(100000, '[') + std::string(100000, ']'), "nests deeper than 64");
  // A number beyond double: nlohmann's out_of_range escaped (found by tests/fuzz/scene_fuzz.cpp).
  expectError(replaced("\"fx\": 525.0", "\"fx\": 0.2E7907"), "invalid JSON");
  expectError(replaced("\"type\": \"", "\"type\": \"cube"), "unknown object type");
  {
    Scene absurd = makePreset("tabletop", 3);
    absurd.reference.objects[1].size.x() = 300.0;
    expectError(sceneToJson(absurd), "reference.objects[1].size[0]: must be in [0.01, 2] m");
    absurd.reference.objects[1].size.x() = 1e300;
    expectError(sceneToJson(absurd), "reference.objects[1].size[0]");
    absurd = makePreset("tabletop", 3);
    absurd.tables[0].size.z() = -0.75;
    expectError(sceneToJson(absurd), "tables[0].size[2]");
  }
  expectError(replaced("\"support\": \"table1\"", "\"support\": \"table9\""),
              "unknown support plane 'table9'");
  expectError(replaced("\"frames\": 30", "\"frames\": 0"), "trajectory[0].frames");
  expectError(replaced("\"frames\": 30", "\"frames\": 2.5"), "expected an integer");
  expectError(replaced("\"seed\"", "\"sed\""), "unknown key 'sed'");
  expectError(replaced("\"fx\": 525.0", "\"fx\": -1.0"), "sensor");
  expectError(replaced("\"id\": 2,", "\"id\": 1,"), "duplicate object id 1");
  expectError(replaced("\"kind\": \"add\"", "\"kind\": \"teleport\""), "unknown change kind");

  TempDir tmp;
  planesdf::test::writeBytes(tmp.file("broken.json"), "{\"reference\": ");
  try {
    loadSceneJson(tmp.file("broken.json"));
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), tmp.file("broken.json"));
  }
  EXPECT_THROW(loadSceneJson(tmp.file("missing.json")), Error);
}

TEST(SimScene, EachChangeKindChangesTheRightObjects) {
  for (const std::uint32_t seed : {1u, 2u, 3u}) {
    const auto make = [seed](ChangeKind k) {
      PresetOptions opt;
      opt.changes = {k};
      return makePreset(seed % 2 ? "tabletop" : "room", seed, opt);
    };
    {
      const Scene s = make(ChangeKind::None);
      const ChangedIds c = changedObjects(s);
      EXPECT_TRUE(c.reference.empty() && c.current.empty());
    }
    {
      const Scene s = make(ChangeKind::Add);
      const ChangedIds c = changedObjects(s);
      EXPECT_TRUE(c.reference.empty());
      ASSERT_EQ(c.current.size(), 1u);
      EXPECT_EQ(findObject(s.reference, c.current[0]), nullptr);
      EXPECT_EQ(s.current.objects.size(), s.reference.objects.size() + 1);
    }
    {
      const Scene s = make(ChangeKind::Remove);
      const ChangedIds c = changedObjects(s);
      ASSERT_EQ(c.reference.size(), 1u);
      EXPECT_TRUE(c.current.empty());
      EXPECT_EQ(findObject(s.current, c.reference[0]), nullptr);
    }
    for (const ChangeKind k : {ChangeKind::Move, ChangeKind::SmallMove}) {
      const Scene s = make(k);
      const ChangedIds c = changedObjects(s);
      ASSERT_EQ(c.reference.size(), 1u);
      EXPECT_EQ(c.reference, c.current);
      const double moved = (findObject(s.reference, c.reference[0])->position -
                            findObject(s.current, c.reference[0])->position)
                               .norm();
      if (k == ChangeKind::Move)
        EXPECT_GE(moved, 0.10);
      else
        EXPECT_NEAR(moved, 0.03, 1e-9);
    }
    {
      const Scene s = make(ChangeKind::Swap);
      const ChangedIds c = changedObjects(s);
      ASSERT_EQ(c.reference.size(), 2u);
      EXPECT_EQ(c.reference, c.current);
      const int a = c.reference[0], b = c.reference[1];
      EXPECT_EQ(findObject(s.current, a)->position, findObject(s.reference, b)->position);
      EXPECT_EQ(findObject(s.current, b)->position, findObject(s.reference, a)->position);
    }
    {
      const Scene s = make(ChangeKind::Replace);
      const ChangedIds c = changedObjects(s);
      ASSERT_EQ(c.reference.size(), 1u);
      ASSERT_EQ(c.current.size(), 1u);
      EXPECT_NE(c.reference[0], c.current[0]);
      const Object* old = findObject(s.reference, c.reference[0]);
      const Object* now = findObject(s.current, c.current[0]);
      EXPECT_EQ(findObject(s.current, old->id), nullptr);
      EXPECT_EQ(old->position, now->position);
      EXPECT_NE(old->type, now->type);
    }
  }
}

// ---- simulation outputs ---------------------------------------------------------------------

TEST(SimOutput, EachChangeKindProducesItsGroundTruth) {
  const std::vector<ChangeKind> kinds = {
      ChangeKind::None,      ChangeKind::Add,  ChangeKind::Remove, ChangeKind::Move,
      ChangeKind::SmallMove, ChangeKind::Swap, ChangeKind::Replace};
  for (const ChangeKind k : kinds) {
    const Scene s = smallPreset("tabletop", 5, {k}, 4);
    const Simulation sim = simulate(s);
    const std::set<int> ref = idsOf(sim.reference.gt), cur = idsOf(sim.current.gt);
    const ChangedIds c = changedObjects(s);
    SCOPED_TRACE(toString(k));
    EXPECT_EQ(ref, std::set<int>(c.reference.begin(), c.reference.end()));
    EXPECT_EQ(cur, std::set<int>(c.current.begin(), c.current.end()));
    switch (k) {
      case ChangeKind::None:
        EXPECT_TRUE(sim.reference.gt.empty());
        EXPECT_TRUE(sim.current.gt.empty());
        break;
      case ChangeKind::Add:
        EXPECT_TRUE(sim.reference.gt.empty());
        EXPECT_EQ(cur.size(), 1u);
        EXPECT_GT(sim.current.gt.size(), 100u);
        break;
      case ChangeKind::Remove:
        EXPECT_EQ(ref.size(), 1u);
        EXPECT_GT(sim.reference.gt.size(), 100u);
        EXPECT_TRUE(sim.current.gt.empty());
        break;
      case ChangeKind::Move:
      case ChangeKind::SmallMove:
        EXPECT_EQ(ref.size(), 1u);
        EXPECT_EQ(ref, cur);
        break;
      case ChangeKind::Swap:
        EXPECT_EQ(ref.size(), 2u);
        EXPECT_EQ(ref, cur);
        break;
      case ChangeKind::Replace:
        EXPECT_EQ(ref.size(), 1u);
        EXPECT_EQ(cur.size(), 1u);
        EXPECT_NE(ref, cur);
        break;
    }
    // Every GT point also is a point of its session's whole cloud.
    for (const SessionData* d : {&sim.reference, &sim.current}) {
      std::vector<std::tuple<float, float, float>> cloud;
      for (const auto& p : d->cloud.points) cloud.emplace_back(p.x(), p.y(), p.z());
      std::sort(cloud.begin(), cloud.end());
      for (const auto& p : d->gt.points)
        ASSERT_TRUE(
            std::binary_search(cloud.begin(), cloud.end(), std::tuple{p.x(), p.y(), p.z()}));
    }
  }
}

TEST(SimOutput, GroundTruthIsExactlyThePointsOfChangedObjects) {
  const Scene s = smallPreset("room", 2, {ChangeKind::Remove, ChangeKind::Move, ChangeKind::Add});
  const Simulation sim = simulate(s);
  const ChangedIds changed = changedObjects(s);
  for (int side = 0; side < 2; ++side) {
    const Session& session = side == 0 ? s.reference : s.current;
    const SessionData& d = side == 0 ? sim.reference : sim.current;
    const std::vector<int>& ids = side == 0 ? changed.reference : changed.current;
    const Pose to_true = localisationErrorPose(session.localisation_error).inverse();
    const std::vector<Primitive> prims = sessionPrimitives(s, session);
    std::map<std::tuple<float, float, float>, int> gt;
    for (std::size_t i = 0; i < d.gt.size(); ++i)
      gt[{d.gt.points[i].x(), d.gt.points[i].y(), d.gt.points[i].z()}] =
          static_cast<int>(d.gt.field("object_id")->values[i]);
    ASSERT_EQ(gt.size(), d.gt.size());
    // Every ground-truth point and every 4th other point of the cloud (to keep the test quick).
    std::size_t considered = 0, checked = 0, labelled = 0;
    for (std::size_t i = 0; i < d.cloud.size(); ++i) {
      const Eigen::Vector3f& pf = d.cloud.points[i];
      if (i % 4 != 0 && !gt.count({pf.x(), pf.y(), pf.z()})) continue;
      ++considered;
      const Vector3d p = to_true * pf.cast<double>();
      // Nearest and second-nearest owners by brute force.
      std::map<int, double> by_owner;
      for (const Primitive& prim : prims) {
        const double dist = std::abs(signedDistance(prim, p));
        auto [it, inserted] = by_owner.emplace(prim.owner, dist);
        if (!inserted) it->second = std::min(it->second, dist);
      }
      int owner = 0;
      double best = 1e9, second = 1e9;
      for (const auto& [o, dist] : by_owner) {
        if (dist < best) {
          second = best;
          best = dist;
          owner = o;
        } else {
          second = std::min(second, dist);
        }
      }
      // Skip the few points on a decision boundary (float rounding of the coordinates).
      if (std::abs(best - kLabelDistance) < 1e-5 || second - best < 1e-5) continue;
      ++checked;
      const bool expected =
          best <= kLabelDistance && std::find(ids.begin(), ids.end(), owner) != ids.end();
      const auto it = gt.find({pf.x(), pf.y(), pf.z()});
      ASSERT_EQ(it != gt.end(), expected) << "side " << side << " point " << p.transpose();
      if (expected) {
        EXPECT_EQ(it->second, owner);
        ++labelled;
      }
    }
    EXPECT_GT(checked, considered * 99 / 100);
    EXPECT_GT(labelled, 100u) << "side " << side;
  }
}

/// All regular files under `dir` with their bytes, by relative path.
std::map<std::string, std::string> folderBytes(const std::string& dir) {
  std::map<std::string, std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file())
      out[fs::relative(e.path(), dir).string()] = io::readFile(e.path().string());
  return out;
}

TEST(SimOutput, SameSeedGivesIdenticalFilesAndSceneJsonReproducesThem) {
  TempDir tmp;
  const Scene s = smallPreset("tabletop", 9, {ChangeKind::Add, ChangeKind::Swap}, 4);
  SimulateOptions one, two;
  one.threads = 1;
  two.threads = 2;
  writeSimulation(tmp.file("a"), s, simulate(s, one));
  writeSimulation(tmp.file("b"), smallPreset("tabletop", 9, {ChangeKind::Add, ChangeKind::Swap}, 4),
                  simulate(s, two));
  const Scene back = loadSceneJson(tmp.file("a/scene.json"));
  writeSimulation(tmp.file("c"), back, simulate(back, two));

  const auto a = folderBytes(tmp.file("a"));
  for (const char* f : {"reference.ply", "current.ply", "gt/reference.ply", "gt/current.ply",
                        "scene.json", "reference/depth.txt", "reference/groundtruth.txt",
                        "reference/intrinsics.txt", "current/depth.txt"})
    EXPECT_TRUE(a.count(f)) << f;
  for (const char* f : {"reference_recon.ply", "current_mesh.ply", "gt/current_recon.ply"})
    EXPECT_TRUE(a.count(f)) << f;
  // 4 PNGs + 3 index files per session; per session a cloud, a reconstruction, a mesh and two
  // ground truths; scene.json.
  EXPECT_EQ(a.size(), 2u * (4u + 3u) + 2u * 5u + 1u);
  EXPECT_TRUE(a == folderBytes(tmp.file("b"))) << "thread count changed the output";
  EXPECT_TRUE(a == folderBytes(tmp.file("c"))) << "scene.json did not reproduce the output";

  // Another seed changes the noise of the same scene.
  Scene reseeded = back;
  reseeded.seed = 10;
  const Simulation other = simulate(reseeded);
  EXPECT_NE(other.reference.frames[0].depth, simulate(back).reference.frames[0].depth);
}

TEST(SimOutput, FilesReadBackThroughTheProjectReaders) {
  TempDir tmp;
  const Scene s = smallPreset("tabletop", 4, {ChangeKind::Move}, 5);
  const Simulation sim = simulate(s);
  writeSimulation(tmp.path(), s, sim);

  for (int side = 0; side < 2; ++side) {
    const char* label = side == 0 ? "reference" : "current";
    const SessionData& d = side == 0 ? sim.reference : sim.current;
    const io::TumSequence seq = io::readTumSequence(tmp.file(label));
    ASSERT_EQ(seq.frames.size(), d.frames.size());
    EXPECT_EQ(seq.dropped_frames, 0u);
    EXPECT_EQ(seq.depth_scale, 1000.0);
    EXPECT_EQ(seq.intrinsics.width, 320);
    EXPECT_EQ(seq.intrinsics.fx, 262.5);
    EXPECT_EQ(seq.intrinsics.cy, 119.5);
    for (std::size_t i = 0; i < seq.frames.size(); ++i) {
      EXPECT_TRUE(seq.frames[i].pose.isApprox(d.reported_poses[i], 1e-12)) << label << " " << i;
      EXPECT_EQ(io::loadTumDepth(seq, i).depth, d.frames[i].depth) << label << " " << i;
    }
    // reported = E * true: the current session is off by 1 cm / 1 degree, the reference is not.
    const Pose E = d.reported_poses[0] * d.true_poses[0].inverse();
    EXPECT_TRUE(E.isApprox(
        localisationErrorPose((side == 0 ? s.reference : s.current).localisation_error), 1e-12));
    EXPECT_EQ(side == 0, E.isApprox(Pose::Identity(), 1e-12));

    const PointCloud cloud = io::readPly(tmp.file(std::string(label) + ".ply"));
    EXPECT_EQ(cloud.points, d.cloud.points);
    const PointCloud gt = io::readPly(tmp.file(std::string("gt/") + label + ".ply"));
    ASSERT_NE(gt.field("object_id"), nullptr);
    EXPECT_EQ(gt.field("object_id")->type, ScalarType::Int32);
    EXPECT_EQ(gt.points, d.gt.points);
    EXPECT_EQ(gt.field("object_id")->values, d.gt.field("object_id")->values);
  }
}

TEST(SimOutput, WholeCloudsAreDownsampledSurfaces) {
  Scene s = smallPreset("tabletop", 6, {ChangeKind::None}, 6);
  s.sensor.intrinsics = Intrinsics{};  // full 640 x 480: the table is sampled finer than kVoxel
  const Simulation sim = simulate(s);
  const PointCloud& cloud = sim.reference.cloud;
  std::size_t pixels = 0;
  for (const DepthFrame& f : sim.reference.frames)
    pixels += static_cast<std::size_t>(
        std::count_if(f.depth.begin(), f.depth.end(), [](float z) { return z > 0.0f; }));
  EXPECT_LT(cloud.size(), pixels / 3);

  // Points lie on the scene's surfaces (up to the sensor noise, flying pixels aside).
  const std::vector<Primitive> prims = sessionPrimitives(s, s.reference);
  int near_1cm = 0, near_5cm = 0, n = 0;
  for (std::size_t i = 0; i < cloud.size(); i += 97, ++n) {
    double best = 1e9;
    for (const Primitive& p : prims)
      best = std::min(best, std::abs(signedDistance(p, cloud.points[i].cast<double>())));
    near_1cm += best <= 0.01;
    near_5cm += best <= 0.05;
  }
  EXPECT_GT(near_1cm, n * 9 / 10);
  EXPECT_GT(near_5cm, n * 99 / 100);

  // The free part of the table top holds between one point per (2 kVoxel)^2 and three per
  // kVoxel^2 (kVoxel cells where it was seen from near, coarser ones beyond 2 m).
  const Table& t = s.tables[0];
  const Pose table = Eigen::Translation3d(t.center.x(), t.center.y(), t.size.z()) *
                     Eigen::AngleAxisd(t.yaw_deg * kPi / 180.0, Vector3d::UnitZ());
  double free_area = t.size.x() * t.size.y();
  for (const Object& o : s.reference.objects) free_area -= o.size.x() * o.size.y();
  std::size_t on_top = 0;
  for (const auto& p : cloud.points) {
    const Vector3d q = table.inverse() * p.cast<double>();
    on_top += std::abs(q.z()) < 0.006 && std::abs(q.x()) < t.size.x() / 2 - 0.01 &&
              std::abs(q.y()) < t.size.y() / 2 - 0.01;
  }
  EXPECT_GT(static_cast<double>(on_top), free_area / (4.0 * kVoxel * kVoxel));
  EXPECT_LT(static_cast<double>(on_top), 3.0 * t.size.x() * t.size.y() / (kVoxel * kVoxel));
}

}  // namespace
}  // namespace planesdf::sim
