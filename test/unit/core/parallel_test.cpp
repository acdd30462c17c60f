#include "octofuse/core/parallel.hpp"

#include <atomic>
#include <catch2/catch.hpp>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <ctime>
#include <random>
#include <thread>
#include <vector>

#include "death.hpp"

namespace octofuse {
namespace {

TEST_CASE("task_range splits items into contiguous, near-equal, complete chunks") {
  const std::size_t items =
      GENERATE(std::size_t{0}, std::size_t{1}, std::size_t{7}, std::size_t{64}, std::size_t{1001});
  const std::size_t tasks =
      GENERATE(std::size_t{1}, std::size_t{2}, std::size_t{3}, std::size_t{16});
  CAPTURE(items, tasks);
  std::size_t expected_begin = 0;
  for (std::size_t t = 0; t < tasks; ++t) {
    const TaskRange r = task_range(items, t, tasks);
    REQUIRE(r.begin == expected_begin);
    REQUIRE(r.end >= r.begin);
    const std::size_t size = r.end - r.begin;
    REQUIRE(size >= items / tasks);
    REQUIRE(size <= items / tasks + 1);
    expected_begin = r.end;
  }
  REQUIRE(expected_begin == items);
}

TEST_CASE("WorkerTeam runs every task exactly once") {
  const int workers = GENERATE(1, 2);
  const WorkerTeam team(workers);
  REQUIRE(team.workers() == workers);
  std::atomic<int> runs[50];
  for (auto& r : runs) r = 0;
  auto fn = [&runs](std::size_t task) { runs[task].fetch_add(1); };
  team.for_each_task(50, fn);
  for (auto& r : runs) REQUIRE(r.load() == 1);

  int calls = 0;
  auto none = [&calls](std::size_t) { ++calls; };
  team.for_each_task(0, none);
  REQUIRE(calls == 0);
}

// A float reduction whose result depends on summation order: per-task partials summed in task
// order must give bit-identical results for any worker count.
struct Reduction {
  const float* values;
  std::size_t count;
  std::size_t tasks;
  float partial[32];

