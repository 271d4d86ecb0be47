// The library's parallel loops (src/parallel.cpp): coverage, worker indices, errors, nesting,
// and workers that sleep instead of spinning.
#include <gtest/gtest.h>
#include <sched.h>
#include <time.h>

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>

#include "parallel.hpp"

namespace {

using planesdf::detail::parallelChunks;

TEST(ParallelTest, EveryIndexOnceForAnySplit) {
  for (const long long n : {0LL, 1LL, 7LL, 1000LL, 4097LL})
    for (const int threads : {1, 2, 3, 8})
      for (const long long grain : {1LL, 4LL, 1000LL}) {
        std::vector<std::atomic<int>> hits(static_cast<std::size_t>(n));
        parallelChunks(n, threads, grain, [&](int worker, long long begin, long long end) {
          ASSERT_GE(worker, 0);
          ASSERT_LT(worker, threads);
          ASSERT_LE(end - begin, grain);
          for (long long i = begin; i < end; ++i) hits[static_cast<std::size_t>(i)]++;
        });
        for (const auto& h : hits) ASSERT_EQ(h.load(), 1) << n << " " << threads << " " << grain;
      }
}

TEST(ParallelTest, AWorkerIndexRunsOneChunkAtATime) {
  constexpr int kThreads = 4;
  std::atomic<int> busy[kThreads] = {};
  std::atomic<int> overlaps{0};
  parallelChunks(2000, kThreads, 1, [&](int worker, long long, long long) {
    if (busy[worker].fetch_add(1) != 0) overlaps++;
    std::this_thread::yield();
    busy[worker].fetch_sub(1);
  });
  EXPECT_EQ(overlaps.load(), 0);
}

TEST(ParallelTest, UsesTheThreadsAskedFor) {
  // Chunks that wait for each other can only finish when two threads run them at once.
  std::atomic<int> arrived{0};
  parallelChunks(2, 2, 1, [&](int, long long, long long) {
    arrived++;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (arrived.load() < 2 && std::chrono::steady_clock::now() < until)
      std::this_thread::yield();
  });
  EXPECT_EQ(arrived.load(), 2);
}

TEST(ParallelTest, TheFirstErrorIsRethrown) {
  try {
    parallelChunks(100, 2, 1, [&](int, long long i, long long) {
      if (i == 3) throw std::runtime_error("chunk 3");
    });
    ADD_FAILURE() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "chunk 3");
  }
  // The pool is usable afterwards.
  std::atomic<int> after{0};
  parallelChunks(100, 2, 1, [&](int, long long, long long) { after++; });
  EXPECT_EQ(after.load(), 100);
}

TEST(ParallelTest, ALoopInsideALoopRunsOnItsThread) {
  std::atomic<int> elsewhere{0}, inner{0};
  parallelChunks(8, 2, 1, [&](int, long long, long long) {
    const std::thread::id me = std::this_thread::get_id();
    parallelChunks(50, 4, 1, [&](int worker, long long, long long) {
      if (std::this_thread::get_id() != me || worker != 0) elsewhere++;
      inner++;
    });
  });
  EXPECT_EQ(inner.load(), 8 * 50);
  EXPECT_EQ(elsewhere.load(), 0);
}

TEST(ParallelTest, ResolvesZeroToTheCpusThisProcessMayUse) {
  cpu_set_t set;
  CPU_ZERO(&set);
  ASSERT_EQ(sched_getaffinity(0, sizeof(set), &set), 0);
  EXPECT_EQ(planesdf::detail::resolveThreads(0), CPU_COUNT(&set));
  EXPECT_EQ(planesdf::detail::resolveThreads(3), 3);
}

double processCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

TEST(ParallelTest, IdleWorkersSleep) {
  // Between loops the workers must not take CPU time: after a loop on 4 threads, 200 ms of
  // sleep on the caller cost the process (nearly) nothing. A spinning worker would add its
  // whole spin; the bound leaves room for a loaded machine's wake-ups.
  std::atomic<long long> sum{0};
  parallelChunks(64, 4, 1, [&](int, long long i, long long) { sum += i; });
  ASSERT_EQ(sum.load(), 64 * 63 / 2);
  const double cpu0 = processCpuSeconds();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  EXPECT_LT(processCpuSeconds() - cpu0, 0.02);
}

TEST(ParallelTest, EachHostThreadHasItsOwnWorkers) {
  // Two host threads run loops at once; each sees all of its indices.
  std::atomic<int> a{0}, b{0};
  std::thread other([&] {
    for (int r = 0; r < 50; ++r)
      parallelChunks(100, 2, 3,
                     [&](int, long long s, long long e) { a += static_cast<int>(e - s); });
  });
  for (int r = 0; r < 50; ++r)
    parallelChunks(100, 2, 3, [&](int, long long s, long long e) { b += static_cast<int>(e - s); });
  other.join();
  EXPECT_EQ(a.load(), 5000);
  EXPECT_EQ(b.load(), 5000);
}

}  // namespace
