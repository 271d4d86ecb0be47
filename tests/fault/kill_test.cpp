// Fault test: `planesdf fuse` and `planesdf detect` killed with SIGKILL at random moments. Each
// output must be the complete old one or the complete new one, and no stray file may remain
// (a killed run's temporary, a hidden `.NAME.tmpXXXXXX` file or detect's build folder
// DIR.tmpXXXXXX, only until the next run into the same output removes it).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "analytic_scene.hpp"
#include "planesdf/io/atomic_file.hpp"
#include "planesdf/io/tum.hpp"
#include "test_support.hpp"

extern char** environ;

namespace {
namespace fs = std::filesystem;
using namespace planesdf;
using Clock = std::chrono::steady_clock;

// Every regular file below `root` (or `root` itself) by relative path, with its bytes.
using Tree = std::map<std::string, std::string>;

Tree readTree(const fs::path& root) {
  Tree tree;
  if (fs::is_regular_file(root)) {
    tree["."] = io::readFile(root.string());
    return tree;
  }
  for (const auto& e : fs::recursive_directory_iterator(root)) {
    const std::string rel = fs::relative(e.path(), root).string();
    if (e.is_regular_file())
      tree[rel] = io::readFile(e.path().string());
    else if (!e.is_directory())
      tree[rel] = "<not a file>";
  }
  return tree;
}

std::vector<std::string> entries(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  return names;
}

struct CliRun {
  bool killed = false;
  double seconds = 0.0;
};

// Runs the CLI with `args`, output discarded; sends SIGKILL after `kill_after` seconds unless it
// has ended. A run that ends by itself must succeed.
CliRun runCli(const std::vector<std::string>& args, double kill_after) {
  std::string cli = test::cliPath();
  std::vector<char*> argv{cli.data()};
  for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 2, "/dev/null", O_WRONLY, 0);
  pid_t pid = 0;
  const auto t0 = Clock::now();
  const int rc = posix_spawn(&pid, cli.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) throw std::runtime_error("cannot start " + cli);
  CliRun run;
  int status = 0;
  while (waitpid(pid, &status, WNOHANG) != pid) {
    run.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    if (run.seconds >= kill_after) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      break;
    }
    usleep(500);
  }
  run.killed = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
  if (!run.killed && !(WIFEXITED(status) && WEXITSTATUS(status) == 0))
    throw std::runtime_error("planesdf " + args.front() + " failed");
  return run;
}

// A session of the tests' tabletop: eight views on a ring, written as a TUM folder.
void writeSession(const std::string& folder, const std::vector<test::Primitive>& objects) {
  const test::AnalyticScene scene = test::tableWith(objects);
  const std::vector<Pose> poses = test::ringPoses({0, 0, test::kTableTop}, 0.9, 0.55, 8);
  std::vector<DepthFrame> frames;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    frames.push_back(test::renderDepth(scene, Intrinsics{}, poses[i]));
    frames.back().timestamp = 1.0 + 0.1 * static_cast<double>(i);
  }
  io::writeTumSequence(folder, frames, poses);
}

// A complete run: its wall time and, for detect, how long it wrote its outputs (both seconds).
struct Complete {
  double seconds = 0.0;
  double output_seconds = 0.0;
};

Complete completeRun(const std::vector<std::string>& args) {
  std::string line;
  for (const std::string& a : args) line += "'" + a + "' ";
  const auto t0 = Clock::now();
  const test::CommandResult r = test::runCli(line);
  if (r.exit_code != 0) throw std::runtime_error(r.out);
  Complete c;
  c.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  const std::size_t at = r.out.find("outputs: ");
  if (at != std::string::npos) c.output_seconds = std::stod(r.out.substr(at + 9)) / 1000.0;
  return c;
}

// Kill moments: uniform over the whole run for half the trials, around the writing of the
// outputs (the last part of the run) for the other half.
double killMoment(std::mt19937& rng, int trial, const Complete& full) {
  const double writing = std::max(1.5 * full.output_seconds, 0.4 * full.seconds);
  const double lo = trial % 2 == 0 ? 0.0 : std::max(0.0, full.seconds - writing);
  return std::uniform_real_distribution<double>(lo, 1.05 * full.seconds)(rng);
}

constexpr int kTrialsPerCommand = 12;

