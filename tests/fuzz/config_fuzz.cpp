// Config JSON (`--config FILE`) through parseConfigJson, the in-memory entry of loadConfigJson.
#include "fuzz_support.hpp"
#include "planesdf/config_io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return planesdf::fuzz::expectOnlyPlanesdfErrors(
      [&] { planesdf::parseConfigJson(planesdf::fuzz::bytes(data, size), "fuzz.json"); });
}
