#include "test_support.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>

namespace planesdf::test {
namespace fs = std::filesystem;

TempDir::TempDir() {
  std::random_device rd;
  for (int attempt = 0; attempt < 100; ++attempt) {
    fs::path p = fs::temp_directory_path() / ("planesdf_test_" + std::to_string(rd()));
    if (fs::create_directory(p)) {
      path_ = p.string();
      return;
    }
  }
  throw std::runtime_error("cannot create a temporary folder");
}

TempDir::~TempDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

std::string sharedDir() {
  if (const char* env = std::getenv("PLANESDF_SHARED_DIR")) return env;
  return PLANESDF_SHARED_DIR;
}

std::string mosdDir() {
  return sharedDir() + "/data/mosd";
}

bool haveMosd() {
  return fs::is_regular_file(mosdDir() + "/pairs.tsv");
}

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("cannot write test fixture " + path);
}

std::string cliPath() {
  if (const char* env = std::getenv("PLANESDF_CLI")) return env;
  return PLANESDF_CLI_PATH;
}

CommandResult runCli(const std::string& args, const std::string& shell_prefix) {
  CommandResult r;
  const std::string cmd = shell_prefix + "'" + cliPath() + "' " + args + " 2>&1";
  FILE* pipe = popen(cmd.c_str(), "r");
  if (!pipe) throw std::runtime_error("popen failed for " + cmd);
  std::array<char, 4096> buf{};
  size_t n = 0;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) r.out.append(buf.data(), n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

}  // namespace planesdf::test
