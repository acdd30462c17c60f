#include "octofuse/pipeline/cost_model.hpp"

#include <algorithm>
#include <cmath>

namespace octofuse {

namespace {
constexpr double kMaxValue = 1e6;
constexpr double kMaxDeadline_ms = 1e5;
constexpr double kMaxSafety = 16.0;
// Below these a view is nearly empty; budgets never fall under them, so a stage that did almost
// nothing once is not starved for good.
constexpr double kMinVoxelDemand = 64.0 * 512.0;  // 64 blocks at scale 0
constexpr double kMinVisitDemand = 64.0;
// Each older frame weighs this much less in a stage's line: about 20 frames count.
constexpr double kForget = 0.95;
// A stage held back by its budget: its demand estimate is what its report shows it wanted, or
// the previous estimate decayed by this much a frame, whichever is larger, so that one large view
// (the first frame's, above all) does not set the floors for good.
constexpr double kCutDemandDecay = 0.9;
// The slope is taken from the spread of the units only when it is wide enough to show one (a
// coefficient of variation of 5 %); otherwise the slope stays and the line goes through the mean.
constexpr double kMinRelativeSpread = 0.05;
// Rest of the frame (validation, pre-processing): a running mean with this gain.
constexpr double kFixedGain = 0.1;
// Safety factor: x1.2 after a frame over a deadline its plan met, x0.999 after one within it, so
// the long-run share over settles near ln(1/0.999) / ln(1.2/0.999), about 0.5 %, where the
// model alone misses more.
constexpr double kSafetyRise = 1.2;
constexpr double kSafetyFall = 0.999;
// What is left of an overrun after the subtractions below is rounding beneath this.
constexpr double kNegligible_ms = 1e-9;

bool rate_ok(double v) {
  return std::isfinite(v) && v > 0.0 && v <= kMaxValue;
}
bool fixed_ok(double v) {
  return std::isfinite(v) && v >= 0.0 && v <= kMaxValue;
}
}  // namespace

Status validate(const CostModel& model, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  for (const StageCost& stage : {model.icp, model.integrate, model.raycast, model.free_space}) {
    if (!fixed_ok(stage.fixed_ms) || !rate_ok(stage.ms_per_munit)) {
      err.set("cost model: stage fixed parts must be finite in [0, 1e6], rates in (0, 1e6]");
      return StatusCode::invalid_argument;
    }
  }
  if (!fixed_ok(model.fixed_ms)) {
    err.set("cost model: fixed_ms must be finite in [0, 1e6]");
    return StatusCode::invalid_argument;
  }
  if (!std::isfinite(model.safety) || !(model.safety >= 1.0) || !(model.safety <= kMaxSafety)) {
    err.set("cost model: safety must be in [1, 16]");
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

Status validate(const DeadlineConfig& config, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  if (!std::isfinite(config.deadline_ms) || !(config.deadline_ms >= 0.0) ||
      !(config.deadline_ms <= kMaxDeadline_ms)) {
    err.set("deadline_ms must be finite and in [0, 1e5]");
    return StatusCode::invalid_argument;
  }
  OCTOFUSE_TRY(validate(config.model, &err));
  for (const int floor : config.min_icp_iterations) {
    if (floor < 0) {
      err.set("deadline min_icp_iterations must be >= 0");
      return StatusCode::invalid_argument;
    }
  }
  for (const float f : {config.min_voxel_fraction, config.min_voxel_fraction_deep,
                        config.min_raycast_fraction, config.min_free_space_fraction}) {
    if (!(f >= 0.0f && f <= 1.0f)) {
      err.set("deadline floor fractions must be in [0, 1]");
      return StatusCode::invalid_argument;
    }
  }
  if (!(config.demand_growth >= 1.0f && config.demand_growth <= 4.0f)) {
    err.set("deadline demand_growth must be in [1, 4]");
    return StatusCode::invalid_argument;
  }
  if (config.max_track_only_frames < 0 || config.max_track_only_frames > 1000) {
    err.set("deadline max_track_only_frames must be in [0, 1000]");
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

const char* deadline_step_name(DeadlineStep step) {
  switch (step) {
    case DeadlineStep::none:
      return "none";
    case DeadlineStep::icp:
      return "icp";
    case DeadlineStep::voxel_updates:
      return "voxel_updates";
    case DeadlineStep::raycast_half:
      return "raycast_half";
    case DeadlineStep::allocation_half:
      return "allocation_half";
    case DeadlineStep::raycast:
      return "raycast";
    case DeadlineStep::free_space:
      return "free_space";
    case DeadlineStep::voxel_updates_deep:
      return "voxel_updates_deep";
    case DeadlineStep::fuse_alternate:
      return "fuse_alternate";
    case DeadlineStep::track_only:
      return "track_only";
  }
  return "unknown";
}

void DeadlineController::reset(const DeadlineConfig& config,
                               const int icp_iterations[kPyramidLevels], int width, int height,
                               bool icp_used, bool free_space_used, double finest_icp_share,
                               double middle_icp_share) {
  config_ = config;
  model_ = config.model;
  icp_used_ = icp_used;
  free_space_used_ = free_space_used;
  for (int level = 0; level < kPyramidLevels; ++level) {
    icp_iterations_[level] = icp_iterations[level];
    icp_floor_[level] = std::min(config.min_icp_iterations[level], icp_iterations[level]);
    level_pixels_[level] =
        static_cast<double>(width >> level) * static_cast<double>(height >> level);
    icp_level_units_[level] = level_pixels_[level] * (level == 0   ? finest_icp_share
                                                      : level == 1 ? middle_icp_share
                                                                   : 1.0);
  }
  half_pixels_ = static_cast<double>((width + 1) / 2) * static_cast<double>((height + 1) / 2);
  icp_fit_ = integrate_fit_ = raycast_fit_ = free_space_fit_ = Regression{};
  have_demand_ = false;
  voxel_demand_ = 0.0;
  raycast_demand_ = 0.0;
  free_space_demand_ = 0.0;
  map_ahead_of_cast_ = false;
  track_only_run_ = 0;
}

double DeadlineController::icp_units(const int iterations[kPyramidLevels]) const {
  double units = 0.0;
  for (int level = 0; level < kPyramidLevels; ++level) {
    units += static_cast<double>(iterations[level]) * icp_level_units_[level];
  }
  return units;
}

DeadlineReport DeadlineController::plan() const {
  DeadlineReport r = plan_stages(true, true);
  if (!r.infeasible || !config_.fuse_alternate) return r;
  // (8) Frames take turns: the one after a frame that fused casts the reference from its own
  // pose; the others fuse. Each runs the ladder again over its own stages.
  const bool cast_turn = map_ahead_of_cast_;
  DeadlineReport half = plan_stages(!cast_turn, cast_turn);
  half.fusion_skipped = cast_turn;
  half.raycast_skipped = !cast_turn;
  half.deepest = DeadlineStep::fuse_alternate;
  if (!half.infeasible || !config_.track_only || track_only_run_ >= config_.max_track_only_frames) {
    return half;
  }
  // (9) Track only; the turn is kept for the next frame.
  DeadlineReport track = plan_stages(false, false);
  track.fusion_skipped = true;
  track.raycast_skipped = true;
  track.deepest = DeadlineStep::track_only;
  return track;
}

DeadlineReport DeadlineController::plan_stages(bool fuse, bool cast) const {
  DeadlineReport r;
  r.active = active();
  r.deadline_ms = config_.deadline_ms;
  for (int level = 0; level < kPyramidLevels; ++level) {
    r.icp_iterations[level] = icp_iterations_[level];
  }
  if (!r.active || !have_demand_) return r;
  r.planned = true;
  r.voxel_demand = voxel_demand_;
  r.raycast_demand = raycast_demand_;
  r.free_space_demand = free_space_used_ ? free_space_demand_ : 0.0;
  const double growth = static_cast<double>(config_.demand_growth);
  double voxels = std::max(voxel_demand_ * growth, kMinVoxelDemand);
  const double voxels_full = voxels;
  double steps = std::max(raycast_demand_ * growth, level_pixels_[0]);
  double visits = free_space_used_ ? std::max(free_space_demand_ * growth, kMinVisitDemand) : 0.0;
  const bool carve = fuse && free_space_used_;
  // A stage the frame skips costs nothing and is cut nothing.
  const double icp_rate = icp_used_ ? model_.icp.ms_per_munit * 1e-6 : 0.0;
  const double voxel_rate = fuse ? model_.integrate.ms_per_munit * 1e-6 : 0.0;
  const double step_rate = cast ? model_.raycast.ms_per_munit * 1e-6 : 0.0;
  const double visit_rate = carve ? model_.free_space.ms_per_munit * 1e-6 : 0.0;
  // What every frame pays whatever its budgets.
  double fixed_ms = model_.fixed_ms + (icp_used_ ? model_.icp.fixed_ms : 0.0) +
                    (fuse ? model_.integrate.fixed_ms : 0.0) +
                    (cast ? model_.raycast.fixed_ms : 0.0) +
                    (carve ? model_.free_space.fixed_ms : 0.0);
  auto stages_ms = [&](const int iterations[kPyramidLevels], double v, double s, double f) {
    return icp_rate * icp_units(iterations) + voxel_rate * v + step_rate * s + visit_rate * f;
  };
  const double available_ms = config_.deadline_ms / model_.safety - fixed_ms;
  const double full_ms = stages_ms(icp_iterations_, voxels, steps, visits);
  if (full_ms <= available_ms) {
    r.predicted_ms = (fixed_ms + full_ms) * model_.safety;
    return r;  // everything fits: the configured budgets stay
  }
  double over_ms = full_ms - available_ms;
  // (1) ICP, finest level first: its iterations cost the most pixels.
  for (int level = 0; level < kPyramidLevels && icp_used_; ++level) {
    while (over_ms > kNegligible_ms && r.icp_iterations[level] > icp_floor_[level]) {
      --r.icp_iterations[level];
      ++r.icp_iterations_given_up;
      over_ms -= icp_level_units_[level] * icp_rate;
      r.deepest = DeadlineStep::icp;
    }
  }
  // (4), (6), (7): each down to its floor before the next.
  // Every budget keeps at least one unit (below), so no cut goes under one either.
  auto cut = [&](double& units, float floor_fraction, double rate, DeadlineStep step) {
    const double room = units - std::max(units * static_cast<double>(floor_fraction), 1.0);
    if (over_ms <= kNegligible_ms || room <= 0.0 || rate <= 0.0) return;
    const double removed = std::min(room, over_ms / rate);
    units -= removed;
    over_ms -= removed * rate;
    r.deepest = step;
  };
  cut(voxels, config_.min_voxel_fraction, voxel_rate, DeadlineStep::voxel_updates);
  // Half resolution: a quarter of the rays, so (about) a quarter of the steps.
  if (over_ms > kNegligible_ms && config_.raycast_half_resolution && step_rate > 0.0) {
    const double half = steps * (half_pixels_ / level_pixels_[0]);
    over_ms -= (steps - half) * step_rate;
    steps = half;
    r.raycast_half = true;
    r.deepest = DeadlineStep::raycast_half;
  }
  // Allocation at every other pixel: its march, the integration's fixed part, at that share.
  if (over_ms > kNegligible_ms && config_.allocation_half && fuse) {
    const double saved_ms = model_.integrate.fixed_ms * (1.0 - half_pixels_ / level_pixels_[0]);
    over_ms -= saved_ms;
    fixed_ms -= saved_ms;
    r.allocation_half = true;
    r.deepest = DeadlineStep::allocation_half;
  }
  cut(steps, config_.min_raycast_fraction, step_rate, DeadlineStep::raycast);
  if (carve) {
    cut(visits, config_.min_free_space_fraction, visit_rate, DeadlineStep::free_space);
  }
  // Voxel updates once more, to the deeper floor (a fraction of the demand, as the first).
  if (config_.min_voxel_fraction_deep < config_.min_voxel_fraction) {
    const double floor =
        std::max(voxels_full * static_cast<double>(config_.min_voxel_fraction_deep), 1.0);
    const double room = voxels - floor;
    if (over_ms > kNegligible_ms && room > 0.0 && voxel_rate > 0.0) {
      const double removed = std::min(room, over_ms / voxel_rate);
      voxels -= removed;
      over_ms -= removed * voxel_rate;
      r.deepest = DeadlineStep::voxel_updates_deep;
    }
  }
  r.infeasible = over_ms > kNegligible_ms;
  // Whole units, rounded down but for the rounding of the subtractions above (a millionth of a
  // unit), so a budget never buys more than the plan's time.
  auto whole = [](double units) { return std::floor(units + 1e-6); };
  r.max_voxel_updates = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(whole(voxels)));
  r.raycast_steps = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(whole(steps)));
  r.free_space_visits = static_cast<std::uint32_t>(std::clamp(whole(visits), 1.0, 4294967295.0));
  r.predicted_ms = (fixed_ms + stages_ms(r.icp_iterations, static_cast<double>(r.max_voxel_updates),
                                         static_cast<double>(r.raycast_steps),
                                         static_cast<double>(r.free_space_visits))) *
                   model_.safety;
  return r;
}

void DeadlineController::learn(Regression& f, StageCost& cost, double units, double ms) {
  if (!std::isfinite(ms) || ms < 0.0 || !std::isfinite(units) || units < 0.0) return;
  const double u = units * 1e-6;  // millions, as the rate
  f.weight = kForget * f.weight + 1.0;
  f.units = kForget * f.units + u;
  f.ms = kForget * f.ms + ms;
  f.units_sq = kForget * f.units_sq + u * u;
  f.units_ms = kForget * f.units_ms + u * ms;
  const double mean_u = f.units / f.weight;
  const double mean_ms = f.ms / f.weight;
  const double var_u = std::max(0.0, f.units_sq / f.weight - mean_u * mean_u);
  const double spread = kMinRelativeSpread * mean_u;
  double rate = cost.ms_per_munit;
  if (f.weight > 2.5 && mean_u > 0.0 && var_u > spread * spread) {
    rate = (f.units_ms / f.weight - mean_u * mean_ms) / var_u;
  }
  // A line through the mean with a positive slope and a fixed part >= 0. A slope that comes out
  // <= 0 (a burst of load on frames of few units) keeps the last one: a line through the origin
  // instead prices a stage held at one unit (free space at its floor) at its whole time per unit,
  // which kept it at its floor for good.
  if (!(rate > 0.0)) rate = cost.ms_per_munit;
  double fixed = mean_ms - rate * mean_u;
  if (fixed < 0.0 && mean_u > 0.0) {
    rate = mean_ms / mean_u;
    fixed = 0.0;
  }
  if (rate > 0.0) cost.ms_per_munit = std::min(rate, kMaxValue);
  cost.fixed_ms = std::clamp(fixed, 0.0, kMaxValue);
}

void DeadlineController::observe(const FrameObservation& frame, const DeadlineReport& plan) {
  if (!active()) return;
  // The turns of (8) follow what ran, (9)'s run length what was planned.
  if (frame.raycast.ran) {
    map_ahead_of_cast_ = false;
  } else if (frame.integrate.ran) {
    map_ahead_of_cast_ = true;
  }
  track_only_run_ = plan.fusion_skipped && plan.raycast_skipped ? track_only_run_ + 1 : 0;
  auto demand = [](double& estimate, const StageObservation& stage) {
    if (!stage.ran) return;
    estimate = stage.budget_hit
                   ? std::max(std::max(stage.units, stage.demand), estimate * kCutDemandDecay)
                   : stage.units;
  };
  demand(voxel_demand_, frame.integrate);
  demand(raycast_demand_, frame.raycast);
  demand(free_space_demand_, frame.free_space);
  if (frame.integrate.ran && frame.raycast.ran) have_demand_ = true;
  if (!config_.adapt || !frame.timed) return;
  if (frame.icp.ran) learn(icp_fit_, model_.icp, frame.icp.units, frame.icp.ms);
  if (frame.integrate.ran) {
    double integrate_ms = frame.integrate.ms;
    if (plan.allocation_half) {
      integrate_ms += model_.integrate.fixed_ms * (1.0 - half_pixels_ / level_pixels_[0]);
    }
    learn(integrate_fit_, model_.integrate, frame.integrate.units, integrate_ms);
  }
  if (frame.raycast.ran) learn(raycast_fit_, model_.raycast, frame.raycast.units, frame.raycast.ms);
  if (frame.free_space.ran) {
    learn(free_space_fit_, model_.free_space, frame.free_space.units, frame.free_space.ms);
  }
  // The rest of a frame that ran to its end (a fusing or a casting turn, or one that tracked only).
  const bool tracked_only = plan.fusion_skipped && plan.raycast_skipped && frame.icp.ran;
  if (frame.integrate.ran || frame.raycast.ran || tracked_only) {
    const double rest_ms =
        frame.total_ms - frame.icp.ms - frame.integrate.ms - frame.raycast.ms - frame.free_space.ms;
    if (std::isfinite(rest_ms)) {
      model_.fixed_ms =
          std::clamp(model_.fixed_ms + kFixedGain * (rest_ms - model_.fixed_ms), 0.0, kMaxValue);
    }
  }
  // Only a plan that met the deadline on paper and missed it says the model was short (below
  // the floors nothing would help); any frame within the deadline lets the factor fall, or one
  // raised by a burst of load would keep every later plan at its floors.
  if (plan.planned) {
    if (frame.total_ms <= config_.deadline_ms) {
      model_.safety = std::max(1.0, model_.safety * kSafetyFall);
    } else if (!plan.infeasible) {
      model_.safety = std::min(kMaxSafety, model_.safety * kSafetyRise);
    }
  }
}

}  // namespace octofuse
