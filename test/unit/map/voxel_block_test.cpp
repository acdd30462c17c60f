#include "octofuse/map/voxel_block.hpp"

#include <catch2/catch.hpp>

namespace octofuse {
namespace {

TEST_CASE("mip level offsets, sides and counts", "[map][block]") {
  CHECK(block_scale_offset(0) == 0);
  CHECK(block_scale_offset(1) == 512);
  CHECK(block_scale_offset(2) == 576);
  CHECK(block_scale_offset(3) == 584);
  CHECK(block_scale_side(0) == 8);
  CHECK(block_scale_side(3) == 1);
  int total = 0;
  for (int s = 0; s <= kMaxBlockScale; ++s) {
    CHECK(block_scale_offset(s) == total);
    total += block_scale_count(s);
  }
  CHECK(total == kBlockVoxelCount);
}

TEST_CASE("index within a level is x + y*s + z*s^2 and covers each level once", "[map][block]") {
  CHECK(block_voxel_index(1, 2, 3, 0) == 1 + 2 * 8 + 3 * 64);
  CHECK(block_voxel_index(1, 2, 3, 1) == 512 + 1 + 2 * 4 + 3 * 16);
  CHECK(block_voxel_index(1, 0, 1, 2) == 576 + 1 + 4);
  CHECK(block_voxel_index(0, 0, 0, 3) == 584);
  int hits[kBlockVoxelCount] = {};
  for (int s = 0; s <= kMaxBlockScale; ++s) {
    const int n = block_scale_side(s);
    for (int z = 0; z < n; ++z)
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) ++hits[block_voxel_index(x, y, z, s)];
  }
  for (int i = 0; i < kBlockVoxelCount; ++i) REQUIRE(hits[i] == 1);
  // Finest-coordinate access snaps: finest voxel (5, 6, 7) is voxel (1, 1, 1) at scale 2.
  CHECK(block_voxel_index_finest(5, 6, 7, 2) == block_voxel_index(1, 1, 1, 2));
}

TEST_CASE("mip levels cost 14% over single-resolution blocks", "[map][block]") {
  const double overhead = static_cast<double>(kBlockVoxelCount) / kBlockFinestVoxelCount - 1.0;
  CHECK(overhead == Approx(0.142578125).epsilon(1e-12));  // 73 / 512
  // The block records hold the voxel array plus a small header.
  CHECK(sizeof(VoxelBlock<MultiresVoxel>) >= kBlockVoxelCount * sizeof(MultiresVoxel));
  CHECK(sizeof(VoxelBlock<MultiresVoxel>) <= kBlockVoxelCount * sizeof(MultiresVoxel) + 64);
  CHECK(sizeof(MultiresVoxel) == 16);
  CHECK(sizeof(TsdfVoxel) == 8);
}

TEST_CASE("a fresh block is unobserved and never integrated", "[map][block]") {
  VoxelBlock<MultiresVoxel> block;
  CHECK_FALSE(block.integrated());
  CHECK(block.min_scale == kNeverIntegrated);
  CHECK(block.mip_scale == kNeverIntegrated);
  CHECK(block.weight_mean == 0.0f);
  CHECK(block.tsdf_min > block.tsdf_max);  // empty summary
  for (const MultiresVoxel& v : block.voxels) {
    REQUIRE_FALSE(voxel_observed(v));
    REQUIRE(v.x == 1.0f);
  }
  block.coords = Eigen::Vector3i(2, 3, 4);
  CHECK(block.min_voxel() == Eigen::Vector3i(16, 24, 32));
  block.at_voxel(Eigen::Vector3i(16 + 5, 24 + 6, 32 + 7), 1).y = 3.0f;
  CHECK(block.at(2, 3, 3, 1).y == 3.0f);
}

}  // namespace
}  // namespace octofuse
