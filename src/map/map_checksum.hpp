#pragma once
// Internal: the checksums of the .psdf format (map_io.cpp), shared with the fuzz target
// tests/fuzz/psdf_fuzz.cpp, which recomputes them so mutated maps reach the parser.
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace planesdf::detail {

inline constexpr std::uint64_t kFnvOffset = 1469598103934665603ull;
inline constexpr std::uint64_t kFnvPrime = 1099511628211ull;

/// Version 1's checksum: one FNV-1a step per byte, each waiting for the last.
inline std::uint64_t fnv1a(const char* data, std::size_t n) {
  std::uint64_t h = kFnvOffset;
  for (std::size_t i = 0; i < n; ++i) {
    h ^= static_cast<unsigned char>(data[i]);
    h *= kFnvPrime;
  }
  return h;
}

/// Version 2's checksum: FNV-1a steps (xor, then multiply by an odd prime: a bijection of the
/// state) over 8-byte little-endian words in 4 interleaved lanes, so four multiplies are in
/// flight; then the tail bytes and the lanes folded in. Any change of one word changes its
/// lane and so the result.
inline std::uint64_t checksum64(const char* data, std::size_t n) {
  std::uint64_t lane[4] = {kFnvOffset, kFnvOffset ^ 1, kFnvOffset ^ 2, kFnvOffset ^ 3};
  std::size_t i = 0;
  for (; i + 32 <= n; i += 32)
    for (int k = 0; k < 4; ++k) {
      std::uint64_t w;
      std::memcpy(&w, data + i + 8 * k, 8);
      lane[k] = (lane[k] ^ w) * kFnvPrime;
    }
  std::uint64_t h = fnv1a(data + i, n - i) ^ static_cast<std::uint64_t>(n);
  for (const std::uint64_t l : lane) h = (h ^ l) * kFnvPrime;
  return h;
}

}  // namespace planesdf::detail
