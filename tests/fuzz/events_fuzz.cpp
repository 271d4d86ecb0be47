// Serialized change events (serializeEvents: what CPlaneChangeMap stores of a detector's state)
// through deserializeEvents. What it accepts serializes to bytes that read back to themselves.
#include "fuzz_support.hpp"
#include "planesdf/change.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string bytes = planesdf::fuzz::bytes(data, size);
  return planesdf::fuzz::expectOnlyPlanesdfErrors([&] {
    const std::string once =
        planesdf::serializeEvents(planesdf::deserializeEvents(bytes, "fuzz.events"));
    if (planesdf::serializeEvents(planesdf::deserializeEvents(once, "fuzz.events")) != once)
      __builtin_trap();
  });
}
