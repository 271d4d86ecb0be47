#include "planesdf/config_io.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <variant>
#include <vector>

#include "../json_depth.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/plane.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {
namespace {

using Member = std::variant<double Config::*, float Config::*, int Config::*, bool Config::*>;
struct Param {
  const char* name;
  Member member;
};

// Every scalar parameter of Config by its member name (the JSON key). `up` is handled apart.
const std::vector<Param>& params() {
  static const std::vector<Param> table = {
      {"up_auto", &Config::up_auto},
      {"ransac_inlier_dist", &Config::ransac_inlier_dist},
      {"ransac_min_inlier_frac", &Config::ransac_min_inlier_frac},
      {"ransac_min_horizontal_frac", &Config::ransac_min_horizontal_frac},
      {"ransac_iterations", &Config::ransac_iterations},
      {"ransac_max_planes_per_frame", &Config::ransac_max_planes_per_frame},
      {"plane_merge_angle_deg", &Config::plane_merge_angle_deg},
      {"plane_merge_offset", &Config::plane_merge_offset},
      {"normal_knn", &Config::normal_knn},
      {"normal_knn_max", &Config::normal_knn_max},
      {"normal_fit_points", &Config::normal_fit_points},
      {"noisy_cloud_share", &Config::noisy_cloud_share},
      {"normal_max_curvature", &Config::normal_max_curvature},
      {"normal_rough_share", &Config::normal_rough_share},
      {"cloud_smooth_knn", &Config::cloud_smooth_knn},
      {"cloud_outlier_sigma", &Config::cloud_outlier_sigma},
      {"vmf_lambda_deg", &Config::vmf_lambda_deg},
      {"offset_split", &Config::offset_split},
      {"min_plane_support", &Config::min_plane_support},
      {"orientation_tolerance_deg", &Config::orientation_tolerance_deg},
      {"refine_loss_scale", &Config::refine_loss_scale},
      {"refine_min_new_inliers", &Config::refine_min_new_inliers},
      {"voxel_size", &Config::voxel_size},
      {"fuse_band", &Config::fuse_band},
      {"below_band", &Config::below_band},
      {"truncation_voxels", &Config::truncation_voxels},
      {"max_depth", &Config::max_depth},
      {"surface_max_depth", &Config::surface_max_depth},
      {"min_depth", &Config::min_depth},
      {"max_weight", &Config::max_weight},
      {"threads", &Config::threads},
      {"memory_limit_mb", &Config::memory_limit_mb},
      {"simd", &Config::simd},
      {"w_min", &Config::w_min},
      {"h_obj", &Config::h_obj},
      {"support_margin", &Config::support_margin},
      {"object_min_solidity", &Config::object_min_solidity},
      {"blob_min_overlap", &Config::blob_min_overlap},
      {"blob_large_area", &Config::blob_large_area},
      {"roughness_tile", &Config::roughness_tile},
      {"roughness_factor", &Config::roughness_factor},
      {"delta_n", &Config::delta_n},
      {"delta_d", &Config::delta_d},
      {"refine_inplane", &Config::refine_inplane},
      {"silhouette_guard_behind", &Config::silhouette_guard_behind},
      {"delta_h", &Config::delta_h},
      {"min_change_cells", &Config::min_change_cells},
      {"dilation_cells", &Config::dilation_cells},
      {"bins_theta", &Config::bins_theta},
      {"bins_phi", &Config::bins_phi},
      {"bins_lambda", &Config::bins_lambda},
      {"sdf_sigma_voxels", &Config::sdf_sigma_voxels},
      {"alpha", &Config::alpha},
      {"delta_blob", &Config::delta_blob},
      {"event_settle_frames", &Config::event_settle_frames},
      {"event_unscored_settle_frames", &Config::event_unscored_settle_frames},
      {"plane_merge_extent_gap", &Config::plane_merge_extent_gap},
      {"plane_merge_coplanar", &Config::plane_merge_coplanar},
      {"through_band_top", &Config::through_band_top},
      {"through_band_fraction", &Config::through_band_fraction},
      {"thin_support_ratio", &Config::thin_support_ratio},
      {"plane_min_extent", &Config::plane_min_extent},
      {"plane_min_width", &Config::plane_min_width},
      {"ransac_max_samples", &Config::ransac_max_samples},
      {"track_pixel_stride", &Config::track_pixel_stride},
      {"plane_reservoir_size", &Config::plane_reservoir_size},
      {"normal_window", &Config::normal_window},
      {"plane_connect_cell", &Config::plane_connect_cell},
      {"refine_max_points", &Config::refine_max_points},
      {"splat_radius_voxels", &Config::splat_radius_voxels},
      {"splat_noise_reach", &Config::splat_noise_reach},
      {"splat_max_noise", &Config::splat_max_noise},
      {"point_cell", &Config::point_cell},
      {"inplane_max_shift", &Config::inplane_max_shift},
      {"inplane_max_yaw_deg", &Config::inplane_max_yaw_deg},
      {"inplane_shift_step", &Config::inplane_shift_step},
      {"inplane_yaw_step_deg", &Config::inplane_yaw_step_deg},
      {"inplane_max_cells", &Config::inplane_max_cells},
      {"inplane_min_compared", &Config::inplane_min_compared},
      {"inplane_min_gain_cells", &Config::inplane_min_gain_cells},
      {"inplane_min_gain_fraction", &Config::inplane_min_gain_fraction},
      {"inplane_min_gain_sigmas", &Config::inplane_min_gain_sigmas},
      {"key_min_abs_det", &Config::key_min_abs_det},
      {"key_max_voxels", &Config::key_max_voxels},
      {"verdict_min_scored", &Config::verdict_min_scored},
      {"verdict_min_scored_splatted", &Config::verdict_min_scored_splatted},
      {"moved_shape_distance", &Config::moved_shape_distance},
      {"in_place_min_overlap", &Config::in_place_min_overlap},
      {"in_place_shift_fraction", &Config::in_place_shift_fraction},
      {"replaced_min_overlap", &Config::replaced_min_overlap},
      {"ownership_parallel_cos", &Config::ownership_parallel_cos},
      {"ownership_surface_distance", &Config::ownership_surface_distance},
      {"ownership_extent_margin", &Config::ownership_extent_margin},
      {"structure_min_extent", &Config::structure_min_extent},
      {"structure_behind", &Config::structure_behind},
      {"structure_front", &Config::structure_front},
      {"wall_min_length", &Config::wall_min_length},
  };
  return table;
}

void setParam(Config& cfg, const Param& p, const nlohmann::json& v, const std::string& name) {
  const std::string key = p.name;
  auto bad = [&](const char* expected) {
    throw Error(name, "key '" + key + "': expected " + expected + ", got " + v.dump());
  };
  std::visit(
      [&](auto member) {
        using T = std::decay_t<decltype(cfg.*member)>;
        if constexpr (std::is_same_v<T, bool>) {
          if (!v.is_boolean()) bad("true or false");
          cfg.*member = v.get<bool>();
        } else if constexpr (std::is_same_v<T, int>) {
          if (!v.is_number_integer()) bad("an integer");
          const auto x = v.get<long long>();
          if (x < -1000000000LL || x > 1000000000LL) bad("an integer in range");
          cfg.*member = static_cast<int>(x);
        } else {
          if (!v.is_number()) bad("a number");
          const double x = v.get<double>();
          if (!std::isfinite(x)) bad("a finite number");
          cfg.*member = static_cast<T>(x);
        }
      },
      p.member);
}

/// The ranges of the in-plane refinement's, the 3D verdicts' and the events' tuning.
void validateChangeTuning(const Config& cfg, const std::string& what) {
  auto require = [&](bool ok, const std::string& msg) {
    if (!ok) throw Error(what, msg);
  };
  auto in = [](double x, double lo, double hi) { return x >= lo && x <= hi; };
  require(in(cfg.inplane_max_shift, 0.0, 10.0), "inplane_max_shift must be in [0, 10] m");
  require(in(cfg.inplane_max_yaw_deg, 0.0, 90.0), "inplane_max_yaw_deg must be in [0, 90]");
  require(in(cfg.inplane_shift_step, 0.0, 1.0), "inplane_shift_step must be in [0, 1] m");
  require(in(cfg.inplane_yaw_step_deg, 0.01, 90.0), "inplane_yaw_step_deg must be in [0.01, 90]");
  require(cfg.inplane_max_cells >= 1, "inplane_max_cells must be >= 1");
  require(cfg.inplane_min_compared >= 0, "inplane_min_compared must be >= 0");
  require(cfg.inplane_min_gain_cells >= 0, "inplane_min_gain_cells must be >= 0");
  require(in(cfg.inplane_min_gain_fraction, 0.0, 1.0),
          "inplane_min_gain_fraction must be in [0, 1]");
  require(in(cfg.inplane_min_gain_sigmas, 0.0, 1000.0),
          "inplane_min_gain_sigmas must be in [0, 1000]");
  require(in(cfg.key_min_abs_det, 0.0, 1e6), "key_min_abs_det must be in [0, 1e6]");
  require(cfg.key_max_voxels >= 1 && cfg.key_max_voxels <= 100000,
          "key_max_voxels must be in [1, 100000]");
  require(cfg.verdict_min_scored >= 1 && cfg.verdict_min_scored_splatted >= 1,
          "verdict_min_scored and verdict_min_scored_splatted must be >= 1");
  require(in(cfg.moved_shape_distance, 0.0, 1000.0), "moved_shape_distance must be in [0, 1000]");
  require(in(cfg.in_place_min_overlap, 0.0, 1.0), "in_place_min_overlap must be in [0, 1]");
  require(in(cfg.in_place_shift_fraction, 0.0, 1000.0),
          "in_place_shift_fraction must be in [0, 1000]");
  require(in(cfg.replaced_min_overlap, 0.0, 1.0), "replaced_min_overlap must be in [0, 1]");
  require(in(cfg.ownership_parallel_cos, 0.0, 1.0), "ownership_parallel_cos must be in [0, 1]");
  require(in(cfg.ownership_surface_distance, 0.0, 10.0),
          "ownership_surface_distance must be in [0, 10] m");
  require(in(cfg.ownership_extent_margin, 0.0, 10.0),
          "ownership_extent_margin must be in [0, 10] m");
  require(in(cfg.structure_behind, 0.0, 10.0), "structure_behind must be in [0, 10] m");
  require(in(cfg.structure_front, 0.0, 10.0), "structure_front must be in [0, 10] m");
  require(in(cfg.structure_min_extent, 0.0, 1000.0) && in(cfg.wall_min_length, 0.0, 1000.0),
          "structure_min_extent and wall_min_length must be in [0, 1000] m");
}

}  // namespace

