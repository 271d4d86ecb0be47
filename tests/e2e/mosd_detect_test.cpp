// Change detection on the 21 real mOSD pairs (single Kinect views in the camera frame, objects
// moved between scenes) through the CLI, scored by the project's own eval: the acceptance figures
// of issue 4. Also: a scene against itself and against a copy of itself expressed in a frame
// displaced by a few cm and degrees reports nothing.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "planesdf/change.hpp"
#include "planesdf/eval.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/io/ply.hpp"
#include "test_support.hpp"

namespace {
using namespace planesdf;
using test::runCli;
using test::TempDir;

struct Pair {
  std::string reference, current, gt_reference, gt_current;
};

std::vector<Pair> mosdPairs() {
  std::ifstream in(test::mosdDir() + "/pairs.tsv");
  std::vector<Pair> pairs;
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::istringstream ss(line);
    std::string group;
    Pair p;
    std::getline(ss, group, '\t');
    std::getline(ss, p.reference, '\t');
    std::getline(ss, p.current, '\t');
    std::getline(ss, p.gt_reference, '\t');
    std::getline(ss, p.gt_current, '\t');
    if (!p.gt_current.empty()) pairs.push_back(p);
  }
  return pairs;
}

TEST(MosdDetect, AllPairsMeetTheAcceptanceFigures) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  const auto pairs = mosdPairs();
  ASSERT_EQ(pairs.size(), 21u);
  const std::string root = test::mosdDir() + "/";
  TempDir tmp;
  double f1_sum = 0.0;
  int max_wrong = 0, total_missed = 0, total_wrong = 0;
  for (std::size_t i = 0; i < pairs.size(); ++i) {
    const Pair& p = pairs[i];
    const std::string out = tmp.file("pair" + std::to_string(i));
    const auto r = runCli("detect '" + root + p.reference + "' '" + root + p.current + "' --out '" +
                          out + "'");
    ASSERT_EQ(r.exit_code, 0) << p.reference << ": " << r.out;
    const EvalResult e = evaluateChanges(
        io::readPly(out + "/removed_points.ply"), io::readPly(out + "/added_points.ply"),
        io::readPly(root + p.gt_reference), io::readPly(root + p.gt_current), 0.007);
    std::printf("%-22s -> %-22s F1 %.3f  P %.3f  R %.3f  M %d  W %d\n", p.reference.c_str(),
                p.current.c_str(), e.pooled.f1, e.pooled.precision, e.pooled.recall,
                e.pooled.missed, e.pooled.wrong);
    f1_sum += e.pooled.f1;
    max_wrong = std::max(max_wrong, e.pooled.wrong);
    total_missed += e.pooled.missed;
    total_wrong += e.pooled.wrong;
    EXPECT_LE(e.pooled.wrong, 1) << p.reference << " -> " << p.current;
  }
  const double mean_f1 = f1_sum / static_cast<double>(pairs.size());
  std::printf("mean pooled F1 %.3f, max W %d, total M %d, total W %d\n", mean_f1, max_wrong,
              total_missed, total_wrong);
  // Measured F1 0.873, M 10, W 0 (docs/accuracy.md); the bounds allow one more missed object.
  EXPECT_GE(mean_f1, 0.86);
  EXPECT_LE(total_missed, 11);
  EXPECT_LE(total_wrong, 2);
}

TEST(MosdDetect, ASceneAgainstItselfReportsNothing) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  const std::string scene = test::mosdDir() + "/scenes/test45.pcd";
  TempDir tmp;
  const auto r = runCli("detect '" + scene + "' '" + scene + "' --out '" + tmp.path() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("0 changes"), std::string::npos) << r.out;
  EXPECT_EQ(io::readPly(tmp.file("removed_points.ply")).size(), 0u);
  EXPECT_EQ(io::readPly(tmp.file("added_points.ply")).size(), 0u);
}

TEST(MosdDetect, ASceneSeenFromADisplacedFrameReportsNothing) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  // The same cloud expressed in a frame displaced by 3 cm and 2 degrees (the sensor pose moves
  // with it), as if the second session's localisation were off by that much.
  Config cfg;
  cfg.up_auto = true;
  for (const char* name : {"test35", "learn43"}) {
    const PointCloud cloud = io::readSceneCloud(test::mosdDir() + "/scenes/" + name + ".pcd");
    Pose T = Pose::Identity();
    T.linear() = (Eigen::AngleAxisd(2.0 * M_PI / 180, Eigen::Vector3d(0.3, 1.0, 0.2).normalized()))
                     .toRotationMatrix();
    T.translation() = Eigen::Vector3d(0.03, -0.01, 0.02);
    PointCloud moved = cloud;
    for (auto& p : moved.points)
      if (PointCloud::isValid(p)) p = (T * p.cast<double>()).cast<float>();
    moved.sensor_pose = T * cloud.sensor_pose;
    const Map a = Map::fromCloud(cloud, cfg);
    const Map b = Map::fromCloud(moved, cfg);
    const ChangeSet s = detectChanges(a, b, cfg);
    EXPECT_TRUE(s.events.empty()) << name << ": " << changesToJson(s.events);
  }
}

}  // namespace
