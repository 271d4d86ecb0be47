// .psdf maps through Map::deserialize, the in-memory entry of Map::load. Each input is read
// twice: as it is, and with the header's payload size and the trailing checksum recomputed, so
// that mutations of the payload (embedded config, planes, blocks, points) get past the checksum
// and reach the parser (format versions 1 and 2).
#include <cstring>

#include "fuzz_support.hpp"
#include "map/map_checksum.hpp"
#include "planesdf/map.hpp"

namespace {

constexpr std::size_t kHeaderSize = 8 + 4 + 4 + 8;  // magic, version, flags, payload size

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string bytes = planesdf::fuzz::bytes(data, size);
  planesdf::fuzz::expectOnlyPlanesdfErrors([&] { planesdf::Map::deserialize(bytes, "fuzz.psdf"); });
  if (bytes.size() < kHeaderSize + 8) return 0;
  std::uint32_t version = 0;
  std::memcpy(&version, bytes.data() + 8, 4);
  const std::uint64_t payload = bytes.size() - kHeaderSize - 8;
  std::memcpy(&bytes[16], &payload, 8);
  const std::uint64_t sum = version == 1
                                ? planesdf::detail::fnv1a(bytes.data() + kHeaderSize, payload)
                                : planesdf::detail::checksum64(bytes.data() + kHeaderSize, payload);
  std::memcpy(&bytes[bytes.size() - 8], &sum, 8);
  return planesdf::fuzz::expectOnlyPlanesdfErrors(
      [&] { planesdf::Map::deserialize(bytes, "fuzz.psdf"); });
}
