// scene.json: the whole scene description as JSON (nlohmann_json), written with every field and
// read strictly (unknown keys and wrong types are errors naming the element).
#include <nlohmann/json.hpp>

#include <cmath>
#include <initializer_list>
#include <limits>
#include <string>
#include <vector>

#include "../json_depth.hpp"
#include "../json_reader.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/sim.hpp"

namespace planesdf::sim {
namespace {
using json = nlohmann::json;
using Reader = detail::JsonReader;
using ojson = nlohmann::ordered_json;
using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr const char* kFormat = "planesdf-scene";
constexpr int kVersion = 1;

// ---- writing ------------------------------------------------------------------------------------

template <class V>
ojson array(const V& v) {
  ojson a = ojson::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) a.push_back(v[i]);
  return a;
}

ojson ids(const std::vector<int>& v) {
  ojson a = ojson::array();
  for (const int id : v) a.push_back(id);
  return a;
}

ojson toJson(const Object& o) {
  ojson j;
  j["id"] = o.id;
  j["type"] = toString(o.type);
  j["size"] = array(o.size);
  j["position"] = array(o.position);
  j["orientation"] = array(o.orientation.coeffs());  // x y z w
  j["support"] = o.support;
  return j;
}

ojson toJson(const Orbit& o) {
  ojson j;
  j["target"] = array(o.target);
  j["center"] = array(o.center);
  j["radius"] = o.radius;
  j["z_min"] = o.z_min;
  j["z_max"] = o.z_max;
  j["height_waves"] = o.height_waves;
  j["start_deg"] = o.start_deg;
  j["end_deg"] = o.end_deg;
  j["frames"] = o.frames;
  j["target_follow"] = o.target_follow;
  return j;
}

ojson toJson(const Session& s) {
  ojson j;
  j["objects"] = ojson::array();
  for (const Object& o : s.objects) j["objects"].push_back(toJson(o));
  j["trajectory"] = ojson::array();
  for (const Orbit& o : s.trajectory) j["trajectory"].push_back(toJson(o));
  ojson e;
  e["translation"] = array(s.localisation_error.translation);
  e["rotation_deg"] = array(s.localisation_error.rotation_deg);
  e["pivot"] = array(s.localisation_error.pivot);
  j["localisation_error"] = e;
  return j;
}

ojson toJson(const SensorModel& s) {
  ojson j;
  j["fx"] = s.intrinsics.fx;
  j["fy"] = s.intrinsics.fy;
  j["cx"] = s.intrinsics.cx;
  j["cy"] = s.intrinsics.cy;
  j["width"] = s.intrinsics.width;
  j["height"] = s.intrinsics.height;
  j["min_depth"] = s.min_depth;
  j["max_depth"] = s.max_depth;
  j["noise"] = s.noise;
  j["axial_a"] = s.axial_a;
  j["axial_b"] = s.axial_b;
  j["axial_z0"] = s.axial_z0;
  j["axial_incidence"] = s.axial_incidence;
  j["lateral_sigma_px"] = s.lateral_sigma_px;
  j["quantisation"] = s.quantisation;
  j["max_incidence_deg"] = s.max_incidence_deg;
  j["edge_jump"] = s.edge_jump;
  j["edge_dropout"] = s.edge_dropout;
  j["flying_pixel"] = s.flying_pixel;
  j["frame_rate"] = s.frame_rate;
  return j;
}

// ---- reading ------------------------------------------------------------------------------------

template <class T, class F>
void optional(const json& j, const char* key, T& out, F read) {
  if (j.contains(key)) out = read(j.at(key));
}

Object readObject(const Reader& r, const json& j, const std::string& e) {
  r.object(j, e, {"id", "type", "size", "position", "orientation", "support"},
           {"id", "type", "size", "position", "support"});
  Object o;
  o.id = r.integer(j.at("id"), e + ".id");
  const std::string type = r.string(j.at("type"), e + ".type");
  const auto t = objectTypeFromString(type);
  if (!t)
    r.fail(e + ".type", "unknown object type '" + type +
                            "' (expected box, cylinder, sphere, cone, torus, mug, book_stack, "
                            "bottle or toy_car)");
  o.type = *t;
  o.size = r.vector<3>(j.at("size"), e + ".size");
  o.position = r.vector<3>(j.at("position"), e + ".position");
  if (j.contains("orientation")) {
    const Eigen::Vector4d q = r.vector<4>(j.at("orientation"), e + ".orientation");
    o.orientation = Eigen::Quaterniond(q[3], q[0], q[1], q[2]);
  }
  o.support = r.string(j.at("support"), e + ".support");
  return o;
}

Orbit readOrbit(const Reader& r, const json& j, const std::string& e) {
  r.object(j, e,
           {"target", "center", "radius", "z_min", "z_max", "height_waves", "start_deg", "end_deg",
            "frames", "target_follow"},
           {"target"});
  Orbit o;
  o.target = r.vector<3>(j.at("target"), e + ".target");
  o.center = o.target.head<2>();
  const auto num = [&](const char* key) {
    return [&r, &e, key](const json& v) { return r.number(v, e + "." + key); };
  };
  const auto integer = [&](const char* key) {
    return [&r, &e, key](const json& v) { return r.integer(v, e + "." + key); };
  };
  optional(j, "center", o.center,
           [&](const json& v) { return Vector2d(r.vector<2>(v, e + ".center")); });
  optional(j, "radius", o.radius, num("radius"));
  optional(j, "z_min", o.z_min, num("z_min"));
  optional(j, "z_max", o.z_max, num("z_max"));
  optional(j, "height_waves", o.height_waves, integer("height_waves"));
  optional(j, "start_deg", o.start_deg, num("start_deg"));
  optional(j, "end_deg", o.end_deg, num("end_deg"));
  optional(j, "frames", o.frames, integer("frames"));
  optional(j, "target_follow", o.target_follow, num("target_follow"));
  return o;
}

Session readSession(const Reader& r, const json& j, const std::string& e) {
  r.object(j, e, {"objects", "trajectory", "localisation_error"}, {"objects", "trajectory"});
  Session s;
  const json& objects = r.array(j.at("objects"), e + ".objects");
  for (std::size_t i = 0; i < objects.size(); ++i)
    s.objects.push_back(readObject(r, objects[i], e + ".objects[" + std::to_string(i) + "]"));
  const json& trajectory = r.array(j.at("trajectory"), e + ".trajectory");
  for (std::size_t i = 0; i < trajectory.size(); ++i)
    s.trajectory.push_back(
        readOrbit(r, trajectory[i], e + ".trajectory[" + std::to_string(i) + "]"));
  if (j.contains("localisation_error")) {
    const json& le = j.at("localisation_error");
    const std::string ee = e + ".localisation_error";
    r.object(le, ee, {"translation", "rotation_deg", "pivot"});
    LocalisationError& out = s.localisation_error;
    optional(le, "translation", out.translation,
             [&](const json& v) { return Vector3d(r.vector<3>(v, ee + ".translation")); });
    optional(le, "rotation_deg", out.rotation_deg,
             [&](const json& v) { return Vector3d(r.vector<3>(v, ee + ".rotation_deg")); });
    optional(le, "pivot", out.pivot,
             [&](const json& v) { return Vector3d(r.vector<3>(v, ee + ".pivot")); });
  }
  return s;
}

SensorModel readSensor(const Reader& r, const json& j) {
  const std::string e = "sensor";
  r.object(j, e,
           {"fx",
            "fy",
            "cx",
            "cy",
            "width",
            "height",
            "min_depth",
            "max_depth",
            "noise",
            "axial_a",
            "axial_b",
            "axial_z0",
            "axial_incidence",
            "lateral_sigma_px",
            "quantisation",
            "max_incidence_deg",
            "edge_jump",
            "edge_dropout",
            "flying_pixel",
            "frame_rate"});
  SensorModel s;
  const auto num = [&](const char* key, double& out) {
    if (j.contains(key)) out = r.number(j.at(key), e + "." + key);
  };
  num("fx", s.intrinsics.fx);
  num("fy", s.intrinsics.fy);
  num("cx", s.intrinsics.cx);
  num("cy", s.intrinsics.cy);
  if (j.contains("width"))
    s.intrinsics.width = static_cast<int>(r.integer(j.at("width"), e + ".width", 1, 16384));
  if (j.contains("height"))
    s.intrinsics.height = static_cast<int>(r.integer(j.at("height"), e + ".height", 1, 16384));
  num("min_depth", s.min_depth);
  num("max_depth", s.max_depth);
  if (j.contains("noise")) s.noise = r.boolean(j.at("noise"), e + ".noise");
  num("axial_a", s.axial_a);
  num("axial_b", s.axial_b);
  num("axial_z0", s.axial_z0);
  num("axial_incidence", s.axial_incidence);
  num("lateral_sigma_px", s.lateral_sigma_px);
  num("quantisation", s.quantisation);
  num("max_incidence_deg", s.max_incidence_deg);
  num("edge_jump", s.edge_jump);
  num("edge_dropout", s.edge_dropout);
  num("flying_pixel", s.flying_pixel);
  num("frame_rate", s.frame_rate);
  return s;
}

}  // namespace

