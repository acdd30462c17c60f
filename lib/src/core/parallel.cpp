#include "octofuse/core/parallel.hpp"

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <thread>

#include "octofuse/core/check.hpp"

namespace octofuse {

namespace {

// std::mutex::lock() refers to std::__throw_system_error, which the no-exceptions rule keeps out
// of lib/. The pool's mutex guards a few loads and stores only, so taking it by try_lock is as
// good; the long waits are on the condition variables, which block.
std::unique_lock<std::mutex> take(std::mutex& mutex) {
  while (!mutex.try_lock()) std::this_thread::yield();
  return std::unique_lock<std::mutex>(mutex, std::adopt_lock);
}

// Yields (not spins) this many times before blocking: back-to-back jobs in a frame find the
// workers awake, while an idle team leaves the cores to other programs on them.
constexpr int kYieldsBeforeBlocking = 64;

constexpr int kMaxHelpers = 63;  // --threads is at most 64

// The process's helper threads, shared by every WorkerTeam. Started by the first team that needs
// them (at init), they block on a condition variable between jobs, so an idle team takes no CPU
// from the drivers and flight stack that share a board's cores (OpenMP's default spin-waiting
// did, unless OMP_WAIT_POLICY=passive was set). One job at a time: a team that finds the pool
// busy (a pipeline on another thread, a run() inside a task) runs its tasks inline, which gives
// the same results because tasks never touch each other's outputs.
class Pool {
 public:
  static Pool& instance() {
    static Pool pool;
    return pool;
  }

  Pool(const Pool&) = delete;
  Pool& operator=(const Pool&) = delete;

  ~Pool() {
    {
      auto lock = take(mutex_);
      stop_ = true;
    }
    work_.notify_all();
    for (int i = 0; i < helper_count_; ++i) threads_[i].join();
  }

  // Grows the pool to at least `helpers` threads (capped at kMaxHelpers).
  void reserve(int helpers) {
    if (helpers > kMaxHelpers) helpers = kMaxHelpers;
    auto lock = take(mutex_);
    while (helper_count_ < helpers) {
      const int index = helper_count_++;
      threads_[index] = std::thread([this, index] { helper_loop(index); });
    }
  }

  // Runs the job with up to `helpers` pool threads beside the caller; false when the pool is busy
  // with another job (the caller then runs the tasks itself). Adds the caller's wait for helpers,
  // read on `clock`, to `wait_us`.
  bool try_run(int helpers, std::size_t task_count, void (*fn)(std::size_t, void*), void* context,
               const Clock& clock, std::int64_t& wait_us) {
    if (busy_.exchange(true, std::memory_order_acquire)) return false;
    {
      auto lock = take(mutex_);
      fn_ = fn;
      context_ = context;
      task_count_ = task_count;
      helpers_ = helpers;
      done_.store(0, std::memory_order_relaxed);
      ++generation_;
      next_.store(generation_ << 32, std::memory_order_release);
      announced_.store(generation_, std::memory_order_release);
    }
    work_.notify_all();
    const std::uint64_t generation = generation_;
    work_on(generation, task_count, fn, context);
    if (!all_done(task_count)) {
      // Helpers still hold claimed tasks: the caller waits, and the wait is measured.
      const std::int64_t wait_start_us = clock.now();
      for (int i = 0; i < kYieldsBeforeBlocking && !all_done(task_count); ++i) {
        std::this_thread::yield();
      }
      if (!all_done(task_count)) {
        auto lock = take(mutex_);
        finished_.wait(lock, [&] { return all_done(task_count); });
      }
      wait_us += clock.now() - wait_start_us;
    }
    busy_.store(false, std::memory_order_release);
    return true;
  }

 private:
  Pool() = default;

  bool all_done(std::size_t task_count) const {
    return done_.load(std::memory_order_acquire) == task_count;
  }

  // Claims tasks of job `generation` until none is left. The generation sits in the high half of
  // the claim counter, so a helper that read a job late cannot claim a task of the next one.
  void work_on(std::uint64_t generation, std::size_t task_count, void (*fn)(std::size_t, void*),
               void* context) {
    for (;;) {
      std::uint64_t claim = next_.load(std::memory_order_acquire);
      std::uint64_t task = 0;
      do {
        task = claim & 0xFFFFFFFFu;
        if ((claim >> 32) != (generation & 0xFFFFFFFFu) || task >= task_count) return;
      } while (!next_.compare_exchange_weak(claim, claim + 1, std::memory_order_acq_rel,
                                            std::memory_order_acquire));
      fn(static_cast<std::size_t>(task), context);
      if (done_.fetch_add(1, std::memory_order_acq_rel) + 1 == task_count) {
        // Taking the mutex orders this notify after the caller's check in finished_.wait.
        { auto lock = take(mutex_); }
        finished_.notify_all();
      }
    }
  }

  void helper_loop(int index) {
    std::uint64_t seen = announced_.load(std::memory_order_acquire);
    for (;;) {
      for (int i = 0;
           i < kYieldsBeforeBlocking && announced_.load(std::memory_order_acquire) == seen; ++i) {
        std::this_thread::yield();
      }
      std::uint64_t generation = 0;
      std::size_t task_count = 0;
      void (*fn)(std::size_t, void*) = nullptr;
      void* context = nullptr;
      {
        auto lock = take(mutex_);
        work_.wait(lock, [&] { return stop_ || generation_ != seen; });
        if (stop_) return;
        seen = generation = generation_;
        if (index >= helpers_) continue;  // this job asked for fewer helpers
        task_count = task_count_;
        fn = fn_;
        context = context_;
      }
      work_on(generation, task_count, fn, context);
    }
  }

  std::mutex mutex_;
  std::condition_variable work_;      // a new job or stop
  std::condition_variable finished_;  // the last task of a job is done
  std::thread threads_[kMaxHelpers];
  int helper_count_ = 0;
  bool stop_ = false;
  // The current job, written under mutex_.
  std::uint64_t generation_ = 0;
  void (*fn_)(std::size_t, void*) = nullptr;
  void* context_ = nullptr;
  std::size_t task_count_ = 0;
  int helpers_ = 0;
  std::atomic<std::uint64_t> announced_{0};  // generation_, readable without the mutex
  std::atomic<std::uint64_t> next_{0};       // generation << 32 | next unclaimed task
  std::atomic<std::size_t> done_{0};         // tasks of the current job finished
  std::atomic<bool> busy_{false};
};

}  // namespace

WorkerTeam::WorkerTeam(int workers) : workers_(workers) {
  OCTOFUSE_CHECK(workers >= 1);
  // Thread creation is an init cost, never a per-frame one.
  if (workers_ > 1) Pool::instance().reserve(workers_ - 1);
}

void WorkerTeam::run(std::size_t task_count, void (*fn)(std::size_t, void*), void* context) const {
  OCTOFUSE_CHECK(static_cast<std::uint64_t>(task_count) < (std::uint64_t{1} << 32));
  if (workers_ > 1 && task_count > 1 &&
      Pool::instance().try_run(workers_ - 1, task_count, fn, context, clock_, helper_wait_us_)) {
    return;
  }
  for (std::size_t task = 0; task < task_count; ++task) fn(task, context);
}

}  // namespace octofuse
