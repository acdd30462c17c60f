#pragma once
// All memory comes from one buffer given at init. LinearArena hands it out front to back and
// never frees; ArenaSizer runs the same sequence of requests without memory and says how many
// bytes it needs, so `bytes_required(config)` is exact by construction: a component writes one
// `reserve(Allocator&)` template and calls it once with each.

#include <cstddef>
#include <cstdint>
#include <new>
#include <type_traits>

#include "octofuse/core/result.hpp"

namespace octofuse {

// Every arena buffer must start at this alignment; sizes computed by ArenaSizer assume it.
inline constexpr std::size_t kArenaAlignment = 64;

constexpr std::size_t align_up(std::size_t value, std::size_t alignment) {
  return (value + alignment - 1) / alignment * alignment;
}

class LinearArena {
 public:
  LinearArena() = default;
  // `buffer` must be aligned to kArenaAlignment (checked) and outlive everything carved from it.
  LinearArena(void* buffer, std::size_t bytes);

  // `count` value-initialised objects of T, or resource_exhausted when the buffer is too small
  // (nothing is taken then). T must be trivially destructible: the arena never runs destructors.
  template <typename T>
  Result<T*> allocate_array(std::size_t count, std::size_t alignment = alignof(T)) {
    static_assert(std::is_trivially_destructible_v<T>, "arena objects are never destroyed");
    Result<void*> raw = allocate_bytes(sizeof(T) * count, alignment);
    if (!raw.ok()) return raw.status();
    T* first = static_cast<T*>(raw.value());
    for (std::size_t i = 0; i < count; ++i) new (first + i) T();
    return first;
  }

  // Like allocate_array but constructs nothing: for storage whose objects are created (placement
  // new) before use, such as pool slots, so pages of a large reservation stay untouched until
  // used.
  template <typename T>
  Result<T*> allocate_array_uninitialized(std::size_t count, std::size_t alignment = alignof(T)) {
    static_assert(std::is_trivially_destructible_v<T>, "arena objects are never destroyed");
    Result<void*> raw = allocate_bytes(sizeof(T) * count, alignment);
    if (!raw.ok()) return raw.status();
    return static_cast<T*>(raw.value());
  }

  Result<void*> allocate_bytes(std::size_t bytes, std::size_t alignment);

  std::size_t capacity() const { return capacity_; }
  std::size_t bytes_used() const { return used_; }
  std::size_t bytes_free() const { return capacity_ - used_; }

 private:
  std::uint8_t* base_ = nullptr;
  std::size_t capacity_ = 0;
  std::size_t used_ = 0;
};

// Same interface as LinearArena, no memory: counts what the same requests would take.
class ArenaSizer {
 public:
  template <typename T>
  Result<T*> allocate_array(std::size_t count, std::size_t alignment = alignof(T)) {
    static_assert(std::is_trivially_destructible_v<T>, "arena objects are never destroyed");
    used_ = align_up(used_, alignment) + sizeof(T) * count;
    return static_cast<T*>(nullptr);
  }
  template <typename T>
  Result<T*> allocate_array_uninitialized(std::size_t count, std::size_t alignment = alignof(T)) {
    return allocate_array<T>(count, alignment);
  }
  Result<void*> allocate_bytes(std::size_t bytes, std::size_t alignment) {
    used_ = align_up(used_, alignment) + bytes;
    return static_cast<void*>(nullptr);
  }
  std::size_t bytes_used() const { return used_; }

 private:
  std::size_t used_ = 0;
};

}  // namespace octofuse
