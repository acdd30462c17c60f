// What a ray-cast costs: tile depth ranges, the step budget, half-resolution casts, and the
// same images for any worker count without allocating.

#include "octofuse/render/raycaster.hpp"

#include <catch2/catch.hpp>

#include "unit/render/raycaster_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("the tile depth ranges hold everything allocated, and empty tiles cost no steps") {
  // 1 cm blocks are projected themselves; 4 mm blocks (3.2 cm) through their 6.4 cm parents.
  const float voxel_m = GENERATE(0.01f, 0.004f);
  MapConfig map_config = test_map_config();
  map_config.voxel_size_m = voxel_m;
  map_config.origin_W = Eigen::Vector3f::Constant(-128.0f * voxel_m) + Eigen::Vector3f(0, 0, 1.0f);
  const Eigen::Vector3f centre_W(0.1f, -0.05f, 1.2f);
  constexpr float kRadius_m = 0.2f;
  const float mu_m = 5.0f * voxel_m;
  auto sdf = [&](const Eigen::Vector3f& p_W) { return (p_W - centre_W).norm() - kRadius_m; };
  test::OwnedMap<MultiresVoxel> owned(map_config);
  test::fill_band(owned.map, mu_m, sdf, [](const Eigen::Vector3i&) { return 0; });
  RaycastConfig config = test_raycast_config();
  config.mu_m = mu_m;
  OwnedRaycaster<MultiresVoxel> rc(config);
  Se3d T_W_C = Se3d::Identity();
  T_W_C.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX()).toRotationMatrix();
  T_W_C.translation() = Eigen::Vector3d(0.02, 0.1, 0.2);
  const PinholeCamera camera = test_camera();
  Result<RaycastStats> stats = rc.raycaster.raycast(owned.map, camera, T_W_C, WorkerTeam(1));
  REQUIRE(stats.ok());
  REQUIRE(stats->valid_pixels > 200u);
  const ImageView<const TileDepthRange> ranges = rc.raycaster.depth_ranges();
  REQUIRE(ranges.width == 8);
  REQUIRE(ranges.height == 6);
  // Every voxel centre of every block that lands in the image lies inside its tile's range.
  const Se3d T_C_W = T_W_C.inverse();
  int checked = 0;
  int outside = 0;
  owned.map.for_each_block([&](const VoxelBlock<MultiresVoxel>& block) {
    for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
      const Eigen::Vector3i voxel =
          block.min_voxel() + Eigen::Vector3i(i & 7, (i >> 3) & 7, i >> 6);
      const Eigen::Vector3f p_C =
          (T_C_W * owned.map.voxel_centre_W(voxel).cast<double>()).cast<float>();
      if (!(p_C.z() >= config.near_m && p_C.z() <= config.far_m)) continue;
      const Eigen::Vector2f px = camera.project(p_C);
      const int x = static_cast<int>(std::floor(px.x() + 0.5f));
      const int y = static_cast<int>(std::floor(px.y() + 0.5f));
      if (x < 0 || y < 0 || x >= camera.width || y >= camera.height) continue;
      const TileDepthRange& r = ranges(x / kRangeTile_px, y / kRangeTile_px);
      // Counted, not asserted one by one: there are about a million.
      if (r.empty() || p_C.z() < r.z_min_m || p_C.z() > r.z_max_m) ++outside;
      ++checked;
    }
  });
  REQUIRE(checked > 1000);
  CHECK(outside == 0);
  // The sphere covers the middle of the view only: the corner tiles see nothing, their pixels
  // stay invalid and take no steps (2 x 2 tiles of 8 x 8 pixels with none).
  int empty_tiles = 0;
  for (int ty = 0; ty < ranges.height; ++ty) {
    for (int tx = 0; tx < ranges.width; ++tx) empty_tiles += ranges(tx, ty).empty() ? 1 : 0;
  }
  REQUIRE(empty_tiles >= 4);
  REQUIRE(ranges(0, 0).empty());
  const SurfaceMap surface = rc.raycaster.surface_W();
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const TileDepthRange& r = ranges(x / kRangeTile_px, y / kRangeTile_px);
      if (r.empty()) {
        REQUIRE_FALSE(surface.valid(x, y));
        continue;
      }
      if (!surface.valid(x, y)) continue;
      const float z_m = (T_C_W * surface.vertices(x, y).cast<double>()).z();
      REQUIRE(z_m >= r.z_min_m);
      REQUIRE(z_m <= r.z_max_m);
    }
  }
  // Same camera, nothing allocated: no steps at all.
  test::OwnedMap<MultiresVoxel> empty_map(map_config);
  Result<RaycastStats> none = rc.raycaster.raycast(empty_map.map, camera, T_W_C, WorkerTeam(1));
  REQUIRE(none.ok());
  CHECK(none->steps == 0u);
  CHECK(none->valid_pixels == 0u);
}

