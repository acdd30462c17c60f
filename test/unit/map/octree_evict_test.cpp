// Eviction and releasing finest levels: what stays is intact, the pool dense and its layout
// independent of the order given.

#include "octofuse/map/octree.hpp"

#include <catch2/catch.hpp>

#include "unit/map/octree_support.hpp"

namespace octofuse {
namespace {

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
        if (scale == 1) REQUIRE(map.acquire_mid(block).ok());
        for (int i = block.first_stored_voxel(); i < kBlockVoxelCount; ++i) {
          MultiresVoxel v = block.voxel(i);
          v.x = evict_test_tsdf(c, i);
          v.y = 1.0f + static_cast<float>(i % 3);
          block.set_voxel(i, v);
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
  // Inner nodes went with their last block: the tree is the kept-only map's, node for node.
  REQUIRE(a.map.node_count() == b.map.node_count());
  REQUIRE(memory.nodes_evicted > 0);
  REQUIRE(a.map.memory().nodes_used + memory.nodes_evicted ==
          b.map.node_count() + memory.nodes_evicted);
  // The node over blocks x in {4, 5} alone is gone: the walk stops above it, at a node whose
  // summary covers kept blocks too.
  const OctantLookup gone = a.map.lookup(Eigen::Vector3i(5, 5, 5) * kBlockSide);
  REQUIRE(gone.node != kNoIndex);
  REQUIRE(gone.block == kNoIndex);
  REQUIRE(a.map.node(gone.node).level < a.map.block_level() - 1);

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
  REQUIRE(a.map.node_count() == 1u);  // the root alone
  REQUIRE_FALSE(a.map.node(0).summary.observed());
}

// Every live node is its parent's child, every block its parent node's child, and the hash
// finds each block where the tree does.
template <typename VoxelT>
void require_tree_consistent(const Octree<VoxelT>& map) {
  const int depth = map.voxel_depth();
  for (std::uint32_t i = 1; i < map.node_count(); ++i) {
    const OctreeNode& n = map.node(i);
    REQUIRE(n.parent < map.node_count());
    REQUIRE(map.node(n.parent).children[child_index(n.key(), depth)] == i);
    REQUIRE(map.find_node_index(n.key()) == i);
    REQUIRE_FALSE(n.childless());
  }
  for (std::uint32_t i = 0; i < map.block_count(); ++i) {
    const auto& b = map.block(i);
    const Key key{b.morton, static_cast<std::uint8_t>(map.block_level())};
    REQUIRE(map.node(b.parent_node).children[child_index(key, depth)] == i);
    REQUIRE(map.find_block_index(b.coords) == i);
  }
}

TEST_CASE("inner nodes go with their last block and come back with it; the node pool stays dense",
          "[map][octree][evict]") {
  // Blocks spread over the cube, so each sits under its own chain of inner nodes.
  MapFixture<MultiresVoxel> a(small_config(64, 64));
  std::vector<Eigen::Vector3i> coords;
  for (int i = 0; i < 8; ++i) {
    coords.emplace_back((i & 1) * 31, ((i >> 1) & 1) * 31, ((i >> 2) & 1) * 31);
    coords.emplace_back((i & 1) * 31, ((i >> 1) & 1) * 31, 14 + (i >> 2));
  }
  for (const Eigen::Vector3i& c : coords) REQUIRE(a.map.allocate_block(c).ok());
  const std::uint32_t full_nodes = a.map.node_count();
  require_tree_consistent(a.map);
  // Evict the first eight (the corners) in two rounds; nodes they alone held go.
  for (int round = 0; round < 2; ++round) {
    std::vector<std::uint32_t> evict;
    for (int k = 4 * round; k < 4 * round + 4; ++k) {
      evict.push_back(a.map.find_block_index(coords[static_cast<std::size_t>(2 * k)]));
    }
    test::AllocationScope scope;
    a.map.evict_blocks(evict.data(), evict.size());
    REQUIRE(scope.allocations() == 0);
    require_tree_consistent(a.map);
  }
  REQUIRE(a.map.block_count() == 8u);
  REQUIRE(a.map.node_count() < full_nodes);
  REQUIRE(a.map.memory().nodes_evicted == full_nodes - a.map.node_count());
  // A map that only ever held the remaining blocks has the same number of nodes.
  MapFixture<MultiresVoxel> b(small_config(64, 64));
  for (std::size_t k = 1; k < coords.size(); k += 2) REQUIRE(b.map.allocate_block(coords[k]).ok());
  REQUIRE(a.map.node_count() == b.map.node_count());
  // They come back with their blocks, and a pool no larger than the full tree suffices again.
  for (std::size_t k = 0; k < coords.size(); k += 2) REQUIRE(a.map.allocate_block(coords[k]).ok());
  REQUIRE(a.map.node_count() == full_nodes);
  require_tree_consistent(a.map);
}

TEST_CASE("a tiny node pool never refuses a block that evicting another frees nodes for",
          "[map][octree][evict]") {
  // Room for one chain of inner nodes (root + 4 levels above the blocks of a 256-voxel cube,
  // plus a spare): a block far from the last needs nodes only eviction can free.
  MapFixture<MultiresVoxel> a(small_config(4, 6));
  const int depth = a.map.voxel_depth();
  (void)depth;
  for (int i = 0; i < 20; ++i) {
    const Eigen::Vector3i c((i * 7) % 32, (i * 13) % 32, (i * 29) % 32);
    if (a.map.find_block_index(c) != kNoIndex) continue;
    Result<std::uint32_t> fresh = a.map.allocate_block(c);
    if (!fresh.ok()) {
      // Evict everything else (the caller's eviction), then it fits.
      std::vector<std::uint32_t> all;
      for (std::uint32_t k = 0; k < a.map.block_count(); ++k) all.push_back(k);
      a.map.evict_blocks(all.data(), all.size());
      REQUIRE(a.map.node_count() == 1u);
      fresh = a.map.allocate_block(c);
    }
    REQUIRE(fresh.ok());
    require_tree_consistent(a.map);
  }
  REQUIRE(a.map.memory().nodes_evicted > 0);
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
    for (int k = 0; k < block_scale_count(1); ++k) lo = std::min(lo, block.level_begin(1)[k].x);
    REQUIRE(block.tsdf_min == lo);
  }
  // The pool lends the levels again.
  REQUIRE(a.map.acquire_finest(a.map.block(0)).ok());
  REQUIRE(a.map.memory().finest_used == 1u);
}

TEST_CASE("release_mid keeps a block at scale 2 with the means of its finer voxels",
          "[map][octree][evict]") {
  MapFixture<MultiresVoxel> a(small_config(256, 256));
  fill_evict_grid(a.map, [](const Eigen::Vector3i&) { return true; });
  // What scale 2 must become: the grid's scale-0 blocks through release_finest's scale 1 first.
  MapFixture<MultiresVoxel> ref(small_config(256, 256));
  fill_evict_grid(ref.map, [](const Eigen::Vector3i&) { return true; });
  std::vector<std::uint32_t> all;
  for (std::uint32_t i = 0; i < a.map.block_count(); ++i) all.push_back(i);
  ref.map.release_finest(all.data(), all.size());
  const std::uint32_t blocks = a.map.block_count();
  {
    test::AllocationScope scope;
    a.map.release_mid(all.data(), all.size());
    REQUIRE(scope.allocations() == 0);
  }
  REQUIRE(a.map.memory().finest_used == 0u);
  REQUIRE(a.map.memory().mid_used == 0u);
  REQUIRE(a.map.block_count() == blocks);  // every block stays
  for (std::uint32_t i = 0; i < blocks; ++i) {
    const VoxelBlock<MultiresVoxel>& block = a.map.block(i);
    const VoxelBlock<MultiresVoxel>& scale_1 = ref.map.block(i);
    REQUIRE(block.coords == scale_1.coords);
    CAPTURE(block.coords.x(), block.coords.y(), block.coords.z());
    REQUIRE_FALSE(block.has_finest());
    REQUIRE_FALSE(block.has_mid());
    REQUIRE(block.current_scale == 2);
    REQUIRE(block.mip_scale == 2);
    // Scale 2 is the mean of the 8 scale-1 voxels it covers (all observed).
    for (int z = 0; z < 2; ++z) {
      for (int y = 0; y < 2; ++y) {
        for (int x = 0; x < 2; ++x) {
          float sum = 0.0f;
          for (int k = 0; k < 8; ++k) {
            sum += scale_1.at(2 * x + (k & 1), 2 * y + ((k >> 1) & 1), 2 * z + ((k >> 2) & 1), 1).x;
          }
          REQUIRE(block.at(x, y, z, 2).x == sum / 8.0f);
        }
      }
    }
    // Scale 1 reads unobserved now; the summary describes scale 2.
    REQUIRE_FALSE(voxel_observed(block.at(1, 1, 1, 1)));
    float lo = 1.0f;
    for (int k = 0; k < block_scale_count(2); ++k) lo = std::min(lo, block.level_begin(2)[k].x);
    REQUIRE(block.tsdf_min == lo);
  }
  // Both pools lend their levels again.
  REQUIRE(a.map.acquire_finest(a.map.block(0)).ok());
  REQUIRE(a.map.memory().finest_used == 1u);
  REQUIRE(a.map.memory().mid_used == 1u);
}

}  // namespace
}  // namespace octofuse
