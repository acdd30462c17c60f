#pragma once
// Up-propagation inside a block (paper eq. 4): with cell-centred voxels a voxel at scale s+1 is
// the mean of its 8 children at scale s. Only observed children count; when none is observed the
// parent is left unchanged. Weights are averaged and rounded up, so a parent of observed children
// is observed. For multires voxels the parent also starts a fresh down-propagation interval
// (x_last = x, delta_y = 0).

#include <cmath>

#include "octofuse/map/voxel.hpp"
#include "octofuse/map/voxel_block.hpp"

namespace octofuse {

inline void set_parent_from_children(TsdfVoxel& parent, float tsdf_mean, float weight_mean) {
  parent.tsdf = tsdf_mean;
  parent.weight = weight_mean;
}
inline void set_parent_from_children(MultiresVoxel& parent, float tsdf_mean, float weight_mean) {
  parent.x = tsdf_mean;
  parent.x_last = tsdf_mean;
  parent.y = weight_mean;
  parent.delta_y = 0.0f;
}
inline void set_parent_from_children(Multires16Voxel& parent, float tsdf_mean, float weight_mean) {
  set_voxel_tsdf(parent, tsdf_mean);
  parent.x_last_q = parent.x_q;
  set_voxel_weight(parent, weight_mean);
  parent.delta_y_q = 0;
}

// Recomputes scale s+1 from scale s, for s = from_scale .. to_scale-1 (0 <= from < to <= 3).
template <typename VoxelT>
void propagate_block_up(VoxelBlock<VoxelT>& block, int from_scale, int to_scale) {
  for (int s = from_scale; s < to_scale; ++s) {
    const int child_side = block_scale_side(s);
    const int side = block_scale_side(s + 1);
    VoxelT* parents = block.level_begin(s + 1);
    // Scale 0's voxels are a type of their own (FinestVoxelT).
    block.with_level(s, [&](const auto* children) {
      for (int z = 0; z < side; ++z) {
        for (int y = 0; y < side; ++y) {
          for (int x = 0; x < side; ++x) {
            float sum_tsdf = 0.0f;
            float sum_weight = 0.0f;
            int observed = 0;
            for (int c = 0; c < 8; ++c) {
              const int cx = 2 * x + (c & 1);
              const int cy = 2 * y + ((c >> 1) & 1);
              const int cz = 2 * z + ((c >> 2) & 1);
              const auto& child = children[cx + cy * child_side + cz * child_side * child_side];
              if (!voxel_observed(child)) continue;
              sum_tsdf += voxel_tsdf(child);
              sum_weight += voxel_weight(child);
              ++observed;
            }
            if (observed == 0) continue;
            const float n = static_cast<float>(observed);
            set_parent_from_children(parents[x + y * side + z * side * side], sum_tsdf / n,
                                     std::ceil(sum_weight / n));
          }
        }
      }
    });
  }
}

}  // namespace octofuse
