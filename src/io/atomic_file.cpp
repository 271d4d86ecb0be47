#include "planesdf/io/atomic_file.hpp"

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <system_error>

#include "planesdf/error.hpp"

namespace planesdf::io {
namespace fs = std::filesystem;

void writeFileAtomic(const std::string& path, const std::function<void(std::ostream&)>& write) {
  const fs::path target(path);
  if (target.filename().empty()) throw Error(path, "output path names no file");
  if (fs::is_directory(target)) throw Error(path, "output path is a directory");
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw Error(path, "output folder '" + dir.string() + "' does not exist");

  std::random_device rd;
  const fs::path tmp =
      dir / ("." + target.filename().string() + ".tmp" + std::to_string(rd() % 1000000));
  try {
    {
      std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
      if (!out)
        throw Error(path, std::string("cannot create temporary file: ") + std::strerror(errno));
      write(out);
      out.flush();
      if (!out) throw Error(path, "write failed (disk full?)");
    }
    fs::rename(tmp, target, ec);
    if (ec) throw Error(path, "cannot rename temporary file into place: " + ec.message());
  } catch (...) {
    fs::remove(tmp, ec);
    throw;
  }
}

void requireRegularFile(const std::string& path) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (!fs::exists(st)) throw Error(path, "file does not exist");
  if (fs::is_directory(st)) throw Error(path, "is a folder, expected a file");
  if (!fs::is_regular_file(st))
    throw Error(path, "not a regular file (a FIFO, socket or device cannot be read as input)");
}

std::string readFile(const std::string& path) {
  requireRegularFile(path);
  std::error_code ec;
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path, std::string("cannot open: ") + std::strerror(errno));
  // Read into a buffer sized to the file: one allocation, one read.
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec) throw Error(path, "cannot get file size: " + ec.message());
  std::string bytes(static_cast<std::size_t>(size), '\0');
  if (size > 0 && !in.read(bytes.data(), static_cast<std::streamsize>(size)))
    throw Error(path, "read failed after " + std::to_string(in.gcount()) + " of " +
                          std::to_string(size) + " bytes");
  return bytes;
}

}  // namespace planesdf::io
