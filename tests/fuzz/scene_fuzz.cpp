// Scene JSON (`simulate --scene FILE.json`) through parseSceneJson, the in-memory entry of
// loadSceneJson.
#include "fuzz_support.hpp"
#include "planesdf/sim.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return planesdf::fuzz::expectOnlyPlanesdfErrors(
      [&] { planesdf::sim::parseSceneJson(planesdf::fuzz::bytes(data, size), "fuzz.json"); });
}
