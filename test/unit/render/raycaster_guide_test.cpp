// Guided ray-casts: rays start at a depth guide, wrong guides are marched in full, and unguided
// pixels wait for their turn.

#include "octofuse/render/raycaster.hpp"

#include <catch2/catch.hpp>

#include "unit/render/raycaster_support.hpp"

namespace octofuse {
namespace {

// One depth for every pixel of the test camera.
struct GuideImage {
  float depth_m[64 * 48];
  explicit GuideImage(float z_m) {
    for (float& d : depth_m) d = z_m;
  }
  ImageView<const float> view() const { return ImageView<const float>(depth_m, 64, 48); }
};

TEMPLATE_TEST_CASE(
    "a depth guide starts rays at the fused surface; a wrong guide is marched in full", "",
    TsdfVoxel, MultiresVoxel) {
  test::OwnedMap<TestType> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, plane_sdf, [](const Eigen::Vector3i&) { return 0; });
  const WorkerTeam team(1);
  const PinholeCamera camera = test_camera();
  OwnedRaycaster<TestType> exact(test_raycast_config());
  Result<RaycastStats> full = exact.raycaster.raycast(owned.map, camera, Se3d::Identity(), team);
  REQUIRE(full.ok());
  REQUIRE(full->valid_pixels == 64u * 48u);
  REQUIRE(full->guided_pixels == 0u);
  auto same_surface = [&](const OwnedRaycaster<TestType>& rc) {
    const SurfaceMap a = exact.raycaster.surface_W();
    const SurfaceMap b = rc.raycaster.surface_W();
    for (int y = 0; y < 48; ++y) {
      for (int x = 0; x < 64; ++x) {
        REQUIRE(b.valid(x, y));
        REQUIRE((b.vertices(x, y) - a.vertices(x, y)).norm() < 1e-3f);
        REQUIRE(std::fabs(b.vertices(x, y).z() - kPlaneZ_m) < kDepthTolerance_m);
        REQUIRE(angle_deg(b.normals(x, y), Eigen::Vector3f(0, 0, -1)) < kNormalTolerance_deg);
      }
    }
  };

  // The depth that was fused: every ray starts in the band, none falls back, fewer steps.
  OwnedRaycaster<TestType> guided(test_raycast_config());
  const GuideImage at_surface(kPlaneZ_m);
  Result<RaycastStats> stats =
      guided.raycaster.raycast(owned.map, camera, Se3d::Identity(), team, at_surface.view());
  REQUIRE(stats.ok());
  REQUIRE(stats->guided_pixels == 64u * 48u);
  REQUIRE(stats->guide_fallback_pixels == 0u);
  REQUIRE(stats->steps < full->steps);
  same_surface(guided);

  // Behind the surface the start reads a negative voxel: every guided ray is marched again and
  // finds the plane.
  const float behind_m = GENERATE(1.07f, 1.1f);
  const GuideImage behind(behind_m);
  stats = guided.raycaster.raycast(owned.map, camera, Se3d::Identity(), team, behind.view());
  REQUIRE(stats.ok());
  REQUIRE(stats->guided_pixels == 64u * 48u);
  REQUIRE(stats->guide_fallback_pixels == 64u * 48u);
  same_surface(guided);

  // No data, NaN, outside near..far or in front of everything allocated: not guided at all.
  const float unusable_m =
      GENERATE(0.0f, -1.0f, 0.5f, 1.3f, 100.0f, std::numeric_limits<float>::quiet_NaN());
  const GuideImage unusable(unusable_m);
  stats = guided.raycaster.raycast(owned.map, camera, Se3d::Identity(), team, unusable.view());
  REQUIRE(stats.ok());
  REQUIRE(stats->guided_pixels == 0u);
  REQUIRE(stats->steps == full->steps);
  same_surface(guided);

