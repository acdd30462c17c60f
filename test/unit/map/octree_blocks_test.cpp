// Blocks in the octree: coordinates, allocation up to the pools' capacity, keys outside the
// cube, voxel access, lookup, iteration order and batched allocation.

#include "octofuse/map/octree.hpp"

#include <catch2/catch.hpp>

#include "unit/map/octree_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("coordinate conversions are cell-centred", "[map][octree]") {
  MapFixture<TsdfVoxel> f(small_config());
  const Octree<TsdfVoxel>& map = f.map;
  constexpr float kTolerance_m = 1e-6f;
  CHECK(map.point_to_voxel({-1.28f + 0.005f, 0.0f, 1.2799f}) == Eigen::Vector3i(0, 128, 255));
  CHECK((map.voxel_centre_W({0, 0, 0}) - Eigen::Vector3f::Constant(-1.275f)).norm() < kTolerance_m);
  // The scale-2 voxel containing finest voxel 5 spans voxels 4..7: centre at 6.0 voxels.
  CHECK(map.voxel_centre_W({5, 0, 0}, 2).x() == Approx(-1.28f + 0.06f));
  CHECK(map.block_centre_W({1, 0, 0}).x() == Approx(-1.28f + 0.12f));
  CHECK(map.voxel_of_point({0.0f, 0.0f, 0.0f}).ok());
  CHECK(map.voxel_of_point({1.3f, 0.0f, 0.0f}).status() == StatusCode::out_of_range);
  CHECK(map.voxel_of_point({-1.2801f, 0.0f, 0.0f}).status() == StatusCode::out_of_range);
  CHECK(map.voxel_of_point({std::numeric_limits<float>::quiet_NaN(), 0.0f, 0.0f}).status() ==
        StatusCode::out_of_range);
  CHECK(map.voxel_of_point({1e30f, -1e30f, 0.0f}).status() == StatusCode::out_of_range);
}

TEST_CASE("allocating the same key twice gives one block", "[map][octree]") {
  MapFixture<MultiresVoxel> f(small_config());
  Octree<MultiresVoxel>& map = f.map;
  const Key key = map.block_key({3, 4, 5});
  const Key keys[] = {key, key};
  AllocationCounts counts;
  REQUIRE(map.allocate(keys, 2, &counts).ok());
  CHECK(counts.new_blocks == 1);
  CHECK(counts.already_allocated == 1);
  CHECK(map.block_count() == 1);
  REQUIRE(map.allocate(&key, 1, &counts).ok());
  CHECK(counts.new_blocks == 0);
  CHECK(map.block_count() == 1);
  // Depth 8, blocks at level 5: the root plus levels 1..4.
  CHECK(map.node_count() == 5);
  VoxelBlock<MultiresVoxel>* block = map.find_block(Eigen::Vector3i(3, 4, 5));
  REQUIRE(block != nullptr);
  CHECK(block->coords == Eigen::Vector3i(3, 4, 5));
  CHECK(map.find_block(key) == block);
  CHECK(map.find_block_at_voxel({24, 39, 47}) == block);
  CHECK(map.find_block_at_voxel({24, 39, 48}) == nullptr);
  CHECK(map.find_block_at_point(map.voxel_centre_W({31, 32, 40})) == block);
  Result<std::uint32_t> again = map.allocate_block({3, 4, 5});
  REQUIRE(again.ok());
  CHECK(&map.block(again.value()) == block);
}

TEST_CASE("exhaustion at exactly the capacity leaves earlier blocks intact", "[map][octree]") {
  constexpr std::uint32_t kCapacity = 10;
  MapFixture<TsdfVoxel> f(small_config(kCapacity, 256));
  Octree<TsdfVoxel>& map = f.map;
  for (std::uint32_t i = 0; i < kCapacity; ++i) {
    Result<std::uint32_t> b = map.allocate_block({static_cast<int>(i), 1, 2});
    REQUIRE(b.ok());
    map.block(b.value()).level_voxel(0) = TsdfVoxel{0.5f, static_cast<float>(i + 1)};
  }
  CHECK(map.refusals() == 0);
  CHECK(map.allocate_block({20, 1, 2}).status() == StatusCode::resource_exhausted);
  CHECK(map.refusals() == 1);
  const Key keys[] = {map.block_key({21, 1, 2}), map.block_key({0, 1, 2})};
  AllocationCounts counts;
  CHECK(map.allocate(keys, 2, &counts) == StatusCode::resource_exhausted);
  CHECK(counts.refused == 1);
  CHECK(counts.already_allocated == 1);
  CHECK(map.refusals() == 2);
  CHECK(map.block_count() == kCapacity);
  CHECK(map.find_block(Eigen::Vector3i(20, 1, 2)) == nullptr);
  for (std::uint32_t i = 0; i < kCapacity; ++i) {
    const VoxelBlock<TsdfVoxel>* b = map.find_block(Eigen::Vector3i(static_cast<int>(i), 1, 2));
    REQUIRE(b != nullptr);
    CHECK(b->voxel(0).weight == static_cast<float>(i + 1));
  }
  const MapMemory m = map.memory();
  CHECK(m.blocks_used == kCapacity);
  CHECK(m.block_capacity == kCapacity);
  CHECK(m.refusals == 2);
  CHECK(m.bytes_used ==
        kCapacity * sizeof(VoxelBlock<TsdfVoxel>) + m.nodes_used * sizeof(OctreeNode));
}

