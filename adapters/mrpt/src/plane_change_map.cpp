#include "planesdf/mrpt/plane_change_map.hpp"

#include <mrpt/config/CConfigFileBase.h>
#include <mrpt/maps/CColouredPointsMap.h>
#include <mrpt/obs/CObservation3DRangeScan.h>
#include <mrpt/poses/CPose3D.h>
#include <mrpt/serialization/CArchive.h>

#include <ostream>
#include <sstream>

#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/mrpt/pose_conversion.hpp"
#include "planesdf/mrpt/range_scan.hpp"

using planesdf::mrpt_adapter::CPlaneChangeMap;

//  ---- map definition: "planeChangeMap" in CMultiMetricMap INI files ----
MAP_DEFINITION_REGISTER("planesdf::mrpt_adapter::CPlaneChangeMap,planeChangeMap",
                        planesdf::mrpt_adapter::CPlaneChangeMap)

CPlaneChangeMap::TMapDefinition::TMapDefinition() = default;

void CPlaneChangeMap::TMapDefinition::loadFromConfigFile_map_specific(
    const mrpt::config::CConfigFileBase& source, const std::string& sectionNamePrefix) {
  const std::string s = sectionNamePrefix + "_creationOpts";
  config_file = source.read_string(s, "config_file", config_file);
  reference_map = source.read_string(s, "reference_map", reference_map);
  detect_every = source.read_int(s, "detect_every", detect_every);
}

void CPlaneChangeMap::TMapDefinition::dumpToTextStream_map_specific(std::ostream& out) const {
  out << "config_file   = " << config_file << "\n"
      << "reference_map = " << reference_map << "\n"
      << "detect_every  = " << detect_every << "\n";
}

mrpt::maps::CMetricMap* CPlaneChangeMap::internal_CreateFromMapDefinition(
    const mrpt::maps::TMetricMapInitializer& def_base) {
  const auto& def = dynamic_cast<const CPlaneChangeMap::TMapDefinition&>(def_base);
  const planesdf::Config cfg =
      def.config_file.empty() ? planesdf::Config{} : planesdf::loadConfigJson(def.config_file);
  auto* map = new CPlaneChangeMap(cfg);
  map->setDetectEvery(def.detect_every);
  if (!def.reference_map.empty()) map->loadReference(def.reference_map);
  return map;
}

IMPLEMENTS_SERIALIZABLE(CPlaneChangeMap, mrpt::maps::CMetricMap, planesdf::mrpt_adapter)

namespace {
// Lets archives read CPlaneChangeMap objects back (`arch >> obj`).
const bool kRegistered = [] {
  mrpt::rtti::registerClass(CLASS_ID(CPlaneChangeMap));
  return true;
}();
}  // namespace

