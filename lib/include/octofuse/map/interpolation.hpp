#pragma once
// Trilinear TSDF sampling over the multi-resolution map (paper section 4.4, Fig. 5): interpolate
// on the common finest grid of the 8 neighbours. Start at the scale the block holding the point
// was last integrated at; when a neighbour's block was last integrated coarser, retry at that
// scale. Blocks integrated finer are read through their (up-propagated) mip levels. Single-res
// maps have every block at scale 0 and take the same path.

#include <algorithm>
#include <cmath>
#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/lanes.hpp"
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

// Blocks around the last slow-path sample: consecutive samples along a ray mostly need the same
// 2x2x2 block neighbourhood, so a caller that samples repeatedly keeps one of these to look each
// block up once instead of once per sample. Valid while the map is not modified.
template <typename VoxelT>
struct BlockNeighbourhood {
  Eigen::Vector3i first_block = Eigen::Vector3i::Constant(-1);  // block of the (0,0,0) corner
  const VoxelBlock<VoxelT>* blocks[8] = {};
  std::int8_t read_scale[8] = {};  // block_read_scale of each block found
  bool looked_up[8] = {};
};

namespace detail {
// The trilinear interpolant of a cell's 8 corner values (x fastest) at `frac` in [0, 1]^3, and
// its gradient per metre for a cell `cell_m` on a side, into `out`.
inline void interpolate_cell(const float (&values)[8], const Eigen::Vector3f& frac, float cell_m,
                             int scale, TsdfSample& out) {
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
  out.gradient = Eigen::Vector3f(dx0 + (dx1 - dx0) * fz, dy0 + (dy1 - dy0) * fz, y1 - y0) / cell_m;
  out.scale = scale;
}
}  // namespace detail

// Samples the normalised TSDF at p_W. False when a neighbour lies outside the map, in an
// unallocated or never-integrated block, or is unobserved (weight 0) at the common scale.
template <typename VoxelT>
bool sample_tsdf(const Octree<VoxelT>& map, const Eigen::Vector3f& p_W, TsdfSample& out) {
  return sample_tsdf(map, p_W, map.find_block_at_voxel(map.point_to_voxel(p_W)), out);
}

template <typename VoxelT>
bool sample_tsdf_at_voxel_coords(const Octree<VoxelT>& map, const Eigen::Vector3f& q,
                                 const VoxelBlock<VoxelT>* home,
                                 BlockNeighbourhood<VoxelT>& neighbourhood, TsdfSample& out);

// Same, with the block holding p_W already found by the caller (`home`, null = none).
template <typename VoxelT>
bool sample_tsdf(const Octree<VoxelT>& map, const Eigen::Vector3f& p_W,
                 const VoxelBlock<VoxelT>* home, TsdfSample& out) {
  BlockNeighbourhood<VoxelT> neighbourhood;
  return sample_tsdf_at_voxel_coords(map, map.point_to_voxel_f(p_W), home, neighbourhood, out);
}

namespace detail {
// sample_tsdf_at_voxel_coords without its argument checks, inlined where it is called: for
// callers that already know `home` exists and q lies in (-1, voxels_per_side + 1)^3 (the
// ray-caster's march, where a call's overhead was a tenth of the sample's cost).
template <typename VoxelT>
__attribute__((always_inline)) inline bool sample_tsdf_checked(
    const Octree<VoxelT>& map, const Eigen::Vector3f& q, const VoxelBlock<VoxelT>& home_block,
    BlockNeighbourhood<VoxelT>& neighbourhood, TsdfSample& out);
}  // namespace detail

// Same, at continuous finest-voxel coordinates q (Octree::point_to_voxel_f), reusing and updating
// the caller's block neighbourhood.
template <typename VoxelT>
bool sample_tsdf_at_voxel_coords(const Octree<VoxelT>& map, const Eigen::Vector3f& q,
                                 const VoxelBlock<VoxelT>* home,
                                 BlockNeighbourhood<VoxelT>& neighbourhood, TsdfSample& out) {
  if (home == nullptr) return false;
  // Also rejects NaN, and keeps the integer conversions below in range.
  const float limit = static_cast<float>(map.voxels_per_side()) + 1.0f;
  if (!(q.x() > -1.0f && q.y() > -1.0f && q.z() > -1.0f && q.x() < limit && q.y() < limit &&
        q.z() < limit)) {
    return false;
  }
  return detail::sample_tsdf_checked(map, q, *home, neighbourhood, out);
}

