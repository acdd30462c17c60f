// Allocation in 2 x 2 groups of pixels (FusionConfig::allocation_group_block_px): a group's first
// ray stands for the others where a block spans enough pixels, and never across a depth edge.
// Checked against the march of every ray on analytic depth images.

#include <cstdint>
#include <set>
#include <tuple>

#include <catch2/catch.hpp>

#include "unit/fusion/integrator_support.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.01f;
constexpr float kMu_m = 8 * kVoxel_m;

using BlockSet = std::set<std::tuple<int, int, int>>;

struct Fused {
  BlockSet blocks;
  std::uint32_t rays = 0;
};

// Fuses one depth image (`depth_at(u, v)`) seen from the origin looking along +z.
template <typename DepthAt>
Fused fuse_image(float group_block_px, int width, int height, float f_px, DepthAt depth_at) {
  FusionConfig config = fusion_config(kMu_m);
  config.allocation_group_block_px = group_block_px;
  const PinholeCamera camera = test::centred_camera(width, height, f_px);
  Fusion<MultiresVoxel> fusion(map_config(kVoxel_m, 9, 20000), config, camera);
  fusion.depth.resize(static_cast<std::size_t>(width * height));
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u)
      fusion.depth[static_cast<std::size_t>(v * width + u)] = depth_at(u, v);
  }
  const WorkerTeam team(1);
  const IntegrationReport report =
      fusion.fuse_rendered(test::looking_along_z(Eigen::Vector3d::Zero()), FusionBudget(), team);
  REQUIRE(report.status.ok());
  REQUIRE(report.keys_dropped == 0);
  Fused out;
  out.rays = report.allocation_rays;
  for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
    const Eigen::Vector3i& c = fusion.map.block(i).coords;
    out.blocks.emplace(c.x(), c.y(), c.z());
  }
  return out;
}

bool contains_all(const BlockSet& big, const BlockSet& small) {
  for (const auto& b : small) {
    if (big.count(b) == 0) return false;
  }
  return true;
}

TEST_CASE("a wall whose blocks span many pixels: a quarter of the rays, nearly every block",
          "[fusion][integrator]") {
  // 120 px focal length, blocks of 8 cm at 0.9-1.1 m: 9-11 px a block, above the 8 px threshold.
  auto wall = [](int u, int v) { return 0.9f + 0.001f * static_cast<float>(u) + 0.0005f * v; };
  const Fused every = fuse_image(0.0f, 160, 120, 120.0f, wall);
  const Fused grouped = fuse_image(8.0f, 160, 120, 120.0f, wall);
  CAPTURE(every.rays, grouped.rays, every.blocks.size(), grouped.blocks.size());
  REQUIRE(every.rays == 160u * 120u);
  REQUIRE(grouped.rays == every.rays / 4);
  // The grouped rays are some of every ray: their blocks are some of every ray's blocks.
  REQUIRE(contains_all(every.blocks, grouped.blocks));
  REQUIRE(grouped.blocks.size() * 100 >= every.blocks.size() * 97);
}

TEST_CASE("where a block spans fewer pixels than the threshold, every ray marches",
          "[fusion][integrator]") {
  // At 3 m a block spans 3.2 px.
  auto far_wall = [](int, int) { return 3.0f; };
  const Fused every = fuse_image(0.0f, 160, 120, 120.0f, far_wall);
  const Fused grouped = fuse_image(8.0f, 160, 120, 120.0f, far_wall);
  REQUIRE(grouped.rays == every.rays);
  REQUIRE(grouped.blocks == every.blocks);
}

TEST_CASE("a bar one pixel wide that only a group's other pixels see keeps its blocks",
          "[fusion][integrator]") {
  // A wall at 1 m and, in columns 51 and 101 (the second column of their groups), a bar 40 cm in
  // front of it: the group's first pixel sees the wall, so the bar's rays must march themselves.
  auto bar_only = [](int u, int) { return u == 51 || u == 101 ? 0.6f : 0.0f; };
  auto wall_and_bar = [](int u, int) { return u == 51 || u == 101 ? 0.6f : 1.0f; };
  const Fused bar = fuse_image(0.0f, 160, 120, 120.0f, bar_only);
  const Fused grouped = fuse_image(8.0f, 160, 120, 120.0f, wall_and_bar);
  REQUIRE(!bar.blocks.empty());
  REQUIRE(contains_all(grouped.blocks, bar.blocks));
  // Elsewhere the wall's groups still march one ray in four.
  REQUIRE(grouped.rays < 160u * 120u / 2);
}

TEST_CASE("groups are taken only on frames where a quarter of the depths can stand for a group",
          "[fusion][integrator]") {
  // Blocks span 8 px up to 1.2 m (120 px focal length, 8 cm blocks). A wall at 3 m with a near
  // box at 1 m over a tenth of the image: too few groups could stand, every ray marches (the same
  // rays and blocks as with groups off).
  auto small_box = [](int u, int v) { return u < 40 && v < 48 ? 1.0f : 3.0f; };
  const Fused every_small = fuse_image(0.0f, 160, 120, 120.0f, small_box);
  const Fused grouped_small = fuse_image(8.0f, 160, 120, 120.0f, small_box);
  REQUIRE(every_small.rays == 160u * 120u);
  REQUIRE(grouped_small.rays == every_small.rays);
  REQUIRE(grouped_small.blocks == every_small.blocks);
  // The box over half of the image: its groups march one ray in four, the wall every ray.
  auto large_box = [](int u, int) { return u < 80 ? 1.0f : 3.0f; };
  const Fused every_large = fuse_image(0.0f, 160, 120, 120.0f, large_box);
  const Fused grouped_large = fuse_image(8.0f, 160, 120, 120.0f, large_box);
  CAPTURE(every_large.rays, grouped_large.rays);
  REQUIRE(every_large.rays == 160u * 120u);
  REQUIRE(grouped_large.rays < every_large.rays * 3 / 4);
  REQUIRE(grouped_large.rays > every_large.rays / 2);
  REQUIRE(contains_all(every_large.blocks, grouped_large.blocks));
}

}  // namespace
}  // namespace octofuse
