// Change events in a binary form that keeps all of them (see serializeEvents).

#include <cstring>
#include <string>
#include <vector>

#include "../binary.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"

namespace planesdf {
namespace {

using detail::Reader;
using detail::Writer;

constexpr char kMagic[8] = {'P', 'S', 'D', 'F', 'E', 'V', 'T', '\0'};
constexpr std::uint32_t kVersion = 1;

template <class V, class T, int N>
void putArrays(Writer& w, const std::vector<V>& items) {
  w.put<std::uint64_t>(items.size());
  for (const V& v : items)
    for (int i = 0; i < N; ++i) w.put<T>(v[i]);
}

template <class V, class T, int N>
std::vector<V> getArrays(Reader& r, const char* what) {
  const auto n = r.get<std::uint64_t>(what);
  r.needItems(n, N * sizeof(T), what);
  std::vector<V> items(n);
  for (V& v : items)
    for (int i = 0; i < N; ++i) v[i] = r.get<T>(what);
  return items;
}

void putRegion(Writer& w, const ChangeRegion& r) {
  w.put<std::int32_t>(r.plane_id);
  putArrays<Eigen::Vector2i, std::int32_t, 2>(w, r.columns);
  putArrays<Eigen::Vector3i, std::int32_t, 3>(w, r.voxels);
  putArrays<Eigen::Vector3f, float, 3>(w, r.points);
  const Eigen::AlignedBox3d box = r.bbox.isEmpty() ? Eigen::AlignedBox3d() : r.bbox;  // one empty
  w.put<std::uint8_t>(box.isEmpty() ? 1 : 0);
  w.putVec(box.min());
  w.putVec(box.max());
  w.putVec(r.centroid);
  const ShapeSignature& s = r.shape;
  w.put<std::int32_t>(s.cells);
  for (const double v : {s.area, s.max_height, s.volume, s.major, s.minor}) w.put<double>(v);
  w.put<std::uint64_t>(s.deciles.size());
  for (const double v : s.deciles) w.put<double>(v);
  w.put<std::int32_t>(r.key_voxels);
  w.put<std::int32_t>(r.scored);
  w.put<double>(r.mean_similarity);
  w.put<std::uint8_t>(static_cast<std::uint8_t>(r.verdict));
}

/// An enum stored as one byte, checked against its largest value.
template <class E>
E getEnum(Reader& r, E largest, const char* what) {
  const auto v = r.get<std::uint8_t>(what);
  if (v > static_cast<std::uint8_t>(largest))
    r.fail(std::string("bad ") + what + " " + std::to_string(v));
  return static_cast<E>(v);
}

ChangeRegion getRegion(Reader& r) {
  ChangeRegion g;
  g.plane_id = r.get<std::int32_t>("plane id");
  g.columns = getArrays<Eigen::Vector2i, std::int32_t, 2>(r, "columns");
  g.voxels = getArrays<Eigen::Vector3i, std::int32_t, 3>(r, "voxels");
  g.points = getArrays<Eigen::Vector3f, float, 3>(r, "points");
  const bool empty = r.get<std::uint8_t>("box") != 0;
  const Eigen::Vector3d lo = r.getVec("box"), hi = r.getVec("box");
  if (!empty) g.bbox = Eigen::AlignedBox3d(lo, hi);
  g.centroid = r.getVec("centroid");
  ShapeSignature& s = g.shape;
  s.cells = r.get<std::int32_t>("shape");
  for (double* v : {&s.area, &s.max_height, &s.volume, &s.major, &s.minor})
    *v = r.get<double>("shape");
  const auto n = r.get<std::uint64_t>("deciles");
  r.needItems(n, sizeof(double), "deciles");
  s.deciles.resize(n);
  for (double& v : s.deciles) v = r.get<double>("deciles");
  g.key_voxels = r.get<std::int32_t>("key voxels");
  g.scored = r.get<std::int32_t>("scored");
  g.mean_similarity = r.get<double>("similarity");
  g.verdict = getEnum(r, BlobValidation::Verdict::Unknown, "verdict");
  return g;
}

}  // namespace

std::string serializeEvents(const std::vector<ChangeEvent>& events) {
  Writer w;
  w.putBytes(kMagic, sizeof(kMagic));
  w.put<std::uint32_t>(kVersion);
  w.put<std::uint64_t>(events.size());
  for (const ChangeEvent& e : events) {
    w.put<std::int32_t>(e.id);
    w.put<std::uint8_t>(static_cast<std::uint8_t>(e.type));
    w.put<std::uint8_t>(static_cast<std::uint8_t>(e.status));
    w.put<double>(e.confidence);
    w.put<std::uint64_t>(e.frame);
    putRegion(w, e.reference);
    putRegion(w, e.current);
  }
  return std::move(w.out);
}

std::vector<ChangeEvent> deserializeEvents(const std::string& bytes, const std::string& what) {
  Reader r(bytes.data(), 0, bytes.size(), what, "change events");
  if (std::memcmp(r.take(sizeof(kMagic), "magic"), kMagic, sizeof(kMagic)) != 0)
    r.fail("not serialized change events (bad magic)");
  const auto version = r.get<std::uint32_t>("version");
  if (version != kVersion) r.fail("unknown version " + std::to_string(version));
  const auto n = r.get<std::uint64_t>("event count");
  r.needItems(n, 4 + 1 + 1 + 8 + 8, "event count");
  std::vector<ChangeEvent> events(n);
  for (ChangeEvent& e : events) {
    e.id = r.get<std::int32_t>("id");
    e.type = getEnum(r, ChangeType::Replaced, "type");
    e.status = getEnum(r, ChangeStatus::Retracted, "status");
    e.confidence = r.get<double>("confidence");
    e.frame = r.get<std::uint64_t>("frame");
    e.reference = getRegion(r);
    e.current = getRegion(r);
  }
  if (r.remaining() != 0) r.fail(std::to_string(r.remaining()) + " bytes after the events");
  return events;
}

}  // namespace planesdf
