#include "octofuse/map/detail/propagation.hpp"

#include <algorithm>

namespace octofuse {
namespace {

// Along one axis: the parent neighbour used for a child and its weight. A child centre sits a
// quarter of a parent voxel from its parent's centre, towards the neighbour; at the border the
// opposite neighbour extrapolates (weight -1/4); a single parent voxel gives a constant.
struct AxisTap {
  int neighbour;
  float weight;
};
AxisTap axis_tap(int child, int parent_side) {
  const int p = child >> 1;
  if (parent_side == 1) return {p, 0.0f};
  const int towards = (child & 1) != 0 ? p + 1 : p - 1;
  if (towards >= 0 && towards < parent_side) return {towards, 0.25f};
  return {2 * p - towards, -0.25f};
}

}  // namespace

template <typename VoxelT>
void propagate_block_down(VoxelBlock<VoxelT>& block, int parent_scale, float y_max) {
  const int child_scale = parent_scale - 1;
  const int pn = block_scale_side(parent_scale);
  const int cn = block_scale_side(child_scale);
  VoxelT* parents = block.level_begin(parent_scale);
  // Per axis and child coordinate, the two parents along that axis (own, neighbour) as index
  // offsets and their weights, computed once instead of per child and corner.
  struct Axis {
    int offset[2];
    float weight[2];
  };
  Axis ax[kBlockSide];
  Axis ay[kBlockSide];
  Axis az[kBlockSide];
  for (int c = 0; c < cn; ++c) {
    const AxisTap t = axis_tap(c, pn);
    const int p = c >> 1;
    ax[c] = Axis{{p, t.neighbour}, {1.0f - t.weight, t.weight}};
    ay[c] = Axis{{p * pn, t.neighbour * pn}, {1.0f - t.weight, t.weight}};
    az[c] = Axis{{p * pn * pn, t.neighbour * pn * pn}, {1.0f - t.weight, t.weight}};
  }
  // Scale 0's voxels are a type of their own (FinestVoxelT): they keep no interval.
  block.with_level(child_scale, [&](auto* children) {
    auto* child_ptr = children;
    for (int cz = 0; cz < cn; ++cz) {
      const Axis& tz = az[cz];
      for (int cy = 0; cy < cn; ++cy) {
        const Axis& ty = ay[cy];
        for (int cx = 0; cx < cn; ++cx, ++child_ptr) {
          const Axis& tx = ax[cx];
          const VoxelT& parent = parents[tx.offset[0] + ty.offset[0] + tz.offset[0]];
          auto& child = *child_ptr;
          if (voxel_observed(child)) {
            set_voxel_tsdf(
                child, std::clamp(voxel_tsdf(child) + (voxel_tsdf(parent) - voxel_x_last(parent)),
                                  -1.0f, 1.0f));
            set_voxel_weight(child, std::min(y_max, voxel_weight(child) + voxel_delta_y(parent)));
            set_voxel_delta_y(child, voxel_delta_y(child) + voxel_delta_y(parent));
            continue;
          }
          if (!voxel_observed(parent)) continue;
          // Trilinear over the 2x2x2 parents around the child centre (corner bit 0 = x
          // neighbour, bit 1 = y, bit 2 = z); weights multiply x, y, z in that order.
          float value = 0.0f;
          bool complete = true;
          for (int c = 0; c < 8; ++c) {
            const int ox = c & 1;
            const int oy = (c >> 1) & 1;
            const int oz = c >> 2;
            const VoxelT& v = parents[tx.offset[ox] + ty.offset[oy] + tz.offset[oz]];
            if (!voxel_observed(v)) {
              complete = false;
              break;
            }
            value += tx.weight[ox] * ty.weight[oy] * tz.weight[oz] * voxel_tsdf(v);
          }
          set_voxel_tsdf(child, complete ? std::clamp(value, -1.0f, 1.0f) : voxel_tsdf(parent));
          set_voxel_x_last(child, voxel_tsdf(child));
          set_voxel_weight(child, voxel_weight(parent));
          set_voxel_delta_y(child, 0.0f);
        }
      }
    }
  });
  for (int i = 0; i < pn * pn * pn; ++i) {
    set_voxel_x_last(parents[i], voxel_tsdf(parents[i]));
    set_voxel_delta_y(parents[i], 0.0f);
  }
}

template void propagate_block_down(VoxelBlock<MultiresVoxel>&, int, float);
template void propagate_block_down(VoxelBlock<Multires16Voxel>&, int, float);

}  // namespace octofuse
