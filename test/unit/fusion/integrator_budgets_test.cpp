// The integrator under limits: the same map for any worker count, no heap per frame, full pools
// and budgets reported in the documented order, bad input refused.

#include "octofuse/fusion/integrator.hpp"

#include <catch2/catch.hpp>

#include "unit/fusion/integrator_support.hpp"

namespace octofuse {
namespace {

// Both maps hold the same blocks, voxels and node summaries, bit for bit.
template <typename VoxelT>
void require_same_map(const Octree<VoxelT>& one, const Octree<VoxelT>& two) {
  REQUIRE(one.block_count() == two.block_count());
  using Block = VoxelBlock<VoxelT>;
  for (std::uint32_t i = 0; i < one.block_count(); ++i) {
    const Block& a = one.block(i);
    const Block& b = two.block(i);
    // Everything but the finest-level pointer (into two different pools) byte for byte.
    const std::size_t header = static_cast<std::size_t>(reinterpret_cast<const char*>(&a.finest) -
                                                        reinterpret_cast<const char*>(&a));
    REQUIRE(std::memcmp(&a, &b, header) == 0);
    REQUIRE(std::memcmp(a.inline_voxels, b.inline_voxels, sizeof(a.inline_voxels)) == 0);
    REQUIRE(a.has_finest() == b.has_finest());
    REQUIRE(std::memcmp(a.finest_begin(), b.finest_begin(),
                        sizeof(FinestVoxelT<VoxelT>) * kBlockFinestVoxelCount) == 0);
  }
  REQUIRE(one.memory().finest_used == two.memory().finest_used);
  for (std::uint32_t i = 0; i < one.node_count(); ++i) {
    const NodeSummary& a = one.node(i).summary;
    const NodeSummary& b = two.node(i).summary;
    REQUIRE(std::memcmp(&a, &b, sizeof(NodeSummary)) == 0);
  }
}

TEMPLATE_TEST_CASE("results are bit-identical for 1, 2 and 3 workers",
                   "[fusion][integrator][threads]", MultiresVoxel, Multires16Voxel) {
  AnalyticScene scene;
  scene.spheres.push_back({Eigen::Vector3d(0.1, 0.0, 1.3), 0.3});
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.9});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  const int workers = GENERATE(2, 3);
  CAPTURE(workers);
  Fusion<TestType> one(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  Fusion<TestType> two(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  for (int i = 0; i < 6; ++i) {
    // Moving back then forward: blocks change scale both ways.
    const Se3d pose = test::looking_along_z({0.02 * i, 0.0, -0.6 + 0.25 * (i % 4)});
    const IntegrationReport a = one.fuse(scene, pose, FusionBudget(), 1);
    const IntegrationReport b = two.fuse(scene, pose, FusionBudget(), workers);
    REQUIRE(a.status.ok());
    REQUIRE(b.status.ok());
    REQUIRE(a.voxels_updated == b.voxels_updated);
    REQUIRE(a.blocks_integrated == b.blocks_integrated);
  }
  require_same_map(one.map, two.map);
}

TEST_CASE("a band of rows whose cell list fills up is finished by the merge, same map",
          "[fusion][integrator][threads]") {
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  // Depth only in the first rows: every block comes from the first band, whose list holds a
  // quarter of max_blocks_per_frame.
  auto fill = [&camera](std::vector<float>& depth) {
    depth.assign(static_cast<std::size_t>(camera.width) * camera.height, 0.0f);
    for (int v = 0; v < 15; ++v) {
      for (int u = 0; u < camera.width; ++u) depth[v * camera.width + u] = 1.0f + 0.001f * u;
    }
  };
  FusionConfig small = fusion_config(0.08f);
  small.max_blocks_per_frame = 256;
  Fusion<MultiresVoxel> tight(map_config(0.01f, 8, 8000), small, camera);
  Fusion<MultiresVoxel> tight_two(map_config(0.01f, 8, 8000), small, camera);
  Fusion<MultiresVoxel> roomy(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  WorkerTeam one_worker(1);
  WorkerTeam two_workers(2);
  for (int i = 0; i < 3; ++i) {
    const Se3d pose = test::looking_along_z({0.01 * i, 0.0, 0.1 * i});
    fill(tight.depth);
    fill(tight_two.depth);
    fill(roomy.depth);
    const IntegrationReport a = tight.fuse_rendered(pose, FusionBudget(), one_worker);
    const IntegrationReport b = tight_two.fuse_rendered(pose, FusionBudget(), two_workers);
    const IntegrationReport c = roomy.fuse_rendered(pose, FusionBudget(), one_worker);
    REQUIRE(a.status.ok());
    REQUIRE(a.keys_dropped == 0);
    REQUIRE(a.blocks_touched > 64);  // more than the band's list holds
    REQUIRE(a.blocks_touched == c.blocks_touched);
    REQUIRE(b.blocks_touched == c.blocks_touched);
    REQUIRE(a.voxels_updated == c.voxels_updated);
    REQUIRE(b.voxels_updated == c.voxels_updated);
  }
  require_same_map(tight.map, roomy.map);
  require_same_map(tight_two.map, roomy.map);
}

TEST_CASE("no heap allocation per frame", "[fusion][integrator][alloc]") {
  AnalyticScene scene;
  scene.spheres.push_back({Eigen::Vector3d(0.0, 0.0, 1.2), 0.2});
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.8});
  const PinholeCamera camera = test::centred_camera(80, 60, 65.0f);
  // Coarse voxels keep this many-frame test quick in debug builds.
  Fusion<MultiresVoxel> multires(map_config(0.05f, 7, 2000), fusion_config(0.4f), camera);
  Fusion<TsdfVoxel> single(map_config(0.05f, 7, 2000), fusion_config(0.4f), camera);
  WorkerTeam team(2);
  constexpr int kFrames = 120;
  std::vector<std::vector<float>> images(8);
  for (int k = 0; k < 8; ++k) {
    scene.render(camera, test::looking_along_z({0.01 * k, 0.0, -0.8 + 0.2 * k}), images[k]);
  }
  test::AllocationScope scope;
  for (int i = 0; i < kFrames; ++i) {
    const int k = i % 8;
    const Se3d pose = test::looking_along_z({0.01 * k, 0.0, -0.8 + 0.2 * k});
    multires.depth.swap(images[k]);
    single.depth.swap(multires.depth);
    REQUIRE(single.fuse_rendered(pose, FusionBudget(), team).status.ok());
    multires.depth.swap(single.depth);
    REQUIRE(multires.fuse_rendered(pose, FusionBudget(), team).status.ok());
    images[k].swap(multires.depth);
  }
  CHECK(scope.allocations() == 0);
}

TEST_CASE("a padded depth image fuses as a packed one; one spanning 2^24 pixels is refused",
          "[fusion][integrator]") {
  AnalyticScene scene;
  scene.spheres.push_back({Eigen::Vector3d(0.05, -0.02, 1.1), 0.25});
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.7});
  const PinholeCamera camera = test::centred_camera(96, 72, 80.0f);
  const Se3d pose = test::looking_along_z({0.0, 0.0, 0.0});
  Fusion<MultiresVoxel> packed(map_config(0.02f, 8, 4000), fusion_config(0.1f), camera);
  Fusion<MultiresVoxel> padded(map_config(0.02f, 8, 4000), fusion_config(0.1f), camera);
  REQUIRE(packed.fuse(scene, pose).status.ok());
  // The same depth with rows 37 pixels apart more than the image is wide.
  constexpr int kPad = 37;
  const std::ptrdiff_t stride = camera.width + kPad;
  std::vector<float> rows(static_cast<std::size_t>(stride) * camera.height, -1.0f);
  for (int y = 0; y < camera.height; ++y) {
    std::copy_n(packed.depth.data() + y * camera.width, camera.width, rows.data() + y * stride);
  }
  WorkerTeam team(1);
  const IntegrationReport report = padded.integrator.integrate(
      padded.map, ImageView<const float>(rows.data(), camera.width, camera.height, stride), camera,
      pose, 0, FusionBudget(), team);
  REQUIRE(report.status.ok());
  CHECK(report.voxels_updated > 10000);
  require_same_map(packed.map, padded.map);

  // Pixel indices are formed in float: an image spanning more than 2^24 is refused up front.
  CHECK(Integrator<MultiresVoxel>::bytes_required(FusionConfig(), 4096, 4096) > 0);
  CHECK(Integrator<MultiresVoxel>::bytes_required(FusionConfig(), 4096, 4097) == 0);
  CHECK(Integrator<TsdfVoxel>::bytes_required(FusionConfig(), 4097, 4096) == 0);
  // ... and so is a view whose row stride makes it span more (nothing is read or changed).
  const std::uint32_t blocks = padded.map.block_count();
  const std::ptrdiff_t huge_stride = fusion_internal::kMaxImageSpan_px / camera.height + 1;
  const IntegrationReport refused = padded.integrator.integrate(
      padded.map, ImageView<const float>(rows.data(), camera.width, camera.height, huge_stride),
      camera, pose, 1, FusionBudget(), team);
  CHECK(refused.status == StatusCode::invalid_argument);
  CHECK(padded.map.block_count() == blocks);
  require_same_map(packed.map, padded.map);
}

