#include "octofuse/fusion/propagation.hpp"

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

void propagate_block_down(VoxelBlock<MultiresVoxel>& block, int parent_scale, float y_max) {
  const int child_scale = parent_scale - 1;
  const int pn = block_scale_side(parent_scale);
  const int cn = block_scale_side(child_scale);
  MultiresVoxel* parents = block.scale_begin(parent_scale);
  MultiresVoxel* children = block.scale_begin(child_scale);
  auto parent_at = [&](int x, int y, int z) -> const MultiresVoxel& {
    return parents[x + y * pn + z * pn * pn];
  };
  for (int cz = 0; cz < cn; ++cz) {
    const AxisTap tz = axis_tap(cz, pn);
    for (int cy = 0; cy < cn; ++cy) {
      const AxisTap ty = axis_tap(cy, pn);
      for (int cx = 0; cx < cn; ++cx) {
        const AxisTap tx = axis_tap(cx, pn);
        const int px = cx >> 1;
        const int py = cy >> 1;
        const int pz = cz >> 1;
        const MultiresVoxel& parent = parent_at(px, py, pz);
        MultiresVoxel& child = children[cx + cy * cn + cz * cn * cn];
        if (voxel_observed(child)) {
          child.x = std::clamp(child.x + (parent.x - parent.x_last), -1.0f, 1.0f);
          child.y = std::min(y_max, child.y + parent.delta_y);
          child.delta_y += parent.delta_y;
          continue;
        }
        if (!voxel_observed(parent)) continue;
        // Trilinear over the 2x2x2 parents around the child centre.
        float value = 0.0f;
        bool complete = true;
        for (int c = 0; c < 8 && complete; ++c) {
          const bool ox = (c & 1) != 0;
          const bool oy = (c & 2) != 0;
          const bool oz = (c & 4) != 0;
          const MultiresVoxel& v =
              parent_at(ox ? tx.neighbour : px, oy ? ty.neighbour : py, oz ? tz.neighbour : pz);
          if (!voxel_observed(v)) complete = false;
          const float w = (ox ? tx.weight : 1.0f - tx.weight) *
                          (oy ? ty.weight : 1.0f - ty.weight) * (oz ? tz.weight : 1.0f - tz.weight);
          value += w * v.x;
        }
        child.x = complete ? std::clamp(value, -1.0f, 1.0f) : parent.x;
        child.x_last = child.x;
        child.y = parent.y;
        child.delta_y = 0.0f;
      }
    }
  }
  for (int i = 0; i < pn * pn * pn; ++i) {
    parents[i].x_last = parents[i].x;
    parents[i].delta_y = 0.0f;
  }
}

}  // namespace octofuse
