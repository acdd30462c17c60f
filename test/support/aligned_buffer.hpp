#pragma once
// kArenaAlignment-aligned heap memory for tests that carve a pipeline or a map from an arena.
//   Buffer: raw bytes for Pipeline::init (a byte more than asked, so a test can also offer
//           bytes_required() - 1).
//   ArenaBuffer: a LinearArena of exactly the bytes asked for.

#include <cstddef>
#include <cstdlib>
#include <memory>

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

struct AlignedFree {
  void operator()(void* p) const { std::free(p); }
};

class ArenaBuffer {
 public:
  explicit ArenaBuffer(std::size_t bytes)
      : bytes_(bytes),
        memory_(
            std::aligned_alloc(kArenaAlignment, align_up(bytes == 0 ? 1 : bytes, kArenaAlignment))),
        arena_(memory_.get(), bytes) {}
  LinearArena& arena() { return arena_; }
  std::size_t bytes() const { return bytes_; }

 private:
  std::size_t bytes_;
  std::unique_ptr<void, AlignedFree> memory_;
  LinearArena arena_;
};

}  // namespace octofuse::test
