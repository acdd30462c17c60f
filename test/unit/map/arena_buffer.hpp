#pragma once
// An aligned heap buffer for tests that carve a map from a LinearArena.

#include <cstddef>
#include <cstdlib>
#include <memory>

#include "octofuse/core/arena.hpp"

namespace octofuse::test {

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
