#pragma once
// IndexPool<T>: a fixed number of slots over arena storage, addressed by 32-bit index (half the
// size of a pointer on aarch64, and stable across a memcpy of the whole pool). allocate() reports
// resource_exhausted when every slot is taken; released slots are reused last-in first-out, so
// the sequence of indices is deterministic for a given sequence of calls.

#include <cstddef>
#include <cstdint>
#include <new>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/check.hpp"
#include "octofuse/core/result.hpp"

namespace octofuse {

template <typename T>
class IndexPool {
 public:
  static constexpr std::uint32_t kInvalidIndex = 0xFFFFFFFFu;

  // Carves storage for `capacity` slots from `arena` (a LinearArena or an ArenaSizer).
  template <typename Arena>
  Status reserve(Arena& arena, std::uint32_t capacity) {
    // Slots are assigned T() in allocate(): leave them untouched so a large pool costs no
    // resident memory until it fills.
    Result<T*> slots = arena.template allocate_array_uninitialized<T>(capacity);
    if (!slots.ok()) return slots.status();
    Result<std::uint32_t*> links = arena.template allocate_array<std::uint32_t>(capacity);
    if (!links.ok()) return links.status();
    slots_ = slots.value();
    free_next_ = links.value();
    capacity_ = capacity;
    reset();
    return ok_status();
  }

  // Forgets every allocation (slots keep their bytes until reallocated).
  void reset() {
    used_ = 0;
    fresh_ = 0;
    free_head_ = kInvalidIndex;
  }

  // A slot, value-initialised, or resource_exhausted (the pool is unchanged then).
  Result<std::uint32_t> allocate() {
    std::uint32_t index;
    if (free_head_ != kInvalidIndex) {
      index = free_head_;
      free_head_ = free_next_[index];
    } else if (fresh_ < capacity_) {
      index = fresh_++;
    } else {
      ++refused_;
      return StatusCode::resource_exhausted;
    }
    ++used_;
    new (&slots_[index]) T();  // starts the slot's lifetime (reserve() constructed nothing)
    return index;
  }

  // Writes the pages of the next `count` slots allocate() will hand out (zeros: allocate()
  // constructs each slot anyway), so the frames that take them pay no first-touch page faults.
  // Those pages become resident; the rest of the pool stays untouched. Allocates nothing.
  void prefault(std::uint32_t count) {
    if (fresh_ >= capacity_ || count == 0) return;
    const std::uint32_t end = capacity_ - fresh_ < count ? capacity_ : fresh_ + count;
    volatile unsigned char* const first = reinterpret_cast<unsigned char*>(slots_ + fresh_);
    const std::size_t bytes = sizeof(T) * static_cast<std::size_t>(end - fresh_);
    // 4 KiB, the smallest page in use: a larger page is only written more than once.
    constexpr std::size_t kStride = 4096;
    for (std::size_t i = 0; i < bytes; i += kStride) first[i] = 0;
    first[bytes - 1] = 0;
  }

  void release(std::uint32_t index) {
    OCTOFUSE_CHECK(index < fresh_ && used_ > 0);
    free_next_[index] = free_head_;
    free_head_ = index;
    --used_;
  }

  // Frees the last slot of a pool that was never released into (so slots [0, used()) are all
  // allocated): callers that keep their slots dense move the last one into a hole, then pop it.
  void pop_back() {
    OCTOFUSE_CHECK(free_head_ == kInvalidIndex && used_ == fresh_ && used_ > 0);
    --used_;
    --fresh_;
  }
  // Index of a slot from its address (which must be one of this pool's slots).
  std::uint32_t index_of(const T* slot) const {
    const std::ptrdiff_t index = slot - slots_;
    OCTOFUSE_CHECK(index >= 0 && static_cast<std::uint64_t>(index) < fresh_);
    return static_cast<std::uint32_t>(index);
  }

  T& operator[](std::uint32_t index) {
    OCTOFUSE_CHECK(index < fresh_);
    return slots_[index];
  }
  const T& operator[](std::uint32_t index) const {
    OCTOFUSE_CHECK(index < fresh_);
    return slots_[index];
  }

  std::uint32_t capacity() const { return capacity_; }
  std::uint32_t used() const { return used_; }
  bool full() const { return used_ == capacity_; }
  // Allocation requests refused because the pool was full, since reserve().
  std::uint64_t refused() const { return refused_; }

 private:
  T* slots_ = nullptr;
  std::uint32_t* free_next_ = nullptr;
  std::uint32_t capacity_ = 0;
  std::uint32_t used_ = 0;
  std::uint32_t fresh_ = 0;  // slots [0, fresh_) have been handed out at least once
  std::uint32_t free_head_ = kInvalidIndex;
  std::uint64_t refused_ = 0;
};

}  // namespace octofuse
