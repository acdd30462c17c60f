// Reserving the octree: exact bytes, the finest-level pool lent and returned, configs refused
// or centred, clear keeping the memory, no heap after reserve.

#include "octofuse/map/octree.hpp"

#include <catch2/catch.hpp>

#include "unit/map/octree_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("voxel_depth_for: the least cube of 2^d voxels that covers the map", "[map][config]") {
  CHECK(voxel_depth_for(8.0f, 0.01f) == 10);   // 1024 voxels, 10.24 m
  CHECK(voxel_depth_for(5.12f, 0.02f) == 8);   // exactly 256 voxels
  CHECK(voxel_depth_for(5.125f, 0.02f) == 8);  // within 0.1 % still fits
  CHECK(voxel_depth_for(5.2f, 0.02f) == 9);    // beyond it takes the next depth
  CHECK(voxel_depth_for(0.01f, 0.01f) == kMinVoxelDepth);
  CHECK(voxel_depth_for(1e9f, 0.001f) == kMaxVoxelDepth);
}

TEST_CASE("bytes_required is exact", "[map][octree]") {
  for (const MapConfig& config : {small_config(), small_config(1000, 3000)}) {
    const std::size_t need = Octree<MultiresVoxel>::bytes_required(config);
    REQUIRE(need > 0);
    CHECK(need >= config.block_capacity * sizeof(VoxelBlock<MultiresVoxel>));
    test::ArenaBuffer exact(need);
    Octree<MultiresVoxel> map;
    REQUIRE(map.reserve(exact.arena(), config).ok());
    CHECK(exact.arena().bytes_used() == need);
    CHECK(map.memory().bytes_reserved == need);

    test::ArenaBuffer short_by_one(need - 1);
    Octree<MultiresVoxel> too_big;
    CHECK(too_big.reserve(short_by_one.arena(), config) == StatusCode::resource_exhausted);
  }
  // The single-resolution map is smaller per block.
  CHECK(Octree<TsdfVoxel>::bytes_required(small_config()) <
        Octree<MultiresVoxel>::bytes_required(small_config()));
}

TEST_CASE("the finest-level pool is sized from its own capacity, exactly", "[map][octree]") {
  MapConfig config = small_config(100, 300);
  const std::size_t worst_case = Octree<MultiresVoxel>::bytes_required(config);
  config.finest_capacity = 10;
  const std::size_t need = Octree<MultiresVoxel>::bytes_required(config);
  // 90 fewer levels of 8 KiB and their free-list links (up to alignment padding).
  constexpr std::size_t kSaved = 90 * (sizeof(FinestLevel<MultiresVoxel>) + sizeof(std::uint32_t));
  CHECK(worst_case - need >= kSaved);
  CHECK(worst_case - need <= kSaved + 2 * kArenaAlignment);
  test::ArenaBuffer exact(need);
  Octree<MultiresVoxel> map;
  REQUIRE(map.reserve(exact.arena(), config).ok());
  CHECK(exact.arena().bytes_used() == need);
  test::ArenaBuffer short_by_one(need - 1);
  Octree<MultiresVoxel> too_big;
  CHECK(too_big.reserve(short_by_one.arena(), config) == StatusCode::resource_exhausted);
  // Single-resolution maps have no such pool: the capacity changes nothing.
  CHECK(Octree<TsdfVoxel>::bytes_required(config) ==
        Octree<TsdfVoxel>::bytes_required(small_config(100, 300)));
  config.finest_capacity = (1u << 30) + 1;
  CHECK(validate(config) == StatusCode::invalid_argument);
}

