// `planesdf eval` as a user runs it: detect-style PLYs with change_id and GT PLYs with object_id
// in a temporary folder, the --json figures, the human table, one-line errors for a missing
// detect output or a bad --tol, and the real mOSD ground truth scored against itself.

#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "planesdf/eval.hpp"
#include "planesdf/io/ply.hpp"
#include "test_support.hpp"

namespace {

using planesdf::PointCloud;
using planesdf::ScalarType;
using planesdf::test::runCli;
using planesdf::test::TempDir;

// A minimal JSON reader for the eval object (the test target does not link nlohmann_json):
// objects, numbers, strings without escapes, true/false/null. Leaves come out as
// "key" / "outer.key" -> number (non-numbers as NaN). Throws std::runtime_error on bad syntax.
class FlatJson {
 public:
  static std::map<std::string, double> parse(const std::string& text) {
    FlatJson p(text);
    std::map<std::string, double> out;
    p.skipSpace();
    p.object("", out);
    p.skipSpace();
    if (p.i_ != text.size()) throw std::runtime_error("trailing characters after the object");
    return out;
  }

 private:
  explicit FlatJson(const std::string& t) : t_(t) {}

  void skipSpace() {
    while (i_ < t_.size() && std::isspace(static_cast<unsigned char>(t_[i_]))) ++i_;
  }
  void expect(char c) {
    skipSpace();
    if (i_ >= t_.size() || t_[i_] != c)
      throw std::runtime_error(std::string("expected '") + c + "' at " + std::to_string(i_));
    ++i_;
  }
  std::string string() {
    expect('"');
    const std::size_t close = t_.find('"', i_);
    if (close == std::string::npos) throw std::runtime_error("unterminated string");
    std::string s = t_.substr(i_, close - i_);
    i_ = close + 1;
    return s;
  }
  void object(const std::string& prefix, std::map<std::string, double>& out) {
    expect('{');
    skipSpace();
    if (i_ < t_.size() && t_[i_] == '}') {
      ++i_;
      return;
    }
    while (true) {
      const std::string key = prefix + string();
      expect(':');
      skipSpace();
      if (i_ >= t_.size()) throw std::runtime_error("truncated");
      if (t_[i_] == '{') {
        object(key + ".", out);
      } else if (t_[i_] == '"') {
        string();
        out[key] = std::nan("");
      } else {
        const char* begin = t_.c_str() + i_;
        char* end = nullptr;
        const double v = std::strtod(begin, &end);
        if (end == begin) {  // true / false / null
          std::size_t n = 0;
          while (i_ + n < t_.size() && std::isalpha(static_cast<unsigned char>(t_[i_ + n]))) ++n;
          if (n == 0) throw std::runtime_error("bad value at " + std::to_string(i_));
          i_ += n;
          out[key] = std::nan("");
        } else {
          i_ += static_cast<std::size_t>(end - begin);
          out[key] = v;
        }
      }
      skipSpace();
      if (i_ < t_.size() && t_[i_] == ',') {
        ++i_;
        continue;
      }
      expect('}');
      return;
    }
  }

  const std::string& t_;
  std::size_t i_ = 0;
};

int countLines(const std::string& s) {
  return static_cast<int>(std::count(s.begin(), s.end(), '\n'));
}

// `n` points 10 cm apart along x from `start`, with `ids` in the int field `field`.
PointCloud cloud(int n, const Eigen::Vector3f& start, const std::string& field, int id) {
  PointCloud c;
  for (int i = 0; i < n; ++i) c.points.push_back(start + Eigen::Vector3f(0.1f * i, 0, 0));
  c.width = static_cast<std::uint32_t>(n);
  c.addField(field, ScalarType::Int32, id);
  return c;
}

PointCloud merge(PointCloud a, const PointCloud& b) {
  a.points.insert(a.points.end(), b.points.begin(), b.points.end());
  for (auto& f : a.fields) {
    const auto* g = b.field(f.name);
    f.values.insert(f.values.end(), g->values.begin(), g->values.end());
  }
  a.width = static_cast<std::uint32_t>(a.points.size());
  return a;
}

std::string shellQuote(const std::string& s) {
  return "'" + s + "'";
}

// A detect folder and GT files with known figures:
//  removed: GT = object 1 (10 points); prediction = those 10 points (cluster 1) plus a wrong
//           cluster 2 of 5 points 5 m away -> P 10/15, R 1, M 0, W 1.
//  added:   GT = objects 3 (4 points) and 4 (6 points, 2 m away); prediction = object 4's points
//           shifted by 3 mm (cluster 7) -> P 1, R 6/10, M 1, W 0.
struct Fixture {
  TempDir tmp;
  std::string detect_dir, gt_ref, gt_cur;