TEST_CASE("the step budget is respected and cuts pixels; a loose budget changes nothing") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, plane_sdf, [](const Eigen::Vector3i&) { return 0; });
  const WorkerTeam team(1);
  OwnedRaycaster<MultiresVoxel> free_rc(test_raycast_config());
  Result<RaycastStats> unbounded =
      free_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(unbounded.ok());
  REQUIRE_FALSE(unbounded->budget_hit());

  RaycastConfig tight = test_raycast_config();
  tight.step_budget = unbounded->steps / 3;
  OwnedRaycaster<MultiresVoxel> tight_rc(tight);
  Result<RaycastStats> cut =
      tight_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(cut.ok());
  REQUIRE(cut->steps <= tight.step_budget);
  REQUIRE(cut->budget_hit());
  REQUIRE(cut->valid_pixels + cut->budget_cut_pixels == 64u * 48u);
  REQUIRE(cut->valid_pixels > 0);
  // Pixels that were finished are the same as without a budget.
  const SurfaceMap a = free_rc.raycaster.surface_W();
  const SurfaceMap b = tight_rc.raycaster.surface_W();
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      if (b.valid(x, y)) REQUIRE(a.vertices(x, y) == b.vertices(x, y));
    }
  }

  RaycastConfig loose = test_raycast_config();
  loose.step_budget = unbounded->steps * 2;
  OwnedRaycaster<MultiresVoxel> loose_rc(loose);
  Result<RaycastStats> full =
      loose_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(full.ok());
  REQUIRE_FALSE(full->budget_hit());
  REQUIRE(full->steps == unbounded->steps);
  REQUIRE(full->valid_pixels == unbounded->valid_pixels);
}

