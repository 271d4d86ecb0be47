// Turning the shared pipeline flags into a Config.
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "commands.hpp"
#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"

namespace planesdf::cli {

Config resolveConfig(const PipelineArgs& args) {
  Config cfg = args.config_file.empty() ? args.cfg : loadConfigJson(args.config_file);
  if (!args.config_file.empty())
    for (const auto& copy : args.given) copy(cfg, args.cfg);
  if (args.up.empty()) {
    if (args.config_file.empty()) {
      cfg.up = Eigen::Vector3d::UnitZ();
      cfg.up_auto = false;
    }
  } else if (args.up == "auto") {
    cfg.up_auto = true;
  } else {
    std::istringstream in(args.up);
    double v[3];
    char c1 = 0, c2 = 0;
    if (!(in >> v[0] >> c1 >> v[1] >> c2 >> v[2]) || c1 != ',' || c2 != ',' || !in.eof())
      throw Error("--up", "expected 'auto' or X,Y,Z, got '" + args.up + "'");
    cfg.up = Eigen::Vector3d(v[0], v[1], v[2]);
    if (!cfg.up.allFinite() || cfg.up.norm() < 1e-9)
      throw Error("--up", "the up axis must be a non-zero vector, got '" + args.up + "'");
    cfg.up.normalize();
    cfg.up_auto = false;
  }
  validateConfig(cfg, "command line");
  return cfg;
}

bool upDefaulted(const PipelineArgs& args) {
  if (!args.up.empty()) return false;
  if (args.config_file.empty()) return true;
  // resolveConfig has read the file already: it parses.
  std::ifstream in(args.config_file);
  const nlohmann::json j = nlohmann::json::parse(in, nullptr, false);
  return !j.is_object() || (!j.contains("up") && !j.contains("up_auto"));
}

}  // namespace planesdf::cli
