// changes.json: the events of a detection as JSON, written and read back (see change.hpp,
// changesToJson and changesFromJson).

#include <nlohmann/json.hpp>

#include <limits>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "../json_depth.hpp"
#include "../json_reader.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"

namespace planesdf {
namespace {

using nlohmann::json;

json vec(const Eigen::Vector3d& v) {
  return json::array({v.x(), v.y(), v.z()});
}

Eigen::Vector3d boxMin(const Eigen::AlignedBox3d& b) {
  return b.isEmpty() ? Eigen::Vector3d::Zero() : b.min();
}
Eigen::Vector3d boxMax(const Eigen::AlignedBox3d& b) {
  return b.isEmpty() ? Eigen::Vector3d::Zero() : b.max();
}

json sideJson(const ChangeRegion& r) {
  json j;
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

/// One object of changes.json: its values through JsonReader, with errors naming the event, the
/// side and the field ("event 2: reference scored: must be in [0, 12], got 13").
class Fields {
 public:
  Fields(const detail::JsonReader& r, const json& j, std::string event, const std::string& side)
      : r_(r), j_(j), event_(std::move(event)), prefix_(side.empty() ? "" : side + " ") {
    if (!j_.is_object()) fail("", "is not an object");
  }

  [[noreturn]] void fail(const std::string& key, const std::string& what) const {
    r_.fail(event_, prefix_ + (key.empty() ? "" : key + " ") + what);
  }

  bool has(const char* key) const { return j_.contains(key); }

  const json& at(const char* key) const {
    if (!j_.contains(key)) fail(key, "is missing");
    return j_.at(key);
  }

  long long integer(const char* key, long long lo, long long hi) const {
    return r_.integer(at(key), element(key), lo, hi);
  }

  double number(const char* key, double lo, double hi) const {
    const double x = r_.number(at(key), element(key));
    if (!(x >= lo && x <= hi))
      fail(key, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return x;
  }

  Eigen::Vector3d vec3(const char* key) const { return r_.vector<3>(at(key), element(key)); }

  /// The one of `values` whose name (toString) string `key` holds, or a failure listing them.
  template <typename T, std::size_t N>
  T oneOf(const char* key, const T (&values)[N]) const {
    const std::string v = r_.string(at(key), element(key));
    std::string allowed;
    for (const T& t : values) {
      if (v == toString(t)) return t;
      allowed += std::string(allowed.empty() ? "" : ", ") + toString(t);
    }
    fail(key, "must be one of " + allowed);
  }

 private:
  std::string element(const char* key) const { return event_ + ": " + prefix_ + key; }

  const detail::JsonReader& r_;
  const json& j_;
  std::string event_;
  std::string prefix_;
};

constexpr long long kMaxCount = std::numeric_limits<int>::max();

ChangeRegion regionOf(const Fields& f) {
  using Verdict = BlobValidation::Verdict;
  ChangeRegion r;
  r.plane_id = static_cast<int>(f.integer("plane_id", 0, kMaxCount));
  const Eigen::Vector3d lo = f.vec3("bbox_min"), hi = f.vec3("bbox_max");
  // The writer gives a region without voxels (none, or not read back) a zero box.
  const bool zero_box = lo.isZero() && hi.isZero();
  if (f.integer("num_voxels", 0, std::numeric_limits<long long>::max()) > 0 || !zero_box) {
    if ((lo.array() > hi.array()).any()) f.fail("bbox_min", "lies above bbox_max");
    r.bbox = Eigen::AlignedBox3d(lo, hi);
  }
  r.centroid = f.vec3("centroid");
  f.integer("num_points", 0, std::numeric_limits<long long>::max());
  r.key_voxels = static_cast<int>(f.integer("key_voxels", 0, kMaxCount));
  r.scored = static_cast<int>(f.integer("scored", 0, r.key_voxels));
  r.mean_similarity = f.number("mean_similarity", -1.0, 1.0);
  r.verdict = f.oneOf("verdict", {Verdict::Changed, Verdict::Unchanged, Verdict::Unknown});
  return r;
}

ChangeEvent eventOf(const detail::JsonReader& r, const json& j, std::size_t index) {
  const std::string event = "event " + std::to_string(index + 1);
  const Fields f(r, j, event, "");
  ChangeEvent e;
  e.id = static_cast<int>(f.integer("id", 1, kMaxCount));
  e.type = f.oneOf(
      "type", {ChangeType::Added, ChangeType::Removed, ChangeType::Moved, ChangeType::Replaced});
  e.status = f.oneOf("status", {ChangeStatus::New, ChangeStatus::Updated, ChangeStatus::Retracted});
  e.confidence = f.number("confidence", 0.0, 1.0);
  if (f.has("reference")) e.reference = regionOf(Fields(r, f.at("reference"), event, "reference"));
  if (f.has("current")) e.current = regionOf(Fields(r, f.at("current"), event, "current"));
  const bool needs_reference = e.type != ChangeType::Added;
  const bool needs_current = e.type != ChangeType::Removed;
  if (e.reference.empty() == needs_reference || e.current.empty() == needs_current)
    f.fail("", std::string("a ") + toString(e.type) + " change needs " +
                   (needs_reference && needs_current ? "both sides"
                    : needs_reference                ? "only a reference side"
                                                     : "only a current side"));
  return e;
}

}  // namespace

std::string changesToJson(const std::vector<ChangeEvent>& events, int indent) {
  json arr = json::array();
  for (const ChangeEvent& e : events) {
    const ChangeRegion& p = e.primary();
    json j;
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

std::vector<ChangeEvent> changesFromJson(const std::string& text, const std::string& name) {
  const json j = detail::parseJson(text, name);
  if (!j.is_array()) throw Error(name, "is not a JSON array of change events");
  const detail::JsonReader r(name);
  std::vector<ChangeEvent> events;
  std::set<int> ids;
  for (std::size_t k = 0; k < j.size(); ++k) {
    events.push_back(eventOf(r, j[k], k));
    if (!ids.insert(events.back().id).second)
      r.fail("event " + std::to_string(k + 1),
             "id " + std::to_string(events.back().id) + " appears twice");
  }
  return events;
}

}  // namespace planesdf
