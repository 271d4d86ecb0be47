// detect outputs: changes.json, removed/added point PLYs and per-stage pictures (design.md,
// "Formats"), written all or nothing and read back.

#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
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

constexpr long long kMaxCount = std::numeric_limits<int>::max();

/// Adds the points of `path` (a detect PLY with int change_id) to side `side` of the events.
void addPoints(const std::string& path, std::vector<ChangeEvent>& events,
               ChangeRegion ChangeEvent::*side) {
  const PointCloud cloud = io::readPly(path);
  const ScalarField* ids = nullptr;
  for (const ScalarField& s : cloud.fields)
    if (s.name == "change_id") ids = &s;
  if (ids == nullptr || ids->values.size() != cloud.points.size())
    throw Error(path, "has no change_id vertex property");
  std::map<int, ChangeRegion*> by_id;
  for (ChangeEvent& e : events) by_id[e.id] = &(e.*side);
  for (std::size_t i = 0; i < cloud.points.size(); ++i) {
    const double id = ids->values[i];
    const bool whole = std::isfinite(id) && id == std::floor(id) && id >= 1.0 && id <= kMaxCount;
    const auto it = whole ? by_id.find(static_cast<int>(id)) : by_id.end();
    if (it == by_id.end() || it->second->empty())
      throw Error(path, "point " + std::to_string(i) + " has change_id " + std::to_string(id) +
                            ", which no event of changes.json has on this side");
    it->second->points.push_back(cloud.points[i]);
  }
}

std::string side(bool reference) {
  return reference ? "ref" : "cur";
}

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

std::vector<ChangeEvent> readChangeOutputs(const std::string& dir) {
  const std::string path = dir + "/changes.json";
  std::vector<ChangeEvent> events = changesFromJson(io::readFile(path), path);
  addPoints(dir + "/removed_points.ply", events, &ChangeEvent::reference);
  addPoints(dir + "/added_points.ply", events, &ChangeEvent::current);
  return events;
}

}  // namespace planesdf
