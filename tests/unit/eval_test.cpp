// Tests for planesdf::evaluateChanges and friends (`planesdf eval`): hand-built point
// sets with known precision / recall / F1 / M / W, the tolerance boundary, empty sides, pooling,
// invalid points, missing id fields, the JSON keys, and the grid search against brute force.

#include "planesdf/eval.hpp"

#include <gtest/gtest.h>

#include <cctype>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <iostream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "planesdf/error.hpp"

namespace {

using planesdf::EvalResult;
using planesdf::evaluateChanges;
using planesdf::PointCloud;
using planesdf::ScalarType;
using planesdf::scoreSide;
using planesdf::SideScore;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// A cloud of `points`; with `field` non-empty, each point gets ids[i] in that int field.
PointCloud makeCloud(const std::vector<Eigen::Vector3f>& points, const std::string& field = "",
                     const std::vector<int>& ids = {}) {
  PointCloud c;
  c.points = points;
  c.width = static_cast<std::uint32_t>(points.size());
  if (!field.empty()) {
    auto& f = c.addField(field, ScalarType::Int32);
    for (std::size_t i = 0; i < ids.size(); ++i) f.values[i] = ids[i];
  }
  return c;
}

PointCloud prediction(const std::vector<Eigen::Vector3f>& points, const std::vector<int>& ids) {
  return makeCloud(points, planesdf::kChangeIdField, ids);
}
PointCloud groundTruth(const std::vector<Eigen::Vector3f>& points, const std::vector<int>& ids) {
  return makeCloud(points, planesdf::kObjectIdField, ids);
}

// `n` points 1 m apart along x from `start` (far apart compared to any tolerance used here).
std::vector<Eigen::Vector3f> row(int n, const Eigen::Vector3f& start = Eigen::Vector3f::Zero()) {
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < n; ++i) pts.push_back(start + Eigen::Vector3f(static_cast<float>(i), 0, 0));
  return pts;
}

