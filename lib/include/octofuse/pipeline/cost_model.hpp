#pragma once
// A frame deadline: a cost model of the machine (work units -> milliseconds, per stage) and the
// controller that derives each frame's budgets from it, so that the modelled frame time stays
// within the deadline. lib/README.md ("The frame deadline") gives the units, the order of the
// cuts and where determinism is lost (only with `adapt`).

#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/depth_pyramid.hpp"

namespace octofuse {

// One stage: fixed_ms whenever it runs, plus ms_per_munit per million units.
struct StageCost {
  double fixed_ms = 0.0;
  double ms_per_munit = 1.0;
  double ms(double units) const { return fixed_ms + ms_per_munit * units * 1e-6; }
};

// The machine's costs (units: lib/README.md, "The frame deadline"). `safety` (>= 1) multiplies the
// modelled frame time before it is compared with the deadline. The defaults are rounded from
// 7-Scenes at 1 cm, QVGA, 1 thread on a 2-core x86-64; a run calibrates them within a few frames.
struct CostModel {
  double fixed_ms = 3.5;                // validation and pre-processing, per frame
  StageCost icp = {0.5, 33.0};          // per million pixel-iterations
  StageCost integrate = {5.0, 10.0};    // per million voxels
  StageCost raycast = {5.0, 90.0};      // per million march steps
  StageCost free_space = {0.5, 250.0};  // per million node visits
  double safety = 1.0;
};

// ok, or invalid_argument: fixed parts finite in [0, 1e6], rates finite in (0, 1e6], safety in
// [1, 16].
Status validate(const CostModel& model, ErrorText* error = nullptr);

struct DeadlineConfig {
  double deadline_ms = 0.0;  // per frame; 0 = off (the budgets are the configured ones)
  CostModel model;           // the starting model (a calibration from an earlier run)
  bool adapt = true;         // false: frozen model, deterministic budgets (lib/README.md)
  // Floors of the cuts. ICP index 0 = finest level, as PipelineBudget::icp_iterations; a floor
  // above the configured budget is the configured budget.
  int min_icp_iterations[kPyramidLevels] = {2, 2, 4};
  float min_voxel_fraction = 0.25f;
  float min_voxel_fraction_deep = 0.125f;  // the last step's floor; above min_voxel_fraction: off
  float min_raycast_fraction = 0.5f;
  float min_free_space_fraction = 0.0f;  // at least one visit stays
  bool raycast_half_resolution = true;   // false: the ray-cast always marches every pixel
  bool allocation_half = true;           // false: allocation always marches every pixel's ray
  // A stage that is not cut gets its demand times this as its budget, so a view that asks for a
  // little more than the last one is served whole.
  float demand_growth = 1.25f;
  // The last steps, when even the floors do not fit: frames take turns, one fusing its depth
  // (integration, free space), the next ray-casting the reference view from its own pose, every
  // frame tracking; then frames that only track, at most max_track_only_frames in a row, so the
  // map and the model's figures of the skipped stages never stop for long.
  bool fuse_alternate = true;
  bool track_only = true;
  int max_track_only_frames = 3;
};

// ok, or invalid_argument: deadline_ms finite in [0, 1e5], the model valid, floors >= 0 and
// fractions in [0, 1], demand_growth in [1, 4], max_track_only_frames in [0, 1000].
Status validate(const DeadlineConfig& config, ErrorText* error = nullptr);

// Degradation steps a deadline plan cuts, numbered in the order it cuts them (pipeline.hpp's
// steps (1), (4), (6) and (7), with the half-resolution ray-cast and allocation before (6) and
// a deeper cut of (4) after (7)); then, below the floors, fusion on every other frame and frames
// that only track.
enum class DeadlineStep : std::uint8_t {
  none = 0,
  icp = 1,
  voxel_updates = 2,
  raycast_half = 3,
  allocation_half = 4,
  raycast = 5,
  free_space = 6,
  voxel_updates_deep = 7,
  fuse_alternate = 8,
  track_only = 9,
};
const char* deadline_step_name(DeadlineStep step);

// One frame's budgets under a deadline, and what the frame gave up for them.
struct DeadlineReport {
  bool active = false;      // a deadline was set and the plan applied
  bool planned = false;     // false: no demand known yet (the first frame), configured budgets
  bool infeasible = false;  // even the deepest step taken does not fit the deadline
  bool over = false;        // the measured frame time exceeded the deadline
  DeadlineStep deepest = DeadlineStep::none;  // the last step the plan cut
  double deadline_ms = 0.0;
  double predicted_ms = 0.0;  // modelled frame time under these budgets, safety included
  int icp_iterations[kPyramidLevels] = {0, 0, 0};  // budgeted per level
  int icp_iterations_given_up = 0;                 // below the configured budget, all levels
  std::uint64_t max_voxel_updates = 0;  // 0 where not cut (the configured budget applies)
  std::uint64_t raycast_steps = 0;
  bool raycast_half = false;     // the reference ray-cast at half resolution
  bool allocation_half = false;  // allocation marched every other pixel's ray in x and y
  std::uint32_t free_space_visits = 0;
  // Stages this frame does not run (fuse_alternate: one of the two; track_only: both). The
  // budgets above are then those of the stages it runs, planned over them alone.
  bool fusion_skipped = false;   // no integration, no free space: this frame's depth is not fused
  bool raycast_skipped = false;  // no reference ray-cast: the next frame tracks an older view
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
  // With budget_hit: the units it would have done unbounded, as far as the stage's report shows
  // (the ray-cast's steps scaled by the pixels it reached and, at half resolution, by the
  // pixels over the rays it marched; integration's units plus the most its coarsened and
  // skipped blocks could have cost); 0 where unknown.
  double demand = 0.0;
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
  // is on; `finest_icp_share`: the share of the finest level's pixels an ICP pass takes, relative
  // to the checkerboard's (a quarter of the pixels against a half-resolution reference: 0.5), so
  // that the units weigh the levels as the passes cost; `middle_icp_share`: the same for the
  // middle level, relative to all its pixels (0.5 with its checkerboard). Forgets the demand
  // estimates and starts from config.model.
  void reset(const DeadlineConfig& config, const int icp_iterations[kPyramidLevels], int width,
             int height, bool icp_used, bool free_space_used, double finest_icp_share = 1.0,
             double middle_icp_share = 1.0);
  bool active() const { return config_.deadline_ms > 0.0; }
  // The next frame's budgets (see DeadlineReport); configured ones before any observation.
  DeadlineReport plan() const;
  // Learns from a finished frame: demand estimates from its work counts; with adapt and a
  // timed observation, the model's rates, fixed part and safety factor too (a frame whose
  // allocation was halved adds the modelled saving back to its integration time first, so the
  // line stays that of a full march).
  void observe(const FrameObservation& frame, const DeadlineReport& plan);
  const CostModel& model() const { return model_; }
  const DeadlineConfig& config() const { return config_; }

