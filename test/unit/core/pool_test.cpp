#include "octofuse/core/pool.hpp"

#include <catch2/catch.hpp>
#include <cstdint>
#include <cstring>

#include "death.hpp"
#include "octofuse/core/arena.hpp"

namespace octofuse {
namespace {

struct Block {
  std::uint32_t id = 0;
  float payload[3] = {0.0f, 0.0f, 0.0f};
};

alignas(kArenaAlignment) std::uint8_t g_buffer[4096];

TEST_CASE("IndexPool hands out 0..N-1, refuses at exactly N, keeps earlier slots intact") {
  constexpr std::uint32_t kCapacity = 5;
  LinearArena arena(g_buffer, sizeof(g_buffer));
  IndexPool<Block> pool;
  REQUIRE(pool.reserve(arena, kCapacity).ok());
  REQUIRE(pool.capacity() == kCapacity);
  REQUIRE(pool.used() == 0);
  REQUIRE_FALSE(pool.full());

  for (std::uint32_t i = 0; i < kCapacity; ++i) {
    const Result<std::uint32_t> index = pool.allocate();
    REQUIRE(index.ok());
    REQUIRE(index.value() == i);
    pool[index.value()].id = 100 + i;
    pool[index.value()].payload[2] = static_cast<float>(i);
  }
  REQUIRE(pool.full());
  REQUIRE(pool.refused() == 0);

  for (int attempt = 1; attempt <= 3; ++attempt) {
    const Result<std::uint32_t> refused = pool.allocate();
    REQUIRE(refused.status().code() == StatusCode::resource_exhausted);
    REQUIRE(pool.refused() == static_cast<std::uint64_t>(attempt));
  }
  REQUIRE(pool.used() == kCapacity);
  for (std::uint32_t i = 0; i < kCapacity; ++i) {
    REQUIRE(pool[i].id == 100 + i);
    REQUIRE(pool[i].payload[2] == static_cast<float>(i));
  }
}

TEST_CASE("IndexPool reuses released slots last-in first-out, value-initialised") {
  LinearArena arena(g_buffer, sizeof(g_buffer));
  IndexPool<Block> pool;
  REQUIRE(pool.reserve(arena, 4).ok());
  for (int i = 0; i < 4; ++i) {
    const std::uint32_t index = pool.allocate().value();
    pool[index].id = 7;
  }
  pool.release(1);
  pool.release(3);
  REQUIRE(pool.used() == 2);
  REQUIRE_FALSE(pool.full());

  const std::uint32_t first = pool.allocate().value();
  const std::uint32_t second = pool.allocate().value();
  REQUIRE(first == 3);
  REQUIRE(second == 1);
  REQUIRE(pool[first].id == 0);
  REQUIRE(pool[second].id == 0);
  REQUIRE(pool[0].id == 7);
  REQUIRE(pool[2].id == 7);
  REQUIRE(pool.allocate().status().code() == StatusCode::resource_exhausted);
}

TEST_CASE("IndexPool::prefault writes the pages of exactly the next slots, and changes nothing") {
  // Slots larger than a page's stride and not dividing it, over a buffer filled with a pattern.
  struct Big {
    std::uint32_t id = 0;
    std::uint8_t bytes[2996] = {};
  };
  constexpr std::uint32_t kCapacity = 20;
  alignas(kArenaAlignment) static std::uint8_t buffer[kCapacity * sizeof(Big) + 4096];
  std::memset(buffer, 0xAB, sizeof(buffer));
  LinearArena arena(buffer, sizeof(buffer));
  IndexPool<Big> pool;
  REQUIRE(pool.reserve(arena, kCapacity).ok());
  auto slot_bytes = [&](std::uint32_t slot) {
    return reinterpret_cast<const std::uint8_t*>(&pool[0]) + slot * sizeof(Big);
  };
  REQUIRE(pool.allocate().value() == 0);
  REQUIRE(pool.allocate().value() == 1);
  pool[0].id = 5;
  pool[1].id = 6;
  pool.prefault(5);  // slots 2..6
  // Written: every 4096th byte from slot 2 on and the last byte of slot 6; nothing else.
  const std::uint8_t* const from = slot_bytes(2);
  const std::size_t span = 5 * sizeof(Big);
  std::size_t zeros = 0;
  for (std::size_t i = 0; i < span; ++i) {
    if (from[i] == 0) ++zeros;
    if (i % 4096 == 0 || i == span - 1) REQUIRE(from[i] == 0);
  }
  REQUIRE(zeros == (span + 4095) / 4096 + 1);
  for (std::size_t i = 0; i < 3 * sizeof(Big); ++i) REQUIRE(slot_bytes(7)[i] == 0xAB);
  // The pool is as it was: the same slots in use, the same next index, value-initialised.
  REQUIRE(pool.used() == 2);
  REQUIRE(pool[0].id == 5);
  REQUIRE(pool[1].id == 6);
  const std::uint32_t next = pool.allocate().value();
  REQUIRE(next == 2);
  REQUIRE(pool[next].id == 0);
  REQUIRE(pool[next].bytes[100] == 0);
  // More than the pool holds stops at its last slot; a full pool is left alone.
  pool.prefault(1000);
  REQUIRE(slot_bytes(kCapacity - 1)[sizeof(Big) - 1] == 0);
  while (!pool.full()) REQUIRE(pool.allocate().ok());
  pool.prefault(3);
  REQUIRE(pool.used() == kCapacity);
}

TEST_CASE("IndexPool reset forgets every allocation; the sequence repeats") {
  LinearArena arena(g_buffer, sizeof(g_buffer));
  IndexPool<Block> pool;
  REQUIRE(pool.reserve(arena, 3).ok());
  std::uint32_t first_run[3];
  for (auto& i : first_run) i = pool.allocate().value();
  pool.release(first_run[0]);
  pool.reset();
  REQUIRE(pool.used() == 0);
  for (std::uint32_t i = 0; i < 3; ++i) REQUIRE(pool.allocate().value() == i);
  REQUIRE(pool.full());
}

TEST_CASE("A zero-capacity pool refuses at once") {
  LinearArena arena(g_buffer, sizeof(g_buffer));
  IndexPool<Block> pool;
  REQUIRE(pool.reserve(arena, 0).ok());
  REQUIRE(pool.full());
  REQUIRE(pool.allocate().status().code() == StatusCode::resource_exhausted);
  REQUIRE(pool.refused() == 1);
}

TEST_CASE("IndexPool reserve fails cleanly when the arena is too small") {
  LinearArena arena(g_buffer, 64);
  IndexPool<Block> pool;
  REQUIRE(pool.reserve(arena, 100).code() == StatusCode::resource_exhausted);
  REQUIRE(pool.capacity() == 0);
  REQUIRE(pool.allocate().status().code() == StatusCode::resource_exhausted);
}

TEST_CASE("IndexPool size from ArenaSizer is exact") {
  ArenaSizer sizer;
  IndexPool<Block> sized;
  REQUIRE(sized.reserve(sizer, 37).ok());
  LinearArena arena(g_buffer, sizer.bytes_used());
  IndexPool<Block> pool;
  REQUIRE(pool.reserve(arena, 37).ok());
  REQUIRE(arena.bytes_free() == 0);
  REQUIRE(sizer.bytes_used() == 37 * sizeof(Block) + 37 * sizeof(std::uint32_t));
}

TEST_CASE("IndexPool misuse trips the check") {
  SECTION("release of a never-allocated index") {
    const auto end = test::run_in_child([](int) {
      LinearArena arena(g_buffer, sizeof(g_buffer));
      IndexPool<Block> pool;
      pool.reserve(arena, 4).ignore();
      pool.allocate().status().ignore();
      pool.release(2);
    });
    REQUIRE(end.aborted);
  }
  SECTION("access past the handed-out slots") {
    const auto end = test::run_in_child([](int) {
      LinearArena arena(g_buffer, sizeof(g_buffer));
      IndexPool<Block> pool;
      pool.reserve(arena, 4).ignore();
      volatile std::uint32_t id = pool[0].id;
      (void)id;
    });
    REQUIRE(end.aborted);
    REQUIRE(end.check_text.find("index < fresh_") != std::string::npos);
  }
}

}  // namespace
}  // namespace octofuse
