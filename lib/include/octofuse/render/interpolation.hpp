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
  const Eigen::Vector3f q = map.point_to_voxel_f(p_W);  // finest voxel units
  const Eigen::Vector3i voxel = map.point_to_voxel(p_W);
  const VoxelBlock<VoxelT>* home = map.find_block_at_voxel(voxel);
  if (home == nullptr) return false;
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
    // Neighbours usually share one block; remember the last one found.
    const VoxelBlock<VoxelT>* cached = nullptr;
    Eigen::Vector3i cached_coords(-1, -1, -1);
    for (int c = 0; c < 8 && ok; ++c) {
      const Eigen::Vector3i corner =
          (base + Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1)) * size;
      if (!map.contains_voxel(corner)) {
        ok = false;
        break;
      }
      const Eigen::Vector3i block_coords = voxel_to_block(corner);
      if (cached == nullptr || block_coords != cached_coords) {
        cached = map.find_block(block_coords);
        cached_coords = block_coords;
      }
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