TEST_CASE("a full block pool is reported and the map stays usable", "[fusion][integrator]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.0});
  constexpr std::uint32_t kBlocks = 40;
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, kBlocks), fusion_config(0.08f),
                               test::centred_camera(160, 120, 131.0f));
  const IntegrationReport first = fusion.fuse(scene, test::looking_along_z({0, 0, 0.3}));
  CHECK(first.status == StatusCode::resource_exhausted);
  CHECK(first.blocks_requested > kBlocks);
  CHECK(first.blocks_allocated == kBlocks);
  CHECK(first.pool_refusals == first.blocks_requested - kBlocks);
  CHECK(first.blocks_integrated == kBlocks);
  CHECK(fusion.map.block_count() == kBlocks);
  const IntegrationReport second = fusion.fuse(scene, test::looking_along_z({0, 0, 0.3}));
  CHECK(second.status == StatusCode::resource_exhausted);
  CHECK(second.blocks_allocated == 0);
  CHECK(second.blocks_integrated == kBlocks);
  for (std::uint32_t i = 0; i < kBlocks; ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    CHECK(b.last_updated_frame == 1);
  }
}

TEST_CASE("budgets bind in the documented order", "[fusion][integrator][budget]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0.3, 0, 1).normalized(), 1.0});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  const Se3d pose = test::looking_along_z({0, 0, 0.3});

  SECTION("new blocks: the nearest are allocated") {
    Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
    FusionBudget budget;
    budget.max_new_blocks = 20;
    const IntegrationReport r = fusion.fuse(scene, pose, budget);
    CHECK(r.status.ok());
    CHECK(r.budget_hit);
    CHECK(r.blocks_allocated == 20);
    CHECK(r.budget_blocks_not_allocated == r.blocks_requested - 20);
    // Every allocated block is at least as near as every one left out.
    float farthest_kept = 0.0f;
    for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
      const Eigen::Vector3f c = fusion.map.block_centre_W(fusion.map.block(i).coords);
      farthest_kept = std::max(farthest_kept, c.z() - 0.3f);
    }
    const IntegrationReport all = fusion.fuse(scene, pose);
    CHECK(all.blocks_allocated == r.budget_blocks_not_allocated);
    for (std::uint32_t i = 20; i < fusion.map.block_count(); ++i) {
      const Eigen::Vector3f c = fusion.map.block_centre_W(fusion.map.block(i).coords);
      CHECK(c.z() - 0.3f >= farthest_kept);
    }
  }
  SECTION("voxel updates: the farthest blocks go one scale coarser, then are skipped") {
    Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f, 0), camera);
    const IntegrationReport free_run = fusion.fuse(scene, pose);
    const std::uint32_t n = free_run.blocks_integrated;
    FusionBudget budget;
    budget.max_voxel_updates = 512ull * n - 400;  // forces a few blocks to scale 1
    const IntegrationReport r = fusion.fuse(scene, pose, budget);
    CHECK(r.budget_hit);
    CHECK(r.budget_blocks_coarsened == 1);
    CHECK(r.blocks_per_scale[1] == 1);
    CHECK(r.budget_blocks_skipped == 0);
    budget.max_voxel_updates = 64ull * n / 2;  // even all at scale 1 is too much
    const IntegrationReport tight = fusion.fuse(scene, pose, budget);
    CHECK(tight.budget_blocks_coarsened == n);
    CHECK(tight.budget_blocks_skipped > 0);
    CHECK(tight.blocks_integrated + tight.budget_blocks_skipped == n);
    CHECK(64ull * tight.blocks_integrated <= budget.max_voxel_updates);
  }
  SECTION("integrated blocks: the farthest are skipped") {
    Fusion<TsdfVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
    const IntegrationReport free_run = fusion.fuse(scene, pose);
    FusionBudget budget;
    budget.max_integrated_blocks = 10;
    const IntegrationReport r = fusion.fuse(scene, pose, budget);
    CHECK(r.budget_hit);
    CHECK(r.blocks_integrated == 10);
    CHECK(r.budget_blocks_skipped == free_run.blocks_integrated - 10);
  }
}

