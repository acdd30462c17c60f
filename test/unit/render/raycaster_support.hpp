#pragma once
// What the ray-caster tests share: a 64 x 48 camera over a map of analytic surfaces written
// straight into the octree, and a ray-caster with its memory.

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

#include "octofuse/fusion/integrator.hpp"
#include "support/aligned_buffer.hpp"
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

inline MapConfig test_map_config() {
  MapConfig config;
  config.voxel_size_m = kVoxel_m;
  config.voxel_depth = 8;  // 2.56 m cube
  config.origin_W = Eigen::Vector3f(-1.28f, -1.28f, 0.0f);
  config.block_capacity = 20000;
  config.node_capacity = 20000;
  return config;
}

inline PinholeCamera test_camera() {
  return test::centred_camera(64, 48, 50.0f);
}

template <typename VoxelT>
struct OwnedRaycaster {
  test::ArenaBuffer memory;
  Raycaster<VoxelT> raycaster;

  explicit OwnedRaycaster(const RaycastConfig& config)
      : memory(Raycaster<VoxelT>::bytes_required(config)) {
    REQUIRE(memory.bytes() > 0);
    REQUIRE(raycaster.reserve(memory.arena(), config).ok());
    REQUIRE(memory.arena().bytes_used() == memory.bytes());
  }
};

inline RaycastConfig test_raycast_config() {
  RaycastConfig config;
  config.width = 64;
  config.height = 48;
  config.near_m = 0.1f;
  config.far_m = 3.0f;
  config.mu_m = kMu_m;
  return config;
}

inline float angle_deg(const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
  const float c = std::max(-1.0f, std::min(1.0f, a.normalized().dot(b.normalized())));
  return std::acos(c) * 180.0f / static_cast<float>(M_PI);
}

auto plane_sdf = [](const Eigen::Vector3f& p_W) { return kPlaneZ_m - p_W.z(); };

}  // namespace
}  // namespace octofuse
