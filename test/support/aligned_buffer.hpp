#pragma once
// The one kArenaAlignment-aligned buffer a test carves a pipeline from (a byte more than asked,
// so a test can also offer bytes_required() - 1).

#include <cstddef>
#include <cstdlib>

#include "octofuse/core/arena.hpp"

namespace octofuse::test {

struct Buffer {
  void* data = nullptr;
  explicit Buffer(std::size_t bytes) {
    data = std::aligned_alloc(kArenaAlignment, align_up(bytes + 1, kArenaAlignment));
  }
  ~Buffer() { std::free(data); }
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;
};

}  // namespace octofuse::test
