#pragma once
// A leaf of the octree: 8^3 voxels plus their mip levels 4^3, 2^3 and 1^3 (585 voxels, level
// offsets 0 / 512 / 576 / 584 in the block's voxel index). Voxels are cell-centred, so a voxel at
// scale s+1 covers exactly 8 voxels at scale s and its value is their mean. Inside a level of side
// n = 8 >> s the index is x + y*n + z*n^2, (x, y, z) local to the block in voxels of that scale.
//
// Storage: single-resolution blocks hold all 585 voxels inline. Multi-resolution blocks hold the
// two coarsest levels (8 + 1 voxels) inline and point to their two fine levels, which the map
// lends from pools of their own only once the block needs them: scale 1 (64 voxels, 1 KiB) when
// it first integrates at scale 1 or finer, scale 0 (512 voxels, 8 KiB) at scale 0. At 2 mm four
// in five blocks only ever integrate at scale 2 or 3: inline, such a block is a sixth of one that
// held every coarse level, and the fine levels would be 98 % of it. A block without a level reads
// as unobserved there (const access); writing there is a programmer error.

#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/check.hpp"
#include "octofuse/map/map_config.hpp"
#include "octofuse/map/voxel.hpp"

namespace octofuse {

inline constexpr int kBlockVoxelCount = 585;
inline constexpr int kBlockFinestVoxelCount = 512;

// Start of scale s's voxels inside a block.
constexpr int block_scale_offset(int scale) {
  return scale == 0 ? 0 : scale == 1 ? 512 : scale == 2 ? 576 : 584;
}
// Voxels per side at scale s (8, 4, 2, 1).
constexpr int block_scale_side(int scale) {
  return kBlockSide >> scale;
}
// Number of voxels at scale s (512, 64, 8, 1).
constexpr int block_scale_count(int scale) {
  return block_scale_side(scale) * block_scale_side(scale) * block_scale_side(scale);
}
// Index into a block's voxel array of local voxel (x, y, z) at scale s (coordinates in voxels of
// that scale, each in [0, 8 >> s)).
constexpr int block_voxel_index(int x, int y, int z, int scale) {
  return block_scale_offset(scale) + x + y * block_scale_side(scale) +
         z * block_scale_side(scale) * block_scale_side(scale);
}
// Same, from finest-voxel coordinates local to the block ([0, 8) each), snapped to scale s.
constexpr int block_voxel_index_finest(int x, int y, int z, int scale) {
  return block_voxel_index(x >> scale, y >> scale, z >> scale, scale);
}

inline constexpr std::int8_t kNeverIntegrated = -1;
inline constexpr std::uint32_t kNoIndex = 0xFFFFFFFFu;

// The finest level of a split block: one slot of the map's finest-level pool, of the TSDF and
// weight alone (FinestVoxelT).
template <typename VoxelT>
struct alignas(64) FinestLevel {
  FinestVoxelT<VoxelT> voxels[kBlockFinestVoxelCount] = {};
};

// Scale 1 of a split block: one slot of the map's mid-level pool.
inline constexpr int kBlockMidVoxelCount = 64;
template <typename VoxelT>
struct alignas(64) MidLevel {
  VoxelT voxels[kBlockMidVoxelCount] = {};
};

// What a block without a finest (mid) level reads at scale 0 (1); never written.
template <typename VoxelT>
inline constexpr FinestLevel<VoxelT> kUnobservedFinestLevel{};
template <typename VoxelT>
inline constexpr MidLevel<VoxelT> kUnobservedMidLevel{};

template <typename VoxelT>
struct VoxelBlock {
  using Voxel = VoxelT;
  // What scale 0 holds: VoxelT for single-resolution blocks, its TSDF and weight for multires.
  using FinestVoxel = FinestVoxelT<VoxelT>;
  // Multires blocks keep their finest and mid levels (scales 0 and 1) out of line (see above).
  static constexpr bool kSplitFinest = IsMultiresVoxel<VoxelT>::value;
  // Block voxel index of the first inline voxel, and how many are inline.
  static constexpr int kInlineBegin =
      kSplitFinest ? kBlockFinestVoxelCount + kBlockMidVoxelCount : 0;
  static constexpr int kInlineCount = kBlockVoxelCount - kInlineBegin;

