#pragma once
// Typed reading of parsed JSON (parseJson) with errors naming the file and the element: the
// scene files and changes.json read their values through it.

#include <nlohmann/json.hpp>

#include <cmath>
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "planesdf/error.hpp"

namespace planesdf::detail {

/// Reads values of one JSON file, naming the element in errors.
class JsonReader {
 public:
  explicit JsonReader(std::string name) : name_(std::move(name)) {}

  [[noreturn]] void fail(const std::string& element, const std::string& message) const {
    throw Error(name_, element + ": " + message);
  }

  static std::string shown(const nlohmann::json& v) {
    std::string s = v.dump();
    if (s.size() > 40) s = s.substr(0, 40) + "...";
    return s;
  }

  /// Checks that `j` is an object with only `allowed` keys and all `required` keys.
  void object(const nlohmann::json& j, const std::string& element,
              std::initializer_list<const char*> allowed,
              std::initializer_list<const char*> required = {}) const {
    if (!j.is_object()) fail(element, "expected a JSON object, got " + shown(j));
    for (auto it = j.begin(); it != j.end(); ++it) {
      bool known = false;
      for (const char* k : allowed) known = known || it.key() == k;
      if (!known) {
        std::string list;
        for (const char* k : allowed) list += std::string(list.empty() ? "" : ", ") + k;
        fail(element, "unknown key '" + it.key() + "' (expected " + list + ")");
      }
    }
    for (const char* k : required)
      if (!j.contains(k)) fail(element, std::string("missing key '") + k + "'");
  }

  double number(const nlohmann::json& v, const std::string& element) const {
    if (!v.is_number()) fail(element, "expected a number, got " + shown(v));
    const double x = v.get<double>();
    if (!std::isfinite(x)) fail(element, "expected a finite number, got " + shown(v));
    return x;
  }

  long long integer(const nlohmann::json& v, const std::string& element, long long lo,
                    long long hi) const {
    if (!v.is_number_integer()) fail(element, "expected an integer, got " + shown(v));
    if (v.is_number_unsigned() && v.get<unsigned long long>() > static_cast<unsigned long long>(hi))
      fail(element,
           "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + shown(v));
    const long long x = v.get<long long>();
    if (x < lo || x > hi)
      fail(element,
           "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + shown(v));
    return x;
  }

  int integer(const nlohmann::json& v, const std::string& element) const {
    return static_cast<int>(integer(v, element, -1000000000LL, 1000000000LL));
  }

  bool boolean(const nlohmann::json& v, const std::string& element) const {
    if (!v.is_boolean()) fail(element, "expected true or false, got " + shown(v));
    return v.get<bool>();
  }

  std::string string(const nlohmann::json& v, const std::string& element) const {
    if (!v.is_string()) fail(element, "expected a string, got " + shown(v));
    return v.get<std::string>();
  }

  template <int N>
  Eigen::Matrix<double, N, 1> vector(const nlohmann::json& v, const std::string& element) const {
    if (!v.is_array() || v.size() != N)
      fail(element, "expected an array of " + std::to_string(N) + " numbers, got " + shown(v));
    Eigen::Matrix<double, N, 1> out;
    for (int i = 0; i < N; ++i)
      out[i] = number(v[static_cast<std::size_t>(i)], element + "[" + std::to_string(i) + "]");
    return out;
  }

  std::vector<int> idList(const nlohmann::json& v, const std::string& element) const {
    if (!v.is_array()) fail(element, "expected an array of object ids, got " + shown(v));
    std::vector<int> out;
    for (std::size_t i = 0; i < v.size(); ++i)
      out.push_back(integer(v[i], element + "[" + std::to_string(i) + "]"));
    return out;
  }

  const nlohmann::json& array(const nlohmann::json& v, const std::string& element) const {
    if (!v.is_array()) fail(element, "expected an array, got " + shown(v));
    return v;
  }

 private:
  std::string name_;
};

}  // namespace planesdf::detail
