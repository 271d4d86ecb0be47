// Config defaults (the paper's values) and the JSON config file.
#include <gtest/gtest.h>

#include "planesdf/config.hpp"
#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"
#include "planesdf/memory.hpp"
#include "planesdf/validation.hpp"
#include "test_support.hpp"

namespace {
using planesdf::Config;
using planesdf::Error;

std::string errorOf(const std::string& text) {
  try {
    planesdf::parseConfigJson(text, "cfg.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

/// Expects parseConfigJson(text) to throw an error whose message contains `message`.
void expectRefused(const std::string& text, const std::string& message) {
  EXPECT_NE(errorOf(text).find(message), std::string::npos) << text << ": " << errorOf(text);
}

TEST(Config, PaperDefaults) {
  const Config c;
  EXPECT_DOUBLE_EQ(c.delta_n, 0.95);
  EXPECT_DOUBLE_EQ(c.delta_d, 0.20);
  EXPECT_DOUBLE_EQ(c.delta_h, 0.02);
  EXPECT_DOUBLE_EQ(c.voxel_size, 0.007);
  EXPECT_DOUBLE_EQ(c.fuse_band, 0.30);
  EXPECT_EQ(c.bins_theta * c.bins_phi * c.bins_lambda * 3 + 1, 451);
  EXPECT_DOUBLE_EQ(c.alpha, 2.0);
  EXPECT_DOUBLE_EQ(c.delta_blob, 0.9);
  EXPECT_EQ(c.event_settle_frames, 10);
  EXPECT_EQ(c.event_unscored_settle_frames, 30);
  EXPECT_DOUBLE_EQ(c.sdf_sigma_voxels, 2.0);
  EXPECT_NEAR(c.truncation(), 0.028, 1e-12);
  EXPECT_NO_THROW(planesdf::validateConfig(c));
}

TEST(Config, JsonRoundTripIsExact) {
  Config c;
  c.voxel_size = 0.0051;
  c.up = Eigen::Vector3d(0, -1, 0);
  c.up_auto = true;
  c.bins_lambda = 7;
  c.max_weight = 37.5f;
  const Config back = planesdf::parseConfigJson(planesdf::configToJson(c), "x");
  EXPECT_EQ(planesdf::configToJson(back), planesdf::configToJson(c));
  EXPECT_EQ(back.voxel_size, 0.0051);
  EXPECT_EQ(back.up, Eigen::Vector3d(0, -1, 0));
  EXPECT_TRUE(back.up_auto);
}

TEST(Config, EveryMemberIsAJsonKey) {
  // Each scalar member of Config must have a JSON key: CMake counts the member declarations in
  // config.hpp, so a parameter added without a key fails here.
  const std::string json = planesdf::configToJson(Config{});
  std::size_t keys = 0;
  for (std::size_t i = json.find("\": "); i != std::string::npos; i = json.find("\": ", i + 1))
    ++keys;
  EXPECT_EQ(keys, 1u + PLANESDF_CONFIG_SCALAR_MEMBERS);
}

TEST(Config, PartialFileKeepsDefaults) {
  const Config c = planesdf::parseConfigJson(R"({"delta_h": 0.03})", "x");
  EXPECT_DOUBLE_EQ(c.delta_h, 0.03);
  EXPECT_DOUBLE_EQ(c.delta_d, 0.20);
}

TEST(Config, BadFilesNameFileAndKey) {
  EXPECT_NE(errorOf("{").find("cfg.json: invalid JSON"), std::string::npos);
  EXPECT_NE(errorOf("[1,2]").find("expected a JSON object"), std::string::npos);
  EXPECT_NE(errorOf(R"({"voxel": 0.01})").find("unknown key 'voxel'"), std::string::npos);
  EXPECT_NE(errorOf(R"({"voxel_size": "big"})").find("key 'voxel_size'"), std::string::npos);
  EXPECT_NE(errorOf(R"({"bins_phi": 2.5})").find("integer"), std::string::npos);
  EXPECT_NE(errorOf(R"({"voxel_size": -1})").find("voxel_size must be"), std::string::npos);
  EXPECT_NE(errorOf(R"({"blob_min_overlap": 1.5})").find("blob_min_overlap must be"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"blob_large_area": -0.1})").find("blob_large_area must be"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"up": [0, 0]})").find("key 'up'"), std::string::npos);
  EXPECT_NE(errorOf(R"({"up": [0, 0, 0]})").find("up axis"), std::string::npos);
  EXPECT_NE(errorOf(R"({"threads": 100000})").find("threads must be in [0, 1024]"),
            std::string::npos);
  // A key given twice: nlohmann would keep the last one silently.
  EXPECT_NE(errorOf(R"({"delta_h": 0.03, "delta_h": 0.05})")
                .find("cfg.json: key 'delta_h' appears twice in one object"),
            std::string::npos);
  // Ranges the pipeline stages check name the file as well.
  EXPECT_NE(
      errorOf(R"({"plane_merge_offset": -1})").find("cfg.json: plane_merge_offset must be >= 0"),
      std::string::npos);
  EXPECT_NE(
      errorOf(R"({"max_weight": 0.5})").find("cfg.json: fusion config: max_weight must be >= 1"),
      std::string::npos);
  // nlohmann throws out_of_range, not parse_error, for a number beyond double (found by
  // tests/fuzz/config_fuzz.cpp); it escaped as a foreign exception.
  EXPECT_NE(errorOf(R"({"voxel_size": 1e400})").find("cfg.json: invalid JSON"), std::string::npos);
  EXPECT_NE(errorOf("89296.8E888888").find("number overflow"), std::string::npos);
}

TEST(Config, SettleFramesAreInRange) {
  EXPECT_NE(errorOf(R"({"event_settle_frames": -1})").find("event_settle_frames must be in"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"event_unscored_settle_frames": 100001})")
                .find("event_unscored_settle_frames must be in [0, 100000]"),
            std::string::npos);
  EXPECT_EQ(planesdf::parseConfigJson(R"({"event_unscored_settle_frames": 0})", "x")
                .event_unscored_settle_frames,
            0);
}

TEST(Config, ChangeTuningIsInRangeAndReadFromTheFile) {
  expectRefused(R"({"verdict_min_scored": 0})", "cfg.json: verdict_min_scored");
  expectRefused(R"({"in_place_min_overlap": 1.5})", "in_place_min_overlap must be");
  expectRefused(R"({"inplane_yaw_step_deg": 0})", "inplane_yaw_step_deg must be");
  const Config c = planesdf::parseConfigJson(
      R"({"moved_shape_distance": 0.25, "inplane_max_shift": 0.05, "key_max_voxels": 50})", "x");
  EXPECT_DOUBLE_EQ(c.moved_shape_distance, 0.25);
  EXPECT_DOUBLE_EQ(c.inplane_max_shift, 0.05);
  EXPECT_EQ(planesdf::validationParams(c).max_key_voxels, 50);
}

TEST(Config, OwnershipGeometryIsInRangeAndReadFromTheFile) {
  expectRefused(R"({"ownership_parallel_cos": 1.2})", "ownership_parallel_cos must be");
  expectRefused(R"({"structure_behind": -0.1})", "structure_behind must be in [0, 10] m");
  expectRefused(R"({"wall_min_length": 2000})", "wall_min_length must be");
  const Config c =
      planesdf::parseConfigJson(R"({"structure_front": 0.04, "wall_min_length": 3})", "x");
  EXPECT_DOUBLE_EQ(c.structure_front, 0.04);
  EXPECT_DOUBLE_EQ(c.wall_min_length, 3.0);
  EXPECT_DOUBLE_EQ(c.structure_behind, Config{}.structure_behind);
}

TEST(Config, MemoryLimitIsInRangeAndDefaultsToHalfThePhysicalMemory) {
  EXPECT_NE(errorOf(R"({"memory_limit_mb": -1})").find("memory_limit_mb must be in [0, 16777216]"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"memory_limit_mb": 16777217})").find("memory_limit_mb must be in"),
            std::string::npos);
  planesdf::Config c = planesdf::parseConfigJson(R"({"memory_limit_mb": 100})", "x");
  EXPECT_EQ(planesdf::memoryLimitBytes(c), std::size_t{100} << 20);
  c.memory_limit_mb = 0;
  const std::size_t physical = planesdf::detail::physicalMemoryBytes();
  EXPECT_EQ(planesdf::memoryLimitBytes(c), physical > 0 ? physical / 2 : std::size_t{8192} << 20);
}

TEST(Config, DeepNestingIsRefusedBeforeParsing) {
  // 100,000 levels overflowed the stack in nlohmann's recursive dump of the error message.
  const std::string deep = "{\"up\": " + std::string(100000, '[') + std::string(100000, ']') + "}";
  EXPECT_NE(errorOf(deep).find("cfg.json: JSON nests deeper than 64 levels"), std::string::npos);
  // Brackets inside strings do not count; 64 levels are still parsed (and refused as a value).
  EXPECT_NE(errorOf(R"({"[[[[": 1})").find("unknown key '[[[['"), std::string::npos);
  const std::string at_limit = "{\"up\": " + std::string(63, '[') + std::string(63, ']') + "}";
  EXPECT_NE(errorOf(at_limit).find("key 'up'"), std::string::npos);
}

TEST(Config, MissingFileNamesIt) {
  planesdf::test::TempDir tmp;
  try {
    planesdf::loadConfigJson(tmp.file("none.json"));
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("none.json"), std::string::npos);
  }
}

}  // namespace