Config parseConfigJson(const std::string& text, const std::string& name, const Config& base) {
  const nlohmann::json j = detail::parseJson(text, name);
  if (!j.is_object()) throw Error(name, "expected a JSON object of Config parameters");
  Config cfg = base;
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& key = it.key();
    if (key == "up") {
      const auto& v = it.value();
      if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() ||
          !v[2].is_number())
        throw Error(name, "key 'up': expected an array of three numbers, got " + v.dump());
      cfg.up = Eigen::Vector3d(v[0].get<double>(), v[1].get<double>(), v[2].get<double>());
      continue;
    }
    const Param* found = nullptr;
    for (const auto& p : params())
      if (key == p.name) found = &p;
    if (!found) throw Error(name, "unknown key '" + key + "'");
    setParam(cfg, *found, it.value(), name);
  }
  validateConfig(cfg, name);
  return cfg;
}

Config loadConfigJson(const std::string& path, const Config& base) {
  return parseConfigJson(io::readFile(path), path, base);
}

std::string configToJson(const Config& cfg) {
  nlohmann::ordered_json j;
  j["up"] = {cfg.up.x(), cfg.up.y(), cfg.up.z()};
  for (const auto& p : params())
    std::visit([&](auto member) { j[p.name] = cfg.*member; }, p.member);
  return j.dump(2) + "\n";
}

