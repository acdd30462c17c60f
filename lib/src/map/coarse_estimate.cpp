#include "octofuse/map/coarse_estimate.hpp"

#include <algorithm>

namespace octofuse {
namespace {

// An entry: the block's Morton code (block coordinates), a taken bit, its min_scale (2 bits).
constexpr int kMortonShift = 3;
constexpr std::uint64_t kTakenBit = 4;
constexpr std::uint64_t kScaleMask = 3;

}  // namespace

template <typename VoxelT>
Result<CoarseEstimate> estimate_coarse_blocks(const Octree<VoxelT>& map, std::uint64_t* scratch,
                                              std::size_t scratch_count) {
  if (scratch == nullptr || scratch_count < map.block_count()) return StatusCode::invalid_argument;
  CoarseEstimate estimate;
  std::size_t count = 0;
  for (std::uint32_t i = 0; i < map.block_count(); ++i) {
    const VoxelBlock<VoxelT>& block = map.block(i);
    if (!block.integrated()) continue;
    scratch[count++] =
        (morton_encode(block.coords) << kMortonShift) | static_cast<std::uint64_t>(block.min_scale);
  }
  estimate.fused_blocks = count;
  // Sorted, the blocks of one octant at any level are consecutive.
  std::sort(scratch, scratch + count);
  for (int up = std::min(kMaxBlockScale, map.block_level()); up >= 1; --up) {
    const int shift = kMortonShift + 3 * up;
    for (std::size_t first = 0; first < count;) {
      std::size_t end = first;
      bool coarse = true;
      while (end < count && (scratch[end] >> shift) == (scratch[first] >> shift)) {
        const std::uint64_t e = scratch[end];
        coarse = coarse && (e & kTakenBit) == 0 && static_cast<int>(e & kScaleMask) >= up;
        ++end;
      }
      if (coarse) {
        ++estimate.octants[up - 1];
        estimate.replaced[up - 1] += end - first;
        for (std::size_t i = first; i < end; ++i) scratch[i] |= kTakenBit;
      }
      first = end;
    }
  }
  return estimate;
}

template Result<CoarseEstimate> estimate_coarse_blocks(const Octree<TsdfVoxel>&, std::uint64_t*,
                                                       std::size_t);
template Result<CoarseEstimate> estimate_coarse_blocks(const Octree<MultiresVoxel>&, std::uint64_t*,
                                                       std::size_t);
template Result<CoarseEstimate> estimate_coarse_blocks(const Octree<Multires16Voxel>&,
                                                       std::uint64_t*, std::size_t);

}  // namespace octofuse
