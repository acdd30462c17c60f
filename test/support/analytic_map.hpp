#pragma once
// Test scenes written straight into the map (no integrator): the normalised TSDF of an analytic
// signed distance function at every voxel centre of a chosen scale, weight 1, coarser mips as the
// mean of their children (what up-propagation leaves), finer scales unobserved.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <memory>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/map/octree.hpp"
#include "support/aligned_buffer.hpp"

namespace octofuse::test {

inline void set_voxel(TsdfVoxel& v, float tsdf, float weight) {
  v.tsdf = tsdf;
  v.weight = weight;
}
inline void set_voxel(MultiresVoxel& v, float tsdf, float weight) {
  v.x = tsdf;
  v.x_last = tsdf;
  v.y = weight;
  v.delta_y = 0.0f;
}
// The same into voxel `index` of `block` (a finest voxel keeps the TSDF and weight).
template <typename VoxelT>
void set_block_voxel(VoxelBlock<VoxelT>& block, int index, float tsdf, float weight) {
  VoxelT v;
  set_voxel(v, tsdf, weight);
  block.set_voxel(index, v);
}

// An octree with its own arena memory.
template <typename VoxelT>
struct OwnedMap {
  ArenaBuffer memory;
  Octree<VoxelT> map;

  explicit OwnedMap(const MapConfig& config) : memory(Octree<VoxelT>::bytes_required(config)) {
    if (!map.reserve(memory.arena(), config).ok()) std::abort();
  }
};

// Writes sdf(p_W) (metres, positive in free space) into one block at `scale`.
template <typename VoxelT, typename Sdf>
void fill_block(Octree<VoxelT>& map, VoxelBlock<VoxelT>& block, int scale, float mu_m,
                const Sdf& sdf) {
  // Multires blocks hold a finest (mid) level only once written at scale 0 (1).
  if (scale == 0 && !map.acquire_finest(block).ok()) std::abort();
  if (scale == 1 && !map.acquire_mid(block).ok()) std::abort();
  for (int i = block.first_stored_voxel(); i < kBlockVoxelCount; ++i) {
    block.set_voxel(i, VoxelT());
  }
  const int side = block_scale_side(scale);
  for (int z = 0; z < side; ++z) {
    for (int y = 0; y < side; ++y) {
      for (int x = 0; x < side; ++x) {
        const Eigen::Vector3i voxel = block.min_voxel() + Eigen::Vector3i(x, y, z) * (1 << scale);
        const float d = sdf(map.voxel_centre_W(voxel, scale));
        set_block_voxel(block, block_voxel_index(x, y, z, scale),
                        std::max(-1.0f, std::min(1.0f, d / mu_m)), 1.0f);
      }
    }
  }
  for (int s = scale + 1; s <= kMaxBlockScale; ++s) {
    const int n = block_scale_side(s);
    for (int z = 0; z < n; ++z) {
      for (int y = 0; y < n; ++y) {
        for (int x = 0; x < n; ++x) {
          float sum = 0.0f;
          for (int c = 0; c < 8; ++c) {
            sum += voxel_tsdf(
                block.at(2 * x + (c & 1), 2 * y + ((c >> 1) & 1), 2 * z + ((c >> 2) & 1), s - 1));
          }
          set_block_voxel(block, block_voxel_index(x, y, z, s), sum / 8.0f, 1.0f);
        }
      }
    }
  }
  block.current_scale = static_cast<std::int8_t>(scale);
  block.min_scale = static_cast<std::int8_t>(scale);
  Octree<VoxelT>::update_block_summary(block);
}

// Allocates and fills every block whose centre lies within mu + half a block diagonal of the
// surface; scale_of(block_coords) picks each block's scale. Returns the number of blocks.
template <typename VoxelT, typename Sdf, typename ScaleOf>
int fill_band(Octree<VoxelT>& map, float mu_m, const Sdf& sdf, const ScaleOf& scale_of) {
  const int blocks_per_side = map.voxels_per_side() / kBlockSide;
  const float reach_m = mu_m + 0.5f * std::sqrt(3.0f) * map.config().block_size_m();
  int count = 0;
  for (int z = 0; z < blocks_per_side; ++z) {
    for (int y = 0; y < blocks_per_side; ++y) {
      for (int x = 0; x < blocks_per_side; ++x) {
        const Eigen::Vector3i coords(x, y, z);
        if (std::fabs(sdf(map.block_centre_W(coords))) > reach_m) continue;
        Result<std::uint32_t> index = map.allocate_block(coords);
        if (!index.ok()) std::abort();
        fill_block(map, map.block(index.value()), scale_of(coords), mu_m, sdf);
        ++count;
      }
    }
  }
  std::uint32_t all[1];
  for (std::uint32_t i = 0; i < map.block_count(); ++i) {
    all[0] = i;
    map.propagate_summaries(all, 1);
  }
  return count;
}

}  // namespace octofuse::test