void validateConfig(const Config& cfg, const std::string& what) {
  auto require = [&](bool ok, const std::string& msg) {
    if (!ok) throw Error(what, msg);
  };
  require(cfg.up.allFinite() && cfg.up.norm() > 1e-9, "up axis must be a non-zero finite vector");
  require(cfg.voxel_size >= 0.001 && cfg.voxel_size <= 1.0, "voxel_size must be in [0.001, 1] m");
  require(cfg.fuse_band > 0.0 && cfg.fuse_band <= 10.0, "fuse_band must be in (0, 10] m");
  require(cfg.below_band >= 0.0, "below_band must be >= 0");
  require(cfg.truncation_voxels >= 1 && cfg.truncation_voxels <= 64,
          "truncation_voxels must be in [1, 64]");
  require(cfg.min_depth >= 0.0 && cfg.max_depth > cfg.min_depth,
          "depth range must satisfy 0 <= min_depth < max_depth");
  require(cfg.surface_max_depth > cfg.min_depth, "surface_max_depth must be > min_depth");
  require(cfg.max_weight > 0.0f && cfg.w_min >= 0.0f, "weights must be positive");
  require(cfg.threads >= 0 && cfg.threads <= kMaxThreads,
          "threads must be in [0, " + std::to_string(kMaxThreads) + "] (0: all cores)");
  require(cfg.memory_limit_mb >= 0 && cfg.memory_limit_mb <= kMaxMemoryLimitMb,
          "memory_limit_mb must be in [0, " + std::to_string(kMaxMemoryLimitMb) +
              "] (0: half the physical memory)");
  require(cfg.delta_n > 0.0 && cfg.delta_n <= 1.0, "delta_n must be in (0, 1]");
  require(cfg.delta_d >= 0.0 && cfg.delta_h > 0.0 && cfg.h_obj > 0.0,
          "delta_d, delta_h and h_obj must be positive");
  require(cfg.support_margin >= 0.0 && std::isfinite(cfg.support_margin),
          "support_margin must be finite and >= 0");
  require(cfg.object_min_solidity >= 0.0 && cfg.object_min_solidity <= 1.0,
          "object_min_solidity must be in [0, 1]");
  require(cfg.blob_min_overlap >= 0.0 && cfg.blob_min_overlap <= 1.0,
          "blob_min_overlap must be in [0, 1]");
  require(cfg.through_band_top >= 0.0 && cfg.through_band_top <= 1.0,
          "through_band_top must be in [0, 1]");
  require(cfg.through_band_fraction >= 0.0 && std::isfinite(cfg.through_band_fraction),
          "through_band_fraction must be finite and >= 0");
  require(cfg.thin_support_ratio >= 0.0 && cfg.thin_support_ratio <= 1.0,
          "thin_support_ratio must be in [0, 1]");
  require(cfg.blob_large_area >= 0.0 && std::isfinite(cfg.blob_large_area),
          "blob_large_area must be finite and >= 0");
  require(cfg.bins_theta >= 1 && cfg.bins_phi >= 1 && cfg.bins_lambda >= 1 &&
              cfg.bins_theta * cfg.bins_phi * cfg.bins_lambda <= 4096,
          "histogram bins must be >= 1 and at most 4096 in all");
  require(cfg.alpha > 0.0 && cfg.delta_blob > 0.0 && cfg.delta_blob <= 1.0,
          "alpha must be > 0 and delta_blob in (0, 1]");
  require(cfg.sdf_sigma_voxels > 0.0, "sdf_sigma_voxels must be > 0");
  require(cfg.ransac_inlier_dist > 0.0 && cfg.ransac_iterations >= 1 &&
              cfg.ransac_min_inlier_frac > 0.0 && cfg.ransac_min_inlier_frac <= 1.0 &&
              cfg.ransac_min_horizontal_frac > 0.0 && cfg.ransac_min_horizontal_frac <= 1.0,
          "RANSAC parameters out of range");
  require(cfg.normal_knn >= 3 && cfg.normal_knn <= 1000, "normal_knn must be in [3, 1000]");
  require(std::isfinite(cfg.splat_noise_reach) && cfg.splat_noise_reach >= 0.0 &&
              cfg.splat_noise_reach <= 10.0,
          "splat_noise_reach must be in [0, 10]");
  require(std::isfinite(cfg.splat_max_noise) && cfg.splat_max_noise >= 0.0,
          "splat_max_noise must be >= 0");
  require(cfg.noisy_cloud_share >= 0.0 && cfg.noisy_cloud_share <= 1.0,
          "noisy_cloud_share must be in [0, 1]");
  require(cfg.normal_knn_max >= cfg.normal_knn && cfg.normal_knn_max <= 4000,
          "normal_knn_max must be in [normal_knn, 4000]");
  require(cfg.normal_fit_points >= cfg.normal_knn && cfg.normal_fit_points <= 4000,
          "normal_fit_points must be in [normal_knn, 4000]");
  require(cfg.normal_max_curvature >= 0.0 && cfg.normal_max_curvature <= 1.0 / 3.0,
          "normal_max_curvature must be in [0, 1/3]");
  require(cfg.normal_rough_share >= 0.0 && cfg.normal_rough_share <= 1.0,
          "normal_rough_share must be in [0, 1]");
  require(cfg.cloud_smooth_knn == 0 || (cfg.cloud_smooth_knn >= 3 && cfg.cloud_smooth_knn <= 1000),
          "cloud_smooth_knn must be 0 or in [3, 1000]");
  require(std::isfinite(cfg.cloud_outlier_sigma) && cfg.cloud_outlier_sigma >= 0.0,
          "cloud_outlier_sigma must be >= 0");
  require(cfg.min_change_cells >= 0 && cfg.dilation_cells >= 0,
          "min_change_cells and dilation_cells must be >= 0");
  require(cfg.roughness_tile >= 0 && cfg.roughness_tile <= 4096,
          "roughness_tile must be in [0, 4096]");
  require(cfg.roughness_factor >= 0.0 && std::isfinite(cfg.roughness_factor),
          "roughness_factor must be finite and >= 0");
  require(cfg.event_settle_frames >= 0 && cfg.event_settle_frames <= 100000,
          "event_settle_frames must be in [0, 100000]");
  require(cfg.event_unscored_settle_frames >= 0 && cfg.event_unscored_settle_frames <= 100000,
          "event_unscored_settle_frames must be in [0, 100000]");
  validateChangeTuning(cfg, what);
  // The stages' own checks, here so that their messages name the config file too.
  try {
    validatePlaneConfig(cfg);
    validateFusionConfig(cfg);
  } catch (const Error& e) {
    throw Error(what, e.message());
  }
}

}  // namespace planesdf