  void operator()(std::size_t task) {
    const TaskRange r = task_range(count, task, tasks);
    float sum = 0.0f;
    for (std::size_t i = r.begin; i < r.end; ++i) sum += values[i] * values[i];
    partial[task] = sum;
  }
  float total() const {
    float sum = 0.0f;
    for (std::size_t t = 0; t < tasks; ++t) sum += partial[t];
    return sum;
  }
};

float reduce_with(int workers, const std::vector<float>& values, std::size_t tasks) {
  const WorkerTeam team(workers);
  Reduction reduction{values.data(), values.size(), tasks, {}};
  team.for_each_task(tasks, reduction);
  return reduction.total();
}

TEST_CASE("WorkerTeam gives bit-identical results for 1 and 2 workers") {
  std::mt19937 rng(1234);
  std::uniform_real_distribution<float> dist(-1000.0f, 1000.0f);
  std::vector<float> values(100003);
  for (float& v : values) v = dist(rng);

  for (const std::size_t tasks : {std::size_t{1}, std::size_t{7}, std::size_t{32}}) {
    CAPTURE(tasks);
    const float one = reduce_with(1, values, tasks);
    const float two = reduce_with(2, values, tasks);
    REQUIRE(std::memcmp(&one, &two, sizeof(float)) == 0);
    REQUIRE(std::isfinite(one));
  }

  // Per-element outputs written by disjoint tasks match too.
  std::vector<float> out1(values.size()), out2(values.size());
  for (int workers = 1; workers <= 2; ++workers) {
    std::vector<float>& out = workers == 1 ? out1 : out2;
    const WorkerTeam team(workers);
    auto fn = [&](std::size_t task) {
      const TaskRange r = task_range(values.size(), task, 16);
      for (std::size_t i = r.begin; i < r.end; ++i) out[i] = std::sqrt(std::abs(values[i]));
    };
    team.for_each_task(16, fn);
  }
  REQUIRE(std::memcmp(out1.data(), out2.data(), out1.size() * sizeof(float)) == 0);
}

TEST_CASE("WorkerTeam runs thousands of back-to-back jobs of every size exactly once") {
  // Teams of different sizes share the helper threads; each job must see only its own tasks.
  const WorkerTeam teams[] = {WorkerTeam(2), WorkerTeam(3), WorkerTeam(4)};
  std::atomic<int> runs[40];
  for (int job = 0; job < 3000; ++job) {
    const WorkerTeam& team = teams[job % 3];
    const std::size_t tasks = 1 + static_cast<std::size_t>(job % 40);
    for (auto& r : runs) r = 0;
    auto fn = [&runs, job](std::size_t task) { runs[task].fetch_add(1 + job % 5); };
    team.for_each_task(tasks, fn);
    for (std::size_t t = 0; t < 40; ++t) {
      REQUIRE(runs[t].load() == (t < tasks ? 1 + job % 5 : 0));
    }
  }
}

TEST_CASE("WorkerTeam runs a job started inside a task, and jobs from two threads at once") {
  const WorkerTeam team(2);
  std::atomic<int> inner_runs{0};
  auto outer = [&](std::size_t) {
    auto inner = [&](std::size_t) { inner_runs.fetch_add(1); };
    team.for_each_task(5, inner);  // the pool is busy: runs inline
  };
  team.for_each_task(4, outer);
  REQUIRE(inner_runs.load() == 20);

  // Two threads with their own teams: one gets the helpers, the other runs inline; both finish
  // with every task done once.
  std::atomic<int> counts[2] = {{0}, {0}};
  auto worker = [&counts](int which) {
    const WorkerTeam own(2);
    for (int job = 0; job < 500; ++job) {
      auto fn = [&counts, which](std::size_t) { counts[which].fetch_add(1); };
      own.for_each_task(8, fn);
    }
  };
  std::thread a(worker, 0);
  std::thread b(worker, 1);
  a.join();
  b.join();
  REQUIRE(counts[0].load() == 4000);
  REQUIRE(counts[1].load() == 4000);
}

TEST_CASE("WorkerTeam threads that wait for work or for a slow task take no CPU") {
  // A task that sleeps 300 ms leaves the other worker with nothing to do: a waiter that spun
  // through it would burn a core that another program on the board needs; one that blocks does
  // not.
  const WorkerTeam team(2);
  auto warm = [](std::size_t) {};
  team.for_each_task(2, warm);
  const std::clock_t cpu_before = std::clock();
  auto fn = [](std::size_t task) {
    if (task == 0) std::this_thread::sleep_for(std::chrono::milliseconds(300));
  };
  team.for_each_task(2, fn);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // idle between jobs
  const double cpu_s = static_cast<double>(std::clock() - cpu_before) / CLOCKS_PER_SEC;
  CAPTURE(cpu_s);
  REQUIRE(cpu_s < 0.1);  // a waiter spinning through the sleeps would use 0.3 s or more
}

std::int64_t steady_us(void*) {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// Runs small jobs until a helper thread has taken a task: a helper that starts after a job was
// announced waits for the next one.
bool helpers_started(const WorkerTeam& team) {
  const std::thread::id caller = std::this_thread::get_id();
  for (int job = 0; job < 1000; ++job) {
    std::atomic<bool> helper_ran{false};
    auto fn = [&](std::size_t) {
      if (std::this_thread::get_id() != caller) helper_ran = true;
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    };
    team.for_each_task(4, fn);
    if (helper_ran) return true;
  }
  return false;
}

// Two tasks: the one the caller claims holds until a helper has claimed the other, which sleeps
// `helper_sleep`; the caller then runs out of tasks and waits for the late helper.
void run_with_late_helper(const WorkerTeam& team, std::chrono::milliseconds helper_sleep,
                          bool* helper_ran) {
  const std::thread::id caller = std::this_thread::get_id();
  std::atomic<bool> helper_started{false};
  auto fn = [&](std::size_t) {
    if (std::this_thread::get_id() != caller) {
      helper_started = true;
      std::this_thread::sleep_for(helper_sleep);
      return;
    }
    const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (!helper_started && std::chrono::steady_clock::now() < give_up) {
      std::this_thread::yield();
    }
  };
  team.for_each_task(2, fn);
  *helper_ran = helper_started;
}

TEST_CASE("WorkerTeam measures the caller's wait for a late helper on its clock") {
  WorkerTeam team(2);
  team.set_clock(Clock{&steady_us, nullptr});
  REQUIRE(helpers_started(team));
  (void)team.take_helper_wait_us();
  bool helper_ran = false;
  run_with_late_helper(team, std::chrono::milliseconds(200), &helper_ran);
  REQUIRE(helper_ran);
  const std::int64_t wait_us = team.take_helper_wait_us();
  CAPTURE(wait_us);
  // The helper slept 200 ms after the caller saw it start; the caller had nothing left but its
  // own return from task 0, so it waited nearly all of it.
  REQUIRE(wait_us >= 100000);
  REQUIRE(wait_us < 5000000);
  REQUIRE(team.take_helper_wait_us() == 0);  // taken: the sum starts over

  // Without a clock (the default) nothing is measured; one worker never waits.
  WorkerTeam unclocked(2);
  run_with_late_helper(unclocked, std::chrono::milliseconds(20), &helper_ran);
  REQUIRE(helper_ran);
  REQUIRE(unclocked.take_helper_wait_us() == 0);
  WorkerTeam alone(1);
  alone.set_clock(Clock{&steady_us, nullptr});
  int calls = 0;
  auto fn = [&calls](std::size_t) { ++calls; };
  alone.for_each_task(8, fn);
  REQUIRE(calls == 8);
  REQUIRE(alone.take_helper_wait_us() == 0);
}

TEST_CASE("WorkerTeam needs at least one worker") {
  const auto end = test::run_in_child([](int) { const WorkerTeam team(0); });
  REQUIRE(end.aborted);
  REQUIRE(end.check_text.find("workers >= 1") != std::string::npos);
}

}  // namespace
}  // namespace octofuse
