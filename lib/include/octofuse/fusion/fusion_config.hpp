#pragma once
// Settings, per-frame budgets and the per-frame report of depth fusion, plus the multires scale
// selection rule (paper 4.3.1; the architecture is in lib/README.md).

#include <cstdint>

#include "octofuse/core/status.hpp"

namespace octofuse {

struct FusionConfig {
  float mu_m = 0.08f;   // truncation distance (default 8 voxels at 1 cm)
  float near_m = 0.4f;  // depth samples outside [near, far] are ignored
  float far_m = 4.0f;
  float y_max = 100.0f;  // weight cap
  // How far behind the measured surface voxels are updated, as a share of mu in (0, 1] (but at
  // least 2.5 voxels of the block's scale). 1: the whole band. A shorter back side keeps the
  // negative half of the band from running through thin objects and onto the surfaces just
  // behind them (a smaller mesh error on the sim scenes), but loses thin objects and, on noisy
  // depth (Kinect), the averaging over the longer band, so the default stays 1. Points more than
  // this behind a surface read unknown instead of inside.
  float behind_mu = 1.0f;
  // Allocation marches every n-th pixel's ray in x and y (1 = every pixel).
  int allocation_pixel_step = 1;
  // > 0: allocation takes the pixels it marches in 2 x 2 groups and marches only the first
  // pixel's ray of a group where a block spans at least this many pixels per step at its depth,
  // unless another pixel of the group lies more than mu / 2 in depth from it (an edge, a thin
  // part), whose ray is marched too. Only on frames where at least a quarter of the valid depths
  // (sampled every 8th pixel) lie near enough for a group to stand: elsewhere (far views, small
  // voxels) the grouped loop costs more than it saves. 0 marches every (step-th) ray.
  float allocation_group_block_px = 8.0f;
  // Distinct blocks one frame may touch (existing and new together); sizes the per-frame key
  // list and set. Rays beyond it are dropped and counted (IntegrationReport::keys_dropped).
  std::uint32_t max_blocks_per_frame = 1u << 17;
  // Relative margin around the scale thresholds a block's ratio must pass before its scale
  // changes (avoids flicker when the camera hovers at a threshold).
  float scale_hysteresis = 0.1f;
  // >= 0: every multires block integrates at this scale, ignoring distance (tests, experiments).
  int fixed_scale = -1;
  // Fixed number of tasks the block list is split into (independent of the worker count, so
  // results are bit-identical for any number of workers).
  int task_count = 32;
};

// ok, or invalid_argument for non-finite/non-positive mu, behind_mu outside (0, 1], near >= far,
// near <= 0, y_max < 1, a
// step < 1, a zero block count, hysteresis outside [0, 1), fixed_scale > 3, task_count < 1.
Status validate(const FusionConfig& config);

// Per-frame work bounds. When one binds the integrator degrades in this fixed order and says so
// in the report: (1) new blocks beyond max_new_blocks are not allocated (the farthest first);
// (2) over max_voxel_updates, multires blocks integrate one scale coarser, farthest first, and
// then the farthest blocks are skipped (single-res: skipped); (3) blocks beyond
// max_integrated_blocks (the farthest) are skipped.
struct FusionBudget {
  std::uint32_t max_new_blocks = 0xFFFFFFFFu;
  std::uint32_t max_integrated_blocks = 0xFFFFFFFFu;
  std::uint64_t max_voxel_updates = ~std::uint64_t{0};
};

struct IntegrationReport {
  // ok; invalid_argument (bad image, camera or pose: nothing was done); failed_precondition
  // (reserve() not called or the image size differs from the reserved one); resource_exhausted
  // (the block pool, the finest-level pool or the per-frame block list was full: the frame was
  // integrated into what fits, blocks refused a finest level at scale 1, and the map is intact).
  Status status;
  std::uint32_t blocks_touched = 0;    // distinct blocks the rays' bands crossed inside the cube
  std::uint32_t blocks_requested = 0;  // of those, not yet allocated
  std::uint32_t blocks_allocated = 0;  // newly allocated this frame
  std::uint32_t blocks_integrated = 0;
  std::uint32_t blocks_per_scale[4] = {0, 0, 0, 0};  // integrated, by scale
  std::uint32_t blocks_refined = 0;                  // multires: integrated finer than last time
  std::uint32_t blocks_coarsened = 0;                // multires: integrated coarser than last time
  std::uint32_t pool_refusals = 0;      // new blocks and finest levels the map's pools refused
  std::uint32_t finest_refusals = 0;    // of those, finest levels (the block stayed at scale 1)
  std::uint32_t mid_refusals = 0;       // and mid levels (the block stayed at scale 2)
  std::uint32_t node_refusals = 0;      // inner nodes refused (set by the pipeline)
  std::uint32_t keys_dropped = 0;       // blocks beyond max_blocks_per_frame
  std::uint32_t rays_outside_cube = 0;  // band samples that left the map's cube
  std::uint32_t allocation_rays = 0;    // pixels whose band the allocation marched
  std::uint32_t budget_blocks_not_allocated = 0;
  std::uint32_t budget_blocks_coarsened = 0;
  std::uint32_t budget_blocks_skipped = 0;
  bool budget_hit = false;
  std::uint64_t voxels_updated = 0;  // TSDF updates applied
};

// Scale from the pixel footprint ratio r = z / (fx * voxel_size_m): r < 1.5 -> 0, < 3 -> 1,
// < 6 -> 2, else 3.
inline constexpr float kScale0MaxRatio = 1.5f;
int scale_for_ratio(float r);

// The scale a block integrates at this frame. current_scale < 0: never integrated (takes the
// raw scale). Otherwise the scale moves only when r passes a threshold by the relative
// `hysteresis` margin, refines by at most one step, and may coarsen by several.
int select_scale(float r, int current_scale, float hysteresis);

// select_scale(r, c, hysteresis) when it is the same for every current scale c (never integrated
// included), so a caller need not read the block's current scale; otherwise -1. Only scales 2
// and 3 can qualify: a block two or more scales coarser than the raw one refines a single step.
int scale_for_any_current(float r, float hysteresis);

}  // namespace octofuse
