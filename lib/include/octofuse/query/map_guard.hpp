#pragma once
// Orders the mapping thread's writes against queries from other threads (a planner).
//
// A writer-preferring reader/writer guard on one atomic word: bit 31 says a writer holds or wants
// the map, the low bits count readers inside. The writer (Pipeline::process, around the stages
// that change the map) sets the bit, so no new reader enters, and waits until the readers inside
// have left; readers wait while the bit is set. Every query therefore sees the map as it was
// after some whole frame, and the writer waits at most for the longest query already running,
// which MapQuery bounds (QueryLimits::max_visits). Waits spin with std::this_thread::yield: no
// mutex, no allocation, nothing that can throw. One writer at a time.

#include <atomic>
#include <cstdint>
#include <thread>

namespace octofuse {

class MapGuard {
 public:
  void lock_shared() const {
    for (;;) {
      std::uint32_t s = state_.load(std::memory_order_relaxed);
      if ((s & kWriter) == 0 && state_.compare_exchange_weak(s, s + 1, std::memory_order_acquire,
                                                             std::memory_order_relaxed)) {
        return;
      }
      std::this_thread::yield();
    }
  }
  void unlock_shared() const { state_.fetch_sub(1, std::memory_order_release); }

  void lock() const {
    // Announce first: readers arriving from now on wait.
    state_.fetch_or(kWriter, std::memory_order_acquire);
    while ((state_.load(std::memory_order_acquire) & kReaders) != 0) std::this_thread::yield();
  }
  void unlock() const { state_.fetch_and(~kWriter, std::memory_order_release); }

 private:
  static constexpr std::uint32_t kWriter = 0x80000000u;
  static constexpr std::uint32_t kReaders = 0x7FFFFFFFu;
  mutable std::atomic<std::uint32_t> state_{0};
};

// Scoped holds.
class SharedHold {
 public:
  explicit SharedHold(const MapGuard* guard) : guard_(guard) {
    if (guard_ != nullptr) guard_->lock_shared();
  }
  ~SharedHold() {
    if (guard_ != nullptr) guard_->unlock_shared();
  }
  SharedHold(const SharedHold&) = delete;
  SharedHold& operator=(const SharedHold&) = delete;

 private:
  const MapGuard* guard_;
};

class ExclusiveHold {
 public:
  explicit ExclusiveHold(const MapGuard& guard) : guard_(guard) { guard_.lock(); }
  ~ExclusiveHold() { guard_.unlock(); }
  ExclusiveHold(const ExclusiveHold&) = delete;
  ExclusiveHold& operator=(const ExclusiveHold&) = delete;

 private:
  const MapGuard& guard_;
};

}  // namespace octofuse
