#pragma once
// What allocating voxel blocks at coarser octree levels would keep of a map (the paper's section
// 4.2: far data that never reaches a block's finest scale need not take a block per 8^3 finest
// voxels). An octant L levels above the blocks (L = 1..3) could be a single 8^3 block of cells
// 2^L finest voxels wide where no block under it was ever fused finer than scale L (its
// min_scale): it would hold what those blocks hold at scale L and above, nothing less. Levels are
// taken coarsest first, each octant only once, so the counts add up: blocks_after() is the block
// count a map allocated that way would have. Measures a map; changes nothing.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/result.hpp"
#include "octofuse/map/octree.hpp"

namespace octofuse {

struct CoarseEstimate {
  std::uint64_t fused_blocks = 0;  // blocks integrated at least once (the others are left out)
  // Index L - 1, for octants L levels above the blocks: the fused blocks they would replace, and
  // how many octants (coarse blocks) that takes.
  std::uint64_t replaced[kMaxBlockScale] = {};
  std::uint64_t octants[kMaxBlockScale] = {};
  std::uint64_t blocks_after() const {
    std::uint64_t blocks = fused_blocks;
    for (int i = 0; i < kMaxBlockScale; ++i) blocks = blocks - replaced[i] + octants[i];
    return blocks;
  }
};

// `scratch` holds at least map.block_count() entries (sorted there). invalid_argument when it is
// smaller. Single-resolution maps fuse every block at scale 0: nothing is replaced.
template <typename VoxelT>
Result<CoarseEstimate> estimate_coarse_blocks(const Octree<VoxelT>& map, std::uint64_t* scratch,
                                              std::size_t scratch_count);

extern template Result<CoarseEstimate> estimate_coarse_blocks(const Octree<TsdfVoxel>&,
                                                              std::uint64_t*, std::size_t);
extern template Result<CoarseEstimate> estimate_coarse_blocks(const Octree<MultiresVoxel>&,
                                                              std::uint64_t*, std::size_t);
extern template Result<CoarseEstimate> estimate_coarse_blocks(const Octree<Multires16Voxel>&,
                                                              std::uint64_t*, std::size_t);

}  // namespace octofuse
