// CPlaneChangeMap: scans of an analytic tabletop (the box removed, a sphere added, the cylinder
// moved) inserted as CObservation3DRangeScan observations, change events delivered to a
// CObserver, coloured change points, creation from a CMultiMetricMap INI and serialization.
#include <gtest/gtest.h>
#include <mrpt/config/CConfigFileMemory.h>
#include <mrpt/io/CMemoryStream.h>
#include <mrpt/maps/CColouredPointsMap.h>
#include <mrpt/maps/CMultiMetricMap.h>
#include <mrpt/obs/CObservation3DRangeScan.h>
#include <mrpt/serialization/CArchive.h>
#include <mrpt/system/CObserver.h>

#include <filesystem>
#include <fstream>
#include <set>

#include "analytic_scene.hpp"
#include "planesdf/mrpt/plane_change_map.hpp"
#include "planesdf/mrpt/pose_conversion.hpp"
#include "planesdf/mrpt/range_scan.hpp"

namespace {
using namespace planesdf;
namespace ma = planesdf::mrpt_adapter;
using test::AnalyticScene;
using test::Primitive;

constexpr double kTable = test::kTableTop;

const AnalyticScene& before() {
  static const AnalyticScene s =
      test::tableWith({Primitive::box({0.05, 0.02, kTable}, {0.15, 0.08, kTable + 0.08}),
                       Primitive::cylinder({-0.15, -0.10, kTable}, 0.04, 0.12)});
  return s;
}
const AnalyticScene& after() {
  static const AnalyticScene s =
      test::tableWith({Primitive::sphere({-0.12, 0.15, kTable + 0.05}, 0.05),
                       Primitive::cylinder({0.05, -0.10, kTable}, 0.04, 0.12)});
  return s;
}
std::vector<Pose> ring() {
  return test::ringPoses({0, 0, kTable}, 0.9, 0.55, 8);
}

const Map& referenceMap() {
  static const Map m = [] {
    Map map{Config{}};
    for (const Pose& T : ring()) map.integrate(test::renderDepth(before(), Intrinsics{}, T), T);
    return map;
  }();
  return m;
}

/// The after-scene scans as MRPT observations: the sensor on a robot at `robot`.
std::vector<mrpt::obs::CObservation3DRangeScan::Ptr> afterScans(const Pose& robot) {
  std::vector<mrpt::obs::CObservation3DRangeScan::Ptr> out;
  for (const Pose& T : ring()) {
    auto s = mrpt::obs::CObservation3DRangeScan::Create();
    ma::toRangeScan(test::renderDepth(after(), Intrinsics{}, T), robot.inverse() * T, *s);
    out.push_back(s);
  }
  return out;
}

class Recorder : public mrpt::system::CObserver {
 public:
  std::vector<ChangeEvent> events;

