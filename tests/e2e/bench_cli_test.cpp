// `planesdf bench` (issue 7) and `planesdf bench --suite` (issue 5): a short benchmark run checks
// the JSON fields and that the values are sane; a reduced comparison suite (2 simulated + 2 mOSD
// pairs) checks that every method's outputs were scored, the figures are rates in [0, 1] and
// PlaneSDF's F1 on the mOSD pairs stays above a bound.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <string>
#include <thread>

#include "planesdf/io/atomic_file.hpp"
#include "test_support.hpp"

namespace {
using nlohmann::json;
using planesdf::test::runCli;
using planesdf::test::TempDir;

TEST(BenchCli, ShortRunWritesSaneJson) {
  TempDir tmp;
  const std::string out = tmp.file("bench.json");
  const auto r = runCli("bench --frames 3 --json '" + out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("Map::integrate"), std::string::npos) << r.out;
  const json j = json::parse(planesdf::io::readFile(out));
  EXPECT_EQ(j.at("frames").get<int>(), 3);
  const double med = j.at("integrate_ms_median").get<double>();
  EXPECT_GT(med, 0.0);
  EXPECT_LT(med, 60000.0);
  EXPECT_GE(j.at("integrate_ms_p95").get<double>(), med);
  // CPU time of all threads: some, and at most every core busy for the whole call (plus a
  // clock tick of slack).
  const double cpu = j.at("integrate_cpu_ms_median").get<double>();
  EXPECT_GT(cpu, 0.0);
  EXPECT_LE(cpu, j.at("integrate_ms_max").get<double>() *
                         static_cast<double>(std::thread::hardware_concurrency()) +
                     10.0);
  // The stages of a frame: each takes some time and none more than the largest whole call.
  const double max_ms = j.at("integrate_ms_max").get<double>();
  for (const char* k : {"tracking_ms_median", "points_ms_median", "fusion_ms_median"}) {
    EXPECT_GT(j.at(k).get<double>(), 0.0) << k;
    EXPECT_LE(j.at(k).get<double>(), max_ms) << k;
  }
  EXPECT_GE(j.at("fusion_ms_p95").get<double>(), j.at("fusion_ms_median").get<double>());
  EXPECT_NE(r.out.find("TSDF fusion"), std::string::npos) << r.out;
  EXPECT_GT(j.at("detect_ms").get<double>(), 0.0);
  EXPECT_GT(j.at("peak_rss_mb").get<double>(), 1.0);
  EXPECT_GT(j.at("map_bytes").get<double>(), 0.0);
  EXPECT_GT(j.at("voxels").get<double>(), 0.0);
  // A voxel costs at least a few bytes and the map is more than its voxels' count of bytes.
  EXPECT_GE(j.at("map_bytes").get<double>(), j.at("voxels").get<double>());
  // The room pair (issue 7's detection target): its frames, one time per detectChanges run and
  // their median.
  EXPECT_EQ(j.at("room_frames").get<int>(), 3);
  const auto runs = j.at("detect_room_ms_runs").get<std::vector<double>>();
  ASSERT_EQ(runs.size(), 3u);
  for (const double ms : runs) EXPECT_GT(ms, 0.0);
  std::vector<double> sorted = runs;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(j.at("detect_room_ms").get<double>(), sorted[1]);
  // The phases' medians: each within the slowest run (a phase's median is at most its slowest
  // run's, which is part of that run); maps and pairs take time.
  for (const char* key : {"detect_room_maps_ms", "detect_room_correction_ms",
                          "detect_room_forward_ms", "detect_room_backward_ms"}) {
    EXPECT_GE(j.at(key).get<double>(), 0.0) << key;
    EXPECT_LE(j.at(key).get<double>(), sorted[2]) << key;
  }
  EXPECT_GT(j.at("detect_room_maps_ms").get<double>(), 0.0);
  EXPECT_GT(j.at("detect_room_forward_ms").get<double>(), 0.0);
  EXPECT_GT(j.at("room_voxels").get<double>(), 0.0);
  EXPECT_GE(j.at("room_map_bytes").get<double>(), j.at("room_voxels").get<double>());
  EXPECT_NE(r.out.find("room pair"), std::string::npos) << r.out;
#ifdef PLANESDF_TEST_HAVE_OCTOMAP
  ASSERT_TRUE(j.at("octomap_ms_median").is_number()) << j.dump();
  EXPECT_GT(j.at("octomap_ms_median").get<double>(), 0.0);
#else
  EXPECT_TRUE(j.at("octomap_ms_median").is_null());
  EXPECT_NE(j.at("octomap_note").get<std::string>().find("not built"), std::string::npos);
#endif
  // Atomic write: nothing but the output in the folder.
  int files = 0;
  for (const auto& e : std::filesystem::directory_iterator(tmp.path())) {
    (void)e;
    ++files;
  }
  EXPECT_EQ(files, 1);
}

void expectRates(const json& m, const std::string& what) {
  for (const char* k : {"precision", "recall", "f1"}) {
    const double v = m.at(k).get<double>();
    EXPECT_GE(v, 0.0) << what << " " << k;
    EXPECT_LE(v, 1.0) << what << " " << k;
  }
  EXPECT_GE(m.at("missed").get<int>(), 0) << what;
  EXPECT_GE(m.at("wrong").get<int>(), 0) << what;
}

TEST(BenchCli, StreamRunAnnouncesEachChangeOnceAndEndsAsDetect) {
  // The tabletop stream of `planesdf bench` (3 changes), the detector updated after every frame
  // with the default settling: each change announced once, within 15 frames of the first frame
  // that sees its place, nothing retracted, and the final events are the offline detect's.
  TempDir tmp;
  const std::string out = tmp.file("stream.json");
  const auto r = runCli("bench --stream --stream-runs tabletop:7 --json '" + out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const json runs = json::parse(planesdf::io::readFile(out));
  ASSERT_EQ(runs.size(), 1u);
  const json& j = runs[0];
  EXPECT_EQ(j.at("event_settle_frames").get<int>(), 10);
  EXPECT_EQ(j.at("gt_changes").get<int>(), 3);
  EXPECT_EQ(j.at("gt_changes_alerted").get<int>(), 3) << j.dump();
  EXPECT_TRUE(j.at("final_events_match_offline").get<bool>()) << j.dump();
  EXPECT_EQ(j.at("retracted").get<int>(), 0) << j.dump();
  EXPECT_LE(j.at("notifications_per_final_event").get<double>(), 4.0 / 3.0) << j.dump();
  EXPECT_LE(j.at("alert_latency_frames_median").get<double>(), 15.0) << j.dump();
  const auto bad = runCli("bench --stream --stream-runs tabletop");
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.out.find("--stream-runs"), std::string::npos) << bad.out;
}

TEST(BenchCli, ReducedSuiteScoresEveryMethod) {
  PLANESDF_SKIP_WITHOUT_MOSD();
  TempDir tmp;
  const std::string dir = tmp.file("suite");
  const auto r =
      runCli("bench --suite '" + dir +
             "' --sim-pairs 2 --room-pairs 1 --room-forms streams,mesh --frames 12 --mosd-pairs 2 "
             "--mosd '" +
             planesdf::test::mosdDir() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const json j = json::parse(planesdf::io::readFile(dir + "/comparison.json"));
  const std::string md = planesdf::io::readFile(dir + "/comparison.md");
  // Each simulated pair's scene, for `planesdf simulate --scene` to render it again.
  for (const char* scene : {"sim/scenes/sim00_none_0.0cm", "sim/scenes/sim01_add_0.0cm",
                            "room/scenes/room00_none_0.0cm"}) {
    const json s = json::parse(planesdf::io::readFile(dir + "/" + scene + ".json"));
    EXPECT_EQ(s.at("format").get<std::string>(), "planesdf-scene") << scene;
  }
  std::vector<std::string> methods{"PlaneSDF", "Point distance"};
#ifdef PLANESDF_TEST_HAVE_OCTOMAP
  methods.push_back("OctoMap");
#endif
  for (const char* set : {"simulated", "mosd", "room_streams", "room_mesh"}) {
    const json& d = j.at(set);
    const std::string kind(set);
    ASSERT_EQ(d.at("pairs").get<int>(), kind.rfind("room", 0) == 0 ? 1 : 2) << set;
    for (const json& pair : d.at("per_pair")) {
      const std::string name = pair.at("name").get<std::string>();
      for (const std::string& m : methods) {
        if (kind == "room_mesh" && m == "OctoMap") {  // no viewpoint: no rays to carve with
          EXPECT_FALSE(pair.at("methods").contains(m)) << name;
          continue;
        }
        ASSERT_TRUE(pair.at("methods").contains(m)) << name << " " << m;
        const json& e = pair.at("methods").at(m);
        expectRates(e, name + " " + m);
        expectRates(e.at("removed"), name + " " + m + " removed");
        expectRates(e.at("added"), name + " " + m + " added");
        EXPECT_GT(e.at("ms").get<double>(), 0.0) << name << " " << m;
        // The outputs were written in the detect format and exist.
        const std::string sub = m == "PlaneSDF"  ? "planesdf"
                                : m == "OctoMap" ? "octomap"
                                                 : "point_distance";
        const std::string folder = kind == "mosd"           ? "mosd"
                                   : kind == "simulated"    ? "sim"
                                   : kind == "room_streams" ? "room/streams"
                                                            : "room/mesh";
        const std::string base = dir + "/" + folder + "/" + name + "/" + sub;
        EXPECT_TRUE(std::filesystem::exists(base + "/removed_points.ply")) << base;
        EXPECT_TRUE(std::filesystem::exists(base + "/added_points.ply")) << base;
      }
    }
    for (const std::string& m : methods) {
      EXPECT_NE(md.find("| " + m + " |"), std::string::npos) << m;
      if (kind == "room_mesh" && m == "OctoMap") continue;
      const json& s = d.at("summary").at(m);
      EXPECT_GE(s.at("f1").get<double>(), 0.0);
      EXPECT_LE(s.at("f1").get<double>(), 1.0);
    }
  }
  // The first two mOSD pairs of pairs.tsv (learn43 -> learn44, learn44 -> test31): PlaneSDF
  // scores pooled F1 0.99 and 0.80 on them (mean 0.89, the same figures as `planesdf detect` in
  // MosdDetect.AllPairsMeetTheAcceptanceFigures, since the suite calls the same library path);
  // 0.7 leaves room for the detector's tuning but catches a broken PlaneSDF row.
  EXPECT_GE(j.at("mosd").at("summary").at("PlaneSDF").at("f1").get<double>(), 0.7);
}

}  // namespace
