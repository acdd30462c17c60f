// begin_frame() / finish_frame(): the frame's blocks collected once, counted before the caller
// makes room, integrated after. Checked against what the pipeline did before them: a pass of
// integrate() that allocates and integrates nothing to count the new blocks, the same eviction,
// then a whole integrate().

#include <cstdint>
#include <vector>

#include <catch2/catch.hpp>

#include "unit/fusion/integrator_support.hpp"

namespace octofuse {
namespace {

template <typename VoxelT>
void require_same_blocks(const Octree<VoxelT>& one, const Octree<VoxelT>& two) {
  REQUIRE(one.block_count() == two.block_count());
  REQUIRE(one.node_count() == two.node_count());
  for (std::uint32_t i = 0; i < one.block_count(); ++i) {
    const VoxelBlock<VoxelT>& a = one.block(i);
    const VoxelBlock<VoxelT>& b = two.block(i);
    // Everything but the finest-level pointer (into two different pools) byte for byte.
    const std::size_t header = static_cast<std::size_t>(reinterpret_cast<const char*>(&a.finest) -
                                                        reinterpret_cast<const char*>(&a));
    REQUIRE(std::memcmp(&a, &b, header) == 0);
    REQUIRE(std::memcmp(a.inline_voxels, b.inline_voxels, sizeof(a.inline_voxels)) == 0);
    REQUIRE(a.has_finest() == b.has_finest());
    if (a.has_finest()) {
      REQUIRE(std::memcmp(a.finest_begin(), b.finest_begin(),
                          sizeof(FinestVoxelT<VoxelT>) * kBlockFinestVoxelCount) == 0);
    }
  }
  for (std::uint32_t i = 0; i < one.node_count(); ++i) {
    REQUIRE(std::memcmp(&one.node(i).summary, &two.node(i).summary, sizeof(NodeSummary)) == 0);
  }
  const MapMemory ma = one.memory();
  const MapMemory mb = two.memory();
  REQUIRE(ma.finest_used == mb.finest_used);
  REQUIRE(ma.refusals == mb.refusals);
  REQUIRE(ma.evicted == mb.evicted);
}

void require_same_report(const IntegrationReport& a, const IntegrationReport& b) {
  REQUIRE(a.status.code() == b.status.code());
  REQUIRE(a.blocks_touched == b.blocks_touched);
  REQUIRE(a.blocks_requested == b.blocks_requested);
  REQUIRE(a.blocks_allocated == b.blocks_allocated);
  REQUIRE(a.blocks_integrated == b.blocks_integrated);
  for (int s = 0; s < 4; ++s) REQUIRE(a.blocks_per_scale[s] == b.blocks_per_scale[s]);
  REQUIRE(a.blocks_refined == b.blocks_refined);
  REQUIRE(a.blocks_coarsened == b.blocks_coarsened);
  REQUIRE(a.pool_refusals == b.pool_refusals);
  REQUIRE(a.finest_refusals == b.finest_refusals);
  REQUIRE(a.keys_dropped == b.keys_dropped);
  REQUIRE(a.rays_outside_cube == b.rays_outside_cube);
  REQUIRE(a.allocation_rays == b.allocation_rays);
  REQUIRE(a.budget_blocks_not_allocated == b.budget_blocks_not_allocated);
  REQUIRE(a.budget_blocks_coarsened == b.budget_blocks_coarsened);
  REQUIRE(a.budget_blocks_skipped == b.budget_blocks_skipped);
  REQUIRE(a.budget_hit == b.budget_hit);
  REQUIRE(a.voxels_updated == b.voxels_updated);
}

// Makes room for `new_blocks` the way an evicting caller would, and more: blocks spread over the
// pool (many of them in view, so pool indices move under the collected list) until used + new
// fits in `capacity` with a margin, then the finest levels of every fifth block that remains
// (their scale changes under the list).
template <typename VoxelT>
void make_room(Octree<VoxelT>& map, std::uint32_t new_blocks, std::uint32_t capacity) {
  const std::uint32_t used = map.block_count();
  const std::uint64_t want = std::uint64_t{used} + new_blocks + 40;
  const std::uint64_t excess = want > capacity ? std::min<std::uint64_t>(want - capacity, used) : 0;
  std::vector<std::uint32_t> indices;
  for (std::uint32_t first = 0; first < 3; ++first) {
    for (std::uint32_t i = first; i < used && indices.size() < excess; i += 3) indices.push_back(i);
  }
  map.evict_blocks(indices.data(), indices.size());
  std::vector<std::uint32_t> demote;
  for (std::uint32_t i = 0; i < map.block_count(); i += 5) demote.push_back(i);
  map.release_finest(demote.data(), demote.size());
}

TEMPLATE_TEST_CASE(
    "begin_frame/finish_frame give the map and report of a counting pass, "
    "eviction and a whole integrate()",
    "[fusion][integrator][demand]", MultiresVoxel, Multires16Voxel) {
  AnalyticScene scene;
  scene.spheres.push_back({Eigen::Vector3d(0.1, 0.0, 1.3), 0.3});
  scene.spheres.push_back({Eigen::Vector3d(-0.4, 0.2, 1.6), 0.2});
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.9});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  // A pool well below what the orbit touches: every frame has to make room.
  constexpr std::uint32_t kCapacity = 1400;
  MapConfig config = map_config(0.01f, 8, kCapacity);
  config.finest_capacity = 300;
  const int workers = GENERATE(1, 3);
  CAPTURE(workers);
  WorkerTeam team(workers);
  Fusion<TestType> before(config, fusion_config(0.08f), camera);
  Fusion<TestType> after(config, fusion_config(0.08f), camera);
  FusionBudget budget;
  budget.max_new_blocks = 900;
  std::uint32_t evicting_frames = 0;
  for (int i = 0; i < 8; ++i) {
    CAPTURE(i);
    const Se3d pose = test::looking_along_z({0.06 * i - 0.2, 0.03 * (i % 3), -0.5 + 0.2 * (i % 4)});
    scene.render(camera, pose, before.depth);
    after.depth = before.depth;
    const ImageView<const float> depth_before(before.depth.data(), camera.width, camera.height);
    const ImageView<const float> depth_after(after.depth.data(), camera.width, camera.height);

    // Before: a pass that allocates and integrates nothing counts the new blocks.
    FusionBudget dry = budget;
    dry.max_new_blocks = 0;
    dry.max_integrated_blocks = 0;
    const IntegrationReport probe = before.integrator.integrate(before.map, depth_before, camera,
                                                                pose, before.frame, dry, team);
    REQUIRE(before.map.block_count() == after.map.block_count());
    // After: collected once and counted.
    const IntegrationReport begun =
        after.integrator.begin_frame(after.map, depth_after, camera, pose, team);
    REQUIRE(begun.status.ok());
    REQUIRE(begun.blocks_requested == probe.blocks_requested);
    REQUIRE(begun.blocks_touched == probe.blocks_touched);
    REQUIRE(begun.blocks_touched > 0);

    const std::uint32_t new_blocks = std::min(begun.blocks_requested, budget.max_new_blocks);
    const std::uint32_t used = before.map.block_count();
    make_room(before.map, new_blocks, kCapacity);
    make_room(after.map, new_blocks, kCapacity);
    if (after.map.block_count() < used) ++evicting_frames;

    const IntegrationReport a = before.integrator.integrate(before.map, depth_before, camera, pose,
                                                            before.frame++, budget, team);
    const IntegrationReport b = after.integrator.finish_frame(after.map, depth_after, camera, pose,
                                                              after.frame++, budget, team);
    require_same_report(a, b);
    require_same_blocks(before.map, after.map);
  }
  // The scenario did what it is for: blocks in view evicted between the parts.
  CHECK(evicting_frames >= 4);
}