std::vector<Eigen::Vector3f> concat(std::vector<Eigen::Vector3f> a,
                                    const std::vector<Eigen::Vector3f>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

void expectRates(const SideScore& s, double p, double r, double f1) {
  EXPECT_DOUBLE_EQ(s.precision, p);
  EXPECT_DOUBLE_EQ(s.recall, r);
  EXPECT_DOUBLE_EQ(s.f1, f1);
}

// Keys of the object `json` at depth 1, in order (compact or indented JSON without strings
// holding braces or quotes, as evalToJson writes it).
std::vector<std::string> topLevelKeys(const std::string& json) {
  std::vector<std::string> keys;
  int depth = 0;
  for (std::size_t i = 0; i < json.size(); ++i) {
    const char ch = json[i];
    if (ch == '{') ++depth;
    if (ch == '}') --depth;
    if (ch == '"' && depth == 1) {
      const std::size_t close = json.find('"', i + 1);
      std::size_t after = close + 1;
      while (after < json.size() && std::isspace(static_cast<unsigned char>(json[after]))) ++after;
      if (after < json.size() && json[after] == ':')
        keys.push_back(json.substr(i + 1, close - i - 1));
      i = close;
    }
  }
  return keys;
}

// The text of the nested object under `key` (depth-1 key), "" when absent.
std::string nestedObject(const std::string& json, const std::string& key) {
  const std::size_t at = json.find("\"" + key + "\"");
  if (at == std::string::npos) return "";
  const std::size_t open = json.find('{', at);
  int depth = 0;
  for (std::size_t i = open; i < json.size(); ++i) {
    if (json[i] == '{') ++depth;
    if (json[i] == '}' && --depth == 0) return json.substr(open, i - open + 1);
  }
  return "";
}

TEST(Eval, PerfectPredictionScoresOne) {
  const auto ref_pts = concat(row(5), row(3, {0, 5, 0}));
  const std::vector<int> ref_ids = {1, 1, 1, 1, 1, 2, 2, 2};
  const auto cur_pts = row(4, {0, 0, 3});
  const std::vector<int> cur_ids = {7, 7, 7, 7};
  const EvalResult r = evaluateChanges(
      prediction(ref_pts, {10, 10, 10, 10, 10, 11, 11, 11}), prediction(cur_pts, {12, 12, 12, 12}),
      groundTruth(ref_pts, ref_ids), groundTruth(cur_pts, cur_ids), 0.01);
  for (const SideScore* s : {&r.removed, &r.added, &r.pooled}) {
    expectRates(*s, 1.0, 1.0, 1.0);
    EXPECT_EQ(s->missed, 0);
    EXPECT_EQ(s->wrong, 0);
  }
  EXPECT_EQ(r.removed.gt_objects, 2);
  EXPECT_EQ(r.removed.predicted_clusters, 2);
  EXPECT_EQ(r.added.gt_objects, 1);
  EXPECT_EQ(r.pooled.gt_points, 12u);
  EXPECT_EQ(r.pooled.matched_predicted, 12u);
  EXPECT_DOUBLE_EQ(r.tol, 0.01);
}

TEST(Eval, HalfTheGroundTruthPredictedGivesRecallHalf) {
  const auto gt_pts = row(10);
  const std::vector<int> gt_ids(10, 3);
  // Predicted points lie 5 mm off the first five GT points: all match at tol 1 cm.
  const auto pred_pts = row(5, {0, 0.005f, 0});
  const SideScore s =
      scoreSide(prediction(pred_pts, std::vector<int>(5, 1)), groundTruth(gt_pts, gt_ids), 0.01);
  expectRates(s, 1.0, 0.5, 2.0 * 0.5 / 1.5);
  EXPECT_EQ(s.matched_gt, 5u);
  EXPECT_EQ(s.gt_points, 10u);
  EXPECT_EQ(s.missed, 0);  // the object has matched points
  EXPECT_EQ(s.wrong, 0);
}

TEST(Eval, WrongClusterFarAwayCountsAsWAndLowersPrecisionByItsShare) {
  const auto gt_pts = row(6);
  const auto pred_pts = concat(gt_pts, row(2, {100, 100, 100}));
  const SideScore s = scoreSide(prediction(pred_pts, {1, 1, 1, 1, 1, 1, 2, 2}),
                                groundTruth(gt_pts, std::vector<int>(6, 5)), 0.01);
  EXPECT_EQ(s.wrong, 1);
  EXPECT_EQ(s.missed, 0);
  EXPECT_EQ(s.predicted_clusters, 2);
  expectRates(s, 6.0 / 8.0, 1.0, 2.0 * 0.75 / 1.75);
}

TEST(Eval, MissedObjectCountsAsM) {
  const auto obj_a = row(4);
  const auto obj_b = row(4, {0, 10, 0});
  const SideScore s = scoreSide(prediction(obj_a, std::vector<int>(4, 1)),
                                groundTruth(concat(obj_a, obj_b), {1, 1, 1, 1, 2, 2, 2, 2}), 0.01);
  EXPECT_EQ(s.missed, 1);
  EXPECT_EQ(s.wrong, 0);
  EXPECT_EQ(s.gt_objects, 2);
  expectRates(s, 1.0, 0.5, 2.0 * 0.5 / 1.5);
}

TEST(Eval, ToleranceBoundaryIsInclusive) {
  // 3-4-5 triangle: distance exactly 5 (exact in float and double), across grid cells.
  const auto gt = groundTruth({{0, 0, 0}}, {1});
  const Eigen::Vector3f at_tol(3, 4, 0);
  const Eigen::Vector3f beyond(3, 4, 0.001f);
  SideScore s = scoreSide(prediction({at_tol}, {1}), gt, 5.0);
  EXPECT_EQ(s.matched_predicted, 1u);
  EXPECT_EQ(s.matched_gt, 1u);
  s = scoreSide(prediction({beyond}, {1}), gt, 5.0);
  EXPECT_EQ(s.matched_predicted, 0u);
  EXPECT_EQ(s.matched_gt, 0u);
  EXPECT_EQ(s.missed, 1);
  EXPECT_EQ(s.wrong, 1);
  // Along one axis, far from the origin: 0.25 apart at tol 0.25 matches, a float step more not.
  const Eigen::Vector3f base(1000.0f, -2000.0f, 3.0f);
  const auto gt_far = groundTruth({base}, {1});
  s = scoreSide(prediction({base + Eigen::Vector3f(0, 0, 0.25f)}, {1}), gt_far, 0.25);
  EXPECT_EQ(s.matched_predicted, 1u);
  const float next = std::nextafter(3.25f, 10.0f);
  s = scoreSide(prediction({Eigen::Vector3f(base.x(), base.y(), next)}, {1}), gt_far, 0.25);
  EXPECT_EQ(s.matched_predicted, 0u);
}

TEST(Eval, BothSidesEmptyScoreOne) {
  const EvalResult r =
      evaluateChanges(PointCloud{}, PointCloud{}, PointCloud{}, PointCloud{}, 0.007);
  for (const SideScore* s : {&r.removed, &r.added, &r.pooled}) {
    expectRates(*s, 1.0, 1.0, 1.0);
    EXPECT_EQ(s->missed, 0);
    EXPECT_EQ(s->wrong, 0);
    EXPECT_EQ(s->predicted_points, 0u);
  }
}

TEST(Eval, EmptyGroundTruthWithPredictionScoresZero) {
  const SideScore s = scoreSide(prediction(row(3), {4, 4, 9}), PointCloud{}, 0.01);
  expectRates(s, 0.0, 0.0, 0.0);
  EXPECT_EQ(s.wrong, 2);
  EXPECT_EQ(s.missed, 0);
}

TEST(Eval, EmptyPredictionWithGroundTruthScoresZero) {
  const SideScore s = scoreSide(PointCloud{}, groundTruth(row(3), {1, 2, 2}), 0.01);
  expectRates(s, 0.0, 0.0, 0.0);
  EXPECT_EQ(s.missed, 2);
  EXPECT_EQ(s.wrong, 0);
}

TEST(Eval, OneEmptySideScoresOneAndPoolsWithTheOther) {
  // Nothing removed and nothing predicted removed; the added side is half right.
  const auto gt_pts = row(4);
  const EvalResult r =
      evaluateChanges(PointCloud{}, prediction(concat(row(2), row(2, {50, 0, 0})), {1, 1, 2, 2}),
                      PointCloud{}, groundTruth(gt_pts, {1, 1, 2, 2}), 0.01);
  expectRates(r.removed, 1.0, 1.0, 1.0);
  expectRates(r.added, 0.5, 0.5, 0.5);
  expectRates(r.pooled, 0.5, 0.5, 0.5);
  EXPECT_EQ(r.pooled.missed, 1);
  EXPECT_EQ(r.pooled.wrong, 1);
}

TEST(Eval, PooledCountsAreSumsOfTheSides) {
  // Removed: 4 GT points, 3 predicted of which 2 match. Added: 2 GT, 5 predicted, 1 matches.
  const auto removed_gt = row(4);
  const auto removed_pred = concat(row(2), row(1, {0, 20, 0}));
  const auto added_gt = row(2, {0, 0, 7});
  const auto added_pred = concat(row(1, {0, 0, 7}), row(4, {0, 30, 0}));
  const EvalResult r =
      evaluateChanges(prediction(removed_pred, {1, 1, 2}), prediction(added_pred, {3, 4, 4, 4, 4}),
                      groundTruth(removed_gt, {1, 1, 2, 2}), groundTruth(added_gt, {5, 6}), 0.01);
  EXPECT_EQ(r.removed.matched_predicted, 2u);
  EXPECT_EQ(r.removed.matched_gt, 2u);
  EXPECT_EQ(r.added.matched_predicted, 1u);
  EXPECT_EQ(r.added.matched_gt, 1u);
  EXPECT_EQ(r.pooled.predicted_points, 8u);
  EXPECT_EQ(r.pooled.gt_points, 6u);
  EXPECT_EQ(r.pooled.matched_predicted, 3u);
  EXPECT_EQ(r.pooled.matched_gt, 3u);
  EXPECT_EQ(r.pooled.gt_objects, 4);
  EXPECT_EQ(r.pooled.predicted_clusters, 4);
  EXPECT_EQ(r.removed.missed, 1);  // object 2
  EXPECT_EQ(r.removed.wrong, 1);   // cluster 2
  EXPECT_EQ(r.added.missed, 1);    // object 6
  EXPECT_EQ(r.added.wrong, 1);     // cluster 4
  EXPECT_EQ(r.pooled.missed, 2);
  EXPECT_EQ(r.pooled.wrong, 2);
  const double p = 3.0 / 8.0, rc = 3.0 / 6.0;
  expectRates(r.pooled, p, rc, 2.0 * p * rc / (p + rc));
  // Pooled rates come from the summed counts, not from averaging the sides.
  EXPECT_NE(r.pooled.precision, 0.5 * (r.removed.precision + r.added.precision));
}

TEST(Eval, NanPointsAreIgnored) {
  const auto gt = groundTruth({{0, 0, 0}, {1, 0, 0}, {kNaN, kNaN, kNaN}}, {1, 1, 2});
  const auto pred = prediction({{0, 0, 0}, {1, 0, 0}, {kNaN, 0, 0}}, {1, 1, 3});
  const SideScore s = scoreSide(pred, gt, 0.01);
  EXPECT_EQ(s.predicted_points, 2u);
  EXPECT_EQ(s.gt_points, 2u);
  EXPECT_EQ(s.gt_objects, 1);          // object 2 has no valid point
  EXPECT_EQ(s.predicted_clusters, 1);  // cluster 3 neither
  expectRates(s, 1.0, 1.0, 1.0);
  EXPECT_EQ(s.missed, 0);
  EXPECT_EQ(s.wrong, 0);
  // Only invalid points on both sides: an empty side.
  const SideScore e =
      scoreSide(prediction({{kNaN, 0, 0}}, {1}), groundTruth({{0, kNaN, 0}}, {1}), 0.01);
  expectRates(e, 1.0, 1.0, 1.0);
}

TEST(Eval, MissingIdFieldsMakeOneObjectOrCluster) {
  const auto gt_pts = concat(row(2), row(2, {0, 10, 0}));
  const SideScore s =
      scoreSide(makeCloud(concat(row(2), row(1, {0, 50, 0}))), makeCloud(gt_pts), 0.01);
  EXPECT_EQ(s.gt_objects, 1);
  EXPECT_EQ(s.predicted_clusters, 1);
  EXPECT_EQ(s.missed, 0);
  EXPECT_EQ(s.wrong, 0);
  expectRates(s, 2.0 / 3.0, 0.5, 2.0 * (2.0 / 3.0) * 0.5 / (2.0 / 3.0 + 0.5));
  // Ids stored as floats work the same as ints.
  PointCloud f = makeCloud(row(3));
  auto& fld = f.addField(planesdf::kObjectIdField, ScalarType::Float32);
  fld.values = {1.0, 2.0, 2.0};
  EXPECT_EQ(scoreSide(PointCloud{}, f, 0.01).missed, 2);
}

TEST(Eval, InvalidToleranceOrCloudThrows) {
  const auto pts = row(2);
  for (double tol : {0.0, -1.0, std::nan(""), std::numeric_limits<double>::infinity()})
    EXPECT_THROW(scoreSide(makeCloud(pts), makeCloud(pts), tol), planesdf::Error) << tol;
  PointCloud bad = makeCloud(pts, planesdf::kObjectIdField, {1, 1});
  bad.fields[0].values.pop_back();
  try {
    evaluateChanges(PointCloud{}, PointCloud{}, bad, PointCloud{}, 0.01);
    FAIL() << "no error";
  } catch (const planesdf::Error& e) {
    EXPECT_NE(std::string(e.what()).find("reference ground truth"), std::string::npos) << e.what();
  }
}

TEST(Eval, JsonHasTheContractKeysAtEveryLevel) {
  const EvalResult r = evaluateChanges(prediction(row(2), {1, 2}), PointCloud{},
                                       groundTruth(row(1), {1}), PointCloud{}, 0.01);
  for (int indent : {-1, 2}) {
    const std::string json = planesdf::evalToJson(r, indent);
    const std::vector<std::string> top = topLevelKeys(json);
    ASSERT_GE(top.size(), 7u) << json;
    EXPECT_EQ(std::vector<std::string>(top.begin(), top.begin() + 5),
              (std::vector<std::string>{"precision", "recall", "f1", "missed", "wrong"}))
        << json;
    for (const char* side : {"removed", "added"}) {
      const std::string obj = nestedObject(json, side);
      ASSERT_FALSE(obj.empty()) << side << ": " << json;
      const std::vector<std::string> keys = topLevelKeys(obj);
      ASSERT_GE(keys.size(), 5u) << obj;
      EXPECT_EQ(std::vector<std::string>(keys.begin(), keys.begin() + 5),
                (std::vector<std::string>{"precision", "recall", "f1", "missed", "wrong"}))
          << obj;
    }
  }
  const std::string compact = planesdf::evalToJson(r, -1);
  EXPECT_EQ(compact.find('\n'), std::string::npos);
  EXPECT_NE(compact.find("\"wrong\":1"), std::string::npos) << compact;
  EXPECT_NE(compact.find("\"precision\":0.5"), std::string::npos) << compact;
  EXPECT_NE(compact.find("\"added\":{\"precision\":1.0,\"recall\":1.0,\"f1\":1.0"),
            std::string::npos)
      << compact;
}

TEST(Eval, GridSearchAgreesWithBruteForce) {
  std::mt19937 rng(42);
  std::uniform_real_distribution<float> u(-0.15f, 0.15f);
  std::vector<Eigen::Vector3f> a(3000), b(2000);
  for (auto& p : a) p = {u(rng), u(rng), u(rng)};
  for (auto& p : b) p = {u(rng), u(rng), 0.3f * u(rng)};
  std::vector<int> ida(a.size()), idb(b.size());
  for (std::size_t i = 0; i < a.size(); ++i) ida[i] = static_cast<int>(i % 40);
  for (std::size_t i = 0; i < b.size(); ++i) idb[i] = static_cast<int>(i % 30);
  for (double tol : {0.004, 0.011, 0.05}) {
    const SideScore s = scoreSide(prediction(a, ida), groundTruth(b, idb), tol);
    std::size_t ma = 0, mb = 0;
    std::vector<bool> hit_b(b.size(), false);
    for (const auto& p : a) {
      bool hit = false;
      for (std::size_t j = 0; j < b.size(); ++j)
        if ((p.cast<double>() - b[j].cast<double>()).squaredNorm() <= tol * tol) {
          hit = true;
          hit_b[j] = true;
        }
      ma += hit;
    }
    for (bool h : hit_b) mb += h;
    EXPECT_EQ(s.matched_predicted, ma) << tol;
    EXPECT_EQ(s.matched_gt, mb) << tol;
    EXPECT_GT(ma, 0u);
    EXPECT_LT(ma, a.size());
  }
}

TEST(Eval, LargeCloudsAreScoredCorrectly) {
  // 40k GT points on a 5 mm grid; 300k predicted points: the GT grid 3 mm above it (matched at
  // the default 7 mm) plus 260k on a plane 0.5 m away (unmatched).
  std::vector<Eigen::Vector3f> gt, pred;
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j) gt.emplace_back(0.005f * i, 0.005f * j, 0.0f);
  for (const auto& p : gt) pred.push_back(p + Eigen::Vector3f(0, 0, 0.003f));
  for (int i = 0; i < 520; ++i)
    for (int j = 0; j < 500; ++j) pred.emplace_back(0.002f * i, 0.002f * j, 0.5f);
  std::vector<int> gt_ids(gt.size()), pred_ids(pred.size());
  for (std::size_t i = 0; i < gt.size(); ++i) gt_ids[i] = gt[i].x() < 0.5f ? 1 : 2;
  for (std::size_t i = 0; i < pred.size(); ++i) pred_ids[i] = i < gt.size() ? 1 : 2;
  const PointCloud pc = prediction(pred, pred_ids), gc = groundTruth(gt, gt_ids);
  const SideScore s = scoreSide(pc, gc, 0.007);
  EXPECT_EQ(s.matched_predicted, gt.size());
  EXPECT_EQ(s.matched_gt, gt.size());
  EXPECT_EQ(s.wrong, 1);
  EXPECT_EQ(s.missed, 0);
}

}  // namespace
