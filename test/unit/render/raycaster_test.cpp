#include "octofuse/render/raycaster.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <vector>

#include <Eigen/Geometry>

#include "support/alloc_counter.hpp"
#include "support/analytic_map.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.01f;
constexpr float kMu_m = 0.05f;
constexpr float kDepthTolerance_m = 0.25f * kVoxel_m;
constexpr float kNormalTolerance_deg = 3.0f;
constexpr float kPlaneZ_m = 1.0f;

MapConfig test_map_config() {
  MapConfig config;
  config.voxel_size_m = kVoxel_m;
  config.voxel_depth = 8;  // 2.56 m cube
  config.origin_W = Eigen::Vector3f(-1.28f, -1.28f, 0.0f);
  config.block_capacity = 20000;
  config.node_capacity = 20000;
  return config;
}

PinholeCamera test_camera() {
  return test::centred_camera(64, 48, 50.0f);
}

template <typename VoxelT>
struct OwnedRaycaster {
  std::unique_ptr<std::uint8_t, void (*)(void*)> memory{nullptr, std::free};
  Raycaster<VoxelT> raycaster;

  explicit OwnedRaycaster(const RaycastConfig& config) {
    const std::size_t bytes = Raycaster<VoxelT>::bytes_required(config);
    REQUIRE(bytes > 0);
    memory.reset(static_cast<std::uint8_t*>(std::aligned_alloc(kArenaAlignment, bytes)));
    LinearArena arena(memory.get(), bytes);
    REQUIRE(raycaster.reserve(arena, config).ok());
    REQUIRE(arena.bytes_used() == bytes);
  }
};

RaycastConfig test_raycast_config() {
  RaycastConfig config;
  config.width = 64;
  config.height = 48;
  config.near_m = 0.1f;
  config.far_m = 3.0f;
  config.mu_m = kMu_m;
  return config;
}

float angle_deg(const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
  const float c = std::max(-1.0f, std::min(1.0f, a.normalized().dot(b.normalized())));
  return std::acos(c) * 180.0f / static_cast<float>(M_PI);
}

auto plane_sdf = [](const Eigen::Vector3f& p_W) { return kPlaneZ_m - p_W.z(); };

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

}  // namespace
}  // namespace octofuse

namespace octofuse {
namespace {

TEST_CASE("corrupt voxels (NaN, out of range) end rays instead of hanging or crashing") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, plane_sdf, [](const Eigen::Vector3i&) { return 0; });
  // Poison every other block.
  for (std::uint32_t b = 0; b < owned.map.block_count(); b += 2) {
    VoxelBlock<MultiresVoxel>& block = owned.map.block(b);
    REQUIRE(owned.map.acquire_finest(block).ok());
    for (int i = 0; i < kBlockVoxelCount; ++i) {
      block.voxel(i).x = (b % 4 == 0) ? std::nanf("") : 1e30f;
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

#include "octofuse/fusion/integrator.hpp"

namespace octofuse {
namespace {

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
  const std::size_t bytes = Integrator<MultiresVoxel>::bytes_required(fusion, 64, 48);
  REQUIRE(bytes > 0);
  std::unique_ptr<std::uint8_t, void (*)(void*)> memory(
      static_cast<std::uint8_t*>(std::aligned_alloc(kArenaAlignment, bytes)), std::free);
  LinearArena arena(memory.get(), bytes);
  Integrator<MultiresVoxel> integrator;
  REQUIRE(integrator.reserve(arena, fusion, 64, 48).ok());
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
