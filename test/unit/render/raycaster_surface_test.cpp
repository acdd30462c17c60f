// Ray-cast surfaces: planes and spheres at their exact depth and normal, across scale changes,
// and the wall the real integrator fused.

#include "octofuse/render/raycaster.hpp"

#include <catch2/catch.hpp>

#include "unit/render/raycaster_support.hpp"

namespace octofuse {
namespace {

TEMPLATE_TEST_CASE("a plane ray-casts to its exact depth and normal", "", TsdfVoxel,
                   MultiresVoxel) {
  const int scale = GENERATE(0, 1, 2);
  // Single-resolution maps hold scale 0 only.
  if (!IsMultiresVoxel<TestType>::value && scale != 0) return;
  test::OwnedMap<TestType> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, plane_sdf, [scale](const Eigen::Vector3i&) { return scale; });
  OwnedRaycaster<TestType> rc(test_raycast_config());
  const WorkerTeam team(1);
  const Se3d T_W_C = Se3d::Identity();
  Result<RaycastStats> stats = rc.raycaster.raycast(owned.map, test_camera(), T_W_C, team);
  REQUIRE(stats.ok());
  REQUIRE(stats->valid_pixels == 64u * 48u);
  REQUIRE(stats->scale_pixels[scale] == 64u * 48u);
  REQUIRE_FALSE(stats->budget_hit());
  const SurfaceMap surface = rc.raycaster.surface_W();
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      REQUIRE(surface.valid(x, y));
      REQUIRE(std::fabs(surface.vertices(x, y).z() - kPlaneZ_m) < kDepthTolerance_m);
      // On the ray of pixel (x, y).
      const Eigen::Vector2f px = test_camera().project(surface.vertices(x, y));
      REQUIRE(std::fabs(px.x() - static_cast<float>(x)) < 1e-2f);
      REQUIRE(std::fabs(px.y() - static_cast<float>(y)) < 1e-2f);
      REQUIRE(angle_deg(surface.normals(x, y), Eigen::Vector3f(0, 0, -1)) < kNormalTolerance_deg);
      REQUIRE(rc.raycaster.scale_image()(x, y) == scale);
    }
  }
}

TEMPLATE_TEST_CASE("a sphere ray-casts to the analytic intersection; misses are invalid", "",
                   TsdfVoxel, MultiresVoxel) {
  const Eigen::Vector3f centre_W(0.1f, -0.05f, 1.2f);
  constexpr float kRadius_m = 0.3f;
  auto sdf = [&](const Eigen::Vector3f& p_W) { return (p_W - centre_W).norm() - kRadius_m; };
  test::OwnedMap<TestType> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sdf, [](const Eigen::Vector3i&) { return 0; });
  OwnedRaycaster<TestType> rc(test_raycast_config());
  const WorkerTeam team(1);
  // Camera a little rotated and shifted, to exercise the pose.
  Se3d T_W_C = Se3d::Identity();
  T_W_C.linear() = Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitY()).toRotationMatrix();
  T_W_C.translation() = Eigen::Vector3d(0.05, 0.0, 0.1);
  Result<RaycastStats> stats = rc.raycaster.raycast(owned.map, test_camera(), T_W_C, team);
  REQUIRE(stats.ok());
  const SurfaceMap surface = rc.raycaster.surface_W();
  const PinholeCamera camera = test_camera();
  const Eigen::Matrix3f R = T_W_C.linear().cast<float>();
  const Eigen::Vector3f o = T_W_C.translation().cast<float>();
  int hits = 0;
  int misses = 0;
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      const Eigen::Vector3f d =
          (R * camera.back_project(static_cast<float>(x), static_cast<float>(y), 1.0f))
              .normalized();
      // Analytic ray-sphere intersection.
      const Eigen::Vector3f oc = o - centre_W;
      const float b = oc.dot(d);
      const float disc = b * b - (oc.squaredNorm() - kRadius_m * kRadius_m);
      // Grazing rays are ambiguous at voxel resolution: only judge clear hits and misses.
      const float margin_m = 2.0f * kVoxel_m;
      const float clear_hit =
          (b * b - (oc.squaredNorm() - (kRadius_m - margin_m) * (kRadius_m - margin_m)));
      const float clear_miss =
          (b * b - (oc.squaredNorm() - (kRadius_m + margin_m) * (kRadius_m + margin_m)));
      if (clear_hit >= 0.0f) {
        const float t = -b - std::sqrt(disc);
        const Eigen::Vector3f expected_W = o + t * d;
        REQUIRE(surface.valid(x, y));
        REQUIRE((surface.vertices(x, y) - expected_W).norm() < kDepthTolerance_m);
        REQUIRE(angle_deg(surface.normals(x, y), expected_W - centre_W) < kNormalTolerance_deg);
        ++hits;
      } else if (clear_miss < 0.0f) {
        REQUIRE_FALSE(surface.valid(x, y));
        REQUIRE(rc.raycaster.scale_image()(x, y) == kNoScale);
        ++misses;
      }
    }
  }
  REQUIRE(hits > 500);
  REQUIRE(misses > 100);
  REQUIRE(stats->valid_pixels >= static_cast<std::uint32_t>(hits));
}