TEST_CASE("finish_frame() needs a begin_frame() with the same inputs", "[fusion][integrator]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.5});
  const PinholeCamera camera = test::centred_camera(80, 60, 65.0f);
  Fusion<MultiresVoxel> fusion(map_config(0.02f, 7, 2000), fusion_config(0.1f), camera);
  const Se3d pose = test::looking_along_z({0.0, 0.0, 0.0});
  scene.render(camera, pose, fusion.depth);
  const ImageView<const float> depth(fusion.depth.data(), camera.width, camera.height);
  WorkerTeam team(1);
  // None begun.
  IntegrationReport r =
      fusion.integrator.finish_frame(fusion.map, depth, camera, pose, 0, FusionBudget(), team);
  CHECK(r.status.code() == StatusCode::failed_precondition);
  CHECK(fusion.map.block_count() == 0);
  // Begun for another pose.
  REQUIRE(fusion.integrator.begin_frame(fusion.map, depth, camera, pose, team).status.ok());
  const Se3d moved = test::looking_along_z({0.05, 0.0, 0.0});
  r = fusion.integrator.finish_frame(fusion.map, depth, camera, moved, 0, FusionBudget(), team);
  CHECK(r.status.code() == StatusCode::failed_precondition);
  CHECK(fusion.map.block_count() == 0);
  // A whole integrate() in between ends what was begun.
  REQUIRE(fusion.integrator.begin_frame(fusion.map, depth, camera, pose, team).status.ok());
  REQUIRE(fusion.integrator.integrate(fusion.map, depth, camera, pose, 0, FusionBudget(), team)
              .status.ok());
  const std::uint32_t blocks = fusion.map.block_count();
  CHECK(blocks > 0);
  r = fusion.integrator.finish_frame(fusion.map, depth, camera, pose, 1, FusionBudget(), team);
  CHECK(r.status.code() == StatusCode::failed_precondition);
  // Begun and finished: the blocks of the frame, as integrate() found them.
  const IntegrationReport begun =
      fusion.integrator.begin_frame(fusion.map, depth, camera, pose, team);
  REQUIRE(begun.status.ok());
  CHECK(begun.blocks_requested == 0);
  CHECK(begun.blocks_touched == blocks);
  r = fusion.integrator.finish_frame(fusion.map, depth, camera, pose, 1, FusionBudget(), team);
  CHECK(r.status.ok());
  CHECK(r.blocks_integrated == blocks);
  // Bad input is refused by both parts alike.
  const ImageView<const float> empty;
  CHECK(fusion.integrator.begin_frame(fusion.map, empty, camera, pose, team).status.code() ==
        StatusCode::invalid_argument);
  CHECK(fusion.integrator.finish_frame(fusion.map, empty, camera, pose, 2, FusionBudget(), team)
            .status.code() == StatusCode::invalid_argument);
}

}  // namespace
}  // namespace octofuse
