#pragma once
// What the query and free-space tests share: a wall at z = 2 m in front of a camera at the
// origin looking along +z, fused with exact depth into a multires map with its free space.
// Every expected answer follows from that geometry.

#include "octofuse/query/map_query.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/fusion/integrator.hpp"
#include "octofuse/query/free_space.hpp"
#include "support/aligned_buffer.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

using test::AnalyticScene;

constexpr float kVoxel_m = 0.02f;
constexpr float kMu_m = 0.1f;
constexpr double kWall_m = 2.0;
// Interpolated signed distance next to a plane fused head-on: within half a voxel.
constexpr float kDistanceTolerance_m = 0.5f * kVoxel_m;

inline PinholeCamera small_camera() {
  return test::centred_camera(160, 120, 120.0f);
}

inline AnalyticScene wall_at(double z_m) {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), z_m});
  return scene;
}

// A multires map, an integrator and the free space over one arena; each fuse() integrates and
// carves one frame, as the pipeline does.
struct Mapper {
  explicit Mapper(FreeSpaceConfig free_config = FreeSpaceConfig())
      : camera(small_camera()),
        map_config(
            MapConfig::centred(Eigen::Vector3f(0.0f, 0.0f, 1.5f), kVoxel_m, 8, 20000, 20000)),
        fusion([] {
          FusionConfig c;
          c.mu_m = kMu_m;
          c.far_m = 6.0f;
          c.max_blocks_per_frame = 1u << 15;
          return c;
        }()),
        buffer(Octree<MultiresVoxel>::bytes_required(map_config) +
               Integrator<MultiresVoxel>::bytes_required(fusion, camera.width, camera.height) +
               FreeSpace::bytes_required(with_defaults(free_config), map_config, camera.width,
                                         camera.height)) {
    REQUIRE(map.reserve(buffer.arena(), map_config).ok());
    REQUIRE(integrator.reserve(buffer.arena(), fusion, camera.width, camera.height).ok());
    REQUIRE(free_space
                .reserve(buffer.arena(), with_defaults(free_config), map_config, camera.width,
                         camera.height)
                .ok());
    REQUIRE(buffer.arena().bytes_used() == buffer.bytes());
  }
  static FreeSpaceConfig with_defaults(FreeSpaceConfig c) {
    c.clearance_m = 0.5f * kMu_m;
    c.occlusion_clear_m = 4.0f * kMu_m;
    return c;
  }

  FreeSpaceReport fuse(const AnalyticScene& scene, const Se3d& T_W_C = Se3d::Identity(),
                       int workers = 1) {
    scene.render(camera, T_W_C, depth);
    ImageView<const float> view(depth.data(), camera.width, camera.height);
    WorkerTeam team(workers);
    const IntegrationReport fused =
        integrator.integrate(map, view, camera, T_W_C, frame, FusionBudget(), team);
    REQUIRE(fused.status.ok());
    return free_space.carve(view, camera, T_W_C, frame++);
  }
  MapQuery<MultiresVoxel> query() const { return MapQuery<MultiresVoxel>(map, &free_space, kMu_m); }

  PinholeCamera camera;
  MapConfig map_config;
  FusionConfig fusion;
  test::ArenaBuffer buffer;
  Octree<MultiresVoxel> map;
  Integrator<MultiresVoxel> integrator;
  FreeSpace free_space;
  std::vector<float> depth;
  std::uint32_t frame = 0;
};

inline PointAnswer ask(const Mapper& m, float x, float y, float z) {
  const Result<PointAnswer> a = m.query().point(Eigen::Vector3f(x, y, z));
  REQUIRE(a.ok());
  return a.value();
}

inline RegionState box_state(const Mapper& m, const Eigen::Vector3f& lo,
                             const Eigen::Vector3f& hi) {
  const Result<RegionAnswer> a = m.query().box(lo, hi);
  REQUIRE(a.ok());
  REQUIRE(!a.value().budget_hit);
  return a.value().state;
}

}  // namespace
}  // namespace octofuse
