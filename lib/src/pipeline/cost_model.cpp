#include "octofuse/pipeline/cost_model.hpp"

#include <algorithm>
#include <cmath>

namespace octofuse {

namespace {
constexpr double kMaxRate = 1e6;
constexpr double kMaxDeadline_ms = 1e5;
constexpr double kMaxSafety = 16.0;
// Below these a view is nearly empty; budgets never fall under them, so a stage that did almost
// nothing once is not starved for good.
constexpr double kMinVoxelDemand = 64.0 * 512.0;  // 64 blocks at scale 0
constexpr double kMinVisitDemand = 64.0;
// Fewer units than this time too coarsely to learn a rate from.
constexpr double kMinUnitsToLearn = 1000.0;
// Asymmetric running mean: follow a slower machine at once, a faster one gradually.
constexpr double kRiseGain = 0.5;
constexpr double kFallGain = 0.05;
// A stage whose budget bound does not show its demand: its estimate decays this much a frame
// unless the work done is larger.
constexpr double kCutDemandDecay = 0.98;
// Safety factor: x1.2 after a frame over the deadline, x0.998 after one within it, so the long-run
// share over settles near ln(1/0.998) / ln(1.2 / 0.998), about 1 %, when the model alone misses.
constexpr double kSafetyRise = 1.2;
constexpr double kSafetyFall = 0.998;
// What is left of an overrun after the subtractions below is rounding beneath this.
constexpr double kNegligible_ms = 1e-9;

bool rate_ok(double v) {
  return std::isfinite(v) && v > 0.0 && v <= kMaxRate;
}

void learn(double& rate, double sample) {
  const double gain = sample > rate ? kRiseGain : kFallGain;
  rate = std::clamp(rate + gain * (sample - rate), 1e-9, kMaxRate);
}
}  // namespace

Status validate(const CostModel& model, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  if (!rate_ok(model.fixed_ms) || !rate_ok(model.icp_ms_per_mpixel_iteration) ||
      !rate_ok(model.integrate_ms_per_mvoxel) || !rate_ok(model.raycast_ms_per_mstep) ||
      !rate_ok(model.free_space_ms_per_mvisit)) {
    err.set("cost model: every rate and fixed_ms must be finite and in (0, 1e6]");
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
  for (const float f :
       {config.min_voxel_fraction, config.min_raycast_fraction, config.min_free_space_fraction}) {
    if (!(f >= 0.0f && f <= 1.0f)) {
      err.set("deadline floor fractions must be in [0, 1]");
      return StatusCode::invalid_argument;
    }
  }
  if (!(config.demand_growth >= 1.0f && config.demand_growth <= 4.0f)) {
    err.set("deadline demand_growth must be in [1, 4]");
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
    case DeadlineStep::raycast:
      return "raycast";
    case DeadlineStep::free_space:
      return "free_space";
  }
  return "unknown";
}

void DeadlineController::reset(const DeadlineConfig& config,
                               const int icp_iterations[kPyramidLevels], int width, int height,
                               bool icp_used, bool free_space_used) {
  config_ = config;
  model_ = config.model;
  icp_used_ = icp_used;
  free_space_used_ = free_space_used;
  for (int level = 0; level < kPyramidLevels; ++level) {
    icp_iterations_[level] = icp_iterations[level];
    icp_floor_[level] = std::min(config.min_icp_iterations[level], icp_iterations[level]);
    level_pixels_[level] =
        static_cast<double>(width >> level) * static_cast<double>(height >> level);
  }
  have_demand_ = false;
  voxel_demand_ = 0.0;
  raycast_demand_ = 0.0;
  free_space_demand_ = 0.0;
}

double DeadlineController::icp_cost_ms(const int iterations[kPyramidLevels]) const {
  if (!icp_used_) return 0.0;
  double units = 0.0;
  for (int level = 0; level < kPyramidLevels; ++level) {
    units += static_cast<double>(iterations[level]) * level_pixels_[level];
  }
  return units * 1e-6 * model_.icp_ms_per_mpixel_iteration;
}

DeadlineReport DeadlineController::plan() const {
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
  double steps = std::max(raycast_demand_ * growth, level_pixels_[0]);
  double visits = free_space_used_ ? std::max(free_space_demand_ * growth, kMinVisitDemand) : 0.0;
  const double voxel_rate = model_.integrate_ms_per_mvoxel * 1e-6;
  const double step_rate = model_.raycast_ms_per_mstep * 1e-6;
  const double visit_rate = model_.free_space_ms_per_mvisit * 1e-6;
  auto stages_ms = [&](const int iterations[kPyramidLevels], double v, double s, double f) {
    return icp_cost_ms(iterations) + voxel_rate * v + step_rate * s + visit_rate * f;
  };
  const double available_ms = config_.deadline_ms / model_.safety - model_.fixed_ms;
  const double full_ms = stages_ms(icp_iterations_, voxels, steps, visits);
  if (full_ms <= available_ms) {
    r.predicted_ms = (model_.fixed_ms + full_ms) * model_.safety;
    return r;  // everything fits: the configured budgets stay
  }
  double over_ms = full_ms - available_ms;
  // (1) ICP, finest level first: its iterations cost the most pixels.
  for (int level = 0; level < kPyramidLevels && icp_used_; ++level) {
    while (over_ms > kNegligible_ms && r.icp_iterations[level] > icp_floor_[level]) {
      --r.icp_iterations[level];
      ++r.icp_iterations_given_up;
      over_ms -= level_pixels_[level] * 1e-6 * model_.icp_ms_per_mpixel_iteration;
      r.deepest = DeadlineStep::icp;
    }
  }
  // (4), (6), (7): each down to its floor before the next.
  auto cut = [&](double& units, float floor_fraction, double rate, DeadlineStep step) {
    const double room = units * (1.0 - static_cast<double>(floor_fraction));
    if (over_ms <= kNegligible_ms || room <= 0.0) return;
    const double removed = std::min(room, over_ms / rate);
    units -= removed;
    over_ms -= removed * rate;
    r.deepest = step;
  };
  cut(voxels, config_.min_voxel_fraction, voxel_rate, DeadlineStep::voxel_updates);
  cut(steps, config_.min_raycast_fraction, step_rate, DeadlineStep::raycast);
  if (free_space_used_) {
    cut(visits, config_.min_free_space_fraction, visit_rate, DeadlineStep::free_space);
  }
  r.infeasible = over_ms > kNegligible_ms;
  // To the nearest unit: the remainders above are rounding, and half a unit costs nothing.
  r.max_voxel_updates = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(voxels + 0.5));
  r.raycast_steps = std::max<std::uint64_t>(1, static_cast<std::uint64_t>(steps + 0.5));
  r.free_space_visits = static_cast<std::uint32_t>(std::clamp(visits + 0.5, 1.0, 4294967295.0));
  r.predicted_ms = (model_.fixed_ms +
                    stages_ms(r.icp_iterations, static_cast<double>(r.max_voxel_updates),
                              static_cast<double>(r.raycast_steps),
                              free_space_used_ ? static_cast<double>(r.free_space_visits) : 0.0)) *
                   model_.safety;
  return r;
}

void DeadlineController::observe(const FrameObservation& frame, const DeadlineReport& plan) {
  if (!active()) return;
  auto demand = [](double& estimate, const StageObservation& stage) {
    if (!stage.ran) return;
    estimate = stage.budget_hit ? std::max(stage.units, estimate * kCutDemandDecay) : stage.units;
  };
  demand(voxel_demand_, frame.integrate);
  demand(raycast_demand_, frame.raycast);
  demand(free_space_demand_, frame.free_space);
  if (frame.integrate.ran && frame.raycast.ran) have_demand_ = true;
  if (!config_.adapt || !frame.timed) return;
  auto rate = [](double& value, const StageObservation& stage) {
    if (!stage.ran || stage.units < kMinUnitsToLearn || !(stage.ms >= 0.0)) return;
    learn(value, stage.ms / (stage.units * 1e-6));
  };
  rate(model_.icp_ms_per_mpixel_iteration, frame.icp);
  rate(model_.integrate_ms_per_mvoxel, frame.integrate);
  rate(model_.raycast_ms_per_mstep, frame.raycast);
  rate(model_.free_space_ms_per_mvisit, frame.free_space);
  if (frame.integrate.ran && frame.raycast.ran) {
    // The rest of the frame: validation, pre-processing, and the stages beyond their units.
    const double rest_ms =
        frame.total_ms - frame.icp.ms - frame.integrate.ms - frame.raycast.ms - frame.free_space.ms;
    if (std::isfinite(rest_ms)) learn(model_.fixed_ms, std::max(rest_ms, 1e-3));
  }
  if (plan.planned) {
    model_.safety = frame.total_ms > config_.deadline_ms
                        ? std::min(kMaxSafety, model_.safety * kSafetyRise)
                        : std::max(1.0, model_.safety * kSafetyFall);
  }
}

}  // namespace octofuse
