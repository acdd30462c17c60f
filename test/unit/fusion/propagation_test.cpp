#include "octofuse/map/detail/propagation.hpp"

#include <algorithm>
#include <cmath>

#include <catch2/catch.hpp>

#include "octofuse/map/detail/mip.hpp"

namespace octofuse {
namespace {

constexpr float kYMax = 100.0f;

TEST_CASE("down-propagation applies the parent's delta to observed children", "[fusion][down]") {
  VoxelBlock<MultiresVoxel> block;
  MidLevel<MultiresVoxel> mid;  // scale 1, as the map would lend it
  block.mid = &mid;
  // Parent (scale 3) was 0.2 at its last propagation and is now 0.5, with 3 new samples.
  block.level_at(0, 0, 0, 3) = MultiresVoxel{0.5f, 0.2f, 10.0f, 3.0f};
  for (int i = 0; i < 8; ++i) {
    MultiresVoxel& child = block.level_voxel(block_scale_offset(2) + i);
    child = MultiresVoxel{0.1f * static_cast<float>(i) - 0.3f, 0.0f, 7.0f, 1.0f};
  }
  block.level_voxel(block_scale_offset(2) + 7).x = 0.9f;   // will clamp at 1
  block.level_voxel(block_scale_offset(2) + 6).y = 99.0f;  // will cap at y_max
  propagate_block_down(block, 3, kYMax);
  for (int i = 0; i < 6; ++i) {
    const MultiresVoxel& child = block.voxel(block_scale_offset(2) + i);
    CHECK(child.x == Approx(0.1f * i - 0.3f + 0.3f).margin(1e-6));
    CHECK(child.y == 10.0f);
    CHECK(child.delta_y == 4.0f);
  }
  CHECK(block.voxel(block_scale_offset(2) + 7).x == 1.0f);
  CHECK(block.voxel(block_scale_offset(2) + 6).y == kYMax);
  // The parent starts a new interval.
  CHECK(block.at(0, 0, 0, 3).x_last == 0.5f);
  CHECK(block.at(0, 0, 0, 3).delta_y == 0.0f);
  CHECK(block.at(0, 0, 0, 3).x == 0.5f);
}

TEST_CASE("down-propagation interpolates unobserved children, extrapolating at the border",
          "[fusion][down]") {
  VoxelBlock<MultiresVoxel> block;
  MidLevel<MultiresVoxel> mid;  // scale 1, as the map would lend it
  block.mid = &mid;
  // Scale-2 parents (2x2x2) with a field linear in x: x = 0.2 + 0.4 * px.
  for (int z = 0; z < 2; ++z)
    for (int y = 0; y < 2; ++y)
      for (int x = 0; x < 2; ++x)
        block.level_at(x, y, z, 2) = MultiresVoxel{0.2f + 0.4f * x, 0.2f + 0.4f * x, 5.0f, 0.0f};
  propagate_block_down(block, 2, kYMax);
  // Children (4 per axis) centres sit at parent coordinates -0.25, 0.25, 0.75, 1.25: a linear
  // field is reproduced exactly, extrapolated beyond the outer parent centres.
  const float expected[4] = {0.1f, 0.3f, 0.5f, 0.7f};
  for (int z = 0; z < 4; ++z)
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 4; ++x) {
        const MultiresVoxel& c = block.at(x, y, z, 1);
        CAPTURE(x, y, z);
        CHECK(c.x == Approx(expected[x]).margin(1e-6));
        CHECK(c.x_last == c.x);
        CHECK(c.y == 5.0f);
        CHECK(c.delta_y == 0.0f);
      }
}

TEST_CASE("hand-computed trilinear value for a non-linear parent field", "[fusion][down]") {
  VoxelBlock<MultiresVoxel> block;
  MidLevel<MultiresVoxel> mid;  // scale 1, as the map would lend it
  block.mid = &mid;
  // Scale-2 parents: all 0 except parent (1,1,1) = 0.8.
  for (int i = 0; i < 8; ++i)
    block.level_voxel(block_scale_offset(2) + i) = {0.0f, 0.0f, 2.0f, 0.0f};
  block.level_at(1, 1, 1, 2).x = 0.8f;
  propagate_block_down(block, 2, kYMax);
  // Child (2,2,2) is nearest parent (1,1,1), 1/4 towards (0,0,0): weight 0.75^3 on 0.8.
  CHECK(block.at(2, 2, 2, 1).x == Approx(0.8f * 0.421875f).margin(1e-6));
  // Child (1,1,1): 1/4 from (0,0,0) towards (1,1,1): weight 0.25^3.
  CHECK(block.at(1, 1, 1, 1).x == Approx(0.8f * 0.015625f).margin(1e-6));
  // Child (3,3,3): extrapolated beyond (1,1,1), weight 1.25^3 on 0.8 (clamped at 1).
  CHECK(block.at(3, 3, 3, 1).x == 1.0f);
  // Child (3,2,2): weights x 1.25, y 0.75, z 0.75 -> 0.8 * 0.703125.
  CHECK(block.at(3, 2, 2, 1).x == Approx(0.8f * 0.703125f).margin(1e-6));
}

TEST_CASE(
    "unobserved parents leave unobserved children alone; a partly observed "
    "neighbourhood falls back to the parent value",
    "[fusion][down]") {
  VoxelBlock<MultiresVoxel> block;
  MidLevel<MultiresVoxel> mid;  // scale 1, as the map would lend it
  block.mid = &mid;
  block.level_at(0, 0, 0, 2) = MultiresVoxel{-0.4f, -0.4f, 3.0f, 0.0f};
  propagate_block_down(block, 2, kYMax);
  CHECK(block.at(0, 0, 0, 1).x == -0.4f);  // neighbours unobserved: nearest parent
  CHECK(block.at(1, 1, 1, 1).y == 3.0f);
  CHECK_FALSE(voxel_observed(block.at(2, 0, 0, 1)));  // parent (1,0,0) unobserved
}

TEST_CASE("down then up: parents are the mean of the updated children", "[fusion][down]") {
  VoxelBlock<MultiresVoxel> block;
  MidLevel<MultiresVoxel> mid;  // scale 1, as the map would lend it
  block.mid = &mid;
  for (int i = 0; i < 8; ++i) {
    block.level_voxel(block_scale_offset(2) + i) =
        MultiresVoxel{0.0625f * static_cast<float>(i), 0.0f, 4.0f, 0.0f};
  }
  propagate_block_up(block, 2, 3);
  block.level_at(0, 0, 0, 3).x += 0.25f;  // a coarse update
  block.level_at(0, 0, 0, 3).delta_y = 1.0f;
  propagate_block_down(block, 3, kYMax);
  propagate_block_up(block, 2, 3);
  CHECK(block.at(0, 0, 0, 3).x == Approx(0.21875f + 0.25f).margin(1e-6));
  CHECK(block.at(0, 0, 0, 3).y == 5.0f);
}

// The same block in both types, its values on the 16-bit grid (so the inputs are equal): the
// 16-bit down-propagation is the float one rounded once, half a step at most, and its weights are
// exact.
TEST_CASE("16-bit down-propagation is the float one rounded to the nearest step",
          "[fusion][down][multires16]") {
  constexpr float kHalfStep = 0.5f / 16384.0f;
  VoxelBlock<MultiresVoxel> ref;
  VoxelBlock<Multires16Voxel> q16;
  FinestLevel<MultiresVoxel> ref_finest;
  FinestLevel<Multires16Voxel> q16_finest;
  MidLevel<MultiresVoxel> ref_mid;
  MidLevel<Multires16Voxel> q16_mid;
  ref.finest = &ref_finest;
  q16.finest = &q16_finest;
  ref.mid = &ref_mid;
  q16.mid = &q16_mid;
  // A curved parent field at scale 1 with steps of fresh samples; every other child observed.
  for (int z = 0; z < 4; ++z)
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 4; ++x) {
        const float value = 0.9f - 0.05f * static_cast<float>(x * x + 2 * y + z);
        const float last = value - 0.01f * static_cast<float>(x + y);
        MultiresVoxel& p = ref.level_at(x, y, z, 1);
        Multires16Voxel& q = q16.level_at(x, y, z, 1);
        set_voxel_tsdf(q, value);
        set_voxel_x_last(q, last);
        set_voxel_weight(q, static_cast<float>(3 + x));
        set_voxel_delta_y(q, static_cast<float>(z));
        p = MultiresVoxel{voxel_tsdf(q), voxel_x_last(q), voxel_weight(q), voxel_delta_y(q)};
      }
  for (int i = 0; i < kBlockFinestVoxelCount; i += 2) {
    Multires16Voxel q;
    set_voxel_tsdf(q, 0.3f - 0.001f * static_cast<float>(i));
    set_voxel_x_last(q, voxel_tsdf(q));
    set_voxel_weight(q, 95.0f + static_cast<float>(i % 7));
    set_voxel_delta_y(q, 1.0f);
    q16.set_voxel(i, q);
    ref.set_voxel(i,
                  MultiresVoxel{voxel_tsdf(q), voxel_x_last(q), voxel_weight(q), voxel_delta_y(q)});
  }
  propagate_block_down(ref, 1, kYMax);
  propagate_block_down(q16, 1, kYMax);
  float worst = 0.0f;
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    CAPTURE(i);
    const MultiresVoxel& a = ref.voxel(i);
    const Multires16Voxel& b = q16.voxel(i);
    REQUIRE(voxel_observed(b));
    CHECK(std::abs(voxel_tsdf(b) - a.x) <= kHalfStep);
    CHECK(std::abs(voxel_x_last(b) - a.x_last) <= kHalfStep);
    CHECK(voxel_weight(b) == a.y);  // whole counts, some capped at y_max
    CHECK(voxel_delta_y(b) == a.delta_y);
    worst = std::max(worst, std::abs(voxel_tsdf(b) - a.x));
  }
  CHECK(worst > 0.0f);
  for (int i = 0; i < block_scale_count(1); ++i) {
    CHECK(q16.voxel(block_scale_offset(1) + i).delta_y_q == 0);
    CHECK(voxel_x_last(q16.voxel(block_scale_offset(1) + i)) ==
          voxel_tsdf(q16.voxel(block_scale_offset(1) + i)));
  }
}

}  // namespace
}  // namespace octofuse
