#pragma once
// Depth fusion into the octree map (paper 4.3). One class template serves every map:
// Integrator<TsdfVoxel> is the single-resolution baseline (every block at scale 0),
// Integrator<MultiresVoxel> the adaptive-resolution fusion (per-block scale from the pixel
// footprint, down-propagation on refinement, up-propagation after every update), and
// Integrator<Multires16Voxel> the same fusion over 16-bit fixed-point voxels (map/voxel.hpp).
//
// Per frame: (1) march each valid pixel's ray over the band depth +- mu and collect the distinct
// blocks it crosses, in first-crossed order (bands of rows in parallel, merged in band order);
// (2) look the blocks up and pick their scales (parallel), allocate the missing ones (sorted by
// Morton code, so pool indices are deterministic); (3) apply the budgets; (4) integrate the blocks
// in pool order (sorted by block index, so headers and voxels are visited in address order, not
// scattered) in a fixed number of tasks over the WorkerTeam (each block is written by one task
// only, so the map is bit-identical for any worker count and any list order); (5) refresh the
// octree's node summaries. Every parallel step uses a fixed task partition.
//
// Memory: reserve() carves everything from the arena; integrate() allocates nothing.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/parallel.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/fusion/fusion_config.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/map/keys.hpp"
#include "octofuse/map/octree.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse {

namespace fusion_internal {

// One block a frame touched.
struct FrameBlock {
  Eigen::Vector3i coords = Eigen::Vector3i::Zero();
  std::uint64_t morton = 0;        // of the block coordinates (the map's hash key)
  std::uint32_t block = kNoIndex;  // pool index once allocated
  float z_m = 0.0f;                // depth of the block centre in the camera frame
  std::int8_t scale = 0;           // scale to integrate at this frame
  std::int8_t skip = 0;            // 1: dropped by a budget
  std::uint8_t padding[2] = {};
};

// Per-frame set of blocks (packed block coordinates); an entry belongs to the current frame when
// its stamp matches, so nothing is cleared between frames.
struct FrameSetEntry {
  std::uint64_t key = 0;
  std::uint32_t stamp = 0;
  std::uint32_t padding = 0;
};

// What one task counted; summed in task order.
// Cells the allocation rays passed recently (direct-mapped, packed block coordinates).
inline constexpr int kSeenCacheLog2 = 12;
inline constexpr std::size_t kSeenCacheSize = std::size_t{1} << kSeenCacheLog2;

// The most pixels (rows times row stride) a depth image may span: the voxel projection forms
// pixel indices in float, exact below 2^24.
inline constexpr std::int64_t kMaxImageSpan_px = std::int64_t{1} << 24;

// Block collection marches the image in this many bands of rows, in parallel; each band lists the
// cells it passes (after its own seen-cell cache) for a serial merge into the frame set.
inline constexpr std::size_t kCollectTasks = 8;

// Where one band's list ended.
struct CollectTally {
  std::uint32_t count = 0;       // cells listed
  std::uint32_t outside = 0;     // band samples outside the cube, up to the stop
  std::uint32_t rays = 0;        // rays marched, up to the stop
  std::int32_t stop_row = -1;    // >= 0: the list filled up at this row (in pixel steps) ...
  std::int32_t stop_column = 0;  // ... and pixel column; the merge marches the rest
};

struct TaskTally {
  std::uint64_t voxels_updated = 0;
  std::uint32_t blocks_per_scale[4] = {0, 0, 0, 0};
  std::uint32_t refined = 0;
  std::uint32_t coarsened = 0;
  std::uint32_t missing = 0;  // blocks looked up and not allocated yet
};

}  // namespace fusion_internal

// Where a block about to integrate at scale 0 without a finest level may find the one it gave up
// for room (the pipeline's finest-level store): the integrator asks before lending it a fresh,
// interpolated one. Called serially, in list order.
template <typename VoxelT>
class FinestLevelSource {
 public:
  enum class Answer {
    none,      // nothing kept: a fresh level is lent
    restored,  // block `index` holds its level again (restore_finest_from_record())
    wait,      // kept but not readable this frame (budget, pool): the block integrates at scale 1
  };
  virtual Answer restore(Octree<VoxelT>& map, std::uint32_t index) = 0;

