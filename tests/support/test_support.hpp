#pragma once
// Helpers shared by the test suites: temporary folders, paths to ../shared data and the CLI,
// and running the CLI to capture its exit code and output.

#include <string>

namespace planesdf::test {

inline constexpr double kPi = 3.14159265358979323846;

/// A fresh empty folder under the system temp dir, removed on destruction.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }
  std::string file(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

/// The shared data folder (env PLANESDF_SHARED_DIR, else the path configured at build time).
std::string sharedDir();
/// <shared>/data/mosd; the test fails (not skips) when it is missing.
std::string mosdDir();

/// Writes `bytes` to `path` (test fixtures; not atomic).
void writeBytes(const std::string& path, const std::string& bytes);

struct CommandResult {
  int exit_code = -1;
  std::string out;  ///< stdout and stderr, merged
};
/// Path of the built `planesdf` executable.
std::string cliPath();
/// Runs `<shell_prefix>planesdf <args>` through the shell and captures exit code and output
/// (a prefix such as "ulimit -v N; " sets limits for the run).
CommandResult runCli(const std::string& args, const std::string& shell_prefix = "");

}  // namespace planesdf::test