TEST_CASE("at half resolution a quarter of the rays march and fill their 2 x 2 squares") {
  const Eigen::Vector3f centre_W(0.0f, 0.0f, 1.0f);
  auto sdf = [&](const Eigen::Vector3f& p_W) { return (p_W - centre_W).norm() - 0.35f; };
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sdf,
                  [](const Eigen::Vector3i& b) { return (b.x() + b.y()) % 3; });
  const WorkerTeam team(2);
  OwnedRaycaster<MultiresVoxel> full_rc(test_raycast_config());
  RaycastConfig half = test_raycast_config();
  half.pixel_stride = 2;
  OwnedRaycaster<MultiresVoxel> half_rc(half);
  const Result<RaycastStats> full =
      full_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  const Result<RaycastStats> quarter =
      half_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(full.ok());
  REQUIRE(quarter.ok());
  CHECK(full->marched_pixels == 64u * 48u);
  CHECK(quarter->marched_pixels == 32u * 24u);
  // The sphere fills much of the view, so its rays' steps dominate: about a quarter of them.
  INFO("steps: full " << full->steps << ", half resolution " << quarter->steps);
  CHECK(quarter->steps * 3 < full->steps);
  CHECK(quarter->steps * 5 > full->steps);
  // A marched pixel is the full cast's, bit for bit; the other three of its square copy it.
  const SurfaceMap a = full_rc.raycaster.surface_W();
  const SurfaceMap b = half_rc.raycaster.surface_W();
  // Each cast says how it was cast, for the readers that pair pixels (ICP).
  CHECK(a.pixel_stride == 1);
  CHECK(b.pixel_stride == 2);
  const ImageView<const std::uint8_t> scale_a = full_rc.raycaster.scale_image();
  const ImageView<const std::uint8_t> scale_b = half_rc.raycaster.scale_image();
  std::uint32_t valid = 0;
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      const int xm = x & ~1;
      const int ym = y & ~1;
      REQUIRE(b.vertices(x, y) == a.vertices(xm, ym));
      REQUIRE(b.normals(x, y) == a.normals(xm, ym));
      REQUIRE(scale_b(x, y) == scale_a(xm, ym));
      if (b.valid(x, y)) ++valid;
    }
  }
  CHECK(valid == quarter->valid_pixels);
  CHECK(valid > 64u * 48u / 4);
  CHECK(quarter->scale_pixels[0] + quarter->scale_pixels[1] + quarter->scale_pixels[2] +
            quarter->scale_pixels[3] ==
        valid);

  // Switched between casts, the stride the cast took is the one it reports.
  half_rc.raycaster.set_pixel_stride(1);
  REQUIRE(half_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team).ok());
  CHECK(half_rc.raycaster.surface_W().pixel_stride == 1);
  half_rc.raycaster.set_pixel_stride(2);
  REQUIRE(half_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team).ok());
  CHECK(half_rc.raycaster.surface_W().pixel_stride == 2);

  // The step budget goes to the marched rows; cut pixels leave their squares invalid.
  half_rc.raycaster.set_step_budget(quarter->steps / 3);
  const Result<RaycastStats> cut =
      half_rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(cut.ok());
  CHECK(cut->steps <= quarter->steps / 3);
  CHECK(cut->budget_hit());
  std::uint32_t invalid = 0;
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) invalid += b.valid(x, y) ? 0u : 1u;
  }
  CHECK(cut->budget_cut_pixels % 4 == 0);
  CHECK(cut->budget_cut_pixels <= invalid);
  CHECK(cut->valid_pixels + invalid == 64u * 48u);
}

TEST_CASE("1 and 2 workers give bit-identical images, and a ray-cast allocates nothing") {
  const Eigen::Vector3f centre_W(0.0f, 0.0f, 1.0f);
  auto sdf = [&](const Eigen::Vector3f& p_W) { return (p_W - centre_W).norm() - 0.35f; };
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sdf,
                  [](const Eigen::Vector3i& b) { return (b.x() + b.y()) % 3; });
  RaycastConfig config = test_raycast_config();
  config.step_budget = 40000;
  OwnedRaycaster<MultiresVoxel> one(config);
  OwnedRaycaster<MultiresVoxel> two(config);
  const WorkerTeam team1(1);
  const WorkerTeam team2(2);
  Se3d T_W_C = Se3d::Identity();
  T_W_C.translation() = Eigen::Vector3d(0.02, -0.03, 0.0);
  REQUIRE(one.raycaster.raycast(owned.map, test_camera(), T_W_C, team1).ok());
  REQUIRE(two.raycaster.raycast(owned.map, test_camera(), T_W_C, team2).ok());
  const std::size_t n = 64 * 48;
  const SurfaceMap a = one.raycaster.surface_W();
  const SurfaceMap b = two.raycaster.surface_W();
  REQUIRE(std::memcmp(a.vertices.data, b.vertices.data, n * sizeof(Eigen::Vector3f)) == 0);
  REQUIRE(std::memcmp(a.normals.data, b.normals.data, n * sizeof(Eigen::Vector3f)) == 0);
  REQUIRE(std::memcmp(one.raycaster.scale_image().data, two.raycaster.scale_image().data, n) == 0);

  test::AllocationScope scope;
  for (int i = 0; i < 3; ++i) {
    Result<RaycastStats> stats = two.raycaster.raycast(owned.map, test_camera(), T_W_C, team2);
    REQUIRE(stats.ok());
  }
  REQUIRE(scope.allocations() == 0);
}

}  // namespace
}  // namespace octofuse
