#pragma once
// Moving multires data between the scales of one block (paper 4.3.2-4.3.3).
//
// Up (eq. 4): map/detail/mip.hpp's propagate_block_up.
// Down (eq. 5), when a block refines from parent scale l+1 to l:
//   observed child:   x += (x_parent - x_last_parent), clamped to [-1, 1];
//                     y = min(y_max, y + delta_y_parent); delta_y += delta_y_parent
//   unobserved child: x = trilinear interpolation of the parent field at the child's centre
//                     (extrapolated at the block border, nearest parent where a neighbour is
//                     unobserved), y = y_parent, x_last = x, delta_y = 0
// then every parent restarts its interval: x_last = x, delta_y = 0.

#include "octofuse/map/voxel.hpp"
#include "octofuse/map/voxel_block.hpp"

namespace octofuse {

// Down-propagates from `parent_scale` (1..3) to parent_scale - 1 (MultiresVoxel and
// Multires16Voxel blocks).
template <typename VoxelT>
void propagate_block_down(VoxelBlock<VoxelT>& block, int parent_scale, float y_max);

}  // namespace octofuse
