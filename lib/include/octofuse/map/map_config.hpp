#pragma once
// What fixes the map's geometry and memory: the cube (origin, finest voxel size, 2^d voxels per
// side) and the pool capacities. Everything the octree reserves follows from this struct.

#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/status.hpp"

namespace octofuse {

// Voxels per block side (8) and its log2; blocks are the octree's leaves.
inline constexpr int kBlockSide = 8;
inline constexpr int kBlockSideLog2 = 3;
// Coarsest scale inside a block: scale s has voxels 2^s finest voxels wide (0 = 8^3 ... 3 = 1^3).
inline constexpr int kMaxBlockScale = 3;
// Morton keys hold 21 bits per axis, which bounds the depth.
inline constexpr int kMinVoxelDepth = 4;
inline constexpr int kMaxVoxelDepth = 21;
// Finest voxel edges a map may have: 0.1 mm (below, float positions in a cube of any useful size
// lose the voxel) to 1 km.
inline constexpr float kMinVoxelSize_m = 1e-4f;
inline constexpr float kMaxVoxelSize_m = 1e3f;
// Largest |coordinate| of the cube's origin, in metres.
inline constexpr float kMaxOrigin_m = 1e9f;

struct MapConfig {
  float voxel_size_m = 0.01f;  // finest voxel edge
  int voxel_depth = 10;        // d: 2^d finest voxels per cube side, kMinVoxelDepth..kMaxVoxelDepth
  // World position of the cube's minimum corner; voxel (0,0,0) spans [origin, origin + voxel).
  Eigen::Vector3f origin_W = Eigen::Vector3f::Zero();
  std::uint32_t block_capacity = 4096;  // voxel blocks in the pool
  std::uint32_t node_capacity = 4096;   // inner octree nodes in the pool (the root included)
  // Multires maps: finest levels (8^3 voxels of TSDF and weight: 4 KiB float, 2 KiB 16-bit) lent to
  // blocks integrated at scale 0; a block refused one stays at scale 1. 0 = block_capacity (never
  // refuses, reserves the worst case, which stays untouched until used). Single-resolution maps
  // ignore it.
  std::uint32_t finest_capacity = 0;
  // Multires maps: mid levels (scale 1: 4^3 voxels, 1 KiB float, 512 B 16-bit) lent to blocks
  // integrated at scale 1 or finer (a finest level comes with one); a block refused one stays at
  // scale 2. 0 = block_capacity (never refuses). Single-resolution maps ignore it.
  std::uint32_t mid_capacity = 0;

  int voxels_per_side() const { return 1 << voxel_depth; }
  float size_m() const { return voxel_size_m * static_cast<float>(voxels_per_side()); }
  // Tree level of the blocks (root = level 0): each level halves the octant side.
  int block_level() const { return voxel_depth - kBlockSideLog2; }
  float block_size_m() const { return voxel_size_m * static_cast<float>(kBlockSide); }
  std::uint32_t effective_finest_capacity() const {
    return finest_capacity == 0 ? block_capacity : finest_capacity;
  }
  std::uint32_t effective_mid_capacity() const {
    return mid_capacity == 0 ? block_capacity : mid_capacity;
  }

  // A cube centred on `centre_W` (the usual choice: the first camera position).
  static MapConfig centred(const Eigen::Vector3f& centre_W, float voxel_size_m, int voxel_depth,
                           std::uint32_t block_capacity, std::uint32_t node_capacity);
};

// ok, or invalid_argument when the voxel size is outside [kMinVoxelSize_m, kMaxVoxelSize_m], the
// depth is outside [kMinVoxelDepth, kMaxVoxelDepth], the origin is not finite or a coordinate's
// magnitude is above kMaxOrigin_m, or a capacity is zero (or the node capacity is above 2^31, the
// block, finest or mid capacity above 2^30).
Status validate(const MapConfig& config);

// The least voxel depth d (kMinVoxelDepth..kMaxVoxelDepth) whose cube of 2^d voxels of
// voxel_size_m covers map_size_m (within 0.1 %).
int voxel_depth_for(float map_size_m, float voxel_size_m);

}  // namespace octofuse