  Eigen::Vector3i coords = Eigen::Vector3i::Zero();  // block coordinates (finest voxel / 8)
  std::uint64_t morton = 0;                          // Morton code of the minimum finest voxel
  std::uint32_t parent_node = kNoIndex;              // index of the inner node holding this block
  std::uint32_t last_updated_frame = 0;              // frame index of the last integration
  std::int8_t current_scale = 0;                     // scale the block was last integrated at, 0..3
  std::int8_t min_scale = kNeverIntegrated;  // finest scale ever integrated, -1 until the first
  // Multires: levels current_scale..mip_scale hold the eq. 4 means of the level below (levels
  // above mip_scale may be stale: up-propagation is lazy). -1 until the first integration.
  std::int8_t mip_scale = kNeverIntegrated;
  // 1 while the block is as restore_block_record() brought it back from a block store (integration
  // clears it): evicting it again needs no write, the store still holds its state.
  std::uint8_t stored_clean = 0;
  // Multires: the frame the block last got or gave up its finest level (0: never). A finest pool
  // smaller than the view lends its levels to the blocks that waited longest and takes them back
  // from those that held one longest, so every block in view gets its turn at scale 0.
  std::uint32_t finest_turn = 0;
  // Summary of the observed voxels at current_scale, kept by the integrator for empty-space
  // skipping: min and max normalised TSDF (1 / -1 when nothing is observed, so min > max).
  float tsdf_min = 1.0f;
  float tsdf_max = -1.0f;
  // Mean normalised TSDF and mean weight (rounded up) of those voxels; weight 0: none observed.
  // The octree's node summaries are built from these.
  float tsdf_mean = 1.0f;
  float weight_mean = 0.0f;
  // Split blocks: the finest level, lent by the map (Octree::acquire_finest), null until then.
  FinestLevel<VoxelT>* finest = nullptr;
  // Split blocks: scale 1, lent by the map (Octree::acquire_mid; a block with a finest level
  // always has one), null until then.
  MidLevel<VoxelT>* mid = nullptr;
  // Block voxel indices kInlineBegin .. 584.
  VoxelT inline_voxels[kInlineCount] = {};

  bool integrated() const { return min_scale != kNeverIntegrated; }
  // Whether the block may hold the surface: its observed voxels at current_scale change sign, or
  // nothing is known of them yet. A finest-level pool smaller than the view serves these first:
  // the surface is what the map's detail is for.
  bool may_hold_surface() const {
    return tsdf_min > tsdf_max || (tsdf_min <= 0.0f && tsdf_max >= 0.0f);
  }
  // Whether scale 0 has storage (always for single-resolution blocks).
  bool has_finest() const {
    if constexpr (kSplitFinest) {
      return finest != nullptr;
    } else {
      return true;
    }
  }
  // Whether scale 1 has storage (always for single-resolution blocks).
  bool has_mid() const {
    if constexpr (kSplitFinest) {
      return mid != nullptr;
    } else {
      return true;
    }
  }
  // Block voxel index of the first voxel with storage (0, 512 or 576): voxels from there on may
  // be written.
  int first_stored_voxel() const {
    return has_finest() ? 0 : has_mid() ? kBlockFinestVoxelCount : block_scale_offset(2);
  }
  // Minimum finest voxel of the block, cube coordinates.
  Eigen::Vector3i min_voxel() const { return coords * kBlockSide; }

