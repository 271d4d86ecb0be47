#include "planesdf/types.hpp"

#include <cmath>

#include "planesdf/error.hpp"

namespace planesdf {

void Intrinsics::validate(const std::string& what) const {
  auto bad = [&](const std::string& m) { throw Error(what, "invalid intrinsics: " + m); };
  if (!(std::isfinite(fx) && fx > 0.0) || !(std::isfinite(fy) && fy > 0.0))
    bad("focal lengths must be positive and finite (fx=" + std::to_string(fx) +
        ", fy=" + std::to_string(fy) + ")");
  if (!std::isfinite(cx) || !std::isfinite(cy)) bad("principal point must be finite");
  if (width < 1 || height < 1 || width > 16384 || height > 16384)
    bad("image size " + std::to_string(width) + "x" + std::to_string(height) +
        " outside [1, 16384]");
}

int scalarTypeSize(ScalarType t) {
  switch (t) {
    case ScalarType::Int8:
    case ScalarType::UInt8:
      return 1;
    case ScalarType::Int16:
    case ScalarType::UInt16:
      return 2;
    case ScalarType::Int32:
    case ScalarType::UInt32:
    case ScalarType::Float32:
      return 4;
    case ScalarType::Float64:
      return 8;
  }
  return 0;
}

std::size_t PointCloud::countValid() const {
  std::size_t n = 0;
  for (const auto& p : points) n += isValid(p) ? 1 : 0;
  return n;
}

const ScalarField* PointCloud::field(const std::string& name) const {
  for (const auto& f : fields)
    if (f.name == name) return &f;
  return nullptr;
}

ScalarField* PointCloud::field(const std::string& name) {
  for (auto& f : fields)
    if (f.name == name) return &f;
  return nullptr;
}

ScalarField& PointCloud::addField(const std::string& name, ScalarType type, double fill) {
  ScalarField* f = field(name);
  if (!f) {
    fields.push_back({});
    f = &fields.back();
    f->name = name;
  }
  f->type = type;
  f->values.assign(points.size(), fill);
  return *f;
}

void PointCloud::validate(const std::string& what) const {
  const std::size_t n = points.size();
  if (!normals.empty() && normals.size() != n)
    throw Error(what, "normals has " + std::to_string(normals.size()) + " entries for " +
                          std::to_string(n) + " points");
  if (!colors.empty() && colors.size() != n)
    throw Error(what, "colors has " + std::to_string(colors.size()) + " entries for " +
                          std::to_string(n) + " points");
  for (const auto& f : fields)
    if (f.values.size() != n)
      throw Error(what, "field '" + f.name + "' has " + std::to_string(f.values.size()) +
                            " values for " + std::to_string(n) + " points");
  if (static_cast<std::size_t>(width) * height != n)
    throw Error(what, "width*height = " + std::to_string(width) + "*" + std::to_string(height) +
                          " does not match " + std::to_string(n) + " points");
}

}  // namespace planesdf
