// `planesdf eval DETECT_DIR --gt-reference R.ply --gt-current C.ply [--tol M] [--json]`: scores
// the removed_points.ply / added_points.ply of a detect output against ground truth (design.md,
// "Formats").
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <string>

#include "commands.hpp"
#include "planesdf/error.hpp"
#include "planesdf/eval.hpp"
#include "planesdf/io/ply.hpp"

namespace planesdf::cli {
namespace {

namespace fs = std::filesystem;

// Reads one PLY of the evaluation; a missing file is bad input naming it.
PointCloud readInput(const std::string& path, const std::string& role) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(path, role + " does not exist");
  return io::readPly(path);
}

std::string fixed(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, v);
  return buf;
}

void printRow(std::ostream& out, const char* name, const SideScore& s) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), "%-8s %6s %6s %6s %4d %4d %10zu %10zu %10zu %10zu %4d %4d\n",
                name, fixed(s.precision, 3).c_str(), fixed(s.recall, 3).c_str(),
                fixed(s.f1, 3).c_str(), s.missed, s.wrong, s.predicted_points, s.matched_predicted,
                s.gt_points, s.matched_gt, s.gt_objects, s.predicted_clusters);
  out << buf;
}

}  // namespace

int runEval(const EvalArgs& args) {
  if (!(std::isfinite(args.tol) && args.tol > 0.0)) {
    std::ostringstream s;
    s << "must be a positive finite distance in metres, got " << args.tol;
    throw Error("--tol", s.str());
  }
  std::error_code ec;
  if (!fs::is_directory(args.detect_dir, ec))
    throw Error(args.detect_dir, "is not a folder (expected the --out folder of planesdf detect)");
  const std::string removed_path = (fs::path(args.detect_dir) / "removed_points.ply").string();
  const std::string added_path = (fs::path(args.detect_dir) / "added_points.ply").string();

  const PointCloud removed = readInput(removed_path, "detect output");
  const PointCloud added = readInput(added_path, "detect output");
  const PointCloud gt_reference = readInput(args.gt_reference, "--gt-reference file");
  const PointCloud gt_current = readInput(args.gt_current, "--gt-current file");

  const EvalResult r = evaluateChanges(removed, added, gt_reference, gt_current, args.tol);
  if (args.json) {
    std::cout << evalToJson(r) << "\n";
    return kExitOk;
  }

  std::cout << "planesdf eval " << args.detect_dir << " (tol " << args.tol << " m)\n";
  char header[256];
  std::snprintf(header, sizeof(header), "%-8s %6s %6s %6s %4s %4s %10s %10s %10s %10s %4s %4s\n",
                "side", "Pr", "Re", "F1", "M", "W", "pred pts", "matched", "GT pts", "matched",
                "obj", "clu");
  std::cout << header;
  printRow(std::cout, "removed", r.removed);
  printRow(std::cout, "added", r.added);
  printRow(std::cout, "pooled", r.pooled);
  std::cout << "Pr/Re/F1 point precision/recall/F1; M missed GT objects, W wrong predicted "
               "clusters; obj GT objects, clu predicted clusters\n";
  // Clouds without ids are scored as one object / cluster each (see planesdf/eval.hpp).
  const auto noteMissing = [](const PointCloud& c, const std::string& path, const char* field) {
    if (!c.field(field) && c.countValid() > 0)
      std::cout << "note: " << path << " has no '" << field
                << "' property; all its points count as one "
                << (std::string(field) == kObjectIdField ? "object" : "cluster") << "\n";
  };
  noteMissing(removed, removed_path, kChangeIdField);
  noteMissing(added, added_path, kChangeIdField);
  noteMissing(gt_reference, args.gt_reference, kObjectIdField);
  noteMissing(gt_current, args.gt_current, kObjectIdField);
  return kExitOk;
}

}  // namespace planesdf::cli
