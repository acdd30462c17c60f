#include "octofuse/core/parallel.hpp"

#include <atomic>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
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

TEST_CASE("WorkerTeam needs at least one worker") {
  const auto end = test::run_in_child([](int) { const WorkerTeam team(0); });
  REQUIRE(end.aborted);
  REQUIRE(end.check_text.find("workers >= 1") != std::string::npos);
}

}  // namespace
}  // namespace octofuse