TEST_CASE("a full node pool refuses, counts, and the map stays usable", "[map][octree]") {
  // Depth 8: a block needs 4 inner nodes below the root. 6 nodes fit one chain plus one more.
  MapFixture<TsdfVoxel> f(small_config(64, 6));
  Octree<TsdfVoxel>& map = f.map;
  REQUIRE(map.allocate_block({0, 0, 0}).ok());
  CHECK(map.allocate_block({31, 31, 31}).status() == StatusCode::resource_exhausted);
  CHECK(map.refusals() == 1);
  REQUIRE(map.allocate_block({1, 0, 0}).ok());  // shares the chain
  CHECK(map.block_count() == 2);
}

TEST_CASE("out-of-cube keys and points never write", "[map][octree]") {
  MapFixture<TsdfVoxel> f(small_config());
  Octree<TsdfVoxel>& map = f.map;
  CHECK(map.allocate_block({32, 0, 0}).status() == StatusCode::out_of_range);
  CHECK(map.allocate_block({-1, 0, 0}).status() == StatusCode::out_of_range);
  const Key outside = key_of_voxel({300, 0, 0}, map.block_level(), 9);
  const Key too_fine = key_of_voxel({0, 0, 0}, map.block_level() + 1, map.voxel_depth());
  const Key keys[] = {outside, too_fine};
  AllocationCounts counts;
  CHECK(map.allocate(keys, 2, &counts) == StatusCode::out_of_range);
  CHECK(counts.rejected == 2);
  CHECK(map.block_count() == 0);
  CHECK(map.node_count() == 1);
  CHECK(map.voxel({-1, 0, 0}, 0) == nullptr);
  CHECK(map.voxel({256, 0, 0}, 0) == nullptr);
  CHECK(map.find_block_at_point({5.0f, 0.0f, 0.0f}) == nullptr);
  CHECK(map.lookup({0, 0, 256}).level == -1);
}

TEST_CASE("voxel access at any scale and across block borders", "[map][octree]") {
  MapFixture<MultiresVoxel> f(small_config());
  Octree<MultiresVoxel>& map = f.map;
  REQUIRE(map.allocate_block({1, 1, 1}).ok());
  REQUIRE(map.allocate_block({2, 1, 1}).ok());
  // Scale 0 of a multires map is finest_voxel() (its own type), scales 1-3 voxel().
  MultiresFinestVoxel* v = map.finest_voxel({15, 8, 8});
  REQUIRE(v != nullptr);
  v->x = 0.25f;
  map.finest_voxel({16, 8, 8})->x = -0.5f;
  map.voxel({16, 8, 8}, 3)->x = 0.75f;  // the whole second block at scale 3
  const Octree<MultiresVoxel>& cmap = map;
  const Eigen::Vector3i step_x(1, 0, 0);
  CHECK(cmap.finest_voxel(Eigen::Vector3i(15, 8, 8) + step_x)->x == -0.5f);
  CHECK(cmap.finest_voxel(Eigen::Vector3i(16, 8, 8) - step_x)->x == 0.25f);
  MultiresVoxel read;
  REQUIRE(cmap.read_voxel({16, 8, 8}, 0, &read));
  CHECK(read.x == -0.5f);
  CHECK(read.x_last == -0.5f);
  REQUIRE(cmap.read_voxel({16, 8, 8}, 3, &read));
  CHECK(read.x == 0.75f);
  CHECK_FALSE(cmap.read_voxel({24, 8, 8}, 0, &read));  // block (3,1,1) absent
  CHECK(cmap.neighbour({9, 10, 11}, 3, step_x)->x == 0.75f);
  CHECK(cmap.neighbour({16, 8, 8}, 3, step_x) == nullptr);  // block (3,1,1) absent
  CHECK(cmap.voxel({23, 15, 15}, 3) == cmap.voxel({16, 8, 8}, 3));
}

TEST_CASE("lookup finds the deepest allocated octant", "[map][octree]") {
  MapFixture<TsdfVoxel> f(small_config());
  Octree<TsdfVoxel>& map = f.map;
  REQUIRE(map.allocate_block({0, 0, 0}).ok());
  OctantLookup hit = map.lookup({3, 4, 5});
  CHECK(hit.level == map.block_level());
  CHECK(hit.block == map.find_block_index({0, 0, 0}));
  CHECK(map.node(hit.node).level == map.block_level() - 1);
  // Voxel 8 is in the sibling block, absent: the deepest octant is the block's parent.
  OctantLookup sibling = map.lookup({8, 0, 0});
  CHECK(sibling.level == map.block_level() - 1);
  CHECK(sibling.block == kNoIndex);
  // Far corner: only the root holds it; the empty octant is half the cube.
  OctantLookup far = map.lookup({255, 255, 255});
  CHECK(far.level == 0);
  CHECK(far.node == Octree<TsdfVoxel>::root_index());
  CHECK(octant_size_voxels(far.level + 1, map.voxel_depth()) == 128);

  const Key node_key = key_of_voxel({0, 0, 0}, 2, map.voxel_depth());
  const std::uint32_t n = map.find_node_index(node_key);
  REQUIRE(n != kNoIndex);
  CHECK(map.node(n).key() == node_key);
  CHECK(map.find_node_index(key_of_voxel({200, 0, 0}, 2, map.voxel_depth())) == kNoIndex);
  // Allocating an inner node key directly.
  const Key inner = key_of_voxel({128, 128, 128}, 3, map.voxel_depth());
  AllocationCounts counts;
  REQUIRE(map.allocate(&inner, 1, &counts).ok());
  CHECK(counts.new_nodes == 3);
  CHECK(map.lookup({130, 129, 140}).level == 3);
}