 protected:
  void OnEvent(const mrpt::system::mrptEvent& e) override {
    if (const auto* pc = e.getAs<ma::mrptEventPlaneChange>()) events.push_back(pc->event);
  }
};

struct MapRun {
  std::shared_ptr<ma::CPlaneChangeMap> map;
  std::vector<ChangeEvent> delivered;
};
const MapRun& mapRun() {
  static const MapRun r = [] {
    MapRun out;
    out.map = std::make_shared<ma::CPlaneChangeMap>(Config{});
    out.map->setReference(referenceMap());
    Recorder rec;
    rec.observeBegin(*out.map);
    Pose robot = Pose::Identity();
    robot.linear() = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    robot.translation() = Eigen::Vector3d(0.4, -0.2, 0.0);
    const auto robot_mrpt = ma::toCPose3D(robot);
    for (const auto& s : afterScans(robot)) EXPECT_TRUE(out.map->insertObservation(*s, robot_mrpt));
    out.map->finishChanges();  // the session ends: what has not settled yet settles now
    rec.observeEnd(*out.map);
    out.delivered = rec.events;
    return out;
  }();
  return r;
}

TEST(MrptChangeMap, ObserversReceiveTheChangeEvents) {
  const MapRun& r = mapRun();
  EXPECT_EQ(r.map->map().frames(), 8u);
  ASSERT_FALSE(r.delivered.empty());
  EXPECT_EQ(r.delivered.front().status, ChangeStatus::New);
  // Every active change was delivered with its final type. (Not its final point count: the
  // ChangeDetector does not notify when only a region's points grow, see events.hpp.)
  const std::vector<ChangeEvent> active = r.map->changes();
  std::set<ChangeType> types;
  for (const ChangeEvent& e : active) {
    types.insert(e.type);
    const ChangeEvent* last = nullptr;
    for (const ChangeEvent& d : r.delivered)
      if (d.id == e.id) last = &d;
    ASSERT_NE(last, nullptr) << "event " << e.id << " never delivered";
    EXPECT_EQ(last->type, e.type);
    EXPECT_GT(last->numPoints(), 0u);
  }
  EXPECT_EQ(types,
            (std::set<ChangeType>{ChangeType::Added, ChangeType::Removed, ChangeType::Moved}))
      << changesToJson(active);
  // The removed box is where it was (world frame, through the robot and sensor poses).
  for (const ChangeEvent& e : active)
    if (e.type == ChangeType::Removed) {
      EXPECT_LT((e.reference.centroid.head<2>() - Eigen::Vector2d(0.10, 0.05)).norm(), 0.02);
    }
}

TEST(MrptChangeMap, ChangedPointsAreColouredByType) {
  const MapRun& r = mapRun();
  mrpt::maps::CColouredPointsMap pts;
  r.map->getChangedPoints(pts);
  std::size_t expected = 0;
  for (const ChangeEvent& e : r.map->changes()) expected += e.numPoints();
  ASSERT_EQ(pts.size(), expected);
  ASSERT_GT(expected, 0u);
  std::size_t i = 0;
  for (const ChangeEvent& e : r.map->changes()) {
    const auto c = changeColor(e.type);
    float x, y, z, R, G, B;
    pts.getPointRGB(i, x, y, z, R, G, B);
    const Eigen::Vector3f& p =
        e.reference.points.empty() ? e.current.points[0] : e.reference.points[0];
    EXPECT_FLOAT_EQ(x, p.x());
    EXPECT_NEAR(R, c[0] / 255.0f, 1e-3) << toString(e.type);
    EXPECT_NEAR(G, c[1] / 255.0f, 1e-3) << toString(e.type);
    EXPECT_NEAR(B, c[2] / 255.0f, 1e-3) << toString(e.type);
    i += e.numPoints();
  }
}

TEST(MrptChangeMap, CreatedFromAMultiMetricMapIni) {
  const auto dir = std::filesystem::temp_directory_path() / "planesdf_mrpt_change_map_ini";
  std::filesystem::create_directories(dir);
  const std::string ref = (dir / "reference.psdf").string();
  referenceMap().save(ref);
  // Results announced as soon as found, so that the detection every 4 scans shows.
  const std::string config = (dir / "planesdf.json").string();
  std::ofstream(config) << R"({"event_settle_frames": 0, "event_unscored_settle_frames": 0})";
  const mrpt::config::CConfigFileMemory ini(
      "[map]\nplaneChangeMap_count=1\n[map_planeChangeMap_00_creationOpts]\nreference_map=" + ref +
      "\nconfig_file=" + config + "\ndetect_every=4\n");
  mrpt::maps::TSetOfMetricMapInitializers inits;
  inits.loadFromConfigFile(ini, "map");
  ASSERT_EQ(inits.size(), 1u);
  mrpt::maps::CMultiMetricMap multi;
  multi.setListOfMaps(inits);
  const auto m = multi.mapByClass<ma::CPlaneChangeMap>();
  ASSERT_TRUE(m);
  EXPECT_TRUE(m->hasReference());
  EXPECT_EQ(m->detectEvery(), 4);
  Recorder rec;
  rec.observeBegin(*m);
  const auto scans = afterScans(Pose::Identity());
  for (std::size_t i = 0; i < scans.size(); ++i) {
    multi.insertObservation(*scans[i]);
    if (i + 1 < 4) {
      EXPECT_TRUE(rec.events.empty()) << "detected before detect_every scans";
    }
    if (i + 1 == 4) {
      EXPECT_FALSE(rec.events.empty()) << "nothing detected after 4 scans";
    }
  }
  rec.observeEnd(*m);
  std::filesystem::remove_all(dir);
}

TEST(MrptChangeMap, SerializationRoundTrip) {
  const MapRun& r = mapRun();
  mrpt::io::CMemoryStream buf;
  auto arch = mrpt::serialization::archiveFrom(buf);
  arch << *r.map;
  buf.Seek(0);
  const auto obj = arch.ReadObject();
  const auto back = std::dynamic_pointer_cast<ma::CPlaneChangeMap>(obj);
  ASSERT_TRUE(back);
  EXPECT_EQ(back->map().frames(), r.map->map().frames());
  EXPECT_EQ(back->map().planes().size(), r.map->map().planes().size());
  EXPECT_TRUE(back->hasReference());
  // The announced changes come back with their ids, and the same maps notify nothing new.
  const std::vector<ChangeEvent> before = r.map->changes(), after = back->changes();
  ASSERT_EQ(after.size(), before.size());
  ASSERT_FALSE(before.empty());
  for (std::size_t i = 0; i < before.size(); ++i) {
    EXPECT_EQ(after[i].id, before[i].id);
    EXPECT_EQ(after[i].type, before[i].type);
    EXPECT_EQ(after[i].current.points, before[i].current.points);
    EXPECT_EQ(after[i].reference.columns, before[i].reference.columns);
  }
  EXPECT_EQ(back->finishChanges(), 0u);
  EXPECT_EQ(back->changes().size(), before.size());
}

}  // namespace
