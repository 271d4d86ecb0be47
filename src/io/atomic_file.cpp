#include "planesdf/io/atomic_file.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>

#include <array>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <ostream>
#include <random>
#include <streambuf>
#include <system_error>

#include "atomic_file_internal.hpp"
#include "planesdf/error.hpp"

namespace planesdf::io {
namespace fs = std::filesystem;
namespace {

std::string lastError() {
  return std::strerror(errno);
}

// A buffered output stream over a file descriptor (std::ofstream cannot write to an O_TMPFILE).
class FdBuf : public std::streambuf {
 public:
  explicit FdBuf(int fd) : fd_(fd) { setp(buf_.data(), buf_.data() + buf_.size()); }

 protected:
  int_type overflow(int_type c) override {
    if (sync() != 0) return traits_type::eof();
    if (traits_type::eq_int_type(c, traits_type::eof())) return traits_type::not_eof(c);
    *pptr() = traits_type::to_char_type(c);
    pbump(1);
    return c;
  }
  int sync() override {
    for (const char* p = pbase(); p < pptr();) {
      const ssize_t n = ::write(fd_, p, static_cast<std::size_t>(pptr() - p));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return -1;
      p += n;
    }
    setp(buf_.data(), buf_.data() + buf_.size());
    return 0;
  }

 private:
  int fd_;
  std::array<char, 1 << 16> buf_{};
};

// Owns a file descriptor; close() reports the error a deferred write may only show there.
struct Fd {
  int fd = -1;
  Fd() = default;
  Fd(Fd&& o) noexcept : fd(o.fd) { o.fd = -1; }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
  bool close() {
    const int r = ::close(fd);
    fd = -1;
    return r == 0;
  }
};

// Six random letters or digits, the unique part of temporary names.
std::string randomSuffix() {
  static const char kChars[] = "abcdefghijklmnopqrstuvwxyz0123456789";
  thread_local std::mt19937 rng{std::random_device{}()};
  std::string suffix(6, 'x');
  for (char& c : suffix) c = kChars[rng() % (sizeof(kChars) - 1)];
  return suffix;
}

// `dir/.NAME.tmpXXXXXX`.
fs::path temporaryName(const fs::path& dir, const fs::path& target) {
  return dir / ("." + target.filename().string() + ".tmp" + randomSuffix());
}

// An unnamed file in `dir`, or -1 when the file system (or a missing /proc) cannot link it later.
int openAnonymous(const fs::path& dir) {
#ifdef O_TMPFILE
  if (::access("/proc/self/fd", X_OK) != 0) return -1;
  const int fd = ::open(dir.c_str(), O_TMPFILE | O_WRONLY | O_CLOEXEC, 0666);
  // Locked before it gets a name, so removeFileLeftovers never takes a file being written.
  if (fd >= 0 && ::flock(fd, LOCK_EX) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
#else
  (void)dir;
  return -1;
#endif
}

// Creates a new named temporary file beside `target`; returns its name.
fs::path createNamed(const fs::path& dir, const fs::path& target, Fd& fd, const std::string& path) {
  for (int attempt = 0; attempt < 100; ++attempt) {
    const fs::path tmp = temporaryName(dir, target);
    fd.fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd.fd < 0 && errno != EEXIST) break;
    if (fd.fd < 0) continue;
    // Locked before anything is written; another run's removeFileLeftovers may have taken the
    // name in the instant before the lock, then the file is gone and a new name is tried.
    struct stat st {};
    if (::flock(fd.fd, LOCK_EX) == 0 && ::fstat(fd.fd, &st) == 0 && st.st_nlink > 0) return tmp;
    fd.close();
  }
  throw Error(path, "cannot create temporary file: " + lastError());
}

// Links the unnamed file `fd` as `target` when no file of that name exists (errno on failure).
bool linkAs(int fd, const fs::path& target) {
  const std::string self = "/proc/self/fd/" + std::to_string(fd);
  return ::linkat(AT_FDCWD, self.c_str(), AT_FDCWD, target.c_str(), AT_SYMLINK_FOLLOW) == 0;
}

// Gives the unnamed file `fd` a new temporary name beside `target`; returns the name.
fs::path linkNamed(int fd, const fs::path& dir, const fs::path& target, const std::string& path) {
  for (int attempt = 0; attempt < 100; ++attempt) {
    const fs::path tmp = temporaryName(dir, target);
    if (linkAs(fd, tmp)) return tmp;
    if (errno != EEXIST) break;
  }
  throw Error(path, "cannot link the temporary file into the folder: " + lastError());
}

void writeThrough(int fd, const std::function<void(std::ostream&)>& write,
                  const std::string& path) {
  FdBuf buf(fd);
  std::ostream out(&buf);
  write(out);
  out.flush();
  if (!out) throw Error(path, "write failed: " + lastError());
}

// Locks folder `p` (flock on an open descriptor): a killed holder releases it with its process.
Fd lockFolder(const fs::path& p, int how) {
  Fd fd;
  fd.fd = ::open(p.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd.fd >= 0 && ::flock(fd.fd, how) != 0) fd.close();
  return fd;
}

// True for `NAME.tmpXXXXXX`, the sibling folders replaceFolderAtomic makes for `NAME`.
bool isTemporarySibling(const std::string& entry, const std::string& name) {
  const std::string prefix = name + ".tmp";
  return entry.size() == prefix.size() + 6 && entry.compare(0, prefix.size(), prefix) == 0;
}

// Removes the temporary siblings of `dir` that no running process holds (killed runs' leftovers).
void removeLeftovers(const fs::path& dir) {
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir.parent_path(), ec)) {
    if (!isTemporarySibling(e.path().filename().string(), dir.filename().string())) continue;
    if (!e.is_directory(ec) || e.is_symlink(ec)) continue;
    Fd lock = lockFolder(e.path(), LOCK_EX | LOCK_NB);
    if (lock.fd >= 0) fs::remove_all(e.path(), ec);
  }
}

