#pragma once
// A growable array for host-side tools that never involves the exception machinery: std::vector
// growth references std::__throw_length_error / __throw_bad_alloc, which the no-exceptions scan
// of every ports/ library forbids. Running out of memory here is fatal (OCTOFUSE_CHECK), as it
// would be for a host program anyway.

#include <cstddef>
#include <cstdlib>
#include <new>
#include <utility>

#include "octofuse/core/check.hpp"

namespace octofuse::host {

template <typename T>
class HostBuffer {
 public:
  HostBuffer() = default;
  HostBuffer(const HostBuffer&) = delete;
  HostBuffer& operator=(const HostBuffer&) = delete;
  HostBuffer(HostBuffer&& other) noexcept { swap(other); }
  HostBuffer& operator=(HostBuffer&& other) noexcept {
    if (this != &other) {
      HostBuffer dropped;
      swap(other);
      other.swap(dropped);
    }
    return *this;
  }
  ~HostBuffer() {
    clear();
    release(data_);
  }

  void reserve(std::size_t capacity) {
    if (capacity <= capacity_) return;
    // aligned_alloc wants a size that is a multiple of the alignment.
    const std::size_t bytes = (capacity * sizeof(T) + kAlignment - 1) / kAlignment * kAlignment;
    T* fresh = static_cast<T*>(std::aligned_alloc(kAlignment, bytes));
    OCTOFUSE_CHECK(fresh != nullptr);  // out of memory in a host tool
    for (std::size_t i = 0; i < size_; ++i) {
      new (fresh + i) T(std::move(data_[i]));
      data_[i].~T();
    }
    release(data_);
    data_ = fresh;
    capacity_ = capacity;
  }
  void push_back(const T& value) {
    if (size_ == capacity_) grow(size_ + 1);
    new (data_ + size_) T(value);
    ++size_;
  }
  // Grows with value-initialised elements or shrinks.
  void resize(std::size_t size) {
    if (size > capacity_) grow(size);
    for (std::size_t i = size_; i < size; ++i) new (data_ + i) T();
    for (std::size_t i = size; i < size_; ++i) data_[i].~T();
    size_ = size;
  }
  void clear() { resize(0); }

  T& operator[](std::size_t i) { return data_[i]; }
  const T& operator[](std::size_t i) const { return data_[i]; }
  T& back() { return data_[size_ - 1]; }
  T* data() { return data_; }
  const T* data() const { return data_; }
  T* begin() { return data_; }
  T* end() { return data_ + size_; }
  const T* begin() const { return data_; }
  const T* end() const { return data_ + size_; }
  std::size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }

 private:
  void grow(std::size_t at_least) {
    std::size_t capacity = capacity_ < 8 ? 8 : capacity_ * 2;
    if (capacity < at_least) capacity = at_least;
    reserve(capacity);
  }
  static constexpr std::size_t kAlignment = alignof(T) > alignof(std::max_align_t)
                                                ? alignof(T)
                                                : alignof(std::max_align_t);
  static void release(T* data) { std::free(data); }
  void swap(HostBuffer& other) noexcept {
    std::swap(data_, other.data_);
    std::swap(size_, other.size_);
    std::swap(capacity_, other.capacity_);
  }

  T* data_ = nullptr;
  std::size_t size_ = 0;
  std::size_t capacity_ = 0;
};

}  // namespace octofuse::host
