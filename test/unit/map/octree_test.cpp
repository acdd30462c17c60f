#include "octofuse/map/octree.hpp"

#include <algorithm>
#include <cstring>
#include <random>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/map/mip.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"

namespace octofuse {
namespace {

MapConfig small_config(std::uint32_t blocks = 64, std::uint32_t nodes = 256) {
  MapConfig config;
  config.voxel_size_m = 0.01f;
  config.voxel_depth = 8;  // 256 voxels, 2.56 m
  config.origin_W = Eigen::Vector3f(-1.28f, -1.28f, -1.28f);
  config.block_capacity = blocks;
  config.node_capacity = nodes;
  return config;
}

template <typename VoxelT>
struct MapFixture {
  explicit MapFixture(const MapConfig& config) : buffer(Octree<VoxelT>::bytes_required(config)) {
    REQUIRE(map.reserve(buffer.arena(), config).ok());
  }
  test::ArenaBuffer buffer;
  Octree<VoxelT> map;
};

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
  // Coarse writes need no finest level.
  map.block(blocks[0]).at(0, 0, 0, 1).y = 2.0f;
  CHECK_FALSE(map.block(blocks[0]).has_finest());

  REQUIRE(map.acquire_finest(map.block(blocks[0])).ok());
  FinestLevel<MultiresVoxel>* first = map.block(blocks[0]).finest;
  REQUIRE(first != nullptr);
  CHECK(map.acquire_finest(map.block(blocks[0])).ok());  // already has one: same level
  CHECK(map.block(blocks[0]).finest == first);
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    REQUIRE_FALSE(voxel_observed(first->voxels[i]));  // lent unobserved
  }
  // The non-const voxel accessor takes a level for writes at scale 0.
  MultiresVoxel* v = map.voxel({8 + 3, 2, 1}, 0);
  REQUIRE(v != nullptr);
  v->y = 1.0f;
  CHECK(map.block(blocks[1]).has_finest());
  CHECK(map.memory().finest_used == 2);

  // Pool full: refused, counted, block unchanged and still readable.
  CHECK(map.acquire_finest(map.block(blocks[2])) == StatusCode::resource_exhausted);
  CHECK_FALSE(map.block(blocks[2]).has_finest());
  CHECK(map.voxel({16, 0, 0}, 0) == nullptr);
  const Octree<MultiresVoxel>& read = map;
  REQUIRE(read.voxel({16, 0, 0}, 0) != nullptr);
  CHECK_FALSE(voxel_observed(*read.voxel({16, 0, 0}, 0)));
  m = map.memory();
  CHECK(m.finest_refusals == 2);
  CHECK(m.refusals == 2);
  CHECK(m.bytes_used == 3 * sizeof(VoxelBlock<MultiresVoxel>) +
                            2 * sizeof(FinestLevel<MultiresVoxel>) +
                            m.nodes_used * sizeof(OctreeNode));
  // The other blocks' data is intact.
  CHECK(map.block(blocks[0]).at(0, 0, 0, 1).y == 2.0f);
  CHECK(read.voxel({8 + 3, 2, 1}, 0)->y == 1.0f);

  map.clear();
  m = map.memory();
  CHECK(m.finest_used == 0);
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
    map.block(b.value()).voxel(0) = TsdfVoxel{0.5f, static_cast<float>(i + 1)};
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
  CHECK(map.voxel({-1, 0, 0}) == nullptr);
  CHECK(map.voxel({256, 0, 0}) == nullptr);
  CHECK(map.find_block_at_point({5.0f, 0.0f, 0.0f}) == nullptr);
  CHECK(map.lookup({0, 0, 256}).level == -1);
}