// True for `.NAME.tmpXXXXXX`, the temporary names writeFileAtomic gives files for `NAME`.
bool isTemporaryFile(const std::string& entry, const std::string& name) {
  return entry.size() > 1 && entry[0] == '.' && isTemporarySibling(entry.substr(1), name);
}

// Removes the temporary files of `target` that no running writer holds locked: a process killed
// between naming its finished file and renaming it over `target` leaves one.
void removeFileLeftovers(const fs::path& dir, const fs::path& target) {
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    if (!isTemporaryFile(e.path().filename().string(), target.filename().string())) continue;
    if (!e.is_regular_file(ec) || e.is_symlink(ec)) continue;
    Fd fd;
    fd.fd = ::open(e.path().c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
    if (fd.fd >= 0 && ::flock(fd.fd, LOCK_EX | LOCK_NB) == 0) ::unlink(e.path().c_str());
  }
}

// A fresh empty sibling folder `dir.tmpXXXXXX` (permissions as for any new folder).
fs::path makeTemporarySibling(const fs::path& dir) {
  for (int attempt = 0; attempt < 100; ++attempt) {
    const fs::path p = dir.parent_path() / (dir.filename().string() + ".tmp" + randomSuffix());
    if (::mkdir(p.c_str(), 0777) == 0) return p;
    if (errno != EEXIST) break;
  }
  throw Error(dir.string(), "cannot create a temporary folder beside it: " + lastError());
}

// Puts folder `fresh` in the place of the existing folder `dir`; returns where the old one is.
fs::path swapIn(const fs::path& fresh, const fs::path& dir) {
  if (::renameat2(AT_FDCWD, fresh.c_str(), AT_FDCWD, dir.c_str(), RENAME_EXCHANGE) == 0)
    return fresh;
  if (errno != EINVAL && errno != ENOSYS && errno != ENOTSUP)
    throw Error(dir.string(), "cannot swap the new folder in: " + lastError());
  // No atomic exchange on this file system: move the old folder away, then the new one in.
  const fs::path old = makeTemporarySibling(dir);
  if (::rename(dir.c_str(), old.c_str()) != 0) {
    const std::string why = lastError();
    ::rmdir(old.c_str());
    throw Error(dir.string(), "cannot move the old folder away: " + why);
  }
  if (::rename(fresh.c_str(), dir.c_str()) != 0) {
    const std::string why = lastError();
    ::rename(old.c_str(), dir.c_str());  // put the old folder back
    throw Error(dir.string(), "cannot move the new folder in: " + why);
  }
  return old;
}

