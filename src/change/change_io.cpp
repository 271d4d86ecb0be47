// detect outputs: changes.json, removed/added point PLYs and per-stage pictures (DESIGN §3).

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include "../parallel.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/ply.hpp"

namespace planesdf {
namespace {

nlohmann::json vec(const Eigen::Vector3d& v) {
  return nlohmann::json::array({v.x(), v.y(), v.z()});
}

Eigen::Vector3d boxMin(const Eigen::AlignedBox3d& b) {
  return b.isEmpty() ? Eigen::Vector3d::Zero() : b.min();
}
Eigen::Vector3d boxMax(const Eigen::AlignedBox3d& b) {
  return b.isEmpty() ? Eigen::Vector3d::Zero() : b.max();
}

nlohmann::json sideJson(const ChangeRegion& r) {
  nlohmann::json j;
  j["plane_id"] = r.plane_id;
  j["bbox_min"] = vec(boxMin(r.bbox));
  j["bbox_max"] = vec(boxMax(r.bbox));
  j["centroid"] = vec(r.centroid);
  j["num_voxels"] = r.voxels.size();
  j["num_points"] = r.points.size();
  j["key_voxels"] = r.key_voxels;
  j["scored"] = r.scored;
  j["mean_similarity"] = r.mean_similarity;
  j["verdict"] = toString(r.verdict);
  return j;
}

std::string side(bool reference) {
  return reference ? "ref" : "cur";
}

}  // namespace

std::array<std::uint8_t, 3> changeColor(ChangeType t) {
  switch (t) {
    case ChangeType::Added:
      return {230, 40, 40};
    case ChangeType::Removed:
      return {40, 90, 230};
    case ChangeType::Moved:
      return {240, 220, 30};
    case ChangeType::Replaced:
      return {220, 40, 220};
  }
  return {255, 255, 255};
}

std::string changesToJson(const std::vector<ChangeEvent>& events, int indent) {
  nlohmann::json arr = nlohmann::json::array();
  for (const ChangeEvent& e : events) {
    const ChangeRegion& p = e.primary();
    nlohmann::json j;
    j["id"] = e.id;
    j["type"] = toString(e.type);
    j["status"] = toString(e.status);
    j["plane_id"] = p.plane_id;
    j["bbox_min"] = vec(boxMin(p.bbox));
    j["bbox_max"] = vec(boxMax(p.bbox));
    j["centroid"] = vec(p.centroid);
    j["num_voxels"] = e.numVoxels();
    j["num_points"] = e.numPoints();
    j["confidence"] = e.confidence;
    if (!e.reference.empty()) j["reference"] = sideJson(e.reference);
    if (!e.current.empty()) j["current"] = sideJson(e.current);
    arr.push_back(std::move(j));
  }
  return arr.dump(indent);
}

namespace {

const char* const kOutputFiles[] = {"changes.json", "removed_points.ply", "added_points.ply"};

// True for `name`, or for the hidden temporary `.name.tmp…` a killed older writer left.
bool isOutputName(const std::string& entry, const std::string& name) {
  return entry == name || entry.rfind("." + name + ".tmp", 0) == 0;
}

// True when `dir` holds nothing but detect outputs, so replacing it loses nothing else.
bool holdsOnlyChangeOutputs(const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    bool known = false;
    for (const char* f : kOutputFiles) known |= isOutputName(name, f);
    if (known && e.is_regular_file(ec)) continue;
    if (name != "planes" || !e.is_directory(ec) || e.is_symlink(ec)) return false;
    for (const auto& pic : fs::directory_iterator(e.path(), ec)) {
      const std::string p = pic.path().filename().string();
      const bool png = p.size() > 4 && p.compare(p.size() - 4, 4, ".png") == 0;
      if (!pic.is_regular_file(ec) || !(png || (p[0] == '.' && p.find(".png.tmp") != p.npos)))
        return false;
    }
  }
  return !ec;
}

void writeChangeFiles(const std::string& dir, const ChangeSet& set) {
  std::error_code ec;
  const std::string json = changesToJson(set.events) + "\n";
  io::writeFileAtomic(dir + "/changes.json", [&](std::ostream& out) { out << json; });

  PointCloud removed, added;
  ScalarField rid{"change_id", ScalarType::Int32, {}}, aid{"change_id", ScalarType::Int32, {}};
  for (const ChangeEvent& e : set.events) {
    const auto color = changeColor(e.type);
    for (const auto& p : e.reference.points) {
      removed.points.push_back(p);
      removed.colors.push_back(color);
      rid.values.push_back(e.id);
    }
    for (const auto& p : e.current.points) {
      added.points.push_back(p);
      added.colors.push_back(color);
      aid.values.push_back(e.id);
    }
  }
  removed.width = static_cast<std::uint32_t>(removed.size());
  added.width = static_cast<std::uint32_t>(added.size());
  removed.fields.push_back(std::move(rid));
  added.fields.push_back(std::move(aid));
  io::writePly(dir + "/removed_points.ply", removed);
  io::writePly(dir + "/added_points.ply", added);

  bool any_stage = false;
  for (const PlanePairResult& r : set.pairs) any_stage |= !r.source_heights.empty();
  if (!any_stage) return;
  const std::string pdir = dir + "/planes";
  std::filesystem::create_directories(pdir, ec);
  if (ec) throw Error(pdir, "cannot create the pictures folder: " + ec.message());
  // The pairs' pictures side by side (PNG encoding is most of the time).
  std::vector<const PlanePairResult*> staged;
  for (const PlanePairResult& r : set.pairs)
    if (!r.source_heights.empty()) staged.push_back(&r);
  detail::parallelFor(static_cast<int>(staged.size()), 0, [&](int k) {
    const PlanePairResult& r = *staged[static_cast<std::size_t>(k)];
    const std::string stem =
        pdir + "/" + side(r.reference_to_current) + "_" + std::to_string(r.match.source_id) +
        "_to_" + side(!r.reference_to_current) + "_" + std::to_string(r.match.target_id) + "_";
    writeHeightMapPng(stem + "source_height.png", r.source_heights);
    writeHeightMapPng(stem + "target_height.png", r.target_heights);
    writeObjectMapPng(stem + "source_objects.png", r.source_objects);
    const HeightMap* bg = &r.source_heights;
    writeMaskPng(stem + "raw.png", r.change.raw, bg, "eq. 2 changed");
    writeMaskPng(stem + "unknown.png", r.change.unknown, bg, "unknown");
    writeMaskPng(stem + "vacated.png", r.change.vacated, bg,
                 "unknown, but free space in the target");
    writeMaskPng(stem + "filtered.png", r.change.filtered, bg, "small components removed");
    writeMaskPng(stem + "cleaned.png", r.change.cleaned, bg, "dilated");
    writeMaskPng(stem + "blobs.png", r.change.blob_mask, bg, "blobs (grown to objects)");
    writeMaskPng(stem + "validated.png", r.validated, bg, "kept by the 3D validation");
  });
}

}  // namespace

void writeChangeOutputs(const std::string& dir, const ChangeSet& set) {
  io::replaceFolderAtomic(
      dir, [&](const std::string& fresh) { writeChangeFiles(fresh, set); }, holdsOnlyChangeOutputs);
}

}  // namespace planesdf