namespace planesdf::mrpt_adapter {

CPlaneChangeMap::CPlaneChangeMap(const Config& cfg) : cfg_(cfg), map_(cfg) {}

void CPlaneChangeMap::setReference(const Map& reference) {
  detector_.emplace(reference, cfg_);
}

void CPlaneChangeMap::loadReference(const std::string& path) {
  setReference(Map::load(path));
}

std::size_t CPlaneChangeMap::detectChanges() {
  return detector_ ? publish(detector_->update(map_)) : 0;
}

std::size_t CPlaneChangeMap::finishChanges() {
  return detector_ ? publish(detector_->finish(map_)) : 0;
}

std::size_t CPlaneChangeMap::publish(const UpdateStats& stats) {
  for (const ChangeEvent& e : stats.notifications) publishEvent(mrptEventPlaneChange(*this, e));
  return stats.notifications.size();
}

std::vector<ChangeEvent> CPlaneChangeMap::changes() const {
  return detector_ ? detector_->events() : std::vector<ChangeEvent>{};
}

void CPlaneChangeMap::getChangedPoints(mrpt::maps::CColouredPointsMap& out) const {
  toColouredPointsMap(changes(), out);
}

bool CPlaneChangeMap::isEmpty() const {
  return map_.frames() == 0 && map_.planes().empty();
}

void CPlaneChangeMap::saveMetricMapRepresentationToFile(const std::string& prefix) const {
  map_.save(prefix + ".psdf");
  const std::string json = changesToJson(changes());
  io::writeFileAtomic(prefix + "_changes.json", [&](std::ostream& os) { os << json << "\n"; });
}

void CPlaneChangeMap::getVisualizationInto(mrpt::opengl::CSetOfObjects& o) const {
  mrpt::maps::CColouredPointsMap points;
  getChangedPoints(points);
  points.getVisualizationInto(o);
}

std::string CPlaneChangeMap::asString() const {
  std::ostringstream ss;
  ss << "planesdf::mrpt_adapter::CPlaneChangeMap: " << map_.frames() << " scans, "
     << map_.planes().size() << " planes, "
     << (detector_ ? std::to_string(detector_->events().size()) + " active changes"
                   : std::string("no reference"));
  return ss.str();
}

void CPlaneChangeMap::internal_clear() {
  map_ = Map(cfg_);
  if (detector_) setReference(Map(detector_->reference()));
}

bool CPlaneChangeMap::internal_insertObservation(
    const mrpt::obs::CObservation& obs,
    const std::optional<const mrpt::poses::CPose3D>& robotPose) {
  const auto* scan = dynamic_cast<const mrpt::obs::CObservation3DRangeScan*>(&obs);
  if (scan == nullptr) return false;
  scan->load();
  if (!scan->hasRangeImage) return false;
  const Pose robot = robotPose ? toPose(*robotPose) : Pose::Identity();
  map_.integrate(toDepthFrame(*scan, "CPlaneChangeMap: " + scan->sensorLabel),
                 cameraPose(*scan, robot));
  if (detect_every_ > 0 && map_.frames() % static_cast<std::uint64_t>(detect_every_) == 0)
    detectChanges();
  return true;
}

double CPlaneChangeMap::internal_computeObservationLikelihood(const mrpt::obs::CObservation&,
                                                              const mrpt::poses::CPose3D&) const {
  return 0.0;
}

// Serialization (version 1): genericMapParams, the Config as JSON, the current map, the
// reference map ("" when none), detect_every, then the detector's announced changes
// (serializeEvents) and its next id, so that a loaded map goes on with the same ids and notifies
// only what changes. Version 0 (without the changes) still loads: its changes come back as new.
uint8_t CPlaneChangeMap::serializeGetVersion() const {
  return 1;
}

void CPlaneChangeMap::serializeTo(mrpt::serialization::CArchive& out) const {
  out << genericMapParams;
  out << configToJson(cfg_) << map_.serialize()
      << (detector_ ? detector_->reference().serialize() : std::string());
  out << static_cast<std::int32_t>(detect_every_);
  out << serializeEvents(changes())
      << static_cast<std::int32_t>(detector_ ? detector_->nextId() : 1);
}

void CPlaneChangeMap::serializeFrom(mrpt::serialization::CArchive& in, uint8_t version) {
  if (version > 1)
    throw Error("CPlaneChangeMap", "unknown serialization version " + std::to_string(version));
  std::string cfg_json, map_bytes, ref_bytes, event_bytes;
  std::int32_t every = 1, next_id = 1;
  in >> genericMapParams;
  in >> cfg_json >> map_bytes >> ref_bytes >> every;
  if (version >= 1) in >> event_bytes >> next_id;
  cfg_ = parseConfigJson(cfg_json, "CPlaneChangeMap config");
  map_ = Map::deserialize(map_bytes, "CPlaneChangeMap map");
  detector_.reset();
  if (!ref_bytes.empty()) setReference(Map::deserialize(ref_bytes, "CPlaneChangeMap reference"));
  if (detector_ && version >= 1)
    detector_->restore(deserializeEvents(event_bytes, "CPlaneChangeMap changes"), next_id);
  detect_every_ = every;
}

void toColouredPointsMap(const std::vector<ChangeEvent>& events,
                         mrpt::maps::CColouredPointsMap& out) {
  for (const ChangeEvent& e : events) {
    const auto c = changeColor(e.type);
    const float r = c[0] / 255.0f, g = c[1] / 255.0f, b = c[2] / 255.0f;
    for (const ChangeRegion* side : {&e.reference, &e.current})
      for (const Eigen::Vector3f& p : side->points)
        out.insertPointRGB(p.x(), p.y(), p.z(), r, g, b);
  }
}

}  // namespace planesdf::mrpt_adapter
