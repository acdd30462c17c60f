#include "octofuse/core/arena.hpp"

#include <catch2/catch.hpp>
#include <cstdint>
#include <cstdlib>

#include "death.hpp"
#include "octofuse/core/fixed_vector.hpp"
#include "octofuse/core/pool.hpp"

namespace octofuse {
namespace {

struct alignas(16) Quad {
  float v[4];
};

std::uintptr_t address(const void* p) {
  return reinterpret_cast<std::uintptr_t>(p);
}

TEST_CASE("align_up rounds up to the next multiple") {
  STATIC_REQUIRE(align_up(0, 64) == 0);
  STATIC_REQUIRE(align_up(1, 64) == 64);
  STATIC_REQUIRE(align_up(64, 64) == 64);
  STATIC_REQUIRE(align_up(65, 8) == 72);
}

TEST_CASE("LinearArena hands out aligned, value-initialised, non-overlapping arrays") {
  alignas(kArenaAlignment) static std::uint8_t buffer[256];
  for (auto& b : buffer) b = 0xAB;
  LinearArena arena(buffer, sizeof(buffer));
  REQUIRE(arena.capacity() == 256);
  REQUIRE(arena.bytes_used() == 0);

  const Result<std::uint8_t*> bytes = arena.allocate_array<std::uint8_t>(3);
  REQUIRE(bytes.ok());
  REQUIRE(bytes.value() == buffer);
  REQUIRE(bytes.value()[2] == 0);  // value-initialised, not 0xAB

  const Result<Quad*> quads = arena.allocate_array<Quad>(2);
  REQUIRE(quads.ok());
  REQUIRE(address(quads.value()) % alignof(Quad) == 0);
  REQUIRE(address(quads.value()) == address(buffer) + 16);
  REQUIRE(quads.value()[1].v[3] == 0.0f);
  REQUIRE(arena.bytes_used() == 16 + 2 * sizeof(Quad));

  const Result<void*> raw = arena.allocate_bytes(10, 64);
  REQUIRE(raw.ok());
  REQUIRE(address(raw.value()) == address(buffer) + 64);
  REQUIRE(arena.bytes_used() == 74);
  REQUIRE(arena.bytes_free() == 256 - 74);
}

TEST_CASE("LinearArena: a request that does not fit takes nothing") {
  alignas(kArenaAlignment) static std::uint8_t buffer[128];
  LinearArena arena(buffer, sizeof(buffer));
  REQUIRE(arena.allocate_array<std::uint32_t>(30).ok());  // 120 bytes
  const std::size_t used = arena.bytes_used();

  REQUIRE(arena.allocate_array<std::uint32_t>(3).status().code() == StatusCode::resource_exhausted);
  REQUIRE(arena.bytes_used() == used);
  // Alignment padding alone can push past the end.
  REQUIRE(arena.allocate_bytes(1, 64).status().code() == StatusCode::resource_exhausted);
  REQUIRE(arena.bytes_used() == used);
  // What still fits, fits exactly.
  REQUIRE(arena.allocate_array<std::uint32_t>(2).ok());
  REQUIRE(arena.bytes_free() == 0);
  REQUIRE(arena.allocate_bytes(1, 1).status().code() == StatusCode::resource_exhausted);
  REQUIRE(arena.allocate_bytes(0, 1).ok());  // an empty request always fits
}

TEST_CASE("LinearArena: huge requests do not wrap around") {
  alignas(kArenaAlignment) static std::uint8_t buffer[64];
  LinearArena arena(buffer, sizeof(buffer));
  REQUIRE(arena.allocate_bytes(8, 1).ok());
  REQUIRE(arena.allocate_bytes(SIZE_MAX - 4, 1).status().code() == StatusCode::resource_exhausted);
  REQUIRE(arena.bytes_used() == 8);
}

TEST_CASE("An empty arena refuses everything but empty requests") {
  LinearArena arena;
  REQUIRE(arena.capacity() == 0);
  REQUIRE(arena.allocate_array<int>(1).status().code() == StatusCode::resource_exhausted);
  REQUIRE(arena.allocate_array<int>(0).ok());
}

// The pattern every component follows: one template that requests memory, run with both.
struct Component {
  IndexPool<Quad> pool;
  SpanVector<std::uint16_t> list;
  std::uint8_t* scratch = nullptr;

  template <typename Arena>
  Status reserve(Arena& arena, std::uint32_t pool_capacity, std::size_t list_capacity) {
    OCTOFUSE_TRY(pool.reserve(arena, pool_capacity));
    OCTOFUSE_TRY_ASSIGN(std::uint16_t * storage,
                        arena.template allocate_array<std::uint16_t>(list_capacity));
    list = SpanVector<std::uint16_t>(storage, list_capacity);
    OCTOFUSE_TRY_ASSIGN(void* raw, arena.allocate_bytes(333, 32));
    scratch = static_cast<std::uint8_t*>(raw);
    return ok_status();
  }
};

TEST_CASE("ArenaSizer computes exactly what LinearArena uses") {
  const std::uint32_t pool_capacity = GENERATE(0u, 1u, 7u, 100u);
  const std::size_t list_capacity = GENERATE(std::size_t{0}, std::size_t{3}, std::size_t{1000});
  CAPTURE(pool_capacity, list_capacity);

  ArenaSizer sizer;
  Component sized;
  REQUIRE(sized.reserve(sizer, pool_capacity, list_capacity).ok());
  const std::size_t required = sizer.bytes_used();

  void* memory = std::aligned_alloc(kArenaAlignment, align_up(required, kArenaAlignment));
  REQUIRE(memory != nullptr);
  {
    LinearArena arena(memory, required);
    Component real;
    REQUIRE(real.reserve(arena, pool_capacity, list_capacity).ok());
    REQUIRE(arena.bytes_used() == required);
    REQUIRE(arena.bytes_free() == 0);
    REQUIRE(real.list.capacity() == list_capacity);
    REQUIRE(real.pool.capacity() == pool_capacity);
  }
  if (required > 0) {
    // One byte less must fail cleanly.
    LinearArena short_arena(memory, required - 1);
    Component real;
    REQUIRE(real.reserve(short_arena, pool_capacity, list_capacity).code() ==
            StatusCode::resource_exhausted);
  }
  std::free(memory);
}

TEST_CASE("LinearArena checks its buffer and alignments") {
  SECTION("a misaligned buffer trips the check") {
    const auto end = test::run_in_child([](int) {
      alignas(kArenaAlignment) static std::uint8_t buffer[128];
      LinearArena arena(buffer + 8, 64);
      (void)arena;
    });
    REQUIRE(end.aborted);
    REQUIRE(end.check_text.find("kArenaAlignment") != std::string::npos);
  }
  SECTION("a non-power-of-two alignment trips the check") {
    const auto end = test::run_in_child([](int) {
      alignas(kArenaAlignment) static std::uint8_t buffer[128];
      LinearArena arena(buffer, sizeof(buffer));
      arena.allocate_bytes(4, 3).status().ignore();
    });
    REQUIRE(end.aborted);
    REQUIRE(end.check_text.find("alignment") != std::string::npos);
  }
  SECTION("an aligned buffer does not") {
    const auto end = test::run_in_child([](int) {
      alignas(kArenaAlignment) static std::uint8_t buffer[128];
      LinearArena arena(buffer + kArenaAlignment, 64);
      arena.allocate_bytes(4, 4).status().ignore();
    });
    REQUIRE_FALSE(end.aborted);
    REQUIRE(end.exit_code == 0);
  }
}

}  // namespace
}  // namespace octofuse
