#include "octofuse/map/voxel.hpp"

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include <catch2/catch.hpp>

#include "octofuse/map/detail/mip.hpp"
#include "octofuse/map/voxel_block.hpp"

namespace octofuse {
namespace {

// One TSDF step is 2^-14; rounding to the nearest step is off by at most half of one.
constexpr float kTsdfStep = 1.0f / 16384.0f;
constexpr float kWeightStep = 1.0f / 64.0f;

TEST_CASE("the 16-bit voxel is half the float multires voxel", "[map][voxel][multires16]") {
  STATIC_REQUIRE(sizeof(Multires16Voxel) == 8);
  STATIC_REQUIRE(sizeof(MultiresVoxel) == 16);
  STATIC_REQUIRE(IsMultiresVoxel<Multires16Voxel>::value);
  // A block's inline levels (73 voxels) and its finest level (512) halve with it.
  STATIC_REQUIRE(sizeof(FinestLevel<Multires16Voxel>) * 2 == sizeof(FinestLevel<MultiresVoxel>));
  STATIC_REQUIRE(sizeof(VoxelBlock<Multires16Voxel>) < sizeof(VoxelBlock<MultiresVoxel>));
}

TEST_CASE("a default 16-bit voxel reads as the float one: TSDF 1, unobserved",
          "[map][voxel][multires16]") {
  const Multires16Voxel v;
  CHECK(voxel_tsdf(v) == 1.0f);
  CHECK(voxel_x_last(v) == 1.0f);
  CHECK(voxel_weight(v) == 0.0f);
  CHECK(voxel_delta_y(v) == 0.0f);
  CHECK_FALSE(voxel_observed(v));
}

TEST_CASE("TSDF quantisation: hand-computed steps, ties away from zero, clamped",
          "[map][voxel][multires16]") {
  CHECK(quantise_tsdf16(0.0f) == 0);
  CHECK(quantise_tsdf16(1.0f) == 16384);
  CHECK(quantise_tsdf16(-1.0f) == -16384);
  CHECK(quantise_tsdf16(0.5f) == 8192);
  // 1/3 * 16384 = 5461.33 -> 5461, read back as 5461 / 16384 = 0.33331298828125.
  CHECK(quantise_tsdf16(1.0f / 3.0f) == 5461);
  CHECK(dequantise_tsdf16(5461) == 0.33331298828125f);
  // -0.7 * 16384 = -11468.8 -> -11469.
  CHECK(quantise_tsdf16(-0.7f) == -11469);
  // Exactly half a step: away from zero, both signs.
  CHECK(quantise_tsdf16(0.5f * kTsdfStep) == 1);
  CHECK(quantise_tsdf16(-0.5f * kTsdfStep) == -1);
  CHECK(quantise_tsdf16(2.5f * kTsdfStep) == 3);
  // Just below half a step: towards zero.
  CHECK(quantise_tsdf16(std::nextafter(0.5f * kTsdfStep, 0.0f)) == 0);
  // Out of range and NaN clamp.
  CHECK(quantise_tsdf16(1.5f) == 16384);
  CHECK(quantise_tsdf16(-7.0f) == -16384);
  CHECK(quantise_tsdf16(std::numeric_limits<float>::infinity()) == 16384);
  CHECK(quantise_tsdf16(std::numeric_limits<float>::quiet_NaN()) == -16384);
}

TEST_CASE("TSDF round trip: every step exact, any value within half a step",
          "[map][voxel][multires16]") {
  for (int q = -16384; q <= 16384; ++q) {
    const auto step = static_cast<std::int16_t>(q);
    REQUIRE(quantise_tsdf16(dequantise_tsdf16(step)) == step);
  }
  std::mt19937 rng(18);
  std::uniform_real_distribution<float> value(-1.0f, 1.0f);
  float worst = 0.0f;
  for (int i = 0; i < 200000; ++i) {
    const float x = value(rng);
    const float error = std::abs(dequantise_tsdf16(quantise_tsdf16(x)) - x);
    worst = std::max(worst, error);
    REQUIRE(error <= 0.5f * kTsdfStep);
  }
  CHECK(worst > 0.45f * kTsdfStep);  // the bound is tight, not loose
}

TEST_CASE("weight quantisation: whole counts exact, 1/64 steps, saturating",
          "[map][voxel][multires16]") {
  for (int n = 0; n <= 1023; ++n) {
    const float w = static_cast<float>(n);
    REQUIRE(dequantise_weight16(quantise_weight16(w)) == w);
  }
  CHECK(quantise_weight16(100.0f) == 6400);
  CHECK(quantise_weight16(2.5f) == 160);
  // 0.3 * 64 = 19.2 -> 19: 0.296875, within half a step of 0.3.
  CHECK(quantise_weight16(0.3f) == 19);
  CHECK(std::abs(dequantise_weight16(19) - 0.3f) <= 0.5f * kWeightStep);
  // A weight below half a step reads unobserved; half a step and more does not.
  CHECK(quantise_weight16(0.49f * kWeightStep) == 0);
  CHECK(quantise_weight16(0.5f * kWeightStep) == 1);
  CHECK(kMultires16MaxWeight == 1023.984375f);
  CHECK(quantise_weight16(kMultires16MaxWeight) == 65535);
  CHECK(quantise_weight16(5000.0f) == 65535);
  CHECK(quantise_weight16(-1.0f) == 0);
  CHECK(quantise_weight16(std::numeric_limits<float>::quiet_NaN()) == 0);
}

TEST_CASE("16-bit accessors store rounded and read back as float", "[map][voxel][multires16]") {
  Multires16Voxel v;
  set_voxel_tsdf(v, -0.25f);
  set_voxel_x_last(v, 0.1f);
  set_voxel_weight(v, 37.0f);
  set_voxel_delta_y(v, 3.0f);
  CHECK(v.x_q == -4096);
  CHECK(v.x_last_q == 1638);  // 1638.4
  CHECK(voxel_tsdf(v) == -0.25f);
  CHECK(std::abs(voxel_x_last(v) - 0.1f) <= 0.5f * kTsdfStep);
  CHECK(voxel_weight(v) == 37.0f);
  CHECK(voxel_delta_y(v) == 3.0f);
  CHECK(voxel_observed(v));
  // delta_y saturates at the largest weight instead of wrapping.
  set_voxel_delta_y(v, kMultires16MaxWeight + 1.0f);
  CHECK(voxel_delta_y(v) == kMultires16MaxWeight);
}

TEST_CASE("a 16-bit parent is the rounded mean of its children and restarts its interval",
          "[map][voxel][multires16]") {
  VoxelBlock<Multires16Voxel> block;
  MidLevel<Multires16Voxel> mid;  // scale 1, as the map would lend it
  block.mid = &mid;
  // Scale 1 -> 2 only (no finest level needed). Children TSDF c/10, weights 1..8.
  for (int c = 0; c < 8; ++c) {
    Multires16Voxel& child = block.level_at(c & 1, (c >> 1) & 1, (c >> 2) & 1, 1);
    set_voxel_tsdf(child, static_cast<float>(c) / 10.0f);
    set_voxel_weight(child, static_cast<float>(c + 1));
  }
  float sum = 0.0f;
  for (int c = 0; c < 8; ++c) {
    sum += voxel_tsdf(block.at(c & 1, (c >> 1) & 1, (c >> 2) & 1, 1));
  }
  propagate_block_up(block, 1, 2);
  const Multires16Voxel& parent = block.at(0, 0, 0, 2);
  CHECK(parent.x_q == quantise_tsdf16(sum / 8.0f));
  // Children off by half a step at most, their mean too, and the mean rounded once more.
  CHECK(std::abs(voxel_tsdf(parent) - 0.35f) <= kTsdfStep);
  CHECK(parent.x_last_q == parent.x_q);
  CHECK(voxel_weight(parent) == 5.0f);  // ceil(36 / 8)
  CHECK(parent.delta_y_q == 0);
}

}  // namespace
}  // namespace octofuse
