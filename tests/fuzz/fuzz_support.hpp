// Shared by the libFuzzer targets: each target feeds the fuzz bytes to one public parser and
// accepts planesdf::Error, the library's error for bad input. Any other exception escapes
// LLVMFuzzerTestOneInput and libFuzzer reports it (abort) like a crash or a sanitizer report.
#pragma once

#include <stdlib.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "planesdf/error.hpp"

namespace planesdf::fuzz {

inline std::string bytes(const std::uint8_t* data, std::size_t size) {
  return std::string(reinterpret_cast<const char*>(data), size);
}

/// Runs `parse` and swallows planesdf::Error only.
template <class F>
int expectOnlyPlanesdfErrors(F&& parse) {
  try {
    parse();
  } catch (const planesdf::Error&) {
    // Bad input, reported as the library promises.
  }
  return 0;
}

/// A private temporary folder under $TMPDIR (scripts/run-fuzz.sh points it at /dev/shm), made
/// once per process for the parsers that take paths, and removed when the process exits.
inline const std::string& scratchFolder() {
  static const std::string folder = [] {
    const char* tmp = getenv("TMPDIR");
    std::string pattern = std::string(tmp && *tmp ? tmp : "/tmp") + "/planesdf-fuzz-XXXXXX";
    if (!mkdtemp(pattern.data())) abort();
    return pattern;
  }();
  static const bool cleanup_registered = [] {
    return std::atexit([] {
             std::error_code ec;
             std::filesystem::remove_all(folder, ec);
           }) == 0;
  }();
  (void)cleanup_registered;
  return folder;
}

/// Writes `content` to `path` (replacing it).
inline void writeScratchFile(const std::string& path, const std::string& content) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(content.data(), static_cast<std::streamsize>(content.size()));
  if (!out) abort();
}

}  // namespace planesdf::fuzz