std::string sceneToJson(const Scene& scene) {
  ojson j;
  j["format"] = kFormat;
  j["version"] = kVersion;
  j["name"] = scene.name;
  j["seed"] = scene.seed;
  ojson room;
  room["size"] = array(scene.room.size);
  room["wall_height"] = scene.room.wall_height;
  room["walls"] = scene.room.walls;
  j["room"] = room;
  j["tables"] = ojson::array();
  for (const Table& t : scene.tables) {
    ojson jt;
    jt["id"] = t.id;
    jt["center"] = array(t.center);
    jt["yaw_deg"] = t.yaw_deg;
    jt["size"] = array(t.size);
    j["tables"].push_back(jt);
  }
  j["shelves"] = ojson::array();
  for (const Shelf& s : scene.shelves) {
    ojson js;
    js["id"] = s.id;
    js["center"] = array(s.center);
    js["yaw_deg"] = s.yaw_deg;
    js["size"] = array(s.size);
    js["boards"] = s.boards;
    j["shelves"].push_back(js);
  }
  j["sensor"] = toJson(scene.sensor);
  j["reference"] = toJson(scene.reference);
  j["current"] = toJson(scene.current);
  j["changes"] = ojson::array();
  for (const Change& c : scene.changes) {
    ojson jc;
    jc["kind"] = toString(c.kind);
    jc["reference_ids"] = ids(c.reference_ids);
    jc["current_ids"] = ids(c.current_ids);
    j["changes"].push_back(jc);
  }
  return j.dump(2) + "\n";
}

