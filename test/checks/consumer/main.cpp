// Uses the installed headers and library: a Status, an arena sized by ArenaSizer, an index pool
// filled to capacity, and a rigid transform from the math area. Exit code 0 means all behaved.
#include <cstdio>

#include <octofuse/core/arena.hpp>
#include <octofuse/core/pool.hpp>
#include <octofuse/core/status.hpp>
#include <octofuse/math/se3.hpp>

namespace {

struct Slot {
  int value;
};

template <typename Arena>
octofuse::Status reserve(Arena& arena, octofuse::IndexPool<Slot>& pool) {
  return pool.reserve(arena, 4);
}

}  // namespace

int main() {
  octofuse::ArenaSizer sizer;
  octofuse::IndexPool<Slot> sizing_pool;
  if (!reserve(sizer, sizing_pool).ok()) return 1;

  alignas(octofuse::kArenaAlignment) static unsigned char buffer[1024];
  if (sizer.bytes_used() > sizeof(buffer)) return 2;
  octofuse::LinearArena arena(buffer, sizer.bytes_used());
  octofuse::IndexPool<Slot> pool;
  if (!reserve(arena, pool).ok()) return 3;
  for (int i = 0; i < 4; ++i) {
    if (!pool.allocate().ok()) return 4;
  }
  const octofuse::Status full = pool.allocate().status();
  if (full.code() != octofuse::StatusCode::resource_exhausted) return 5;

  octofuse::Vector6d twist;
  twist << 0.1, 0.2, 0.3, 0.0, 0.0, 0.5;
  if (!octofuse::is_rigid(octofuse::se3_exp(twist).matrix())) return 6;

  std::printf("octofuse consumer: %s after %u slots, arena %zu bytes\n", full.name(),
              pool.capacity(), arena.bytes_used());
  return 0;
}