  // A guide of another size is refused.
  const float small[4] = {1, 1, 1, 1};
  REQUIRE(
      guided.raycaster
          .raycast(owned.map, camera, Se3d::Identity(), team, ImageView<const float>(small, 2, 2))
          .status() == StatusCode::invalid_argument);
}

TEST_CASE("in a guided cast, unguided pixels that found nothing wait for their turn") {
  // A sphere in the middle of the view: the rays around it find nothing.
  const Eigen::Vector3f centre_W(0.0f, 0.0f, 1.2f);
  constexpr float kRadius_m = 0.3f;
  auto sphere = [&](const Eigen::Vector3f& p_W) { return (p_W - centre_W).norm() - kRadius_m; };
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sphere, [](const Eigen::Vector3i&) { return 0; });
  const WorkerTeam team(1);
  const PinholeCamera camera = test_camera();
  OwnedRaycaster<MultiresVoxel> rc(test_raycast_config());
  // A guide image without a single usable depth: every ray is unguided.
  const GuideImage no_data(0.0f);
  Result<RaycastStats> first =
      rc.raycaster.raycast(owned.map, camera, Se3d::Identity(), team, no_data.view());
  REQUIRE(first.ok());
  REQUIRE(first->miss_skipped_pixels == 0u);  // the first cast marches every pixel
  REQUIRE(first->valid_pixels > 0u);
  REQUIRE(first->valid_pixels < 64u * 48u);
  std::vector<std::uint8_t> hit_first(64 * 48);
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) hit_first[y * 64 + x] = rc.raycaster.surface_W().valid(x, y);
  }
  // The second cast (turn 1) marches only the misses with (x + y + 1) % 4 == 0; the hits are
  // marched again and found again.
  Result<RaycastStats> second =
      rc.raycaster.raycast(owned.map, camera, Se3d::Identity(), team, no_data.view());
  REQUIRE(second.ok());
  // Rays of tiles with nothing allocated are not marched at all, so they do not count.
  const ImageView<const TileDepthRange> ranges = rc.raycaster.depth_ranges();
  std::uint32_t expected_skips = 0;
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      if (!hit_first[y * 64 + x] && (x + y + 1) % 4 != 0 &&
          !ranges(x / kRangeTile_px, y / kRangeTile_px).empty()) {
        ++expected_skips;
      }
    }
  }
  REQUIRE(expected_skips > 100u);
  REQUIRE(second->miss_skipped_pixels == expected_skips);
  REQUIRE(second->valid_pixels == first->valid_pixels);
  REQUIRE(second->steps < first->steps);
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      REQUIRE(rc.raycaster.surface_W().valid(x, y) == static_cast<bool>(hit_first[y * 64 + x]));
    }
  }
  // A wall appears behind the sphere: each pixel that missed finds it on its turn, so after four
  // casts every pixel has a surface. Pixels with a guide never wait.
  auto far_wall = [](const Eigen::Vector3f& p_W) { return 1.9f - p_W.z(); };
  test::fill_band(owned.map, kMu_m, far_wall, [](const Eigen::Vector3i&) { return 0; });
  std::uint32_t valid = 0;
  for (int cast = 0; cast < 4; ++cast) {
    Result<RaycastStats> stats =
        rc.raycaster.raycast(owned.map, camera, Se3d::Identity(), team, no_data.view());
    REQUIRE(stats.ok());
    REQUIRE(stats->valid_pixels >= valid);
    valid = stats->valid_pixels;
  }
  REQUIRE(valid == 64u * 48u);
  // After forget_previous_cast() the next guided cast marches every pixel again.
  test::OwnedMap<MultiresVoxel> sphere_only(test_map_config());
  test::fill_band(sphere_only.map, kMu_m, sphere, [](const Eigen::Vector3i&) { return 0; });
  REQUIRE(
      rc.raycaster.raycast(sphere_only.map, camera, Se3d::Identity(), team, no_data.view()).ok());
  rc.raycaster.forget_previous_cast();
  Result<RaycastStats> fresh =
      rc.raycaster.raycast(sphere_only.map, camera, Se3d::Identity(), team, no_data.view());
  REQUIRE(fresh.ok());
  REQUIRE(fresh->miss_skipped_pixels == 0u);
  REQUIRE(fresh->valid_pixels == first->valid_pixels);
}

TEST_CASE("a guided ray returns the surface nearest its guide, not one further in front") {
  // Two parallel walls, 1.0 m and 1.5 m; the unguided ray-cast sees the near one.
  auto two_walls = [](const Eigen::Vector3f& p_W) {
    return p_W.z() < 1.25f ? kPlaneZ_m - p_W.z() : 1.5f - p_W.z();
  };
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, two_walls, [](const Eigen::Vector3i&) { return 0; });
  const WorkerTeam team(1);
  OwnedRaycaster<MultiresVoxel> rc(test_raycast_config());
  REQUIRE(rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team).ok());
  REQUIRE(std::fabs(rc.raycaster.surface_W().vertices(32, 24).z() - kPlaneZ_m) < kDepthTolerance_m);
  const GuideImage far_wall(1.5f);
  Result<RaycastStats> stats =
      rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team, far_wall.view());
  REQUIRE(stats.ok());
  REQUIRE(stats->valid_pixels == 64u * 48u);
  REQUIRE(stats->guide_fallback_pixels == 0u);
  const SurfaceMap surface = rc.raycaster.surface_W();
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      REQUIRE(std::fabs(surface.vertices(x, y).z() - 1.5f) < kDepthTolerance_m);
    }
  }
}

}  // namespace
}  // namespace octofuse
