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
/// <shared>/data/mosd (it may be missing: tests that read it start with
/// PLANESDF_SKIP_WITHOUT_MOSD(); .ci/run refuses to run without it).
std::string mosdDir();
bool haveMosd();

/// Skips the current test, with a message, when the mOSD data folder is missing.
#define PLANESDF_SKIP_WITHOUT_MOSD()                                           \
  do {                                                                         \
    if (!::planesdf::test::haveMosd())                                         \
      GTEST_SKIP() << "mOSD data not found at " << ::planesdf::test::mosdDir() \
                   << " (set PLANESDF_SHARED_DIR)";                            \
  } while (false)

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
