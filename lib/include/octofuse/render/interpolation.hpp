#pragma once
// Trilinear TSDF sampling over the multi-resolution map (paper section 4.4, Fig. 5): interpolate
// on the common finest grid of the 8 neighbours. Start at the scale the block holding the point
// was last integrated at; when a neighbour's block was last integrated coarser, retry at that
// scale. Blocks integrated finer are read through their (up-propagated) mip levels. Single-res
// maps have every block at scale 0 and take the same path.

#include <cmath>
#include <cstdint>

#include <Eigen/Core>

#include "octofuse/map/octree.hpp"

namespace octofuse {

// The scale a block is read at: where it was last integrated for multi-resolution maps (clamped
// against corrupt values), always 0 for single-resolution ones. Whether a block was integrated at
// all is left to the voxel weights (0 = unobserved), so a block the integrator never touched
// reads as unobserved either way.
template <typename VoxelT>
int block_read_scale(const VoxelBlock<VoxelT>& block) {
  if constexpr (IsMultiresVoxel<VoxelT>::value) {
    const int s = block.current_scale;
    return s < 0 ? 0 : s > kMaxBlockScale ? kMaxBlockScale : s;
  } else {
    return 0;
  }
}

struct TsdfSample {
  float tsdf = 1.0f;                                   // normalised by mu
  Eigen::Vector3f gradient = Eigen::Vector3f::Zero();  // of the trilinear cell, per metre
  int scale = 0;                                       // scale of the grid used
};

// Samples the normalised TSDF at p_W. False when a neighbour lies outside the map, in an
// unallocated or never-integrated block, or is unobserved (weight 0) at the common scale.
template <typename VoxelT>
bool sample_tsdf(const Octree<VoxelT>& map, const Eigen::Vector3f& p_W, TsdfSample& out) {
  return sample_tsdf(map, p_W, map.find_block_at_voxel(map.point_to_voxel(p_W)), out);
}

// Same, with the block holding p_W already found by the caller (`home`, null = none).
template <typename VoxelT>
bool sample_tsdf(const Octree<VoxelT>& map, const Eigen::Vector3f& p_W,
                 const VoxelBlock<VoxelT>* home, TsdfSample& out) {
  if (home == nullptr) return false;
  const Eigen::Vector3f q = map.point_to_voxel_f(p_W);  // finest voxel units
  int scale = block_read_scale(*home);
  while (scale <= kMaxBlockScale) {
    const int size = 1 << scale;
    // Continuous coordinates on the grid of this scale, whose samples sit at voxel centres.
    const Eigen::Vector3f qs = q / static_cast<float>(size) - Eigen::Vector3f::Constant(0.5f);
    const Eigen::Vector3f base_f(std::floor(qs.x()), std::floor(qs.y()), std::floor(qs.z()));
    const Eigen::Vector3f frac = qs - base_f;
    const Eigen::Vector3i base = base_f.cast<int>();
    float values[8];
    int needed = scale;
    bool ok = true;
    // Fast path: all 8 neighbours inside the home block, read at this scale directly.
    const int side = block_scale_side(scale);
    const Eigen::Vector3i local = base - home->min_voxel() / size;
    if (local.x() >= 0 && local.y() >= 0 && local.z() >= 0 && local.x() < side - 1 &&
        local.y() < side - 1 && local.z() < side - 1) {
      const VoxelT* level = home->scale_begin(scale);
      const int first = local.x() + local.y() * side + local.z() * side * side;
      const int offsets[8] = {0,
                              1,
                              side,
                              side + 1,
                              side * side,
                              side * side + 1,
                              side * side + side,
                              side * side + side + 1};
      for (int c = 0; c < 8 && ok; ++c) {
        const VoxelT& v = level[first + offsets[c]];
        ok = voxel_observed(v);
        values[c] = voxel_tsdf(v);
      }
      if (!ok) return false;
    } else {
      // The corners span at most 2 blocks per axis: look each block up once, the home block
      // not at all.
      const VoxelBlock<VoxelT>* near[8] = {};
      bool looked_up[8] = {};
      const Eigen::Vector3i first_block = voxel_to_block(base * size);
      for (int c = 0; c < 8 && ok; ++c) {
        const Eigen::Vector3i corner =
            (base + Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1)) * size;
        if (!map.contains_voxel(corner)) {
          ok = false;
          break;
        }
        const Eigen::Vector3i block_coords = voxel_to_block(corner);
        const Eigen::Vector3i d = block_coords - first_block;
        const int slot = d.x() + 2 * d.y() + 4 * d.z();
        if (!looked_up[slot]) {
          near[slot] = block_coords == home->coords ? home : map.find_block(block_coords);
          looked_up[slot] = true;
        }
        const VoxelBlock<VoxelT>* cached = near[slot];
        if (cached == nullptr) {
          ok = false;
          break;
        }
        const int cached_scale = block_read_scale(*cached);
        if (cached_scale > needed) needed = cached_scale;
        const VoxelT& v = cached->at_voxel(corner, scale);
        if (!voxel_observed(v)) {
          ok = false;
          break;
        }
        values[c] = voxel_tsdf(v);
      }
    }
    if (!ok) {
      // A coarser neighbour may still make the coarser grid complete; only retry for that.
      if (needed > scale) {
        scale = needed;
        continue;
      }
      return false;
    }
    if (needed > scale) {
      scale = needed;
      continue;
    }
    const float fx = frac.x();
    const float fy = frac.y();
    const float fz = frac.z();
    const float x00 = values[0] + (values[1] - values[0]) * fx;
    const float x10 = values[2] + (values[3] - values[2]) * fx;
    const float x01 = values[4] + (values[5] - values[4]) * fx;
    const float x11 = values[6] + (values[7] - values[6]) * fx;
    const float y0 = x00 + (x10 - x00) * fy;
    const float y1 = x01 + (x11 - x01) * fy;
    out.tsdf = y0 + (y1 - y0) * fz;
    // Derivatives of the trilinear interpolant, per grid unit, then per metre.
    const float dx0 = (values[1] - values[0]) * (1 - fy) + (values[3] - values[2]) * fy;
    const float dx1 = (values[5] - values[4]) * (1 - fy) + (values[7] - values[6]) * fy;
    const float dy0 = (values[2] - values[0]) * (1 - fx) + (values[3] - values[1]) * fx;
    const float dy1 = (values[6] - values[4]) * (1 - fx) + (values[7] - values[5]) * fx;
    const float cell_m = map.voxel_size_m() * static_cast<float>(size);
    out.gradient =
        Eigen::Vector3f(dx0 + (dx1 - dx0) * fz, dy0 + (dy1 - dy0) * fz, y1 - y0) / cell_m;
    out.scale = scale;
    return true;
  }
  return false;
}

}  // namespace octofuse
