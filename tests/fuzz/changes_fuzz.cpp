// changes.json text (what `planesdf detect` writes) through changesFromJson. What it accepts
// writes (changesToJson) to a text that reads back to itself.
#include "fuzz_support.hpp"
#include "planesdf/change.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text = planesdf::fuzz::bytes(data, size);
  return planesdf::fuzz::expectOnlyPlanesdfErrors([&] {
    const std::string once =
        planesdf::changesToJson(planesdf::changesFromJson(text, "fuzz/changes.json"));
    if (planesdf::changesToJson(planesdf::changesFromJson(once, "fuzz/changes.json")) != once)
      __builtin_trap();
  });
}
