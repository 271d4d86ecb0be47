// Depth PNGs through readDepthPng (header check, then OpenCV's decoder), which takes a path. The
// intrinsics take the image size from the IHDR chunk when it is at most 256x256, so that mutated
// sizes reach the decoder; other sizes meet 64x48 intrinsics and the header check.
#include "fuzz_support.hpp"
#include "planesdf/io/tum.hpp"

namespace {

std::uint32_t bigEndian32(const std::uint8_t* p) {
  return std::uint32_t{p[0]} << 24 | std::uint32_t{p[1]} << 16 | std::uint32_t{p[2]} << 8 |
         std::uint32_t{p[3]};
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  planesdf::Intrinsics intrinsics;
  intrinsics.width = 64;
  intrinsics.height = 48;
  intrinsics.cx = 31.5;
  intrinsics.cy = 23.5;
  if (size >= 24) {
    const std::uint32_t w = bigEndian32(data + 16);
    const std::uint32_t h = bigEndian32(data + 20);
    if (w >= 1 && w <= 256 && h >= 1 && h <= 256) {
      intrinsics.width = static_cast<int>(w);
      intrinsics.height = static_cast<int>(h);
    }
  }
  static const std::string path = planesdf::fuzz::scratchFolder() + "/depth.png";
  planesdf::fuzz::writeScratchFile(path, planesdf::fuzz::bytes(data, size));
  return planesdf::fuzz::expectOnlyPlanesdfErrors(
      [&] { planesdf::io::readDepthPng(path, intrinsics, 5000.0); });
}