TEST_CASE("finest levels are lent on demand, refused when the pool is full, returned by clear",
          "[map][octree]") {
  MapConfig config = small_config(8, 64);
  config.finest_capacity = 2;
  MapFixture<MultiresVoxel> f(config);
  Octree<MultiresVoxel>& map = f.map;
  std::uint32_t blocks[3];
  for (int i = 0; i < 3; ++i) blocks[i] = map.allocate_block({i, 0, 0}).value();
  MapMemory m = map.memory();
  CHECK(m.finest_used == 0);
  CHECK(m.finest_capacity == 2);
  CHECK(m.bytes_per_finest == sizeof(FinestLevel<MultiresVoxel>));
  CHECK(m.bytes_used == 3 * sizeof(VoxelBlock<MultiresVoxel>) + m.nodes_used * sizeof(OctreeNode));
  // Writes at scales 2 and 3 need no level; at scale 1 the accessor takes a mid level.
  map.block(blocks[0]).level_at(0, 0, 0, 2).y = 2.0f;
  CHECK_FALSE(map.block(blocks[0]).has_finest());
  CHECK_FALSE(map.block(blocks[0]).has_mid());
  MultiresVoxel* mid_voxel = map.voxel({0, 0, 0}, 1);
  REQUIRE(mid_voxel != nullptr);
  mid_voxel->y = 4.0f;
  CHECK(map.block(blocks[0]).has_mid());
  CHECK_FALSE(map.block(blocks[0]).has_finest());
  CHECK(map.memory().mid_used == 1);

  REQUIRE(map.acquire_finest(map.block(blocks[0])).ok());
  FinestLevel<MultiresVoxel>* first = map.block(blocks[0]).finest;
  REQUIRE(first != nullptr);
  CHECK(map.acquire_finest(map.block(blocks[0])).ok());  // already has one: same level
  CHECK(map.block(blocks[0]).finest == first);
  CHECK(map.memory().mid_used == 1);  // the block's mid level kept
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    REQUIRE_FALSE(voxel_observed(first->voxels[i]));  // lent unobserved
  }
  // The non-const finest voxel accessor takes both levels for writes at scale 0.
  MultiresFinestVoxel* v = map.finest_voxel({8 + 3, 2, 1});
  REQUIRE(v != nullptr);
  v->y = 1.0f;
  CHECK(map.block(blocks[1]).has_finest());
  CHECK(map.block(blocks[1]).has_mid());
  CHECK(map.memory().finest_used == 2);
  CHECK(map.memory().mid_used == 2);

  // Pool full: refused, counted, block's data unchanged and still readable (it took the mid
  // level that scale 1, where it integrates instead, needs).
  CHECK(map.acquire_finest(map.block(blocks[2])) == StatusCode::resource_exhausted);
  CHECK_FALSE(map.block(blocks[2]).has_finest());
  CHECK(map.finest_voxel({16, 0, 0}) == nullptr);
  const Octree<MultiresVoxel>& read = map;
  REQUIRE(read.finest_voxel({16, 0, 0}) != nullptr);
  CHECK_FALSE(voxel_observed(*read.finest_voxel({16, 0, 0})));
  m = map.memory();
  CHECK(m.finest_refusals == 2);
  CHECK(m.mid_refusals == 0);
  CHECK(m.refusals == 2);
  CHECK(m.mid_used == 3);
  CHECK(m.bytes_used ==
        3 * sizeof(VoxelBlock<MultiresVoxel>) + 2 * sizeof(FinestLevel<MultiresVoxel>) +
            3 * sizeof(MidLevel<MultiresVoxel>) + m.nodes_used * sizeof(OctreeNode));
  // The other blocks' data is intact.
  CHECK(map.block(blocks[0]).at(0, 0, 0, 2).y == 2.0f);
  CHECK(map.block(blocks[0]).at(0, 0, 0, 1).y == 4.0f);
  CHECK(read.finest_voxel({8 + 3, 2, 1})->y == 1.0f);

  map.clear();
  m = map.memory();
  CHECK(m.finest_used == 0);
  CHECK(m.mid_used == 0);
  CHECK(m.finest_refusals == 0);
  const std::uint32_t again = map.allocate_block({5, 5, 5}).value();
  CHECK_FALSE(map.block(again).has_finest());  // a new block starts without one
  REQUIRE(map.acquire_finest(map.block(again)).ok());
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    REQUIRE_FALSE(voxel_observed(map.block(again).finest->voxels[i]));  // re-lent clean
  }
}

TEST_CASE("invalid configs are refused", "[map][octree]") {
  MapConfig bad = small_config();
  bad.voxel_depth = 3;
  CHECK(validate(bad) == StatusCode::invalid_argument);
  bad = small_config();
  bad.voxel_depth = 22;
  CHECK(validate(bad) == StatusCode::invalid_argument);
  bad = small_config();
  bad.voxel_size_m = 0.0f;
  CHECK(validate(bad) == StatusCode::invalid_argument);
  bad = small_config();
  bad.block_capacity = 0;
  CHECK(validate(bad) == StatusCode::invalid_argument);
  bad = small_config();
  bad.origin_W.x() = std::numeric_limits<float>::quiet_NaN();
  CHECK(validate(bad) == StatusCode::invalid_argument);
  CHECK(Octree<TsdfVoxel>::bytes_required(bad) == 0);
  CHECK(validate(small_config()).ok());
  MapConfig deep = small_config();
  deep.voxel_depth = 16;
  CHECK(validate(deep).ok());
}