TEST_CASE("iteration order is the allocation order and is deterministic", "[map][octree]") {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> coord(0, 31);
  Key keys[40];
  MapFixture<TsdfVoxel> a(small_config());
  MapFixture<TsdfVoxel> b(small_config());
  for (Key& k : keys) k = a.map.block_key({coord(rng), coord(rng), coord(rng)});
  std::sort(std::begin(keys), std::end(keys));
  REQUIRE(a.map.allocate(keys, 40).ok());
  REQUIRE(b.map.allocate(keys, 40).ok());
  REQUIRE(a.map.block_count() == b.map.block_count());
  std::uint64_t previous = 0;
  for (std::uint32_t i = 0; i < a.map.block_count(); ++i) {
    CHECK(a.map.block(i).coords == b.map.block(i).coords);
    if (i > 0) CHECK(a.map.block(i).morton > previous);  // sorted keys -> Morton order
    previous = a.map.block(i).morton;
  }
  std::uint32_t visited = 0;
  a.map.for_each_block([&visited](VoxelBlock<TsdfVoxel>&) { ++visited; });
  CHECK(visited == a.map.block_count());
}

TEST_CASE("one allocate call over many keys builds the tree that one call per key builds",
          "[map][octree]") {
  // allocate() starts each walk where the previous key's path and this one part; keys one call
  // apart start at the root. Mixed levels, repeats, keys outside the cube and a node pool that
  // runs out on the way must all give the same pools, links and counts.
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> coord(-2, 33);
  std::uniform_int_distribution<int> level(1, 5);
  for (const std::uint32_t node_capacity : {256u, 40u}) {
    std::vector<Key> keys;
    MapFixture<TsdfVoxel> batch(small_config(64, node_capacity));
    MapFixture<TsdfVoxel> single(small_config(64, node_capacity));
    for (int i = 0; i < 120; ++i) {
      const Eigen::Vector3i block(coord(rng), coord(rng), coord(rng));
      const Eigen::Vector3i voxel = block * kBlockSide;
      const bool inside = batch.map.contains_voxel(voxel);
      const Key key = inside ? key_of_voxel(voxel, level(rng), batch.map.voxel_depth())
                             : Key{~std::uint64_t{0} >> 1, 5};
      keys.push_back(key);
      if (i % 7 == 0) keys.push_back(key);
    }
    std::sort(keys.begin(), keys.begin() + 60);  // half sorted, half in random order
    AllocationCounts batch_counts;
    const Status batch_status = batch.map.allocate(keys.data(), keys.size(), &batch_counts);
    AllocationCounts sum;
    for (const Key& key : keys) {
      AllocationCounts one;
      (void)single.map.allocate(&key, 1, &one);
      sum.new_blocks += one.new_blocks;
      sum.new_nodes += one.new_nodes;
      sum.already_allocated += one.already_allocated;
      sum.refused += one.refused;
      sum.rejected += one.rejected;
    }
    CHECK((batch_status.code() == StatusCode::resource_exhausted) == (sum.refused > 0));
    CHECK(batch_counts.new_blocks == sum.new_blocks);
    CHECK(batch_counts.new_nodes == sum.new_nodes);
    CHECK(batch_counts.already_allocated == sum.already_allocated);
    CHECK(batch_counts.refused == sum.refused);
    CHECK(batch_counts.rejected == sum.rejected);
    CHECK(sum.rejected > 0);
    if (node_capacity < 256) CHECK(sum.refused > 0);
    REQUIRE(batch.map.node_count() == single.map.node_count());
    REQUIRE(batch.map.block_count() == single.map.block_count());
    for (std::uint32_t n = 0; n < batch.map.node_count(); ++n) {
      const OctreeNode& a = batch.map.node(n);
      const OctreeNode& b = single.map.node(n);
      CHECK(a.key() == b.key());
      CHECK(a.parent == b.parent);
      CHECK(std::equal(std::begin(a.children), std::end(a.children), std::begin(b.children)));
    }
    for (std::uint32_t i = 0; i < batch.map.block_count(); ++i) {
      CHECK(batch.map.block(i).coords == single.map.block(i).coords);
      CHECK(batch.map.block(i).parent_node == single.map.block(i).parent_node);
    }
  }
}

}  // namespace
}  // namespace octofuse
