// Internal: JSON parsing with a nesting limit checked first and repeated keys refused (not
// installed).
#pragma once

#include <nlohmann/json.hpp>

#include <cstddef>
#include <set>
#include <string>
#include <vector>

#include "planesdf/error.hpp"

namespace planesdf::detail {

/// Deepest nesting any planesdf JSON file needs is 4 (scene objects); this leaves room for
/// hand-written files while keeping nlohmann's recursive dump (error messages) off a deep stack.
inline constexpr int kMaxJsonDepth = 64;

/// Throws Error(name, ...) when arrays and objects nest deeper than kMaxJsonDepth. Brackets in
/// strings do not count; malformed texts are left to the parser.
inline void checkJsonDepth(const std::string& text, const std::string& name) {
  int depth = 0;
  bool in_string = false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      if (c == '\\')
        ++i;
      else if (c == '"')
        in_string = false;
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > kMaxJsonDepth)
        throw Error(name, "JSON nests deeper than " + std::to_string(kMaxJsonDepth) +
                              " levels (at byte " + std::to_string(i) + ")");
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
}

/// Parses a JSON text after checkJsonDepth. Throws Error(name, ...) when it is not JSON or when
/// an object has a key twice (nlohmann would keep the last one silently).
inline nlohmann::json parseJson(const std::string& text, const std::string& name) {
  checkJsonDepth(text, name);
  using Event = nlohmann::json::parse_event_t;
  std::vector<std::set<std::string>> keys;  // per open object, the keys seen so far
  std::string repeated;
  const auto note = [&](int, Event event, nlohmann::json& parsed) {
    if (event == Event::object_start) keys.emplace_back();
    if (event == Event::object_end) keys.pop_back();
    if (event == Event::key && !keys.back().insert(parsed.get<std::string>()).second &&
        repeated.empty())
      repeated = parsed.get<std::string>();
    return true;
  };
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text, note);
  } catch (const nlohmann::json::exception& e) {
    // parse_error, and out_of_range for a number beyond double (e.g. 1e400).
    throw Error(name, std::string("invalid JSON: ") + e.what());
  }
  if (!repeated.empty()) throw Error(name, "key '" + repeated + "' appears twice in one object");
  return j;
}

}  // namespace planesdf::detail
