// The library's parallel loops: a blocking worker pool per calling thread (parallel.hpp).
#include "parallel.hpp"

#include <sched.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <mutex>
#include <system_error>
#include <thread>
#include <vector>

namespace planesdf::detail {
namespace {

/// A spin-wait hint to the CPU (sched_yield would hand the core to another process).
inline void cpuRelax() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#endif
}

/// How long a caller waits awake for the chunks in progress before it blocks.
constexpr std::chrono::microseconds kCallerSpin{50};

/// True on a pool's workers, and on a caller while it takes part in a loop: a loop started there
/// runs on that thread alone.
thread_local bool tl_in_loop = false;

/// One loop: chunks claimed in order from an atomic counter.
struct Job {
  const ChunkBody* body = nullptr;
  long long n = 0;
  long long grain = 1;
  std::atomic<long long> next{0};
  std::atomic<bool> failed{false};
  std::mutex error_mutex;
  std::exception_ptr error;

  /// Claims and runs chunks as `worker` until none are left or one has thrown.
  void work(int worker) {
    for (;;) {
      const long long begin = next.fetch_add(grain, std::memory_order_relaxed);
      if (begin >= n || failed.load(std::memory_order_relaxed)) return;
      try {
        (*body)(worker, begin, std::min(n, begin + grain));
      } catch (...) {
        const std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
        failed.store(true, std::memory_order_relaxed);
      }
    }
  }
};

/// Worker threads of one calling thread. A loop publishes its job and wakes them; each joins
/// while the job is open. The caller works too, then closes the job and waits only for the
/// workers inside a chunk: a worker the scheduler has not run yet is not waited for.
class Pool {
 public:
  Pool() = default;
  Pool(const Pool&) = delete;
  Pool& operator=(const Pool&) = delete;
  ~Pool() {
    if (getpid() != owner_) {  // a forked child: the workers live in the parent only
      new std::vector<std::thread>(std::move(threads_));  // neither joinable nor joined here
      return;
    }
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    for (std::thread& t : threads_) t.join();
  }

  /// Runs `job` on the calling thread and up to `helpers` workers.
  void run(Job& job, int helpers) {
    if (getpid() != owner_) helpers = 0;  // a forked child: run it here
    grow(helpers);
    helpers = std::min(helpers, static_cast<int>(threads_.size()));
    if (helpers > 0) {
      {
        const std::lock_guard<std::mutex> lock(mutex_);
        job_ = &job;
        wanted_ = helpers;
        ++generation_;
      }
      wake_.notify_all();
    }
    job.work(0);
    if (helpers == 0) return;
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      job_ = nullptr;
    }
    // The chunks in progress usually end within microseconds: wait for them awake for a short
    // bounded time, since a caller that sleeps gives its core to the host's other threads and
    // may wait a time slice for it back; then block.
    const auto until = std::chrono::steady_clock::now() + kCallerSpin;
    while (active_.load(std::memory_order_acquire) != 0 && std::chrono::steady_clock::now() < until)
      cpuRelax();
    std::unique_lock<std::mutex> lock(mutex_);
    done_.wait(lock, [&] { return active_.load(std::memory_order_acquire) == 0; });
  }

 private:
  /// Starts workers up to `helpers`; a thread the system refuses leaves the loop fewer.
  void grow(int helpers) {
    while (static_cast<int>(threads_.size()) < helpers) {
      try {
        const int index = static_cast<int>(threads_.size());
        threads_.emplace_back([this, index] { loop(index); });
      } catch (const std::system_error&) {
        return;
      }
    }
  }

  void loop(int index) {
    tl_in_loop = true;
    std::uint64_t seen = 0;
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
      if (job_ == nullptr || index >= wanted_) continue;
      Job* job = job_;
      active_.fetch_add(1, std::memory_order_relaxed);
      lock.unlock();
      job->work(index + 1);
      lock.lock();
      if (active_.fetch_sub(1, std::memory_order_release) == 1) done_.notify_one();
    }
  }

  const pid_t owner_ = getpid();
  std::mutex mutex_;
  std::condition_variable wake_;  // a new job, or stop
  std::condition_variable done_;  // the last active worker left its job
  std::vector<std::thread> threads_;
  Job* job_ = nullptr;  // the open job, if any
  std::uint64_t generation_ = 0;
  int wanted_ = 0;              // workers 0..wanted_-1 may join the open job
  std::atomic<int> active_{0};  // workers inside the job (changed under mutex_)
  bool stop_ = false;
};

}  // namespace

int resolveThreads(int requested) {
  if (requested > 0) return requested;
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) return std::max(1, CPU_COUNT(&set));
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

void parallelChunks(long long n, int threads, long long grain, const ChunkBody& body) {
  if (n <= 0) return;
  grain = std::max(1LL, grain);
  const long long chunks = (n + grain - 1) / grain;
  const int helpers = static_cast<int>(std::min<long long>(std::max(threads, 1), chunks)) - 1;
  if (helpers <= 0 || tl_in_loop) {
    for (long long begin = 0; begin < n; begin += grain) body(0, begin, std::min(n, begin + grain));
    return;
  }
  thread_local Pool pool;
  Job job;
  job.body = &body;
  job.n = n;
  job.grain = grain;
  struct InLoop {
    InLoop() { tl_in_loop = true; }
    ~InLoop() { tl_in_loop = false; }
  } in_loop;
  pool.run(job, helpers);
  if (job.error) std::rethrow_exception(job.error);
}

}  // namespace planesdf::detail