 protected:
  ~FinestLevelSource() = default;
};

template <typename VoxelT>
class Integrator {
 public:
  static constexpr bool kMultires = IsMultiresVoxel<VoxelT>::value;

  // Exactly what reserve() takes from a LinearArena at a kArenaAlignment-aligned offset.
  static std::size_t bytes_required(const FusionConfig& config, int image_width, int image_height) {
    ArenaSizer sizer;
    Integrator probe;
    if (!probe.reserve(sizer, config, image_width, image_height).ok()) return 0;
    return sizer.bytes_used();
  }

  // invalid_argument: validate(config) failed or the image size is not positive or spans more
  // than fusion_internal::kMaxImageSpan_px; resource_exhausted: the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, const FusionConfig& config, int image_width, int image_height) {
    OCTOFUSE_TRY(validate(config));
    if (image_width <= 0 || image_height <= 0 ||
        std::int64_t{image_width} * image_height > fusion_internal::kMaxImageSpan_px) {
      return StatusCode::invalid_argument;
    }
    using namespace fusion_internal;
    std::size_t set_size = 16;
    int set_bits = 4;
    while (set_size < 2 * static_cast<std::size_t>(config.max_blocks_per_frame)) {
      set_size *= 2;
      ++set_bits;
    }
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    Result<FrameSetEntry*> set = arena.template allocate_array<FrameSetEntry>(set_size);
    OCTOFUSE_TRY(set);
    Result<FrameBlock*> blocks =
        arena.template allocate_array<FrameBlock>(config.max_blocks_per_frame);
    OCTOFUSE_TRY(blocks);
    Result<Key*> keys = arena.template allocate_array<Key>(config.max_blocks_per_frame);
    OCTOFUSE_TRY(keys);
    Result<std::uint32_t*> indices =
        arena.template allocate_array<std::uint32_t>(config.max_blocks_per_frame);
    OCTOFUSE_TRY(indices);
    // The blocks to integrate in pool order, and the radix sort's second buffer.
    Result<std::uint64_t*> pool_order =
        arena.template allocate_array<std::uint64_t>(2 * std::size_t{config.max_blocks_per_frame});
    OCTOFUSE_TRY(pool_order);
    // One seen-cell cache per band plus one for the merge.
    Result<std::uint64_t*> seen =
        arena.template allocate_array<std::uint64_t>((kCollectTasks + 1) * kSeenCacheSize);
    OCTOFUSE_TRY(seen);
    // A quarter of the frame's blocks per band (an eighth of the rows) leaves room for repeats
    // across bands; a band that fills up is finished serially by the merge.
    const std::size_t band_capacity = std::max<std::size_t>(16, config.max_blocks_per_frame / 4);
    Result<std::uint64_t*> band_cells =
        arena.template allocate_array<std::uint64_t>(kCollectTasks * band_capacity);
    OCTOFUSE_TRY(band_cells);
    Result<CollectTally*> collect = arena.template allocate_array<CollectTally>(kCollectTasks);
    OCTOFUSE_TRY(collect);
    Result<TaskTally*> tallies =
        arena.template allocate_array<TaskTally>(static_cast<std::size_t>(config.task_count));
    OCTOFUSE_TRY(tallies);
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    config_ = config;
    width_ = image_width;
    height_ = image_height;
    set_ = set.value();
    set_mask_ = set_size - 1;
    set_bits_ = set_bits;
    frame_blocks_ = blocks.value();
    keys_ = keys.value();
    block_indices_ = indices.value();
    pool_order_ = pool_order.value();
    seen_ = seen.value();
    band_cells_ = band_cells.value();
    band_capacity_ = band_capacity;
    collect_tallies_ = collect.value();
    tallies_ = tallies.value();
    stamp_ = 0;
    reserved_ = !std::is_same_v<Arena, ArenaSizer>;
    return ok_status();
  }

  // Fuses one depth image (metres, 0 or non-finite = no measurement; size = the reserved size)
  // seen by `camera` (same resolution) from pose T_W_C, as frame `frame_index`. See
  // IntegrationReport for the status codes. Never allocates heap memory.
  IntegrationReport integrate(Octree<VoxelT>& map, ImageView<const float> depth_m,
                              const PinholeCamera& camera, const Se3d& T_W_C,
                              std::uint32_t frame_index, const FusionBudget& budget,
                              const WorkerTeam& team);

  // integrate() in two parts, for a caller that makes room in the map between them (the pipeline
  // evicts exactly the blocks this frame will allocate). begin_frame() does step 1 and step 2's
  // look-up, changes nothing on the map, and returns the blocks not allocated yet in
  // blocks_requested (with the status and step 1's counts). finish_frame(), with the same map and
  // inputs, looks the collected blocks up again (blocks may have been evicted, demoted or read
  // back in between: the look-up is cheap, the collection is not and depends on no block) and
  // does the rest: the same report and map as integrate() on the map as it is then.
  // failed_precondition: finish_frame() without a begin_frame() for these inputs.
  IntegrationReport begin_frame(const Octree<VoxelT>& map, ImageView<const float> depth_m,
                                const PinholeCamera& camera, const Se3d& T_W_C,
                                const WorkerTeam& team);
  IntegrationReport finish_frame(Octree<VoxelT>& map, ImageView<const float> depth_m,
                                 const PinholeCamera& camera, const Se3d& T_W_C,
                                 std::uint32_t frame_index, const FusionBudget& budget,
                                 const WorkerTeam& team);

  // Between begin_frame() and finish_frame(): each block the frame touches, as visit(morton,
  // block coordinates, pool index as looked up at begin_frame(): kNoIndex where not allocated,
  // the scale picked for it), in the list's order (the pipeline reads back stored ones in the place
  // of the missing, and eviction keeps the allocated ones to the last).
  template <typename Visit>
  void for_each_listed_block(Visit&& visit) const {
    if (begun_.map == nullptr) return;
    for (std::uint32_t i = 0; i < frame_block_count_; ++i) {
      const fusion_internal::FrameBlock& b = frame_blocks_[i];
      visit(b.morton, b.coords, b.block, static_cast<int>(b.scale));
    }
  }

  // Between begin_frame() and finish_frame(): drops from the list each block for which
  // leave_out(morton, pool index as looked up at begin_frame()) is true (the pipeline leaves out
  // stored blocks it could not read back this frame rather than have them mapped afresh); the rest
  // keep their order, and finish_frame() fuses them as usual. Returns how many were dropped.
  template <typename LeaveOut>
  std::uint32_t leave_out_listed_blocks(LeaveOut&& leave_out) {
    if (begun_.map == nullptr) return 0;
    std::uint32_t kept = 0;
    for (std::uint32_t i = 0; i < frame_block_count_; ++i) {
      const fusion_internal::FrameBlock& b = frame_blocks_[i];
      if (!leave_out(b.morton, b.block)) frame_blocks_[kept++] = b;
    }
    const std::uint32_t dropped = frame_block_count_ - kept;
    frame_block_count_ = kept;
    begun_.report.blocks_touched = kept;
    return dropped;
  }

  // Blocks that gave their finest level up ask `source` for it back (null: none asked). Set it
  // between frames; it must outlive its use.
  void set_finest_source(FinestLevelSource<VoxelT>* source) { finest_source_ = source; }

  const FusionConfig& config() const { return config_; }
  // Between frames (a frame deadline's step): allocation marches every step-th pixel's ray in x
  // and y; below 1 is 1. Blocks only the skipped rays cross are not integrated that frame.
  void set_allocation_pixel_step(int step) { config_.allocation_pixel_step = step > 1 ? step : 1; }

 private:
  struct Frame;
  // integrate()'s steps (numbered as at the top of this file).
  StatusCode check_inputs(const Octree<VoxelT>& map, ImageView<const float> depth_m,
                          const PinholeCamera& camera, const Se3d& T_W_C) const;
  Frame frame_constants(const Octree<VoxelT>& map, ImageView<const float> depth_m,
                        const PinholeCamera& camera, const Se3d& T_W_C) const;
  void start_frame_set();
  // Steps 1 and 2's look-up; `missing`: the blocks not allocated yet.
  IntegrationReport collect_and_look_up(const Octree<VoxelT>& map, const Frame& frame,
                                        const PinholeCamera& camera, const WorkerTeam& team);
  // Steps 2 (allocation) to 5 over the looked-up list; `report` holds steps 1-2's counts.
  IntegrationReport integrate_looked_up(Octree<VoxelT>& map, Frame& frame,
                                        std::uint32_t frame_index, const FusionBudget& budget,
                                        const WorkerTeam& team, IntegrationReport report);
  // Returns the blocks not allocated yet.
  std::uint32_t look_up_blocks(const Octree<VoxelT>& map, const Frame& frame,
                               const PinholeCamera& camera, std::uint32_t touched,
                               const WorkerTeam& team);
  // Returns how many blocks were integrated (their parents are in block_indices_).
  std::uint32_t integrate_blocks(Octree<VoxelT>& map, const Frame& frame, std::uint32_t count,
                                 std::uint32_t frame_index, const WorkerTeam& team,
                                 IntegrationReport& report);
  std::uint32_t collect_blocks(const Octree<VoxelT>& map, const Frame& frame,
                               IntegrationReport& report, const WorkerTeam& team);
  bool insert_frame_block(std::uint64_t key, const Eigen::Vector3i& coords,
                          IntegrationReport& report);
  // `cost`: the voxel updates of the list as it is. True when a budget bound.
  bool apply_budgets(std::uint32_t count, std::uint64_t cost, const FusionBudget& budget,
                     IntegrationReport& report);
  static void integrate_block(VoxelBlock<VoxelT>& block, int scale, const Frame& frame,
                              fusion_internal::TaskTally& tally);

  FusionConfig config_;
  FinestLevelSource<VoxelT>* finest_source_ = nullptr;
  int width_ = 0;
  int height_ = 0;
  fusion_internal::FrameSetEntry* set_ = nullptr;
  std::size_t set_mask_ = 0;
  int set_bits_ = 4;
  fusion_internal::FrameBlock* frame_blocks_ = nullptr;
  std::uint32_t frame_block_count_ = 0;
  Key* keys_ = nullptr;
  std::uint32_t* block_indices_ = nullptr;
  // Step 4's list: (block index << 8) | scale, sorted by block index; twice max_blocks_per_frame.
  // Step 3 rations the finest levels in it.
  std::uint64_t* pool_order_ = nullptr;
  std::uint64_t* seen_ = nullptr;        // (kCollectTasks + 1) * kSeenCacheSize entries
  std::uint64_t* band_cells_ = nullptr;  // kCollectTasks lists of band_capacity_ packed cells
  std::size_t band_capacity_ = 0;
  fusion_internal::CollectTally* collect_tallies_ = nullptr;
  fusion_internal::TaskTally* tallies_ = nullptr;
  std::uint32_t stamp_ = 0;
  bool reserved_ = false;
  // What begin_frame() collected for (finish_frame() checks it got the same), and its counts.
  struct Begun {
    const void* map = nullptr;
    const float* depth = nullptr;
    Se3d T_W_C = Se3d::Identity();
    IntegrationReport report;
  };
  Begun begun_;
};

extern template class Integrator<TsdfVoxel>;
extern template class Integrator<MultiresVoxel>;
extern template class Integrator<Multires16Voxel>;

using SingleResIntegrator = Integrator<TsdfVoxel>;
using MultiresIntegrator = Integrator<MultiresVoxel>;

}  // namespace octofuse