template <typename VoxelT>
__attribute__((always_inline)) inline bool detail::sample_tsdf_checked(
    const Octree<VoxelT>& map, const Eigen::Vector3f& q, const VoxelBlock<VoxelT>& home_block,
    BlockNeighbourhood<VoxelT>& neighbourhood, TsdfSample& out) {
  const VoxelBlock<VoxelT>* home = &home_block;
  int scale = block_read_scale(*home);
  while (scale <= kMaxBlockScale) {
    const int size = 1 << scale;
    // Continuous coordinates on the grid of this scale, whose samples sit at voxel centres.
    // 1 / 2^scale is exact, so the product equals the quotient. In 4-lane vectors (the fourth
    // unused), each lane computing what floor_to_int and the scalar expressions would.
    const Lanes4 qs = Lanes4{q.x(), q.y(), q.z(), 0.0f} * (1.0f / static_cast<float>(size)) - 0.5f;
    const Ints4 floored = floor_lanes(qs);
    const Lanes4 frac_lanes = qs - __builtin_convertvector(floored, Lanes4);
    const Eigen::Vector3i base(floored[0], floored[1], floored[2]);
    const Eigen::Vector3f frac(frac_lanes[0], frac_lanes[1], frac_lanes[2]);
    float values[8];
    int needed = scale;
    bool ok = true;
    // Fast path: all 8 neighbours inside the home block, read at this scale directly.
    const int side = block_scale_side(scale);
    const Eigen::Vector3i home_min = home->min_voxel();  // non-negative: shifts divide exactly
    const Eigen::Vector3i local =
        base - Eigen::Vector3i(home_min.x() >> scale, home_min.y() >> scale, home_min.z() >> scale);
    if (local.x() >= 0 && local.y() >= 0 && local.z() >= 0 && local.x() < side - 1 &&
        local.y() < side - 1 && local.z() < side - 1) {
      const int first = local.x() + local.y() * side + local.z() * side * side;
      const int offsets[8] = {0,
                              1,
                              side,
                              side + 1,
                              side * side,
                              side * side + 1,
                              side * side + side,
                              side * side + side + 1};
      // All 8 read, then one test: the reads stay inside the block either way.
      home->with_level(scale, [&](const auto* level) {
        for (int c = 0; c < 8; ++c) {
          const auto& v = level[first + offsets[c]];
          ok &= voxel_observed(v);
          values[c] = voxel_tsdf(v);
        }
      });
      if (!ok) return false;
    } else {
      // The corners span at most 2 blocks per axis: look each block up once, the home block
      // not at all, and keep them for the next sample.
      const Eigen::Vector3i first_block = voxel_to_block(base * size);
      if (first_block != neighbourhood.first_block) {
        neighbourhood = BlockNeighbourhood<VoxelT>{};
        neighbourhood.first_block = first_block;
      }
      const VoxelBlock<VoxelT>** near = neighbourhood.blocks;
      bool* looked_up = neighbourhood.looked_up;
      // Per axis, for the lower and upper corner: which of the two blocks (0/1) and the index
      // inside it at this scale; the 8 corners combine these.
      const int n = map.voxels_per_side();
      int block_of[3][2];
      int local_of[3][2];
      for (int a = 0; a < 3; ++a) {
        for (int k = 0; k < 2; ++k) {
          const int v = (base[a] + k) * size;
          if (v < 0 || v >= n) return false;  // outside the cube at every coarser scale too
          block_of[a][k] = (v >> 3) - first_block[a];
          local_of[a][k] = (v & 7) >> scale;
        }
      }
      const int stride_y = side;
      const int stride_z = side * side;
      // Per corner (bit 0: x, 1: y, 2: z) its block slot and index, from the per-axis parts.
      int slot_of[8];
      int index_of[8];
      for (int c = 0; c < 8; ++c) {
        const int i = c & 1;
        const int j = (c >> 1) & 1;
        const int k = (c >> 2) & 1;
        slot_of[c] = block_of[0][i] + 2 * block_of[1][j] + 4 * block_of[2][k];
        index_of[c] = local_of[0][i] + local_of[1][j] * stride_y + local_of[2][k] * stride_z;
      }
      for (int c = 0; c < 8; ++c) {
        const int slot = slot_of[c];
        if (!looked_up[slot]) {
          const Eigen::Vector3i block_coords =
              first_block + Eigen::Vector3i(slot & 1, (slot >> 1) & 1, (slot >> 2) & 1);
          const VoxelBlock<VoxelT>* found =
              block_coords == home->coords ? home : map.find_block(block_coords);
          near[slot] = found;
          if (found != nullptr) {
            neighbourhood.read_scale[slot] = static_cast<std::int8_t>(block_read_scale(*found));
          }
          looked_up[slot] = true;
        }
        const VoxelBlock<VoxelT>* cached = near[slot];
        if (cached == nullptr) {
          ok = false;
          break;
        }
        const int cached_scale = neighbourhood.read_scale[slot];
        if (cached_scale > needed) needed = cached_scale;
        cached->with_level(scale, [&](const auto* level) {
          const auto& v = level[index_of[c]];
          ok = voxel_observed(v);
          values[c] = voxel_tsdf(v);
        });
        if (!ok) break;
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
    detail::interpolate_cell(values, frac, map.voxel_size_m() * static_cast<float>(size), scale,
                             out);
    return true;
  }
  return false;
}

// The trilinear sample at q from the observed corners alone, for where the full sample fails: the
// corners in unallocated blocks or unobserved take the mean of the observed ones, weighted as the
// full sample weighs them, so the value is that weighted mean and the gradient that of the
// completed cell. The scale is chosen as the full sample chooses it (the coarsest read scale of
// the blocks found). False when the observed corners carry less than `min_weight` of the cell's
// weight (in (0, 1]), or as the full sample (no home block, outside the cube).
template <typename VoxelT>
bool sample_tsdf_observed_at_voxel_coords(const Octree<VoxelT>& map, const Eigen::Vector3f& q,
                                          const VoxelBlock<VoxelT>* home, float min_weight,
                                          TsdfSample& out) {
  if (home == nullptr) return false;
  const float limit = static_cast<float>(map.voxels_per_side()) + 1.0f;
  if (!(q.x() > -1.0f && q.y() > -1.0f && q.z() > -1.0f && q.x() < limit && q.y() < limit &&
        q.z() < limit)) {
    return false;
  }
  const int n = map.voxels_per_side();
  int scale = block_read_scale(*home);
  while (scale <= kMaxBlockScale) {
    const int size = 1 << scale;
    const Eigen::Vector3f qs =
        q * (1.0f / static_cast<float>(size)) - Eigen::Vector3f::Constant(0.5f);
    const Eigen::Vector3i base(floor_to_int(qs.x()), floor_to_int(qs.y()), floor_to_int(qs.z()));
    const Eigen::Vector3f frac = qs - base.cast<float>();
    float values[8];
    bool observed[8];
    float weight_sum = 0.0f;
    float value_sum = 0.0f;
    int needed = scale;
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3i corner = base + Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1);
      const Eigen::Vector3i v = corner * size;
      observed[c] = false;
      values[c] = 0.0f;
      if (v.x() < 0 || v.y() < 0 || v.z() < 0 || v.x() >= n || v.y() >= n || v.z() >= n) {
        continue;
      }
      const Eigen::Vector3i block_coords = voxel_to_block(v);
      const VoxelBlock<VoxelT>* block =
          block_coords == home->coords ? home : map.find_block(block_coords);
      if (block == nullptr) continue;
      needed = std::max(needed, block_read_scale(*block));
      const VoxelT& voxel = block->at_voxel(v, scale);
      if (!voxel_observed(voxel)) continue;
      const float w = ((c & 1) != 0 ? frac.x() : 1.0f - frac.x()) *
                      (((c >> 1) & 1) != 0 ? frac.y() : 1.0f - frac.y()) *
                      (((c >> 2) & 1) != 0 ? frac.z() : 1.0f - frac.z());
      observed[c] = true;
      values[c] = voxel_tsdf(voxel);
      weight_sum += w;
      value_sum += w * values[c];
    }
    if (needed > scale) {
      scale = needed;
      continue;
    }
    // Also false for NaN voxels.
    if (!(weight_sum >= min_weight)) return false;
    const float mean = value_sum / weight_sum;
    for (int c = 0; c < 8; ++c) {
      if (!observed[c]) values[c] = mean;
    }
    detail::interpolate_cell(values, frac, map.voxel_size_m() * static_cast<float>(size), scale,
                             out);
    return true;
  }
  return false;
}

}  // namespace octofuse
