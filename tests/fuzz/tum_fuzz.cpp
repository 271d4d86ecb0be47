// The TUM RGB-D index files through readTumSequence, which takes a folder: the input is split at
// lines "%%" into depth.txt, groundtruth.txt and intrinsics.txt (rgb.txt has the same
// `timestamp filename` form as depth.txt). A missing part is a missing file. The depth PNGs the
// lists name are not opened by readTumSequence.
#include <filesystem>
#include <vector>

#include "fuzz_support.hpp"
#include "planesdf/io/tum.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace fs = std::filesystem;
  const std::string input = planesdf::fuzz::bytes(data, size);
  std::vector<std::string> parts;
  std::size_t begin = 0;
  while (parts.size() < 2) {
    const std::size_t sep = input.find("\n%%\n", begin);
    if (sep == std::string::npos) break;
    parts.push_back(input.substr(begin, sep - begin + 1));
    begin = sep + 4;
  }
  parts.push_back(input.substr(begin));

  const fs::path folder = fs::path(planesdf::fuzz::scratchFolder()) / "tum";
  static const char* const kFiles[] = {"depth.txt", "groundtruth.txt", "intrinsics.txt"};
  std::error_code ec;
  fs::create_directories(folder, ec);
  for (std::size_t i = 0; i < 3; ++i) {
    const fs::path file = folder / kFiles[i];
    if (i < parts.size())
      planesdf::fuzz::writeScratchFile(file.string(), parts[i]);
    else
      fs::remove(file, ec);
  }
  return planesdf::fuzz::expectOnlyPlanesdfErrors(
      [&] { planesdf::io::readTumSequence(folder.string()); });
}
