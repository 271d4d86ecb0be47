// The LZF decoder of binary_compressed PCD on its own: the first 3 bytes (little endian) are the
// expected decompressed size (below 16 MiB), the rest is the compressed stream.
#include "fuzz_support.hpp"
#include "planesdf/io/pcd.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 3) return 0;
  const std::size_t expected =
      std::size_t{data[0]} | std::size_t{data[1]} << 8 | std::size_t{data[2]} << 16;
  return planesdf::fuzz::expectOnlyPlanesdfErrors([&] {
    planesdf::io::lzfDecompress(reinterpret_cast<const char*>(data + 3), size - 3, expected,
                                "fuzz.lzf");
  });
}