TEST_CASE("voxel access at any scale and across block borders", "[map][octree]") {
  MapFixture<MultiresVoxel> f(small_config());
  Octree<MultiresVoxel>& map = f.map;
  REQUIRE(map.allocate_block({1, 1, 1}).ok());
  REQUIRE(map.allocate_block({2, 1, 1}).ok());
  MultiresVoxel* v = map.voxel({15, 8, 8}, 0);
  REQUIRE(v != nullptr);
  v->x = 0.25f;
  map.voxel({16, 8, 8}, 0)->x = -0.5f;
  map.voxel({16, 8, 8}, 3)->x = 0.75f;  // the whole second block at scale 3
  const Octree<MultiresVoxel>& cmap = map;
  const Eigen::Vector3i step_x(1, 0, 0);
  CHECK(cmap.neighbour({15, 8, 8}, 0, step_x)->x == -0.5f);
  CHECK(cmap.neighbour({16, 8, 8}, 0, -step_x)->x == 0.25f);
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

TEST_CASE("node summaries propagate up to the root", "[map][octree]") {
  MapFixture<MultiresVoxel> f(small_config());
  Octree<MultiresVoxel>& map = f.map;
  const std::uint32_t b0 = map.allocate_block({0, 0, 0}).value();
  const std::uint32_t b1 = map.allocate_block({1, 0, 0}).value();
  const std::uint32_t b2 = map.allocate_block({31, 31, 31}).value();  // stays unobserved
  for (std::uint32_t idx : {b0, b1}) {
    VoxelBlock<MultiresVoxel>& block = map.block(idx);
    const float value = idx == b0 ? 0.5f : -0.25f;
    REQUIRE(map.acquire_finest(block).ok());
    for (int i = 0; i < kBlockFinestVoxelCount; ++i) block.voxel(i) = {value, value, 4.0f, 0.0f};
    propagate_block_up(block, 0, kMaxBlockScale);
    Octree<MultiresVoxel>::update_block_summary(block);
  }
  const std::uint32_t all[] = {b0, b1, b2};
  map.propagate_summaries(all, 3);
  const OctreeNode& parent = map.node(map.block(b0).parent_node);
  CHECK(parent.summary.tsdf_mean == 0.125f);
  CHECK(parent.summary.weight_mean == 4.0f);
  CHECK(parent.summary.tsdf_min == -0.25f);
  CHECK(parent.summary.tsdf_max == 0.5f);
  const NodeSummary& root = map.node(Octree<MultiresVoxel>::root_index()).summary;
  CHECK(root.tsdf_mean == 0.125f);  // the unobserved branch does not dilute it
  CHECK(root.tsdf_min == -0.25f);
  CHECK_FALSE(map.node(map.block(b2).parent_node).summary.observed());
}

TEST_CASE("summaries from the blocks' parent nodes match those from the blocks", "[map][octree]") {
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> coord(0, 31);
  std::uniform_real_distribution<float> tsdf(-1.0f, 1.0f);
  MapFixture<MultiresVoxel> a(small_config(64, 1000));
  MapFixture<MultiresVoxel> b(small_config(64, 1000));
  std::vector<std::uint32_t> blocks;
  std::vector<std::uint32_t> parents;
  for (int i = 0; i < 60; ++i) {
    const Eigen::Vector3i c(coord(rng), coord(rng), coord(rng));
    const std::uint32_t ia = a.map.allocate_block(c).value();
    const std::uint32_t ib = b.map.allocate_block(c).value();
    REQUIRE(ia == ib);
    const float value = tsdf(rng);
    for (Octree<MultiresVoxel>* map : {&a.map, &b.map}) {
      VoxelBlock<MultiresVoxel>& block = map->block(ia);
      block.tsdf_mean = value;
      block.weight_mean = 3.0f;
      block.tsdf_min = value - 0.5f;
      block.tsdf_max = value + 0.25f;
    }
    blocks.push_back(ia);
    parents.push_back(a.map.block(ia).parent_node);
    if (i % 7 == 0) parents.push_back(kNoIndex);  // skipped entries
  }
  a.map.propagate_summaries(blocks.data(), blocks.size());
  b.map.propagate_summaries_from_parents(parents.data(), parents.size());
  REQUIRE(a.map.node_count() == b.map.node_count());
  for (std::uint32_t n = 0; n < a.map.node_count(); ++n) {
    const NodeSummary& sa = a.map.node(n).summary;
    const NodeSummary& sb = b.map.node(n).summary;
    CHECK(sa.tsdf_mean == sb.tsdf_mean);
    CHECK(sa.weight_mean == sb.weight_mean);
    CHECK(sa.tsdf_min == sb.tsdf_min);
    CHECK(sa.tsdf_max == sb.tsdf_max);
  }
  CHECK(a.map.node(Octree<MultiresVoxel>::root_index()).summary.observed());
}

TEST_CASE("wide summary levels in parallel tasks match the serial pass", "[map][octree][threads]") {
  // One block in each of the 16^3 parent octants: the first level is wide enough for the tasks.
  MapFixture<MultiresVoxel> a(small_config(4096, 5000));
  MapFixture<MultiresVoxel> b(small_config(4096, 5000));
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> tsdf(-1.0f, 1.0f);
  std::vector<std::uint32_t> blocks;
  std::vector<std::uint32_t> parents;
  for (int z = 0; z < 16; ++z) {
    for (int y = 0; y < 16; ++y) {
      for (int x = 0; x < 16; ++x) {
        const Eigen::Vector3i c(2 * x + (z & 1), 2 * y, 2 * z);
        const std::uint32_t ia = a.map.allocate_block(c).value();
        REQUIRE(b.map.allocate_block(c).value() == ia);
        const float value = tsdf(rng);
        for (Octree<MultiresVoxel>* map : {&a.map, &b.map}) {
          VoxelBlock<MultiresVoxel>& block = map->block(ia);
          block.tsdf_mean = value;
          block.weight_mean = 1.0f + static_cast<float>(x);
          block.tsdf_min = value - 0.125f;
          block.tsdf_max = value + 0.5f;
        }
        blocks.push_back(ia);
        parents.push_back(a.map.block(ia).parent_node);
      }
    }
  }
  a.map.propagate_summaries(blocks.data(), blocks.size());
  b.map.propagate_summaries_from_parents(parents.data(), parents.size(), WorkerTeam(2));
  REQUIRE(a.map.node_count() == b.map.node_count());
  for (std::uint32_t n = 0; n < a.map.node_count(); ++n) {
    const NodeSummary& sa = a.map.node(n).summary;
    const NodeSummary& sb = b.map.node(n).summary;
    REQUIRE(std::memcmp(&sa, &sb, sizeof(NodeSummary)) == 0);
  }
  CHECK(a.map.node(Octree<MultiresVoxel>::root_index()).summary.observed());
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

// --- Eviction.

// A 6x6x6 cube of blocks; every other one holds a finest level. Voxel values are a function of
// the block coordinates and voxel index, so a block found after compaction can be checked.
constexpr int kEvictGrid = 6;

float evict_test_tsdf(const Eigen::Vector3i& c, int i) {
  return static_cast<float>((c.x() * 37 + c.y() * 11 + c.z() * 5 + i) % 199) / 99.0f - 1.0f;
}
bool evict_test_has_finest(const Eigen::Vector3i& c) {
  return (c.x() + c.y() + c.z()) % 2 == 0;
}

// Allocates and fills the grid's blocks for which keep(coords) holds, in x-fastest order, and
// propagates their summaries.
template <typename Keep>
void fill_evict_grid(Octree<MultiresVoxel>& map, const Keep& keep) {
  std::vector<std::uint32_t> all;
  for (int z = 0; z < kEvictGrid; ++z) {
    for (int y = 0; y < kEvictGrid; ++y) {
      for (int x = 0; x < kEvictGrid; ++x) {
        const Eigen::Vector3i c(x, y, z);
        if (!keep(c)) continue;
        Result<std::uint32_t> index = map.allocate_block(c);
        REQUIRE(index.ok());
        VoxelBlock<MultiresVoxel>& block = map.block(index.value());
        const int scale = evict_test_has_finest(c) ? 0 : 1;
        if (scale == 0) REQUIRE(map.acquire_finest(block).ok());
        for (int i = scale == 0 ? 0 : kBlockFinestVoxelCount; i < kBlockVoxelCount; ++i) {
          block.voxel(i).x = evict_test_tsdf(c, i);
          block.voxel(i).y = 1.0f + static_cast<float>(i % 3);
        }
        block.current_scale = static_cast<std::int8_t>(scale);
        block.min_scale = static_cast<std::int8_t>(scale);
        block.last_updated_frame = static_cast<std::uint32_t>(x + 100 * y);
        Octree<MultiresVoxel>::update_block_summary(block);
        all.push_back(index.value());
      }
    }
  }
  map.propagate_summaries(all.data(), all.size());
}

bool same_summary(const NodeSummary& a, const NodeSummary& b) {
  return std::memcmp(&a, &b, sizeof(NodeSummary)) == 0;
}

TEST_CASE("evicted blocks are gone, every other block is found intact, the pool stays dense",
          "[map][octree][evict]") {
  const MapConfig config = small_config(256, 256);
  MapFixture<MultiresVoxel> a(config);
  fill_evict_grid(a.map, [](const Eigen::Vector3i&) { return true; });
  const std::uint32_t all_blocks = kEvictGrid * kEvictGrid * kEvictGrid;
  REQUIRE(a.map.block_count() == all_blocks);
  const std::uint32_t finest_before = a.map.memory().finest_used;
  REQUIRE(finest_before == all_blocks / 2);

  // Evict x >= 3 (half the cube), given in a shuffled order.
  auto kept = [](const Eigen::Vector3i& c) { return c.x() < 3; };
  std::vector<std::uint32_t> evict;
  std::uint32_t evicted_finest = 0;
  for (std::uint32_t i = 0; i < a.map.block_count(); ++i) {
    if (kept(a.map.block(i).coords)) continue;
    evict.push_back(i);
    if (a.map.block(i).has_finest()) ++evicted_finest;
  }
  std::mt19937 rng(5);
  std::shuffle(evict.begin(), evict.end(), rng);
  {
    test::AllocationScope scope;
    a.map.evict_blocks(evict.data(), evict.size());
    REQUIRE(scope.allocations() == 0);
  }
  const MapMemory memory = a.map.memory();
  REQUIRE(a.map.block_count() == all_blocks / 2);
  REQUIRE(memory.blocks_used == all_blocks / 2);
  REQUIRE(memory.finest_used == finest_before - evicted_finest);
  REQUIRE(memory.evicted == evict.size());

  for (int z = 0; z < kEvictGrid; ++z) {
    for (int y = 0; y < kEvictGrid; ++y) {
      for (int x = 0; x < kEvictGrid; ++x) {
        const Eigen::Vector3i c(x, y, z);
        CAPTURE(x, y, z);
        const std::uint32_t index = a.map.find_block_index(c);
        const OctantLookup look = a.map.lookup(c * kBlockSide + Eigen::Vector3i(3, 4, 5));
        if (!kept(c)) {
          REQUIRE(index == kNoIndex);
          REQUIRE(look.block == kNoIndex);
          continue;
        }
        REQUIRE(index < a.map.block_count());
        REQUIRE(look.block == index);  // the tree and the hash agree
        const VoxelBlock<MultiresVoxel>& block = a.map.block(index);
        REQUIRE(block.coords == c);
        REQUIRE(block.has_finest() == evict_test_has_finest(c));
        REQUIRE(block.last_updated_frame == static_cast<std::uint32_t>(x + 100 * y));
        for (int i = block.has_finest() ? 0 : kBlockFinestVoxelCount; i < kBlockVoxelCount; ++i) {
          REQUIRE(block.voxel(i).x == evict_test_tsdf(c, i));
        }
      }
    }
  }

  // Node summaries are those of a map that only ever held the kept blocks: nodes over evicted
  // blocks alone read unobserved, mixed ones and the root summarise what stayed.
  MapFixture<MultiresVoxel> b(config);
  fill_evict_grid(b.map, kept);
  for (std::uint32_t i = 0; i < b.map.node_count(); ++i) {
    const OctreeNode& expected = b.map.node(i);
    const std::uint32_t found = a.map.find_node_index(expected.key());
    REQUIRE(found != kNoIndex);
    REQUIRE(same_summary(a.map.node(found).summary, expected.summary));
  }
  REQUIRE(a.map.node(0).summary.observed());
  const OctantLookup gone = a.map.lookup(Eigen::Vector3i(5, 5, 5) * kBlockSide);
  REQUIRE(gone.node != kNoIndex);
  REQUIRE_FALSE(a.map.node(gone.node).summary.observed());  // covers blocks x in {4, 5} only

  // Evicted space can be allocated again: a fresh, unobserved block at the end of the pool, and
  // the finest levels given back are lent again.
  Result<std::uint32_t> again = a.map.allocate_block(Eigen::Vector3i(4, 0, 0));
  REQUIRE(again.ok());
  REQUIRE(again.value() == all_blocks / 2);
  REQUIRE_FALSE(a.map.block(again.value()).integrated());
  REQUIRE_FALSE(a.map.block(again.value()).has_finest());
  REQUIRE(a.map.acquire_finest(a.map.block(again.value())).ok());
  REQUIRE(a.map.memory().finest_used == finest_before - evicted_finest + 1);
}

TEST_CASE("the pool's layout after eviction depends on the evicted set, not the given order",
          "[map][octree][evict]") {
  const MapConfig config = small_config(256, 256);
  MapFixture<MultiresVoxel> a(config);
  MapFixture<MultiresVoxel> b(config);
  fill_evict_grid(a.map, [](const Eigen::Vector3i&) { return true; });
  fill_evict_grid(b.map, [](const Eigen::Vector3i&) { return true; });
  // Every third block, and the last one (the hole the compaction fills from).
  std::vector<std::uint32_t> evict;
  for (std::uint32_t i = 0; i < a.map.block_count(); i += 3) evict.push_back(i);
  evict.push_back(a.map.block_count() - 1);
  std::vector<std::uint32_t> reversed(evict.rbegin(), evict.rend());
  std::mt19937 rng(9);
  std::shuffle(evict.begin(), evict.end(), rng);
  a.map.evict_blocks(evict.data(), evict.size());
  b.map.evict_blocks(reversed.data(), reversed.size());
  REQUIRE(a.map.block_count() == b.map.block_count());
  for (std::uint32_t i = 0; i < a.map.block_count(); ++i) {
    REQUIRE(a.map.block(i).coords == b.map.block(i).coords);
  }
  // Evicting everything leaves an empty, unobserved map.
  std::vector<std::uint32_t> rest;
  for (std::uint32_t i = 0; i < a.map.block_count(); ++i) rest.push_back(i);
  a.map.evict_blocks(rest.data(), rest.size());
  REQUIRE(a.map.block_count() == 0u);
  REQUIRE(a.map.memory().finest_used == 0u);
  REQUIRE_FALSE(a.map.node(0).summary.observed());
}

TEST_CASE("release_finest keeps a block at scale 1 with the means of its finest voxels",
          "[map][octree][evict]") {
  MapFixture<MultiresVoxel> a(small_config(256, 256));
  fill_evict_grid(a.map, [](const Eigen::Vector3i&) { return true; });
  std::vector<std::uint32_t> all;
  for (std::uint32_t i = 0; i < a.map.block_count(); ++i) all.push_back(i);
  const std::uint32_t blocks = a.map.block_count();
  {
    test::AllocationScope scope;
    a.map.release_finest(all.data(), all.size());
    REQUIRE(scope.allocations() == 0);
  }
  REQUIRE(a.map.memory().finest_used == 0u);
  REQUIRE(a.map.block_count() == blocks);  // every block stays
  for (std::uint32_t i = 0; i < blocks; ++i) {
    const VoxelBlock<MultiresVoxel>& block = a.map.block(i);
    const Eigen::Vector3i c = block.coords;
    CAPTURE(c.x(), c.y(), c.z());
    REQUIRE_FALSE(block.has_finest());
    REQUIRE(block.current_scale == 1);
    if (!evict_test_has_finest(c)) {
      // Never at scale 0: untouched.
      REQUIRE(block.at(1, 2, 3, 1).x == evict_test_tsdf(c, block_voxel_index(1, 2, 3, 1)));
      continue;
    }
    // Scale 1 is now the mean of the 8 scale-0 voxels it covers (all observed, weights 1-3).
    for (int z = 0; z < 4; ++z) {
      for (int y = 0; y < 4; ++y) {
        for (int x = 0; x < 4; ++x) {
          float sum = 0.0f;
          for (int k = 0; k < 8; ++k) {
            sum += evict_test_tsdf(c, block_voxel_index(2 * x + (k & 1), 2 * y + ((k >> 1) & 1),
                                                        2 * z + ((k >> 2) & 1), 0));
          }
          REQUIRE(block.at(x, y, z, 1).x == sum / 8.0f);
        }
      }
    }
    // The block summary describes scale 1 now.
    float lo = 1.0f;
    for (int k = 0; k < block_scale_count(1); ++k) lo = std::min(lo, block.scale_begin(1)[k].x);
    REQUIRE(block.tsdf_min == lo);
  }
  // The pool lends the levels again.
  REQUIRE(a.map.acquire_finest(a.map.block(0)).ok());
  REQUIRE(a.map.memory().finest_used == 1u);
}

}  // namespace
}  // namespace octofuse