  Fixture() {
    detect_dir = tmp.file("detect");
    std::filesystem::create_directory(detect_dir);
    gt_ref = tmp.file("gt_reference.ply");
    gt_cur = tmp.file("gt_current.ply");
    const PointCloud ref_obj = cloud(10, {0, 0, 1}, "object_id", 1);
    planesdf::io::writePly(gt_ref, ref_obj);
    PointCloud removed = cloud(10, {0, 0, 1}, "change_id", 1);
    removed = merge(removed, cloud(5, {5, 5, 5}, "change_id", 2));
    planesdf::io::writePly(detect_dir + "/removed_points.ply", removed);

    const PointCloud obj3 = cloud(4, {0, 1, 1}, "object_id", 3);
    const PointCloud obj4 = cloud(6, {0, 3, 1}, "object_id", 4);
    planesdf::io::writePly(gt_cur, merge(obj3, obj4), planesdf::io::PlyFormat::Ascii);
    planesdf::io::writePly(detect_dir + "/added_points.ply",
                           cloud(6, {0, 3.003f, 1}, "change_id", 7));
  }
  std::string args(const std::string& extra = "") const {
    return "eval " + shellQuote(detect_dir) + " --gt-reference " + shellQuote(gt_ref) +
           " --gt-current " + shellQuote(gt_cur) + extra;
  }
};

TEST(EvalCli, JsonFiguresMatchAHandBuiltPair) {
  Fixture f;
  const auto r = runCli(f.args(" --json"));
  ASSERT_EQ(r.exit_code, 0) << r.out;
  std::map<std::string, double> j;
  ASSERT_NO_THROW(j = FlatJson::parse(r.out)) << r.out;  // stdout holds only the object
  for (const std::string level : {"", "removed.", "added."})
    for (const char* key : {"precision", "recall", "f1", "missed", "wrong"})
      EXPECT_EQ(j.count(level + key), 1u) << level << key << " missing: " << r.out;

  EXPECT_DOUBLE_EQ(j["removed.precision"], 10.0 / 15.0);
  EXPECT_DOUBLE_EQ(j["removed.recall"], 1.0);
  EXPECT_DOUBLE_EQ(j["removed.f1"], 2.0 * (10.0 / 15.0) / (10.0 / 15.0 + 1.0));
  EXPECT_EQ(j["removed.missed"], 0);
  EXPECT_EQ(j["removed.wrong"], 1);

  EXPECT_DOUBLE_EQ(j["added.precision"], 1.0);
  EXPECT_DOUBLE_EQ(j["added.recall"], 0.6);
  EXPECT_DOUBLE_EQ(j["added.f1"], 2.0 * 0.6 / 1.6);
  EXPECT_EQ(j["added.missed"], 1);
  EXPECT_EQ(j["added.wrong"], 0);

  const double p = 16.0 / 21.0, rc = 16.0 / 20.0;
  EXPECT_DOUBLE_EQ(j["precision"], p);
  EXPECT_DOUBLE_EQ(j["recall"], rc);
  EXPECT_DOUBLE_EQ(j["f1"], 2.0 * p * rc / (p + rc));
  EXPECT_EQ(j["missed"], 1);
  EXPECT_EQ(j["wrong"], 1);
  EXPECT_DOUBLE_EQ(j["tol"], 0.007);  // default: one voxel
}

TEST(EvalCli, ToleranceFlagChangesTheMatch) {
  Fixture f;
  // The added prediction is 3 mm off: unmatched at 2 mm.
  const auto r = runCli(f.args(" --tol 0.002 --json"));
  ASSERT_EQ(r.exit_code, 0) << r.out;
  auto j = FlatJson::parse(r.out);
  EXPECT_DOUBLE_EQ(j["added.precision"], 0.0);
  EXPECT_DOUBLE_EQ(j["added.f1"], 0.0);
  EXPECT_EQ(j["added.missed"], 2);
  EXPECT_EQ(j["added.wrong"], 1);
  EXPECT_DOUBLE_EQ(j["tol"], 0.002);
}

TEST(EvalCli, HumanTableHasARowPerSide) {
  Fixture f;
  const auto r = runCli(f.args());
  ASSERT_EQ(r.exit_code, 0) << r.out;
  for (const char* word : {"removed", "added", "pooled", "Pr", "Re", "F1", "0.667", "0.750"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word << " missing:\n" << r.out;
  EXPECT_EQ(r.out.find('{'), std::string::npos) << r.out;
}

TEST(EvalCli, MissingDetectOutputIsOneLineNamingTheFile) {
  Fixture f;
  const std::string removed = f.detect_dir + "/removed_points.ply";
  std::filesystem::remove(removed);
  const auto r = runCli(f.args(" --json"));
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_EQ(countLines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find(removed), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("does not exist"), std::string::npos) << r.out;

  const auto no_dir = runCli("eval " + shellQuote(f.tmp.file("nowhere")) + " --gt-reference " +
                             shellQuote(f.gt_ref) + " --gt-current " + shellQuote(f.gt_cur));
  EXPECT_EQ(no_dir.exit_code, 1) << no_dir.out;
  EXPECT_EQ(countLines(no_dir.out), 1) << no_dir.out;
  EXPECT_NE(no_dir.out.find(f.tmp.file("nowhere")), std::string::npos) << no_dir.out;
}

TEST(EvalCli, MissingGroundTruthIsOneLineNamingTheFile) {
  Fixture f;
  std::filesystem::remove(f.gt_cur);
  const auto r = runCli(f.args());
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_EQ(countLines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find(f.gt_cur), std::string::npos) << r.out;
}

TEST(EvalCli, BadToleranceIsRejectedNamingTheFlag) {
  Fixture f;
  for (const std::string tol : {"-1", "0", "nan", "inf", "abc"}) {
    const auto r = runCli(f.args(" --tol " + tol));
    EXPECT_TRUE(r.exit_code == 1 || r.exit_code == 2) << tol << ": " << r.exit_code << " " << r.out;
    EXPECT_NE(r.out.find("--tol"), std::string::npos) << tol << ": " << r.out;
  }
}

TEST(EvalCli, MosdGroundTruthScoredAgainstItselfIsPerfect) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  const std::string gt = planesdf::test::mosdDir() + "/gt/learn43__learn44";
  TempDir tmp;
  // The GT files as a detect output: change_id = object_id.
  for (const auto& [side, out] :
       {std::pair<std::string, std::string>{"reference", "removed"}, {"current", "added"}}) {
    PointCloud c = planesdf::io::readPly(gt + "." + side + ".ply");
    ASSERT_GT(c.countValid(), 0u) << side;
    const auto* ids = c.field("object_id");
    ASSERT_NE(ids, nullptr) << side;
    const std::vector<double> values = ids->values;
    c.addField("change_id", ScalarType::Int32).values = values;
    planesdf::io::writePly(tmp.file(out + "_points.ply"), c);
  }
  const auto r = runCli("eval " + shellQuote(tmp.path()) + " --gt-reference " +
                        shellQuote(gt + ".reference.ply") + " --gt-current " +
                        shellQuote(gt + ".current.ply") + " --json");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  auto j = FlatJson::parse(r.out);
  for (const std::string level : {"", "removed.", "added."}) {
    EXPECT_DOUBLE_EQ(j[level + "precision"], 1.0) << level;
    EXPECT_DOUBLE_EQ(j[level + "recall"], 1.0) << level;
    EXPECT_DOUBLE_EQ(j[level + "f1"], 1.0) << level;
    EXPECT_EQ(j[level + "missed"], 0) << level;
    EXPECT_EQ(j[level + "wrong"], 0) << level;
  }
  // pairs.tsv lists 3 removed and 3 added objects for this pair.
  EXPECT_EQ(j["removed.gt_objects"], 3);
  EXPECT_EQ(j["added.gt_objects"], 3);
  EXPECT_GT(j["gt_points"], 1000);
}

}  // namespace