  // Voxel by block voxel index (0..584, see block_voxel_index), by value (const, so that an
  // assignment to it does not compile): a finest voxel of a split block reads with x_last = x
  // and delta_y = 0 (it keeps neither). Writes: level_voxel(), finest_begin(), set_voxel().
  const VoxelT voxel(int index) const {
    if constexpr (kSplitFinest) {
      if (index < kInlineBegin) {
        if (index < kBlockFinestVoxelCount) return widen_voxel(readable_finest()[index]);
        return readable_mid()[index - kBlockFinestVoxelCount];
      }
    }
    return inline_voxels[index - kInlineBegin];
  }
  // Writable voxel by block voxel index, at scales 1-3 of a split block (its scale 0 is
  // finest_begin(), of another type) and at any scale of a single-resolution one.
  VoxelT& level_voxel(int index) {
    if constexpr (kSplitFinest) {
      OCTOFUSE_CHECK(index >= kBlockFinestVoxelCount);
      if (index < kInlineBegin) return writable_mid()[index - kBlockFinestVoxelCount];
    }
    return inline_voxels[index - kInlineBegin];
  }
  VoxelT& level_at(int x, int y, int z, int scale) {
    return level_voxel(block_voxel_index(x, y, z, scale));
  }
  // Writes voxel `index` (0..584); scale 0 of a split block keeps its TSDF and weight.
  void set_voxel(int index, const VoxelT& v) {
    if constexpr (kSplitFinest) {
      if (index < kInlineBegin) {
        if (index < kBlockFinestVoxelCount) {
          writable_finest()[index] = finest_part(v);
        } else {
          writable_mid()[index - kBlockFinestVoxelCount] = v;
        }
        return;
      }
    }
    inline_voxels[index - kInlineBegin] = v;
  }
  const VoxelT at(int x, int y, int z, int scale) const {
    return voxel(block_voxel_index(x, y, z, scale));
  }
  // Voxel at scale s containing finest voxel `voxel` (cube coordinates, inside this block).
  const VoxelT at_voxel(const Eigen::Vector3i& v, int scale) const {
    return voxel(block_voxel_index_finest(v.x() & 7, v.y() & 7, v.z() & 7, scale));
  }
  // Scale 0's 512 voxels, contiguous.
  FinestVoxel* finest_begin() {
    if constexpr (kSplitFinest) {
      return writable_finest();
    } else {
      return inline_voxels;
    }
  }
  const FinestVoxel* finest_begin() const {
    if constexpr (kSplitFinest) {
      return readable_finest();
    } else {
      return inline_voxels;
    }
  }
  // The block_scale_count(scale) voxels of level `scale`, contiguous; scale 1-3 for split blocks
  // (their scale 0 is finest_begin()).
  VoxelT* level_begin(int scale) {
    if constexpr (kSplitFinest) {
      OCTOFUSE_CHECK(scale > 0);
      if (scale == 1) return writable_mid();
    }
    return inline_voxels + (block_scale_offset(scale) - kInlineBegin);
  }
  const VoxelT* level_begin(int scale) const {
    if constexpr (kSplitFinest) {
      OCTOFUSE_CHECK(scale > 0);
      if (scale == 1) return readable_mid();
    }
    return inline_voxels + (block_scale_offset(scale) - kInlineBegin);
  }
  // Calls f with level `scale`'s voxels: finest_begin() at scale 0, level_begin() above (one
  // pointer type for single-resolution blocks, two for split ones).
  template <typename F>
  decltype(auto) with_level(int scale, F&& f) {
    if (scale == 0) return f(finest_begin());
    return f(level_begin(scale));
  }
  template <typename F>
  decltype(auto) with_level(int scale, F&& f) const {
    if (scale == 0) return f(finest_begin());
    return f(level_begin(scale));
  }
  // Copies n voxels of the block's type into finest voxels (their TSDF and weight).
  static void narrow_copy(const VoxelT* from, int n, FinestVoxel* to) {
    for (int i = 0; i < n; ++i) to[i] = finest_part(from[i]);
  }

 private:
  FinestVoxel* writable_finest() {
    OCTOFUSE_CHECK(finest != nullptr);  // writes at scale 0 need acquire_finest() first
    return finest->voxels;
  }
  const FinestVoxel* readable_finest() const {
    return finest != nullptr ? finest->voxels : kUnobservedFinestLevel<VoxelT>.voxels;
  }
  VoxelT* writable_mid() {
    OCTOFUSE_CHECK(mid != nullptr);  // writes at scale 1 need acquire_mid() first
    return mid->voxels;
  }
  const VoxelT* readable_mid() const {
    return mid != nullptr ? mid->voxels : kUnobservedMidLevel<VoxelT>.voxels;
  }
};

}  // namespace octofuse
