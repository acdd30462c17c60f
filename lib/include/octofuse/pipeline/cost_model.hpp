#pragma once
// A frame deadline: a cost model of the machine (work units -> milliseconds, per stage) and the
// controller that derives each frame's budgets from it, so that the modelled frame time stays
// within the deadline. When the work the last frames asked for does not fit, it cuts in the
// pipeline's degradation order (pipeline.hpp), each step down to its floor before the next:
//   (1) ICP iterations, the finest level first, down to min_icp_iterations;
//   (4) voxel updates (far blocks one scale coarser, then skipped), down to min_voxel_fraction
//       of the demand;
//   (6) ray-cast steps (the rows' last pixels stay invalid), down to min_raycast_fraction;
//   (7) free-space node visits, down to min_free_space_fraction.
// Eviction (2) answers memory, not time, and is left as configured; new blocks (3) and the
// integrated-block count (5) are inside the voxel-update budget, which bounds their cost.
//
// Units per stage (the quantities the budgets bound): ICP pixel-iterations (a pyramid level's
// pixels times its iterations, summed), integration voxel cost (block_scale_count of each
// integrated block's scale, as FusionBudget::max_voxel_updates counts it), ray-cast march steps,
// free-space node visits. The model keeps milliseconds per million units of each and a fixed
// part (validation, pre-processing and what the stages do besides their units).
//
// Once all floors are in the plan and the frame still does not fit, the plan says so
// (infeasible) and the frame runs at the floors.
//
// Where determinism is lost: with `adapt` the model learns from the stage times the clock
// measures (an asymmetric running mean that follows increases fast and decreases slowly, and a
// safety factor raised after each frame over the deadline), so the budgets, and through them the
// map and the trajectory, depend on the machine and its load. A frozen model (`adapt` false)
// reads no time: the budgets follow from the model's numbers and the work counts of the earlier
// frames, which are the same for any worker count and CPU, so the same model and input give
// bit-identical results. The demand estimates come from work counts only, in both modes.

#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/depth_pyramid.hpp"

namespace octofuse {

// Milliseconds per million units of each stage (see the top of this file), and a fixed part per
// frame. `safety` (>= 1) multiplies the modelled frame time before it is compared with the
// deadline. The defaults are the medians of a 1-thread 7-Scenes run at 1 cm, QVGA, on a 2-core
// x86-64; a run calibrates them within a few frames.
struct CostModel {
  double fixed_ms = 3.5;
  double icp_ms_per_mpixel_iteration = 35.0;
  double integrate_ms_per_mvoxel = 14.0;
  double raycast_ms_per_mstep = 110.0;
  double free_space_ms_per_mvisit = 350.0;
  double safety = 1.0;
};

// ok, or invalid_argument: every rate and fixed_ms must be finite and in (0, 1e6], safety in
// [1, 16].
Status validate(const CostModel& model, ErrorText* error = nullptr);

struct DeadlineConfig {
  double deadline_ms = 0.0;  // per frame; 0 = off (the budgets are the configured ones)
  CostModel model;           // the starting model (a calibration from an earlier run)
  bool adapt = true;         // false: frozen model, deterministic budgets (see above)
  // Floors of the cuts. ICP index 0 = finest level, as PipelineBudget::icp_iterations; a floor
  // above the configured budget is the configured budget.
  int min_icp_iterations[kPyramidLevels] = {1, 1, 2};
  float min_voxel_fraction = 0.25f;
  float min_raycast_fraction = 0.25f;
  float min_free_space_fraction = 0.0f;  // at least one visit stays
  // A stage that is not cut gets its demand times this as its budget, so a view that asks for a
  // little more than the last one is served whole.
  float demand_growth = 1.25f;
};

// ok, or invalid_argument: deadline_ms finite in [0, 1e5], the model valid, floors >= 0 and
// fractions in [0, 1], demand_growth in [1, 4].
Status validate(const DeadlineConfig& config, ErrorText* error = nullptr);

// Degradation steps a deadline plan cuts (pipeline.hpp's numbering).
enum class DeadlineStep : std::uint8_t {
  none = 0,
  icp = 1,
  voxel_updates = 4,
  raycast = 6,
  free_space = 7,
};
const char* deadline_step_name(DeadlineStep step);

// One frame's budgets under a deadline, and what the frame gave up for them.
struct DeadlineReport {
  bool active = false;      // a deadline was set and the plan applied
  bool planned = false;     // false: no demand known yet (the first frame), configured budgets
  bool infeasible = false;  // the floors alone do not fit the deadline
  bool over = false;        // the measured frame time exceeded the deadline
  DeadlineStep deepest = DeadlineStep::none;  // the last step the plan cut
  double deadline_ms = 0.0;
  double predicted_ms = 0.0;  // modelled frame time under these budgets, safety included
  int icp_iterations[kPyramidLevels] = {0, 0, 0};  // budgeted per level
  int icp_iterations_given_up = 0;                 // below the configured budget, all levels
  std::uint64_t max_voxel_updates = 0;  // 0 where not cut (the configured budget applies)
  std::uint64_t raycast_steps = 0;
  std::uint32_t free_space_visits = 0;
  // Demand estimates the plan started from (units).
  double voxel_demand = 0.0;
  double raycast_demand = 0.0;
  double free_space_demand = 0.0;
};

// What one frame did and took, for the controller.
struct StageObservation {
  bool ran = false;         // the stage ran this frame
  bool budget_hit = false;  // its budget bound (it wanted more)
  double units = 0.0;
  double ms = 0.0;
};
struct FrameObservation {
  bool timed = false;  // the times come from a clock (a null clock reads none)
  double total_ms = 0.0;
  StageObservation icp, integrate, raycast, free_space;
};

class DeadlineController {
 public:
  // `icp_iterations`: the configured budget per level; `width` x `height`: the working
  // resolution (pyramid level 0); `icp_used`: the pose source tracks; `free_space_used`: carving
  // is on. Forgets the demand estimates and starts from config.model.
  void reset(const DeadlineConfig& config, const int icp_iterations[kPyramidLevels], int width,
             int height, bool icp_used, bool free_space_used);
  bool active() const { return config_.deadline_ms > 0.0; }
  // The next frame's budgets (see DeadlineReport); configured ones before any observation.
  DeadlineReport plan() const;
  // Learns from a finished frame: demand estimates from its work counts; with adapt and a
  // timed observation, the model's rates, fixed part and safety factor too.
  void observe(const FrameObservation& frame, const DeadlineReport& plan);
  const CostModel& model() const { return model_; }
  const DeadlineConfig& config() const { return config_; }

 private:
  double icp_cost_ms(const int iterations[kPyramidLevels]) const;

  DeadlineConfig config_;
  CostModel model_;
  int icp_iterations_[kPyramidLevels] = {0, 0, 0};
  int icp_floor_[kPyramidLevels] = {0, 0, 0};
  double level_pixels_[kPyramidLevels] = {0.0, 0.0, 0.0};
  bool icp_used_ = true;
  bool free_space_used_ = true;
  bool have_demand_ = false;
  double voxel_demand_ = 0.0;
  double raycast_demand_ = 0.0;
  double free_space_demand_ = 0.0;
};

}  // namespace octofuse
