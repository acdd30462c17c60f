// Node summaries: propagated up to the root, the same from blocks or their parents, and the
// same in parallel tasks as in the serial pass.

#include "octofuse/map/octree.hpp"

#include <catch2/catch.hpp>

#include "unit/map/octree_support.hpp"

namespace octofuse {
namespace {

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
    for (int i = 0; i < kBlockFinestVoxelCount; ++i)
      block.set_voxel(i, MultiresVoxel{value, value, 4.0f, 0.0f});
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

}  // namespace
}  // namespace octofuse
