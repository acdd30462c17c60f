#pragma once
// A fixed worker team chosen at init. Work is split into a fixed number of tasks that does not
// depend on the worker count, and each task writes only its own outputs, so results are
// bit-identical for 1 or N workers. Reductions go through per-task partials summed in task order.
// Helper threads block between jobs (no spinning on shared cores); 1 worker runs tasks inline.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/clock.hpp"

namespace octofuse {

class WorkerTeam {
 public:
  // `workers` >= 1. Starts the team once (thread creation happens here, not per frame).
  explicit WorkerTeam(int workers = 1);
  int workers() const { return workers_; }

  // Calls fn(task, context) for task in [0, task_count), spread over the workers, and returns
  // when all are done. fn must not touch another task's outputs.
  void run(std::size_t task_count, void (*fn)(std::size_t task, void* context),
           void* context) const;

  // Reads `clock` around the caller's wait for helpers still on their tasks after it has run out
  // of tasks to claim (a helper whose core another program holds keeps its claimed task until it
  // runs again). A null clock, the default, measures nothing.
  void set_clock(Clock clock) { clock_ = clock; }
  // Microseconds the caller has waited so far for helpers, summed over jobs; resets the sum.
  // For the thread that calls run().
  std::int64_t take_helper_wait_us() {
    const std::int64_t wait_us = helper_wait_us_;
    helper_wait_us_ = 0;
    return wait_us;
  }

  template <typename Fn>
  void for_each_task(std::size_t task_count, Fn& fn) const {
    run(
        task_count, [](std::size_t task, void* ctx) { (*static_cast<Fn*>(ctx))(task); }, &fn);
  }

 private:
  int workers_ = 1;
  Clock clock_;
  mutable std::int64_t helper_wait_us_ = 0;
};

// The half-open range of items [begin, end) that task `task` of `task_count` owns when `items`
// are split into contiguous, near-equal chunks.
struct TaskRange {
  std::size_t begin;
  std::size_t end;
};
constexpr TaskRange task_range(std::size_t items, std::size_t task, std::size_t task_count) {
  return TaskRange{items * task / task_count, items * (task + 1) / task_count};
}

}  // namespace octofuse
