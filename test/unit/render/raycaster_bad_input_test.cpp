// Bad input and corrupt maps: a Status, or rays that end, never a crash or a hang.

#include "octofuse/render/raycaster.hpp"

#include <catch2/catch.hpp>

#include "unit/render/raycaster_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("bad input is a Status, not a crash") {
  test::OwnedMap<TsdfVoxel> owned(test_map_config());
  OwnedRaycaster<TsdfVoxel> rc(test_raycast_config());
  const WorkerTeam team(1);
  PinholeCamera wrong = test_camera();
  wrong.width = 32;
  REQUIRE(rc.raycaster.raycast(owned.map, wrong, Se3d::Identity(), team).status() ==
          StatusCode::invalid_argument);
  Se3d nan_pose = Se3d::Identity();
  nan_pose.translation().x() = std::nan("");
  REQUIRE(rc.raycaster.raycast(owned.map, test_camera(), nan_pose, team).status() ==
          StatusCode::invalid_argument);
  Raycaster<TsdfVoxel> unreserved;
  REQUIRE(unreserved.raycast(owned.map, test_camera(), Se3d::Identity(), team).status() ==
          StatusCode::failed_precondition);
  RaycastConfig bad = test_raycast_config();
  bad.far_m = bad.near_m;
  REQUIRE(validate(bad) == StatusCode::invalid_argument);
  // An empty map: every pixel invalid.
  Result<RaycastStats> stats =
      rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(stats.ok());
  REQUIRE(stats->valid_pixels == 0u);
}

TEST_CASE("corrupt voxels (NaN, out of range) end rays instead of hanging or crashing") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, plane_sdf, [](const Eigen::Vector3i&) { return 0; });
  // Poison every other block.
  for (std::uint32_t b = 0; b < owned.map.block_count(); b += 2) {
    VoxelBlock<MultiresVoxel>& block = owned.map.block(b);
    REQUIRE(owned.map.acquire_finest(block).ok());
    for (int i = 0; i < kBlockVoxelCount; ++i) {
      MultiresVoxel v = block.voxel(i);
      v.x = (b % 4 == 0) ? std::nanf("") : 1e30f;
      block.set_voxel(i, v);
    }
    owned.map.block(b).current_scale = static_cast<std::int8_t>(b % 4 == 0 ? 0 : 100);
  }
  OwnedRaycaster<MultiresVoxel> rc(test_raycast_config());
  const WorkerTeam team(1);
  Result<RaycastStats> stats =
      rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(stats.ok());
  const SurfaceMap surface = rc.raycaster.surface_W();
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      if (!surface.valid(x, y)) continue;
      REQUIRE(surface.vertices(x, y).allFinite());
      REQUIRE(std::fabs(surface.normals(x, y).norm() - 1.0f) < 1e-4f);
    }
  }
}

}  // namespace
}  // namespace octofuse
