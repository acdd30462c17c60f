// The allocation counter in test/support: later tests rely on it to prove "zero allocations per
// frame", so first prove that it sees every kind of allocation.
#include "support/alloc_counter.hpp"

#include <catch2/catch.hpp>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <new>
#include <thread>
#include <vector>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/fixed_vector.hpp"

namespace octofuse {
namespace {

// Stores through a volatile pointer so the compiler cannot drop a new/delete or malloc/free pair.
void* volatile g_sink = nullptr;

struct alignas(128) OverAligned {
  std::uint8_t bytes[128];
};

TEST_CASE("AllocationScope counts operator new and new[]") {
  const test::AllocationScope scope;
  REQUIRE(scope.allocations() == 0);

  int* one = new int(3);
  g_sink = one;
  delete one;
  REQUIRE(scope.allocations() >= 1);
  const std::uint64_t after_one = scope.allocations();

  double* many = new double[10];
  g_sink = many;
  delete[] many;
  REQUIRE(scope.allocations() >= after_one + 1);
  REQUIRE(scope.bytes() >= sizeof(int) + 10 * sizeof(double));
}

TEST_CASE("AllocationScope tells this thread's allocations from another thread's") {
  const test::AllocationScope scope;
  std::thread other([] {
    int* p = new int(5);
    g_sink = p;
    delete p;
  });
  other.join();  // std::thread's own start-up state is allocated by this thread
  const std::uint64_t mine_before = scope.thread_allocations();
  const std::uint64_t all_before = scope.allocations();
  REQUIRE(all_before >= mine_before + 1);  // the other thread's int at least

  int* mine = new int(7);
  g_sink = mine;
  delete mine;
  REQUIRE(scope.thread_allocations() == mine_before + 1);
  REQUIRE(scope.allocations() == all_before + 1);
}

TEST_CASE("AllocationScope counts over-aligned and nothrow new") {
  const test::AllocationScope scope;
  auto* aligned = new OverAligned;
  g_sink = aligned;
  delete aligned;
  int* quiet = new (std::nothrow) int(1);
  g_sink = quiet;
  delete quiet;
  REQUIRE(scope.allocations() >= 2);
}

TEST_CASE("AllocationScope counts malloc, calloc and realloc where the build allows") {
  if (!test::counts_malloc()) {
    WARN("malloc is owned by the sanitizer runtime in this build; only operator new is counted");
    return;
  }
  // Counts are read before any REQUIRE so the test framework's own work cannot be counted.
  const test::AllocationScope scope;
  void* p = std::malloc(40);
  g_sink = p;
  const std::uint64_t after_malloc = scope.allocations();
  const std::uint64_t bytes_after_malloc = scope.bytes();
  p = std::realloc(p, 80);
  g_sink = p;
  std::free(p);
  void* q = std::calloc(4, 8);
  g_sink = q;
  std::free(q);
  const std::uint64_t total = scope.allocations();
  const std::uint64_t total_bytes = scope.bytes();
  REQUIRE(after_malloc == 1);
  REQUIRE(bytes_after_malloc == 40);
  REQUIRE(total == 3);
  REQUIRE(total_bytes == 40 + 80 + 32);
}

TEST_CASE("Standard containers are seen allocating") {
  const test::AllocationScope scope;
  std::vector<int> v;
  for (int i = 0; i < 100; ++i) v.push_back(i);
  g_sink = v.data();
  REQUIRE(scope.allocations() >= 1);
  auto shared = std::make_shared<int>(5);
  g_sink = shared.get();
  REQUIRE(scope.allocations() >= 2);
}

TEST_CASE("SpanVector and FixedVector push_back do not allocate") {
  alignas(kArenaAlignment) static std::uint8_t buffer[4096];
  LinearArena arena(buffer, sizeof(buffer));
  float* storage = arena.allocate_array<float>(1000).value();

  const test::AllocationScope scope;
  SpanVector<float> span(storage, 1000);
  bool all_pushed = true;
  for (int i = 0; i < 1000; ++i)
    all_pushed = all_pushed && span.push_back(static_cast<float>(i)).ok();
  const Status overflow = span.push_back(0.0f);
  FixedVector<int, 64> fixed;
  for (int i = 0; i < 65; ++i) fixed.push_back(i).ignore();
  const std::uint64_t allocations = scope.allocations();
  const std::uint64_t bytes = scope.bytes();
  REQUIRE(all_pushed);
  REQUIRE(overflow.code() == StatusCode::resource_exhausted);
  REQUIRE(fixed.size() == 64);
  REQUIRE(allocations == 0);
  REQUIRE(bytes == 0);
}

}  // namespace
}  // namespace octofuse