TEST_CASE("centred config puts the centre in the middle of the cube", "[map][octree]") {
  const MapConfig c = MapConfig::centred({1.0f, 2.0f, 3.0f}, 0.002f, 12, 10, 10);
  CHECK(c.size_m() == Approx(8.192f));
  CHECK(c.origin_W.x() == Approx(1.0f - 4.096f));
  CHECK(c.block_level() == 9);
}

TEST_CASE("clear forgets blocks and keeps the memory", "[map][octree]") {
  MapFixture<TsdfVoxel> f(small_config(4, 64));
  for (int i = 0; i < 4; ++i) REQUIRE(f.map.allocate_block({i, 0, 0}).ok());
  CHECK(f.map.allocate_block({9, 0, 0}).status() == StatusCode::resource_exhausted);
  f.map.clear();
  CHECK(f.map.block_count() == 0);
  CHECK(f.map.refusals() == 0);
  CHECK(f.map.find_block(Eigen::Vector3i(0, 0, 0)) == nullptr);
  REQUIRE(f.map.allocate_block({9, 0, 0}).ok());
  CHECK(f.map.block(0).voxel(0).weight == 0.0f);
}

TEST_CASE("no heap allocation after reserve across 10000 allocations and lookups",
          "[map][octree]") {
  MapConfig config = small_config(10000, 20000);
  config.voxel_depth = 10;
  MapFixture<MultiresVoxel> f(config);
  std::mt19937 rng(1);
  std::uniform_int_distribution<int> coord(0, 31);
  test::AllocationScope scope;
  std::uint32_t found = 0;
  for (int i = 0; i < 10000; ++i) {
    const Eigen::Vector3i b(coord(rng), coord(rng), coord(rng));
    Result<std::uint32_t> index = f.map.allocate_block(b);
    REQUIRE(index.ok());
    found += f.map.find_block(b) != nullptr ? 1u : 0u;
    found += f.map.voxel(block_to_voxel(b), 2) != nullptr ? 1u : 0u;
  }
  CHECK(scope.allocations() == 0);
  CHECK(found == 20000);
}

TEST_CASE("mid levels are lent on demand, refused when the pool is full, returned on eviction",
          "[map][octree]") {
  MapConfig config = small_config(8, 64);
  config.mid_capacity = 1;
  MapFixture<MultiresVoxel> f(config);
  Octree<MultiresVoxel>& map = f.map;
  std::uint32_t blocks[2];
  for (int i = 0; i < 2; ++i) blocks[i] = map.allocate_block({i, 0, 0}).value();
  CHECK(map.memory().mid_capacity == 1);
  CHECK(map.memory().bytes_per_mid == sizeof(MidLevel<MultiresVoxel>));
  REQUIRE(map.voxel({1, 1, 1}, 1) != nullptr);
  CHECK(map.block(blocks[0]).has_mid());
  // Pool full: no mid level, and no finest level either (it needs one).
  CHECK(map.voxel({8, 0, 0}, 1) == nullptr);
  CHECK(map.acquire_finest(map.block(blocks[1])) == StatusCode::resource_exhausted);
  CHECK_FALSE(map.block(blocks[1]).has_mid());
  CHECK_FALSE(map.block(blocks[1]).has_finest());
  MapMemory m = map.memory();
  CHECK(m.mid_refusals == 2);
  CHECK(m.finest_refusals == 0);
  CHECK(m.refusals == 2);
  CHECK(m.finest_used == 0);
  // Evicting the block gives its level back: the other block can take it.
  std::uint32_t evict = blocks[0];
  map.evict_blocks(&evict, 1);
  CHECK(map.memory().mid_used == 0);
  const std::uint32_t moved = map.find_block_index({1, 0, 0});
  REQUIRE(moved != kNoIndex);
  REQUIRE(map.acquire_finest(map.block(moved)).ok());
  CHECK(map.block(moved).has_mid());
  CHECK(map.memory().mid_used == 1);
  CHECK(map.memory().finest_used == 1);
}

}  // namespace
}  // namespace octofuse