Scene parseSceneJson(const std::string& text, const std::string& name) {
  const json j = detail::parseJson(text, name);
  const Reader r(name);
  r.object(j, "scene",
           {"format", "version", "name", "seed", "room", "tables", "shelves", "sensor", "reference",
            "current", "changes"},
           {"reference", "current"});
  if (j.contains("format") && j.at("format") != kFormat)
    r.fail("format",
           "expected \"" + std::string(kFormat) + "\", got " + Reader::shown(j.at("format")));
  if (j.contains("version") && r.integer(j.at("version"), "version") != kVersion)
    r.fail("version", "unsupported version " + Reader::shown(j.at("version")) + " (expected " +
                          std::to_string(kVersion) + ")");
  Scene s;
  if (j.contains("name")) s.name = r.string(j.at("name"), "name");
  if (j.contains("seed"))
    s.seed = static_cast<std::uint32_t>(r.integer(j.at("seed"), "seed", 0, 4294967295LL));
  if (j.contains("room")) {
    const json& room = j.at("room");
    r.object(room, "room", {"size", "wall_height", "walls"});
    if (room.contains("size")) s.room.size = r.vector<2>(room.at("size"), "room.size");
    if (room.contains("wall_height"))
      s.room.wall_height = r.number(room.at("wall_height"), "room.wall_height");
    if (room.contains("walls")) s.room.walls = r.boolean(room.at("walls"), "room.walls");
  }
  if (j.contains("tables")) {
    const json& tables = r.array(j.at("tables"), "tables");
    for (std::size_t i = 0; i < tables.size(); ++i) {
      const std::string e = "tables[" + std::to_string(i) + "]";
      const json& jt = tables[i];
      r.object(jt, e, {"id", "center", "yaw_deg", "size"}, {"id", "center", "size"});
      Table t;
      t.id = r.integer(jt.at("id"), e + ".id");
      t.center = r.vector<2>(jt.at("center"), e + ".center");
      if (jt.contains("yaw_deg")) t.yaw_deg = r.number(jt.at("yaw_deg"), e + ".yaw_deg");
      t.size = r.vector<3>(jt.at("size"), e + ".size");
      s.tables.push_back(t);
    }
  }
  if (j.contains("shelves")) {
    const json& shelves = r.array(j.at("shelves"), "shelves");
    for (std::size_t i = 0; i < shelves.size(); ++i) {
      const std::string e = "shelves[" + std::to_string(i) + "]";
      const json& js = shelves[i];
      r.object(js, e, {"id", "center", "yaw_deg", "size", "boards"}, {"id", "center", "size"});
      Shelf sh;
      sh.id = r.integer(js.at("id"), e + ".id");
      sh.center = r.vector<2>(js.at("center"), e + ".center");
      if (js.contains("yaw_deg")) sh.yaw_deg = r.number(js.at("yaw_deg"), e + ".yaw_deg");
      sh.size = r.vector<3>(js.at("size"), e + ".size");
      if (js.contains("boards")) sh.boards = r.integer(js.at("boards"), e + ".boards");
      s.shelves.push_back(sh);
    }
  }
  if (j.contains("sensor")) s.sensor = readSensor(r, j.at("sensor"));
  s.reference = readSession(r, j.at("reference"), "reference");
  s.current = readSession(r, j.at("current"), "current");
  if (j.contains("changes")) {
    const json& changes = r.array(j.at("changes"), "changes");
    for (std::size_t i = 0; i < changes.size(); ++i) {
      const std::string e = "changes[" + std::to_string(i) + "]";
      const json& jc = changes[i];
      r.object(jc, e, {"kind", "reference_ids", "current_ids"}, {"kind"});
      Change c;
      const std::string kind = r.string(jc.at("kind"), e + ".kind");
      const auto k = changeKindFromString(kind);
      if (!k)
        r.fail(e + ".kind", "unknown change kind '" + kind +
                                "' (expected none, add, remove, move, small_move, swap or "
                                "replace)");
      c.kind = *k;
      if (jc.contains("reference_ids"))
        c.reference_ids = r.idList(jc.at("reference_ids"), e + ".reference_ids");
      if (jc.contains("current_ids"))
        c.current_ids = r.idList(jc.at("current_ids"), e + ".current_ids");
      s.changes.push_back(c);
    }
  }
  validateScene(s, name);
  return s;
}

Scene loadSceneJson(const std::string& path) {
  return parseSceneJson(io::readFile(path), path);
}

void saveSceneJson(const std::string& path, const Scene& scene) {
  const std::string text = sceneToJson(scene);
  io::writeFileAtomic(path, [&](std::ostream& out) { out << text; });
}

}  // namespace planesdf::sim
