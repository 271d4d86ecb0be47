// PLY (ascii, binary little and big endian) through parsePly, the in-memory entry of readPly.
#include "fuzz_support.hpp"
#include "planesdf/io/ply.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return planesdf::fuzz::expectOnlyPlanesdfErrors(
      [&] { planesdf::io::parsePly(planesdf::fuzz::bytes(data, size), "fuzz.ply"); });
}
