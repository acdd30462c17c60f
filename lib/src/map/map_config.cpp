#include "octofuse/map/map_config.hpp"

#include <cmath>

namespace octofuse {

MapConfig MapConfig::centred(const Eigen::Vector3f& centre_W, float voxel_size_m, int voxel_depth,
                             std::uint32_t block_capacity, std::uint32_t node_capacity) {
  MapConfig config;
  config.voxel_size_m = voxel_size_m;
  config.voxel_depth = voxel_depth;
  config.block_capacity = block_capacity;
  config.node_capacity = node_capacity;
  config.origin_W = centre_W - Eigen::Vector3f::Constant(0.5f * config.size_m());
  return config;
}

int voxel_depth_for(float map_size_m, float voxel_size_m) {
  int depth = kMinVoxelDepth;
  while (depth < kMaxVoxelDepth &&
         voxel_size_m * static_cast<float>(1 << depth) < map_size_m * 0.999f) {
    ++depth;
  }
  return depth;
}

Status validate(const MapConfig& config) {
  if (!(config.voxel_size_m >= kMinVoxelSize_m) || !(config.voxel_size_m <= kMaxVoxelSize_m)) {
    return StatusCode::invalid_argument;  // also NaN
  }
  if (config.voxel_depth < kMinVoxelDepth || config.voxel_depth > kMaxVoxelDepth) {
    return StatusCode::invalid_argument;
  }
  if (!config.origin_W.allFinite() || !(config.origin_W.cwiseAbs().maxCoeff() <= kMaxOrigin_m)) {
    return StatusCode::invalid_argument;
  }
  if (config.block_capacity == 0 || config.block_capacity > (1u << 30)) {
    return StatusCode::invalid_argument;
  }
  if (config.finest_capacity > (1u << 30)) return StatusCode::invalid_argument;
  if (config.mid_capacity > (1u << 30)) return StatusCode::invalid_argument;
  if (config.node_capacity == 0 || config.node_capacity > (1u << 31)) {
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

}  // namespace octofuse
