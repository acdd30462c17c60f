#include "octofuse/map/detail/mip.hpp"

#include <random>

#include <catch2/catch.hpp>

namespace octofuse {
namespace {

TEST_CASE("reads at scale s of a block filled at scale 0 follow the mean rule", "[map][mip]") {
  VoxelBlock<MultiresVoxel> block;
  MidLevel<MultiresVoxel> mid;  // scale 1, as the map would lend it
  block.mid = &mid;
  FinestLevel<MultiresVoxel> finest;  // what the map would lend
  block.finest = &finest;
  // Integer-valued fields keep the float means exact: x = (x + 2y + 4z) / 64.
  for (int z = 0; z < 8; ++z)
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x) {
        MultiresFinestVoxel& v = block.finest_begin()[block_voxel_index(x, y, z, 0)];
        v.x = static_cast<float>(x + 2 * y + 4 * z) / 64.0f;
        v.y = static_cast<float>(1 + x);
      }
  propagate_block_up(block, 0, kMaxBlockScale);
  for (int s = 1; s <= kMaxBlockScale; ++s) {
    const int n = block_scale_side(s);
    const int w = 1 << s;
    for (int z = 0; z < n; ++z)
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
          // Mean over the w^3 finest voxels below: coordinates average to base + (w-1)/2.
          const double cx = x * w + (w - 1) / 2.0;
          const double cy = y * w + (w - 1) / 2.0;
          const double cz = z * w + (w - 1) / 2.0;
          const MultiresVoxel& v = block.at(x, y, z, s);
          CAPTURE(s, x, y, z);
          REQUIRE(v.x == Approx((cx + 2 * cy + 4 * cz) / 64.0).margin(1e-6));
          REQUIRE(v.x_last == v.x);
          REQUIRE(v.delta_y == 0.0f);
          // Mean of (1 + x) over the children, rounded up at each level.
          REQUIRE(v.y >= static_cast<float>(1 + cx));
          REQUIRE(v.y <= static_cast<float>(1 + cx) + 1.0f);
        }
  }
  // Scale 1 exactly: children x in {2x, 2x+1} -> weights (1+2x, 2+2x) -> mean 1.5+2x -> 2+2x.
  CHECK(block.at(0, 0, 0, 1).y == 2.0f);
  CHECK(block.at(3, 0, 0, 1).y == 8.0f);
}

TEST_CASE("up-propagation averages observed children only", "[map][mip]") {
  VoxelBlock<TsdfVoxel> block;
  // In the first parent (children of (0,0,0) at scale 1) observe three children.
  block.level_at(0, 0, 0, 0) = TsdfVoxel{0.5f, 2.0f};
  block.level_at(1, 0, 0, 0) = TsdfVoxel{-0.25f, 3.0f};
  block.level_at(0, 1, 1, 0) = TsdfVoxel{0.0f, 3.0f};
  // The second parent keeps a value and no observed children: it must stay unchanged.
  block.level_at(1, 0, 0, 1) = TsdfVoxel{0.125f, 7.0f};
  propagate_block_up(block, 0, 1);
  CHECK(block.at(0, 0, 0, 1).tsdf == Approx(0.25f / 3.0f).margin(1e-7));
  CHECK(block.at(0, 0, 0, 1).weight == 3.0f);  // ceil(8 / 3)
  CHECK(block.at(1, 0, 0, 1).tsdf == 0.125f);
  CHECK(block.at(1, 0, 0, 1).weight == 7.0f);
  CHECK_FALSE(voxel_observed(block.at(0, 1, 0, 1)));
}

}  // namespace
}  // namespace octofuse
