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
  CHECK(sizeof(MultiresVoxel) == 16);
  CHECK(sizeof(TsdfVoxel) == 8);
}

TEST_CASE("single-res blocks hold all levels inline, multires blocks only the coarse ones",
          "[map][block]") {
  // The header is 72 bytes with 64-bit pointers (64 on 32-bit targets).
  constexpr std::size_t kMaxHeaderBytes = 72;
  VoxelBlock<MultiresVoxel> probe;
  const std::size_t header = static_cast<std::size_t>(
      reinterpret_cast<const char*>(probe.inline_voxels) - reinterpret_cast<const char*>(&probe));
  CHECK(header <= kMaxHeaderBytes);
  // The header, the inline voxels and the tail padding to the block's alignment (32-bit targets
  // pad a header's blocks to 8 bytes).
  const auto padded = [](std::size_t bytes, std::size_t align) {
    return (bytes + align - 1) / align * align;
  };
  CHECK(sizeof(VoxelBlock<TsdfVoxel>) ==
        padded(header + kBlockVoxelCount * sizeof(TsdfVoxel), alignof(VoxelBlock<TsdfVoxel>)));
  // Scales 2 and 3 inline: 9 voxels.
  CHECK(sizeof(VoxelBlock<MultiresVoxel>) ==
        padded(header + 9 * sizeof(MultiresVoxel), alignof(VoxelBlock<MultiresVoxel>)));
  // Scale 0 keeps the TSDF and weight alone: half of a level of the block's voxel type.
  CHECK(sizeof(MultiresFinestVoxel) == 8);
  CHECK(sizeof(Multires16FinestVoxel) == 4);
  CHECK(sizeof(FinestLevel<MultiresVoxel>) == kBlockFinestVoxelCount * sizeof(MultiresVoxel) / 2);
  CHECK(sizeof(FinestLevel<Multires16Voxel>) ==
        kBlockFinestVoxelCount * sizeof(Multires16Voxel) / 2);
  CHECK(sizeof(FinestLevel<TsdfVoxel>) == kBlockFinestVoxelCount * sizeof(TsdfVoxel));
  CHECK(sizeof(MidLevel<MultiresVoxel>) == 64 * sizeof(MultiresVoxel));
  CHECK_FALSE(VoxelBlock<TsdfVoxel>::kSplitFinest);
  CHECK(VoxelBlock<MultiresVoxel>::kSplitFinest);
  VoxelBlock<TsdfVoxel> single;
  CHECK(single.has_finest());
  CHECK(single.has_mid());
  CHECK(single.finest_begin() == single.inline_voxels);
  CHECK(single.level_begin(1) == single.inline_voxels + 512);
}

TEST_CASE("a fresh block is unobserved and never integrated", "[map][block]") {
  VoxelBlock<MultiresVoxel> block;
  CHECK_FALSE(block.integrated());
  CHECK_FALSE(block.has_finest());
  CHECK_FALSE(block.has_mid());
  CHECK(block.min_scale == kNeverIntegrated);
  CHECK(block.mip_scale == kNeverIntegrated);
  CHECK(block.weight_mean == 0.0f);
  CHECK(block.tsdf_min > block.tsdf_max);  // empty summary
  const VoxelBlock<MultiresVoxel>& read = block;
  for (int i = 0; i < kBlockVoxelCount; ++i) {
    REQUIRE_FALSE(voxel_observed(read.voxel(i)));
    REQUIRE(read.voxel(i).x == 1.0f);
  }
  block.coords = Eigen::Vector3i(2, 3, 4);
  CHECK(block.min_voxel() == Eigen::Vector3i(16, 24, 32));
  MidLevel<MultiresVoxel> mid;
  block.mid = &mid;
  block.level_at(2, 3, 3, 1).y = 3.0f;
  CHECK(block.at_voxel(Eigen::Vector3i(16 + 5, 24 + 6, 32 + 7), 1).y == 3.0f);
  CHECK(&block.level_at(2, 3, 3, 1) == block.level_begin(1) + 2 + 3 * 4 + 3 * 16);
  CHECK(&block.level_at(2, 3, 3, 1) == &mid.voxels[2 + 3 * 4 + 3 * 16]);
}

TEST_CASE("without a finest level, scale 0 reads as unobserved; with one it is that level",
          "[map][block]") {
  VoxelBlock<MultiresVoxel> block;
  const VoxelBlock<MultiresVoxel>& read = block;
  // Reads of scale 0 see a shared, never-written level.
  CHECK(read.finest_begin() == kUnobservedFinestLevel<MultiresVoxel>.voxels);
  CHECK_FALSE(voxel_observed(read.at(7, 7, 7, 0)));
  CHECK_FALSE(voxel_observed(read.at_voxel(Eigen::Vector3i(3, 4, 5), 0)));
  FinestLevel<MultiresVoxel> level;
  block.finest = &level;
  CHECK(block.has_finest());
  // A voxel written at scale 0 keeps its TSDF and weight; it reads back as one whose interval
  // just started (x_last = x, delta_y = 0).
  block.set_voxel(block_voxel_index(1, 2, 3, 0), MultiresVoxel{-0.25f, 0.5f, 5.0f, 2.0f});
  CHECK(level.voxels[1 + 2 * 8 + 3 * 64].x == -0.25f);
  CHECK(level.voxels[1 + 2 * 8 + 3 * 64].y == 5.0f);
  CHECK(read.finest_begin() == level.voxels);
  const MultiresVoxel back = read.at(1, 2, 3, 0);
  CHECK(back.x == -0.25f);
  CHECK(back.x_last == -0.25f);
  CHECK(back.y == 5.0f);
  CHECK(back.delta_y == 0.0f);
  // Scale 1 likewise: shared and unobserved until the block has a mid level, then that level.
  CHECK(read.level_begin(1) == kUnobservedMidLevel<MultiresVoxel>.voxels);
  CHECK_FALSE(voxel_observed(read.at(3, 3, 3, 1)));
  MidLevel<MultiresVoxel> mid;
  block.mid = &mid;
  CHECK(block.has_mid());
  block.level_at(3, 0, 1, 1).y = 2.0f;
  CHECK(mid.voxels[3 + 0 * 4 + 1 * 16].y == 2.0f);
  CHECK(&block.level_voxel(block_voxel_index(3, 0, 1, 1)) == &mid.voxels[3 + 16]);
  CHECK(read.voxel(block_voxel_index(3, 0, 1, 1)).y == 2.0f);
  // The two coarsest levels stay inline.
  CHECK(block.level_begin(2) == block.inline_voxels);
  CHECK(block.level_begin(3) == block.inline_voxels + 8);
  CHECK(&block.level_voxel(block_voxel_index(1, 1, 1, 2)) == block.inline_voxels + 7);
}

}  // namespace
}  // namespace octofuse
