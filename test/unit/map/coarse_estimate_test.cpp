// The coarse-allocation estimate on a hand-built map: which octants above the blocks could be one
// coarse block each, counted coarsest first.

#include "octofuse/map/coarse_estimate.hpp"

#include <vector>

#include <catch2/catch.hpp>

#include "unit/map/octree_support.hpp"

namespace octofuse {
namespace {

// Allocates the block at `coords` and marks it fused down to `min_scale` (-1: never fused).
template <typename VoxelT>
void add_block(Octree<VoxelT>& map, const Eigen::Vector3i& coords, int min_scale) {
  const Result<std::uint32_t> index = map.allocate_block(coords);
  REQUIRE(index.ok());
  map.block(index.value()).min_scale = static_cast<std::int8_t>(min_scale);
}

TEST_CASE("coarse estimate: each octant whose blocks never fused finer than its level counts once",
          "[map][coarse]") {
  MapFixture<MultiresVoxel> f(small_config());  // 32 blocks per side
  Octree<MultiresVoxel>& map = f.map;
  // Octants 2 levels up span 4^3 blocks, 3 levels up 8^3, 1 level up 2^3.
  // Blocks 0..3: one 2-up octant, all at scale 2 (inside a 3-up octant that block 4..7 spoil).
  add_block(map, {0, 0, 0}, 2);
  add_block(map, {1, 2, 3}, 2);
  add_block(map, {3, 3, 3}, 3);
  // Blocks 4..7: a scale-1 block spoils the 2-up octant; its two 1-up octants qualify.
  add_block(map, {4, 0, 0}, 2);
  add_block(map, {5, 1, 0}, 1);
  add_block(map, {6, 0, 0}, 2);
  // A block fused at scale 0 stays; so does its 1-up octant's scale-3 neighbour.
  add_block(map, {8, 0, 0}, 0);
  add_block(map, {9, 0, 0}, 3);
  // A 3-up octant fused at scale 3 only.
  add_block(map, {16, 0, 0}, 3);
  add_block(map, {23, 7, 7}, 3);
  // Never fused: left out, and it spoils nothing.
  add_block(map, {17, 0, 0}, -1);

  std::vector<std::uint64_t> scratch(map.block_count());
  const Result<CoarseEstimate> result = estimate_coarse_blocks(map, scratch.data(), scratch.size());
  REQUIRE(result.ok());
  const CoarseEstimate& e = result.value();
  CHECK(e.fused_blocks == 10);
  CHECK(e.replaced[2] == 2);  // blocks 16, 23
  CHECK(e.octants[2] == 1);
  CHECK(e.replaced[1] == 3);  // blocks 0..3
  CHECK(e.octants[1] == 1);
  CHECK(e.replaced[0] == 3);  // blocks 4 + 5, and 6
  CHECK(e.octants[0] == 2);
  CHECK(e.blocks_after() == 10 - 8 + 4);

  SECTION("a scratch smaller than the pool is refused") {
    const Result<CoarseEstimate> small =
        estimate_coarse_blocks(map, scratch.data(), scratch.size() - 1);
    CHECK(small.status().code() == StatusCode::invalid_argument);
    CHECK(estimate_coarse_blocks(map, nullptr, 0).status().code() == StatusCode::invalid_argument);
  }
}

TEST_CASE("coarse estimate: a map fused at scale 0 keeps every block", "[map][coarse]") {
  MapFixture<TsdfVoxel> f(small_config());
  for (int x = 0; x < 8; ++x) add_block(f.map, {x, 0, 0}, 0);
  std::vector<std::uint64_t> scratch(f.map.block_count());
  const Result<CoarseEstimate> result =
      estimate_coarse_blocks(f.map, scratch.data(), scratch.size());
  REQUIRE(result.ok());
  CHECK(result.value().fused_blocks == 8);
  CHECK(result.value().blocks_after() == 8);
  for (int i = 0; i < kMaxBlockScale; ++i) CHECK(result.value().octants[i] == 0);
}

}  // namespace
}  // namespace octofuse
