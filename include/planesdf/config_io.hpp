#pragma once
/// \file config_io.hpp
/// Config as JSON (`planesdf detect --config FILE`): an object whose keys are the Config member
/// names (e.g. {"voxel_size": 0.007, "delta_h": 0.02, "up": [0, -1, 0]}); keys not given keep
/// their defaults. Unknown keys, wrong types and out-of-range values are errors naming the file
/// and the key.

#include <string>

#include "planesdf/config.hpp"

namespace planesdf {

/// Reads a JSON config file on top of `base`. Throws planesdf::Error naming the file.
Config loadConfigJson(const std::string& path, const Config& base = Config{});
/// Parses JSON text on top of `base`; `name` is used in error messages.
Config parseConfigJson(const std::string& text, const std::string& name,
                       const Config& base = Config{});
/// Every parameter as a JSON object (pretty-printed), which parseConfigJson reads back exactly.
std::string configToJson(const Config& cfg);
/// Throws planesdf::Error (naming `what`) when a parameter is out of its valid range
/// (non-positive voxel size, band or truncation; thresholds outside their domains; zero up axis).
void validateConfig(const Config& cfg, const std::string& what = "config");

}  // namespace planesdf