TEST(KillDuringOutput, FuseMapIsOldOrNewAndNoStrayFileRemains) {
  test::TempDir tmp;
  const std::string sessions[2] = {tmp.file("before"), tmp.file("after")};
  writeSession(sessions[0], {test::Primitive::box({0.05, 0.02, 0.75}, {0.15, 0.08, 0.83})});
  writeSession(sessions[1], {test::Primitive::sphere({-0.12, 0.15, 0.80}, 0.05)});
  fs::create_directory(tmp.file("out"));
  const std::string out = tmp.file("out/map.psdf");
  Tree complete[2];
  Complete full;  // the faster of the two runs, so that most trials are killed
  full.seconds = 1e9;
  for (int s = 0; s < 2; ++s) {
    full.seconds = std::min(full.seconds, completeRun({"fuse", sessions[s], "--out", out}).seconds);
    complete[s] = readTree(out);
  }
  ASSERT_NE(complete[0], complete[1]);
  std::mt19937 rng(27);
  int state = 1, killed = 0;  // `out` holds the map of sessions[state]
  for (int trial = 0; trial < kTrialsPerCommand; ++trial) {
    const int next = 1 - state;
    const CliRun run = runCli({"fuse", sessions[next], "--out", out}, killMoment(rng, trial, full));
    killed += run.killed;
    const Tree now = readTree(out);
    ASSERT_TRUE(now == complete[state] || now == complete[next]) << "trial " << trial;
    if (now == complete[next]) state = next;
    // A run killed between naming its finished map and the rename leaves one hidden temporary
    // file; the next run that completes removes it.
    std::vector<std::string> names = entries(tmp.file("out"));
    std::sort(names.begin(), names.end());
    if (run.killed && names.size() == 2 && names[0].rfind(".map.psdf.tmp", 0) == 0)
      names.erase(names.begin());
    ASSERT_EQ(names, std::vector<std::string>{"map.psdf"}) << "trial " << trial;
  }
  std::printf("fuse: %d of %d runs killed\n", killed, kTrialsPerCommand);
  EXPECT_GE(killed, kTrialsPerCommand / 4);
  completeRun({"fuse", sessions[0], "--out", out});
  EXPECT_EQ(entries(tmp.file("out")), std::vector<std::string>{"map.psdf"});
}

TEST(KillDuringOutput, DetectFolderIsOldOrNewAndTheNextRunRemovesTheLeftover) {
  test::TempDir tmp;
  const std::string maps[2] = {tmp.file("before.psdf"), tmp.file("after.psdf")};
  writeSession(tmp.file("before"), {test::Primitive::box({0.05, 0.02, 0.75}, {0.15, 0.08, 0.83})});
  writeSession(tmp.file("after"), {test::Primitive::sphere({-0.12, 0.15, 0.80}, 0.05)});
  completeRun({"fuse", tmp.file("before"), "--out", maps[0]});
  completeRun({"fuse", tmp.file("after"), "--out", maps[1]});
  fs::create_directory(tmp.file("out"));
  const std::string out = tmp.file("out/detect");
  // Outputs of the pair in both orders: reference first (0) or current first (1).
  const auto args = [&](int order) {
    return std::vector<std::string>{"detect", maps[order], maps[1 - order], "--out", out};
  };
  Tree complete[2];
  Complete full;
  full.seconds = 1e9;
  for (int order = 0; order < 2; ++order) {
    const Complete c = completeRun(args(order));
    if (c.seconds < full.seconds) full = c;
    complete[order] = readTree(out);
  }
  std::printf("detect: %.2f s, outputs %.2f s\n", full.seconds, full.output_seconds);
  ASSERT_NE(complete[0], complete[1]);
  std::mt19937 rng(2027);
  int state = 1, killed = 0;
  for (int trial = 0; trial < kTrialsPerCommand; ++trial) {
    const int next = 1 - state;
    const CliRun run = runCli(args(next), killMoment(rng, trial, full));
    killed += run.killed;
    const Tree now = readTree(out);
    ASSERT_TRUE(now == complete[state] || now == complete[next]) << "trial " << trial;
    if (now == complete[next]) state = next;
    // Beside the folder at most the build folders of this and the previous killed run.
    int leftovers = 0;
    for (const std::string& name : entries(tmp.file("out"))) {
      if (name == "detect") continue;
      ASSERT_EQ(name.rfind("detect.tmp", 0), 0u) << name;
      ++leftovers;
    }
    ASSERT_LE(leftovers, 2) << "trial " << trial;
  }
  std::printf("detect: %d of %d runs killed\n", killed, kTrialsPerCommand);
  EXPECT_GE(killed, kTrialsPerCommand / 4);
  completeRun(args(0));
  EXPECT_EQ(readTree(out), complete[0]);
  EXPECT_EQ(entries(tmp.file("out")), std::vector<std::string>{"detect"});
}

}  // namespace
