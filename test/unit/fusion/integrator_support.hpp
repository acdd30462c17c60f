#pragma once
// What the integrator tests share: an integrator and map with their memory, the configurations
// they fuse with, and reading the fused surface back.

#include "octofuse/fusion/integrator.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <memory>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/map/detail/mip.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

using test::AnalyticScene;

// A map and an integrator over one arena, sized by bytes_required.
template <typename VoxelT>
struct Fusion {
  Fusion(const MapConfig& map_config, const FusionConfig& fusion_config, const PinholeCamera& cam)
      : camera(cam),
        buffer(Octree<VoxelT>::bytes_required(map_config) +
               Integrator<VoxelT>::bytes_required(fusion_config, cam.width, cam.height)) {
    REQUIRE(map.reserve(buffer.arena(), map_config).ok());
    REQUIRE(integrator.reserve(buffer.arena(), fusion_config, cam.width, cam.height).ok());
    REQUIRE(buffer.arena().bytes_used() == buffer.bytes());
  }

  IntegrationReport fuse(const AnalyticScene& scene, const Se3d& T_W_C,
                         const FusionBudget& budget = FusionBudget(), int workers = 1) {
    scene.render(camera, T_W_C, depth);
    WorkerTeam team(workers);
    return fuse_rendered(T_W_C, budget, team);
  }
  IntegrationReport fuse_rendered(const Se3d& T_W_C, const FusionBudget& budget,
                                  const WorkerTeam& team) {
    ImageView<const float> view(depth.data(), camera.width, camera.height);
    return integrator.integrate(map, view, camera, T_W_C, frame++, budget, team);
  }

  PinholeCamera camera;
  test::ArenaBuffer buffer;
  Octree<VoxelT> map;
  Integrator<VoxelT> integrator;
  std::vector<float> depth;
  std::uint32_t frame = 0;
};

inline MapConfig map_config(float voxel_size_m, int depth, std::uint32_t blocks) {
  return MapConfig::centred(Eigen::Vector3f(0.0f, 0.0f, 1.0f), voxel_size_m, depth, blocks, blocks);
}

inline FusionConfig fusion_config(float mu_m, int fixed_scale = -1) {
  FusionConfig c;
  c.mu_m = mu_m;
  c.fixed_scale = fixed_scale;
  c.max_blocks_per_frame = 1u << 15;
  c.far_m = 6.0f;
  return c;
}

// Zero crossing (front to back, + to -) along world z at the voxel column through finest voxel
// `column` at `scale`, by linear interpolation between voxel centres; NaN when there is none.
template <typename VoxelT>
double zero_crossing_z(const Octree<VoxelT>& map, Eigen::Vector3i column, int scale, int z_begin,
                       int z_end) {
  const int step = 1 << scale;
  bool have_previous = false;
  VoxelT previous;
  double previous_z = 0.0;
  for (int z = z_begin; z < z_end; z += step) {
    column.z() = z;
    VoxelT v;
    const bool found = map.read_voxel(column, scale, &v);
    const double centre_z = map.voxel_centre_W(column, scale).z();
    if (found && voxel_observed(v) && have_previous && voxel_observed(previous) &&
        voxel_tsdf(previous) > 0.0f && voxel_tsdf(v) <= 0.0f) {
      const double a = voxel_tsdf(previous);
      const double b = voxel_tsdf(v);
      return previous_z + (centre_z - previous_z) * a / (a - b);
    }
    have_previous = found;
    previous = v;
    previous_z = centre_z;
  }
  return std::nan("");
}

}  // namespace
}  // namespace octofuse