TEST_CASE("across a scale change the scale image shows each side's scale and depth stays exact") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  // Blocks left of x = 0 at scale 0, right of it at scale 2.
  const int split = static_cast<int>(std::lround(1.28f / (8 * kVoxel_m)));
  test::fill_band(owned.map, kMu_m, plane_sdf,
                  [split](const Eigen::Vector3i& b) { return b.x() < split ? 0 : 2; });
  OwnedRaycaster<MultiresVoxel> rc(test_raycast_config());
  const WorkerTeam team(1);
  Result<RaycastStats> stats =
      rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(stats.ok());
  REQUIRE(stats->valid_pixels == 64u * 48u);
  const SurfaceMap surface = rc.raycaster.surface_W();
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      REQUIRE(std::fabs(surface.vertices(x, y).z() - kPlaneZ_m) < kDepthTolerance_m);
      const float x_W = surface.vertices(x, y).x();
      const std::uint8_t s = rc.raycaster.scale_image()(x, y);
      // Well inside each side the scale is that side's; near the seam the coarser grid is used.
      if (x_W < -0.05f) REQUIRE(s == 0);
      if (x_W > 0.0f) REQUIRE(s == 2);
    }
  }
  REQUIRE(stats->scale_pixels[0] > 0);
  REQUIRE(stats->scale_pixels[2] > 0);
  REQUIRE(stats->scale_pixels[0] + stats->scale_pixels[2] == 64u * 48u);
}

// End to end with the real integrator: fuse a fronto-parallel wall from exact depth images,
// then ray-cast it from the same pose.
TEST_CASE("ray-casting what the integrator fused gives the wall back") {
  const int fixed_scale = GENERATE(-1, 0, 1, 2);
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  FusionConfig fusion;
  fusion.mu_m = kMu_m;
  fusion.near_m = 0.1f;
  fusion.far_m = 3.0f;
  fusion.fixed_scale = fixed_scale;
  test::ArenaBuffer memory(Integrator<MultiresVoxel>::bytes_required(fusion, 64, 48));
  REQUIRE(memory.bytes() > 0);
  Integrator<MultiresVoxel> integrator;
  REQUIRE(integrator.reserve(memory.arena(), fusion, 64, 48).ok());
  float depth[64 * 48];
  for (float& d : depth) d = kPlaneZ_m;
  const WorkerTeam team(1);
  for (std::uint32_t frame = 0; frame < 3; ++frame) {
    const IntegrationReport report =
        integrator.integrate(owned.map, ImageView<const float>(depth, 64, 48), test_camera(),
                             Se3d::Identity(), frame, FusionBudget{}, team);
    REQUIRE(report.status.ok());
  }
  OwnedRaycaster<MultiresVoxel> rc(test_raycast_config());
  Result<RaycastStats> stats =
      rc.raycaster.raycast(owned.map, test_camera(), Se3d::Identity(), team);
  REQUIRE(stats.ok());
  // Pixels at the image border see partly observed voxels; the bulk must be valid.
  REQUIRE(stats->valid_pixels > 64u * 48u * 8u / 10u);
  const SurfaceMap surface = rc.raycaster.surface_W();
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      if (!surface.valid(x, y)) continue;
      const int scale = rc.raycaster.scale_image()(x, y);
      if (fixed_scale >= 0) REQUIRE(scale == fixed_scale);
      REQUIRE(std::fabs(surface.vertices(x, y).z() - kPlaneZ_m) <
              kDepthTolerance_m * static_cast<float>(1 << scale));
      REQUIRE(angle_deg(surface.normals(x, y), Eigen::Vector3f(0, 0, -1)) < kNormalTolerance_deg);
    }
  }

  // Guided by the depth it fused, as the pipeline ray-casts: every pixel found before is found
  // again on the same wall (with a few border pixels the full march missed), in fewer steps.
  OwnedRaycaster<MultiresVoxel> guided(test_raycast_config());
  Result<RaycastStats> guided_stats = guided.raycaster.raycast(
      owned.map, test_camera(), Se3d::Identity(), team, ImageView<const float>(depth, 64, 48));
  REQUIRE(guided_stats.ok());
  REQUIRE(guided_stats->guided_pixels == 64u * 48u);
  REQUIRE(guided_stats->valid_pixels >= stats->valid_pixels);
  REQUIRE(guided_stats->steps < stats->steps);
  const SurfaceMap guided_surface = guided.raycaster.surface_W();
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      if (surface.valid(x, y)) REQUIRE(guided_surface.valid(x, y));
      if (!guided_surface.valid(x, y)) continue;
      const int scale = guided.raycaster.scale_image()(x, y);
      if (fixed_scale >= 0) REQUIRE(scale == fixed_scale);
      REQUIRE(std::fabs(guided_surface.vertices(x, y).z() - kPlaneZ_m) <
              kDepthTolerance_m * static_cast<float>(1 << scale));
      REQUIRE(angle_deg(guided_surface.normals(x, y), Eigen::Vector3f(0, 0, -1)) <
              kNormalTolerance_deg);
    }
  }
}

}  // namespace
}  // namespace octofuse
