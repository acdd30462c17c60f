#pragma once
// Counts heap allocations made by this process (global operator new in every form, and malloc,
// calloc, realloc where the build allows replacing them), to prove "zero allocations per frame".
//
//   octofuse::test::AllocationScope scope;   // starts counting at zero
//   run_frames();
//   REQUIRE(scope.allocations() == 0);

#include <cstddef>
#include <cstdint>

namespace octofuse::test {

std::uint64_t allocation_count();         // since process start, all threads
std::uint64_t allocated_bytes();          // since process start, all threads
std::uint64_t thread_allocation_count();  // since this thread started, this thread only
bool counts_malloc();                     // false under sanitizers, which own malloc

class AllocationScope {
 public:
  AllocationScope()
      : start_count_(allocation_count()),
        start_bytes_(allocated_bytes()),
        start_thread_count_(thread_allocation_count()) {}
  std::uint64_t allocations() const { return allocation_count() - start_count_; }
  // Those made by the thread that is asking (the scope's own thread).
  std::uint64_t thread_allocations() const {
    return thread_allocation_count() - start_thread_count_;
  }
  std::uint64_t bytes() const { return allocated_bytes() - start_bytes_; }

 private:
  std::uint64_t start_count_;
  std::uint64_t start_bytes_;
  std::uint64_t start_thread_count_;
};

}  // namespace octofuse::test
