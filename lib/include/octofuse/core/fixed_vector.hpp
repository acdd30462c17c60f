#pragma once
// Vectors that never allocate. FixedVector<T, N> stores N elements inline; SpanVector<T> works
// over storage carved from an arena at init (capacity from the config). push_back reports
// resource_exhausted when full instead of growing, dropping or throwing.

#include <cstddef>
#include <new>
#include <type_traits>
#include <utility>

#include "octofuse/core/check.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse {

template <typename T>
class SpanVector {
  static_assert(std::is_trivially_destructible_v<T>, "elements are overwritten, never destroyed");

 public:
  SpanVector() = default;
  SpanVector(T* storage, std::size_t capacity) : data_(storage), capacity_(capacity) {}

  Status push_back(const T& value) {
    if (size_ == capacity_) return StatusCode::resource_exhausted;
    data_[size_++] = value;
    return ok_status();
  }
  void pop_back() {
    OCTOFUSE_CHECK(size_ > 0);
    --size_;
  }
  // Shrinks to `n` (n <= size) or grows to `n` (n <= capacity) with value-initialised elements.
  Status resize(std::size_t n) {
    if (n > capacity_) return StatusCode::resource_exhausted;
    for (std::size_t i = size_; i < n; ++i) data_[i] = T();
    size_ = n;
    return ok_status();
  }
  void clear() { size_ = 0; }

  T& operator[](std::size_t i) {
    OCTOFUSE_CHECK(i < size_);
    return data_[i];
  }
  const T& operator[](std::size_t i) const {
    OCTOFUSE_CHECK(i < size_);
    return data_[i];
  }
  T& back() { return (*this)[size_ - 1]; }

  T* data() { return data_; }
  const T* data() const { return data_; }
  T* begin() { return data_; }
  T* end() { return data_ + size_; }
  const T* begin() const { return data_; }
  const T* end() const { return data_ + size_; }
  std::size_t size() const { return size_; }
  std::size_t capacity() const { return capacity_; }
  bool empty() const { return size_ == 0; }
  bool full() const { return size_ == capacity_; }

 private:
  T* data_ = nullptr;
  std::size_t capacity_ = 0;
  std::size_t size_ = 0;
};

template <typename T, std::size_t N>
class FixedVector {
  static_assert(std::is_trivially_destructible_v<T>, "elements are overwritten, never destroyed");

 public:
  FixedVector() = default;
  FixedVector(const FixedVector& other) { *this = other; }
  FixedVector& operator=(const FixedVector& other) {
    size_ = other.size_;
    for (std::size_t i = 0; i < size_; ++i) storage_[i] = other.storage_[i];
    return *this;
  }

  Status push_back(const T& value) {
    if (size_ == N) return StatusCode::resource_exhausted;
    storage_[size_++] = value;
    return ok_status();
  }
  void pop_back() {
    OCTOFUSE_CHECK(size_ > 0);
    --size_;
  }
  void clear() { size_ = 0; }
  Status resize(std::size_t n) {
    if (n > N) return StatusCode::resource_exhausted;
    for (std::size_t i = size_; i < n; ++i) storage_[i] = T();
    size_ = n;
    return ok_status();
  }

  T& operator[](std::size_t i) {
    OCTOFUSE_CHECK(i < size_);
    return storage_[i];
  }
  const T& operator[](std::size_t i) const {
    OCTOFUSE_CHECK(i < size_);
    return storage_[i];
  }
  T& back() { return (*this)[size_ - 1]; }
  T* data() { return storage_; }
  const T* data() const { return storage_; }
  T* begin() { return storage_; }
  T* end() { return storage_ + size_; }
  const T* begin() const { return storage_; }
  const T* end() const { return storage_ + size_; }
  std::size_t size() const { return size_; }
  static constexpr std::size_t capacity() { return N; }
  bool empty() const { return size_ == 0; }
  bool full() const { return size_ == N; }

 private:
  T storage_[N] = {};
  std::size_t size_ = 0;
};

}  // namespace octofuse
