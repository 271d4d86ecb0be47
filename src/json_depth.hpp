// Internal: a nesting limit checked before nlohmann parses a JSON text (not installed).
#pragma once

#include <cstddef>
#include <string>

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

}  // namespace planesdf::detail
