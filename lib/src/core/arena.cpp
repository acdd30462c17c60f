#include "octofuse/core/arena.hpp"

namespace octofuse {

LinearArena::LinearArena(void* buffer, std::size_t bytes)
    : base_(static_cast<std::uint8_t*>(buffer)), capacity_(bytes) {
  OCTOFUSE_CHECK(reinterpret_cast<std::uintptr_t>(buffer) % kArenaAlignment == 0);
}

Result<void*> LinearArena::allocate_bytes(std::size_t bytes, std::size_t alignment) {
  OCTOFUSE_CHECK(alignment != 0 && (alignment & (alignment - 1)) == 0);
  const std::size_t start = align_up(used_, alignment);
  if (start > capacity_ || bytes > capacity_ - start) return StatusCode::resource_exhausted;
  used_ = start + bytes;
  return static_cast<void*>(base_ + start);
}

}  // namespace octofuse