// `dir` made absolute, without a trailing separator, and through symbolic links when it exists.
fs::path folderTarget(const std::string& dir) {
  if (dir.empty()) throw Error(dir, "the output folder name is empty");
  fs::path p = fs::absolute(dir).lexically_normal();
  if (!p.has_filename()) p = p.parent_path();
  std::error_code ec;
  if (fs::exists(p, ec)) p = fs::canonical(p, ec);
  if (ec || p == p.root_path()) throw Error(dir, "cannot be replaced as an output folder");
  return p;
}

}  // namespace

void writeFileAtomic(const std::string& path, const std::function<void(std::ostream&)>& write,
                     bool allow_anonymous) {
  const fs::path target(path);
  if (target.filename().empty()) throw Error(path, "output path names no file");
  if (fs::is_directory(target)) throw Error(path, "output path is a directory");
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw Error(path, "output folder '" + dir.string() + "' does not exist");

  // The file gets a name only once complete. A new file is linked under its own name, so a
  // killed process leaves nothing; a replacement is linked under a temporary name and renamed
  // over the target, and the next replacement removes what a run killed in between left.
  Fd fd;
  fs::path tmp;
  if (allow_anonymous) fd.fd = openAnonymous(dir);
  if (fd.fd < 0) {
    removeFileLeftovers(dir, target);
    tmp = createNamed(dir, target, fd, path);
  }
  try {
    writeThrough(fd.fd, write, path);
    if (tmp.empty() && linkAs(fd.fd, target)) {
      if (fd.close()) return;
      const std::string why = lastError();
      ::unlink(target.c_str());
      throw Error(path, "write failed: " + why);
    }
    if (tmp.empty()) {
      removeFileLeftovers(dir, target);
      tmp = linkNamed(fd.fd, dir, target, path);
    }
    if (!fd.close()) throw Error(path, "write failed: " + lastError());
    if (::rename(tmp.c_str(), target.c_str()) != 0)
      throw Error(path, "cannot rename temporary file into place: " + lastError());
  } catch (...) {
    if (!tmp.empty()) ::unlink(tmp.c_str());
    throw;
  }
}

void writeFileAtomic(const std::string& path, const std::function<void(std::ostream&)>& write) {
  writeFileAtomic(path, write, true);
}
void replaceFolderAtomic(const std::string& dir,
                         const std::function<void(const std::string&)>& build,
                         const std::function<bool(const std::string&)>& replaceable) {
  const fs::path target = folderTarget(dir);
  std::error_code ec;
  const bool exists = fs::exists(target, ec);
  if (exists && !fs::is_directory(target, ec)) throw Error(dir, "exists and is not a folder");
  if (exists && !replaceable(target.string()))
    throw Error(dir,
                "holds files that are not outputs of this command; give a new or empty folder");
  fs::create_directories(target.parent_path(), ec);
  if (ec) throw Error(dir, "cannot create the parent folder: " + ec.message());
  removeLeftovers(target);

  const fs::path fresh = makeTemporarySibling(target);
  const Fd lock = lockFolder(fresh, LOCK_EX);  // keeps other runs' removeLeftovers away
  try {
    build(fresh.string());
    if (!exists && ::rename(fresh.c_str(), target.c_str()) != 0)
      throw Error(dir, "cannot move the new folder in: " + lastError());
    if (exists) fs::remove_all(swapIn(fresh, target), ec);
  } catch (...) {
    fs::remove_all(fresh, ec);
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
