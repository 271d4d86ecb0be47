// PCD (DATA ascii, binary and binary_compressed with LZF) through parsePcd, the in-memory entry
// of readPcd.
#include "fuzz_support.hpp"
#include "planesdf/io/pcd.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return planesdf::fuzz::expectOnlyPlanesdfErrors(
      [&] { planesdf::io::parsePcd(planesdf::fuzz::bytes(data, size), "fuzz.pcd"); });
}