TEST_CASE("bad input is refused without touching the map", "[fusion][integrator]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.0});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  scene.render(camera, Se3d::Identity(), fusion.depth);
  const ImageView<const float> view(fusion.depth.data(), 160, 120);
  WorkerTeam team(1);
  Se3d bad_pose = Se3d::Identity();
  bad_pose.matrix()(0, 3) = std::numeric_limits<double>::quiet_NaN();
  CHECK(fusion.integrator.integrate(fusion.map, view, camera, bad_pose, 0, FusionBudget(), team)
            .status == StatusCode::invalid_argument);
  Se3d skew = Se3d::Identity();
  skew.matrix()(0, 0) = 2.0;
  CHECK(
      fusion.integrator.integrate(fusion.map, view, camera, skew, 0, FusionBudget(), team).status ==
      StatusCode::invalid_argument);
  PinholeCamera wrong = camera;
  wrong.width = 80;
  CHECK(fusion.integrator
            .integrate(fusion.map, view, wrong, Se3d::Identity(), 0, FusionBudget(), team)
            .status == StatusCode::invalid_argument);
  const ImageView<const float> small(fusion.depth.data(), 80, 60);
  PinholeCamera small_camera = test::centred_camera(80, 60, 65.0f);
  CHECK(fusion.integrator
            .integrate(fusion.map, small, small_camera, Se3d::Identity(), 0, FusionBudget(), team)
            .status == StatusCode::failed_precondition);
  CHECK(fusion.map.block_count() == 0);
  // A rigid pose far outside the cube: every ray misses it.
  Se3d far_away = Se3d::Identity();
  far_away.translation() = Eigen::Vector3d(1e30, -1e30, 1e25);
  const IntegrationReport outside =
      fusion.integrator.integrate(fusion.map, view, camera, far_away, 0, FusionBudget(), team);
  CHECK(outside.status.ok());
  CHECK(outside.rays_outside_cube > 0);
  CHECK(fusion.map.block_count() == 0);
  // NaN and negative depths are no measurement.
  for (std::size_t i = 0; i < fusion.depth.size(); ++i) {
    fusion.depth[i] = (i % 2 == 0) ? std::numeric_limits<float>::quiet_NaN() : -1.0f;
  }
  const IntegrationReport r = fusion.integrator.integrate(
      fusion.map, view, camera, Se3d::Identity(), 0, FusionBudget(), team);
  CHECK(r.status.ok());
  CHECK(r.blocks_touched == 0);
  CHECK(fusion.map.block_count() == 0);
}

}  // namespace
}  // namespace octofuse
