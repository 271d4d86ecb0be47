#pragma once
// The subcommands of the planesdf CLI, one file each (cmd_<name>.cpp). main.cpp parses the
// arguments into these structs and maps planesdf::Error to exit code 1.

#include <string>

#include "planesdf/config.hpp"

namespace planesdf::cli {

constexpr int kExitOk = 0;
constexpr int kExitBadInput = 1;
constexpr int kExitUsage = 2;  ///< usage errors and subcommands that are not implemented yet

/// Parameters shared by every subcommand that builds maps (DESIGN §2), as given on the line.
struct PipelineArgs {
  Config cfg;
  std::string up = "0,0,1";  ///< "auto" or "X,Y,Z"
  std::string intrinsics;    ///< "fx,fy,cx,cy[,width,height]" for TUM folders
};

/// Applies --up to args.cfg (throws planesdf::Error("--up", ...) on a malformed value).
Config resolveConfig(const PipelineArgs& args);

struct EvalArgs {
  std::string detect_dir;
  std::string gt_reference;
  std::string gt_current;
  double tol = 0.007;
  bool json = false;
};
int runEval(const EvalArgs& args);

struct FuseArgs {
  std::string input;
  std::string out;
  std::string pictures;  ///< optional folder for height-map / object-map PNGs
  PipelineArgs pipeline;
};
int runFuse(const FuseArgs& args);

int runInfo(const std::string& input);

}  // namespace planesdf::cli