 private:
  // Units and times of the recent frames of one stage, each older frame weighing kForget less.
  struct Regression {
    double weight = 0.0;
    double units = 0.0, ms = 0.0, units_sq = 0.0, units_ms = 0.0;
  };
  static void learn(Regression& regression, StageCost& cost, double units, double ms);
  double icp_units(const int iterations[kPyramidLevels]) const;
  // The ladder of cuts over the stages the frame runs.
  DeadlineReport plan_stages(bool fuse, bool cast) const;

  Regression icp_fit_, integrate_fit_, raycast_fit_, free_space_fit_;

  DeadlineConfig config_;
  CostModel model_;
  int icp_iterations_[kPyramidLevels] = {0, 0, 0};
  int icp_floor_[kPyramidLevels] = {0, 0, 0};
  double level_pixels_[kPyramidLevels] = {0.0, 0.0, 0.0};
  double icp_level_units_[kPyramidLevels] = {0.0, 0.0, 0.0};  // one ICP iteration's units
  double half_pixels_ = 0.0;  // the rays a half-resolution ray-cast marches
  bool icp_used_ = true;
  bool free_space_used_ = true;
  bool have_demand_ = false;
  double voxel_demand_ = 0.0;
  double raycast_demand_ = 0.0;
  double free_space_demand_ = 0.0;
  bool map_ahead_of_cast_ = false;  // the last frame that did either fused and did not cast
  int track_only_run_ = 0;          // frames in a row that only tracked
};

}  // namespace octofuse
