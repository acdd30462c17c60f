// The frame deadline through the whole pipeline, timed by a clock whose stage times are a known
// function of the work each stage did (the "machine" below): the derived budgets keep that
// modelled frame time within the deadline, cuts follow the documented order, a frozen
// calibration gives bit-identical results for 1 and 3 workers whatever the clock says, a
// deadline of 0 (or one everything fits in) changes nothing, and frames stay allocation-free.

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/pipeline/steady_clock.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/small_sim.hpp"

namespace octofuse {
namespace {

constexpr int kWidth = test::kSmallSimWidth;
constexpr int kHeight = test::kSmallSimHeight;
// The noisy 2 cm desk at 160 x 120 over 60 frames tracks the first 38, deadline or not: the runs
// take the first kFrames.
constexpr int kSimFrames = 60;
constexpr int kFrames = 36;

using test::small_sim;

// Of the deadline below (85 % of the median unbounded frame): where the floors of ICP and the
// voxel updates no longer fit on the small sim.
constexpr double kHalfResolutionShare = 0.5;
// And where the half-resolution ray-cast does not suffice either.
constexpr double kAllocationHalfShare = 0.4;
// And where the voxel updates must fall below their first floor.
constexpr double kVoxelDeepShare = 0.3;
// Where even the floors do not fit: frames take turns fusing and casting.
constexpr double kAlternateShare = 0.4;
// And where ICP alone at its floors is about all that fits.
constexpr double kTrackOnlyShare = 0.1;

PipelineConfig small_config(const sim::SimSource& source, int workers) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  PipelineConfig config =
      default_pipeline_config(source.intrinsics(), 0.02f, 9, 20000,
                              (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>());
  config.preprocess.downsample_factor = 1;
  config.workers = workers;
  config.initial_T_W_C = T_W_C0;
  // The reference cast at every pixel, so the deadline's own half-resolution step has work to cut.
  config.budget.raycast_half = false;
  // The ICP iterations the deadlines below were chosen at (the default until 2026-12-05): the
  // deadlines are shares of this config's own frame time, and the sim is the desk squeezed into
  // 60 frames (13 cm a frame), where one lost frame fails the turn-taking test.
  config.budget.icp_iterations[0] = 4;
  config.budget.icp_iterations[1] = 5;
  config.budget.icp_iterations[2] = 10;
  return config;
}

// The modelled machine: what each stage's work costs, in the model's own terms (fixed parts and
// ms per million units), so a calibration can state it exactly.
CostModel machine() {
  CostModel m;
  m.fixed_ms = 1.0;
  m.icp = {0.2, 50.0};
  m.integrate = {0.5, 20.0};
  m.raycast = {0.3, 100.0};
  m.free_space = {0.1, 200.0};
  return m;
}

double icp_units(const FrameStats& s) {
  double units = 0.0;
  for (int level = 0; level < kPyramidLevels; ++level) {
    units +=
        static_cast<double>(s.track.iterations[level]) * (kWidth >> level) * (kHeight >> level);
  }
  return units;
}

double voxel_units(const FrameStats& s) {
  double units = 0.0;
  for (int scale = 0; scale < 4; ++scale) {
    units += static_cast<double>(s.integration.blocks_per_scale[scale]) * block_scale_count(scale);
  }
  return units;
}

// Reads the frame the pipeline is working on: each stage's report is in place before the clock
// is read after it, so the time so far is the modelled cost of the stages done. Frame k starts at
// k * 10 s; a stage's fixed part counts once its report shows it ran.
struct ModelClock {
  const Pipeline<MultiresVoxel>* pipeline = nullptr;
  CostModel cost = machine();

  static double frame_ms(const FrameStats& s, const CostModel& c) {
    double ms = 0.0;
    if (s.input.pixel_count > 0) ms += c.fixed_ms;
    if (s.track_attempted) ms += c.icp.ms(icp_units(s));
    if (s.integration.blocks_touched > 0) {
      ms += c.integrate.ms(voxel_units(s));
      // Its fixed part is the allocation march, a quarter of it at every other pixel.
      if (s.deadline.allocation_half) ms -= 0.75 * c.integrate.fixed_ms;
    }
    if (s.free_space.node_visits > 0) ms += c.free_space.ms(s.free_space.node_visits);
    if (s.raycast.steps > 0) ms += c.raycast.ms(static_cast<double>(s.raycast.steps));
    return ms;
  }
  static std::int64_t now_us(void* context) {
    const ModelClock& self = *static_cast<const ModelClock*>(context);
    const FrameStats& s = self.pipeline->frame_in_progress();
    const double ms = static_cast<double>(s.frame_index) * 1e4 + frame_ms(s, self.cost);
    // Rounded down to the microsecond: the frame's start is a whole one, so a frame never reads
    // longer than its modelled time.
    return static_cast<std::int64_t>(std::floor(ms * 1e3));
  }
};

enum class ClockKind { none, model, steady };

struct Run {
  std::vector<Se3d> poses;
  std::vector<FrameStats> stats;
  CostModel final_model;
  std::uint64_t allocations = 0;
};

Run run(const PipelineConfig& config, ClockKind clock_kind, int frames = kFrames) {
  sim::SimSource source(small_sim(kSimFrames));
  REQUIRE(source.open().ok());
  const std::size_t bytes = bytes_required(config);
  REQUIRE(bytes > 0);
  test::Buffer buffer(bytes);
  Pipeline<MultiresVoxel> pipeline;
  ModelClock model_clock;
  model_clock.pipeline = &pipeline;
  Clock clock;
  if (clock_kind == ClockKind::model) clock = Clock{&ModelClock::now_us, &model_clock};
  if (clock_kind == ClockKind::steady) clock = steady_clock();
  REQUIRE(pipeline.init(buffer.data, bytes, config, clock).ok());
  Run out;
  out.poses.reserve(static_cast<std::size_t>(frames));
  out.stats.reserve(static_cast<std::size_t>(frames));
  DepthFrame frame;
  test::AllocationScope scope;
  while (out.poses.size() < static_cast<std::size_t>(frames) &&
         source.next(frame).outcome == FrameOutcome::frame) {
    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    REQUIRE((status.ok() || stats.result == FrameResult::lost));
    out.poses.push_back(pipeline.T_W_C());
    out.stats.push_back(stats);
  }
  out.allocations = scope.allocations();
  out.final_model = pipeline.cost_model();
  REQUIRE(out.poses.size() == static_cast<std::size_t>(frames));
  return out;
}

bool same_bits(const Run& a, const Run& b) {
  if (a.poses.size() != b.poses.size()) return false;
  for (std::size_t i = 0; i < a.poses.size(); ++i) {
    if (std::memcmp(a.poses[i].matrix().data(), b.poses[i].matrix().data(), sizeof(double) * 16) !=
        0) {
      return false;
    }
    const FrameStats& x = a.stats[i];
    const FrameStats& y = b.stats[i];
    if (x.integration.voxels_updated != y.integration.voxels_updated ||
        x.integration.blocks_allocated != y.integration.blocks_allocated ||
        x.raycast.steps != y.raycast.steps || x.raycast.valid_pixels != y.raycast.valid_pixels ||
        x.free_space.node_visits != y.free_space.node_visits ||
        x.memory.blocks_used != y.memory.blocks_used) {
      return false;
    }
    for (int level = 0; level < kPyramidLevels; ++level) {
      if (x.track.iterations[level] != y.track.iterations[level]) return false;
    }
  }
  return true;
}

// The deadline: 85 % of the median modelled frame without one, so most frames must give up work.
double deadline_for(const Run& unbounded) {
  std::vector<double> totals;
  for (const FrameStats& s : unbounded.stats) totals.push_back(s.times.total_ms);
  std::sort(totals.begin(), totals.end());
  return 0.85 * totals[totals.size() / 2];
}

// One worker, deadline_ms, the built-in calibration frozen (no time is read into the plan).
PipelineConfig frozen_config(const sim::SimSource& source, double deadline_ms) {
  PipelineConfig config = small_config(source, 1);
  config.deadline.deadline_ms = deadline_ms;
  config.deadline.model = machine();
  config.deadline.adapt = false;
  return config;
}

// The ladder down to its floors alone, without the last steps (fusion in turns, tracking only).
PipelineConfig floors_only(PipelineConfig config) {
  config.deadline.fuse_alternate = false;
  config.deadline.track_only = false;
  return config;
}

TEST_CASE("derived budgets keep the modelled frame time within the deadline, in order") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const Run unbounded = run(small_config(probe, 2), ClockKind::model);
  const double deadline_ms = deadline_for(unbounded);
  INFO("deadline " << deadline_ms << " ms");
  REQUIRE(deadline_ms > 5.0);

  PipelineConfig config = small_config(probe, 2);
  config.deadline.deadline_ms = deadline_ms;
  config.deadline.model = machine();  // a calibration from an earlier run, still learning
  const Run limited = run(config, ClockKind::model);
  REQUIRE(limited.allocations == 0);
  int planned = 0, cut = 0, over_without = 0, lost = 0, infeasible = 0;
  int steps_cut[10] = {};
  for (std::size_t i = 0; i < limited.stats.size(); ++i) {
    CAPTURE(i);
    const FrameStats& s = limited.stats[i];
    const DeadlineReport& d = s.deadline;
    REQUIRE(d.active);
    if (s.result == FrameResult::lost) ++lost;
    if (!d.planned) {
      REQUIRE(i == 0);  // only the first frame has no demand to plan from
      continue;
    }
    ++planned;
    if (unbounded.stats[i].times.total_ms > deadline_ms) ++over_without;
    // The model is the machine, so the plan's prediction bounds the frame: within D unless even
    // the floors did not fit.
    REQUIRE(s.times.total_ms <= d.predicted_ms + 1e-3);
    if (d.infeasible) {
      ++infeasible;
      REQUIRE(static_cast<int>(d.deepest) >= static_cast<int>(DeadlineStep::voxel_updates_deep));
      REQUIRE(d.free_space_visits == 1);
    } else {
      REQUIRE(s.times.total_ms <= deadline_ms);
      REQUIRE_FALSE(d.over);
    }
    ++steps_cut[static_cast<int>(d.deepest)];
    if (d.deepest == DeadlineStep::none) continue;
    ++cut;
    // Work within the derived budgets.
    for (int level = 0; level < kPyramidLevels; ++level) {
      REQUIRE(s.track.iterations[level] <= d.icp_iterations[level]);
    }
    REQUIRE(voxel_units(s) <= static_cast<double>(d.max_voxel_updates));
    REQUIRE(s.raycast.steps <= d.raycast_steps);
    REQUIRE(s.free_space.node_visits <= d.free_space_visits);
    // The documented order: a later step is cut only with the earlier ones at their floors.
    if (d.deepest != DeadlineStep::icp) {
      for (int level = 0; level < kPyramidLevels; ++level) {
        REQUIRE(d.icp_iterations[level] == config.deadline.min_icp_iterations[level]);
      }
    }
    const double growth = config.deadline.demand_growth;
    const double voxels_full = std::max(d.voxel_demand * growth, 64.0 * 512.0);
    if (static_cast<int>(d.deepest) > static_cast<int>(DeadlineStep::voxel_updates) &&
        d.deepest != DeadlineStep::voxel_updates_deep) {
      REQUIRE(std::fabs(static_cast<double>(d.max_voxel_updates) -
                        voxels_full * config.deadline.min_voxel_fraction) <= 1.0);
    }
    if (d.deepest == DeadlineStep::voxel_updates_deep) {
      REQUIRE(static_cast<double>(d.max_voxel_updates) <
              voxels_full * config.deadline.min_voxel_fraction);
      REQUIRE(static_cast<double>(d.max_voxel_updates) >=
              std::floor(voxels_full * config.deadline.min_voxel_fraction_deep));
    }
    // Half resolution from its step on, and then a quarter of the rays march.
    const bool half = static_cast<int>(d.deepest) >= static_cast<int>(DeadlineStep::raycast_half);
    REQUIRE(d.raycast_half == half);
    REQUIRE(d.allocation_half ==
            (static_cast<int>(d.deepest) >= static_cast<int>(DeadlineStep::allocation_half)));
    REQUIRE(s.raycast.marched_pixels ==
            static_cast<std::uint32_t>(half ? kWidth * kHeight / 4 : kWidth * kHeight));
    if (static_cast<int>(d.deepest) >= static_cast<int>(DeadlineStep::free_space)) {
      const double full = std::max(d.raycast_demand * growth, double{kWidth * kHeight});
      REQUIRE(std::fabs(static_cast<double>(d.raycast_steps) -
                        0.25 * full * config.deadline.min_raycast_fraction) <= 1.0);
    }
    if (d.deepest == DeadlineStep::icp) REQUIRE(d.icp_iterations_given_up > 0);
  }
  REQUIRE(planned == kFrames - 1);
  INFO("lost " << lost << ", below the floors " << infeasible << "; deepest step cut: icp "
               << steps_cut[1] << ", voxels " << steps_cut[2] << ", half-resolution ray-cast "
               << steps_cut[3] << ", allocation " << steps_cut[4] << ", ray-cast steps "
               << steps_cut[5] << ", free space " << steps_cut[6] << ", voxels again "
               << steps_cut[7]);
  CHECK(lost == 0);
  CHECK(infeasible <= planned / 10);
  // Not vacuous: without the deadline most of these frames were over it, and with it they gave
  // work up.
  REQUIRE(over_without > planned / 2);
  REQUIRE(cut > planned / 2);
  // The learnt model is still the machine (its lines fit the times exactly).
  CHECK(limited.final_model.raycast.ms_per_munit ==
        Approx(machine().raycast.ms_per_munit).epsilon(1e-3));
  CHECK(limited.final_model.integrate.fixed_ms ==
        Approx(machine().integrate.fixed_ms).margin(1e-3));
  CHECK(limited.final_model.safety == 1.0);
}

TEST_CASE("starting from the default model, the deadline holds once the model has learnt") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const double deadline_ms = deadline_for(run(small_config(probe, 1), ClockKind::model));
  PipelineConfig config = small_config(probe, 1);
  config.deadline.deadline_ms = deadline_ms;
  const Run limited = run(config, ClockKind::model);
  int over_late = 0;
  constexpr std::size_t kWarmUp = 10;
  for (std::size_t i = kWarmUp; i < limited.stats.size(); ++i) {
    if (limited.stats[i].times.total_ms > deadline_ms) ++over_late;
  }
  INFO("deadline " << deadline_ms << " ms; frames over after " << kWarmUp << ": " << over_late);
  REQUIRE(over_late == 0);
}

TEST_CASE("a frozen calibration gives bit-identical results for 1 and 3 workers, any clock") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const double deadline_ms = deadline_for(run(small_config(probe, 1), ClockKind::model));
  const PipelineConfig one = frozen_config(probe, deadline_ms);
  PipelineConfig three = one;
  three.workers = 3;
  // The frozen budgets read no time: a modelled clock, none and the real one all agree.
  const Run a = run(one, ClockKind::model);
  const Run b = run(three, ClockKind::steady);
  const Run c = run(three, ClockKind::none);
  REQUIRE(same_bits(a, b));
  REQUIRE(same_bits(a, c));
  int cut = 0;
  for (std::size_t i = 0; i < a.stats.size(); ++i) {
    const DeadlineReport& x = a.stats[i].deadline;
    const DeadlineReport& y = b.stats[i].deadline;
    REQUIRE(x.deepest == y.deepest);
    REQUIRE(x.max_voxel_updates == y.max_voxel_updates);
    REQUIRE(x.raycast_steps == y.raycast_steps);
    REQUIRE(x.free_space_visits == y.free_space_visits);
    REQUIRE(std::memcmp(&x.predicted_ms, &y.predicted_ms, sizeof(double)) == 0);
    if (x.deepest != DeadlineStep::none) ++cut;
  }
  REQUIRE(cut > kFrames / 2);  // the budgets did bind
  // Frozen: the model did not move.
  CHECK(a.final_model.raycast.ms_per_munit == machine().raycast.ms_per_munit);
  CHECK(a.final_model.integrate.fixed_ms == machine().integrate.fixed_ms);
  CHECK(a.final_model.safety == machine().safety);
  // And the result differs from no deadline: the budgets changed the map.
  REQUIRE_FALSE(same_bits(a, run(small_config(probe, 1), ClockKind::none)));
}

TEST_CASE(
    "below the first floors the reference is ray-cast at half resolution, deterministically") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const Run unbounded = run(small_config(probe, 1), ClockKind::model);
  // Tighter than above: ICP and the voxel updates at their floors do not fit.
  const double deadline_ms = kHalfResolutionShare * deadline_for(unbounded);
  const PipelineConfig config = floors_only(frozen_config(probe, deadline_ms));
  const Run a = run(config, ClockKind::model);
  int half = 0;
  for (std::size_t i = 1; i < a.stats.size(); ++i) {
    CAPTURE(i);
    const FrameStats& s = a.stats[i];
    const FrameStats& u = unbounded.stats[i];
    const DeadlineReport& d = s.deadline;
    REQUIRE(d.planned);
    if (!d.raycast_half) {
      REQUIRE(static_cast<int>(d.deepest) < static_cast<int>(DeadlineStep::raycast_half));
      REQUIRE(s.raycast.marched_pixels == static_cast<std::uint32_t>(kWidth * kHeight));
      continue;
    }
    ++half;
    // Engaged only with the earlier steps at their floors, and within the modelled deadline
    // unless the floors after it do not fit either.
    REQUIRE(static_cast<int>(d.deepest) >= static_cast<int>(DeadlineStep::raycast_half));
    for (int level = 0; level < kPyramidLevels; ++level) {
      REQUIRE(d.icp_iterations[level] == config.deadline.min_icp_iterations[level]);
    }
    if (!d.infeasible) REQUIRE(s.times.total_ms <= deadline_ms);
    // A quarter of the rays march and take well under half of the steps, and the model stays
    // dense where no step budget cut it.
    REQUIRE(s.raycast.marched_pixels == static_cast<std::uint32_t>(kWidth * kHeight / 4));
    REQUIRE(s.raycast.steps * 2 < u.raycast.steps);
    if (d.deepest == DeadlineStep::raycast_half) {
      REQUIRE(s.raycast.budget_cut_pixels == 0);
      REQUIRE(s.raycast.valid_pixels * 10 > u.raycast.valid_pixels * 8);
    }
  }
  INFO("deadline " << deadline_ms << " ms: " << half << " frames at half resolution");
  REQUIRE(half > kFrames / 2);
  CHECK(a.stats.back().result == FrameResult::tracked);
  // Frozen, the half-resolution frames are the same for 3 workers and any clock.
  PipelineConfig three = config;
  three.workers = 3;
  const Run b = run(three, ClockKind::steady);
  REQUIRE(same_bits(a, b));
  for (std::size_t i = 0; i < a.stats.size(); ++i) {
    REQUIRE(a.stats[i].deadline.raycast_half == b.stats[i].deadline.raycast_half);
    REQUIRE(a.stats[i].raycast.marched_pixels == b.stats[i].raycast.marched_pixels);
  }
}

TEST_CASE("deeper still, allocation marches every other pixel's ray, deterministically") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  // Every ray of the step, not in groups: the rays' ratio below is then the step's alone.
  PipelineConfig every_ray = small_config(probe, 1);
  every_ray.fusion.allocation_group_block_px = 0.0f;
  const Run unbounded = run(every_ray, ClockKind::model);
  const double deadline_ms = kAllocationHalfShare * deadline_for(unbounded);
  PipelineConfig config = floors_only(frozen_config(probe, deadline_ms));
  config.fusion.allocation_group_block_px = 0.0f;
  const Run a = run(config, ClockKind::model);
  int halved = 0;
  for (std::size_t i = 1; i < a.stats.size(); ++i) {
    CAPTURE(i);
    const FrameStats& s = a.stats[i];
    const FrameStats& u = unbounded.stats[i];
    const DeadlineReport& d = s.deadline;
    REQUIRE(d.planned);
    if (!d.allocation_half) {
      REQUIRE(static_cast<int>(d.deepest) < static_cast<int>(DeadlineStep::allocation_half));
      continue;
    }
    ++halved;
    REQUIRE(d.raycast_half);  // the step before it is in the plan
    if (!d.infeasible) REQUIRE(s.times.total_ms <= deadline_ms);
    // About a quarter of the rays march, and they still find most blocks (at this sim's 2 cm
    // and 160 x 120 a skipped ray's band is more often the only one in a block than at 1 cm).
    REQUIRE(s.integration.allocation_rays * 3 < u.integration.allocation_rays);
    REQUIRE(s.integration.allocation_rays * 5 > u.integration.allocation_rays);
    REQUIRE(s.integration.blocks_touched * 10 > u.integration.blocks_touched * 8);
  }
  INFO("deadline " << deadline_ms << " ms: " << halved << " frames with allocation halved");
  REQUIRE(halved > kFrames / 2);
  CHECK(a.stats.back().result == FrameResult::tracked);
  PipelineConfig three = config;
  three.workers = 3;
  const Run b = run(three, ClockKind::none);
  REQUIRE(same_bits(a, b));
  for (std::size_t i = 0; i < a.stats.size(); ++i) {
    REQUIRE(a.stats[i].deadline.allocation_half == b.stats[i].deadline.allocation_half);
    REQUIRE(a.stats[i].integration.allocation_rays == b.stats[i].integration.allocation_rays);
  }
}

TEST_CASE("deepest, voxel updates fall to their deeper floor, deterministically") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const Run unbounded = run(small_config(probe, 1), ClockKind::model);
  const double deadline_ms = kVoxelDeepShare * deadline_for(unbounded);
  const PipelineConfig config = floors_only(frozen_config(probe, deadline_ms));
  const Run a = run(config, ClockKind::model);
  int deep = 0;
  for (std::size_t i = 1; i < a.stats.size(); ++i) {
    CAPTURE(i);
    const FrameStats& s = a.stats[i];
    const DeadlineReport& d = s.deadline;
    REQUIRE(d.planned);
    if (d.deepest != DeadlineStep::voxel_updates_deep) continue;
    ++deep;
    REQUIRE(d.free_space_visits == 1);  // the step before it is at its floor
    if (!d.infeasible) REQUIRE(s.times.total_ms <= deadline_ms);
    // Below the first floor, a quarter of the demand, and the integration within it.
    const double voxels_full = std::max(d.voxel_demand * config.deadline.demand_growth, 32768.0);
    REQUIRE(static_cast<double>(d.max_voxel_updates) <
            voxels_full * config.deadline.min_voxel_fraction);
    REQUIRE(voxel_units(s) <= static_cast<double>(d.max_voxel_updates));
    REQUIRE(voxel_units(s) * 4 < voxel_units(unbounded.stats[i]));
  }
  INFO("deadline " << deadline_ms << " ms: " << deep << " frames at the deeper voxel floor");
  REQUIRE(deep > kFrames / 2);
  PipelineConfig three = config;
  three.workers = 3;
  REQUIRE(same_bits(a, run(three, ClockKind::steady)));
}

// The largest distance between a run's camera positions and the ground truth's.
double max_position_error_m(const Run& r, const sim::SimSource& source) {
  double worst = 0.0;
  for (std::size_t i = 0; i < r.poses.size(); ++i) {
    const Se3d truth = source.ground_truth_T_W_C(static_cast<int>(i));
    worst = std::max(worst, (r.poses[i].translation() - truth.translation()).norm());
  }
  return worst;
}

TEST_CASE("below every floor, frames take turns fusing and casting and track every frame") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const Run unbounded = run(small_config(probe, 1), ClockKind::model);
  const double deadline_ms = kAlternateShare * deadline_for(unbounded);
  const PipelineConfig config = frozen_config(probe, deadline_ms);
  // Not vacuous: at this deadline the floors alone do not fit.
  const Run floors = run(floors_only(config), ClockKind::model);
  int floors_infeasible = 0;
  for (const FrameStats& s : floors.stats) floors_infeasible += s.deadline.infeasible ? 1 : 0;
  REQUIRE(floors_infeasible > kFrames / 2);

  const Run a = run(config, ClockKind::model);
  REQUIRE(a.allocations == 0);
  int fused = 0, cast = 0, infeasible = 0, tracked_only = 0;
  bool last_fused_only = false;  // the previous frame fused and did not cast
  for (std::size_t i = 1; i < a.stats.size(); ++i) {
    CAPTURE(i);
    const FrameStats& s = a.stats[i];
    const DeadlineReport& d = s.deadline;
    REQUIRE(d.planned);
    REQUIRE(s.track_attempted);  // every frame tracks
    REQUIRE(s.result == FrameResult::tracked);
    // Each frame says what it gave up, and gave up just that.
    REQUIRE((s.integration.blocks_touched == 0) == d.fusion_skipped);
    REQUIRE((s.free_space.node_visits == 0) == d.fusion_skipped);
    REQUIRE((s.raycast.steps == 0) == d.raycast_skipped);
    // The model is the machine: a plan that fits keeps the frame within D.
    REQUIRE(s.times.total_ms <= d.predicted_ms + 1e-3);
    if (d.infeasible) {
      ++infeasible;
    } else {
      REQUIRE(s.times.total_ms <= deadline_ms);
    }
    if (d.deepest == DeadlineStep::track_only) {
      REQUIRE(d.fusion_skipped);  // both given up; the turn stays
      REQUIRE(d.raycast_skipped);
      ++tracked_only;
      continue;
    }
    if (d.deepest != DeadlineStep::fuse_alternate) {
      REQUIRE_FALSE(d.fusion_skipped);
      REQUIRE_FALSE(d.raycast_skipped);
      last_fused_only = false;
      continue;
    }
    // One of the two, in turns: a frame casts after one that fused without casting.
    REQUIRE(d.fusion_skipped != d.raycast_skipped);
    REQUIRE(d.fusion_skipped == last_fused_only);
    last_fused_only = !d.fusion_skipped;
    (d.fusion_skipped ? cast : fused) += 1;
  }
  INFO("deadline " << deadline_ms << " ms: " << fused << " fusing turns, " << cast
                   << " casting turns, " << tracked_only << " track-only, " << infeasible
                   << " over D by plan");
  // Every frame below the floors; the turns alternate; only a frame the track-only cap let
  // through may be over D.
  REQUIRE(fused + cast + tracked_only == kFrames - 1);
  REQUIRE(fused > kFrames / 4);
  REQUIRE(std::abs(fused - cast) <= 1);
  REQUIRE(infeasible * (config.deadline.max_track_only_frames + 1) <= kFrames);
  // Half the depth fused, ICP against half-resolution casts, still tracks: within one and a
  // half voxels of 2 cm at every frame (1.7 cm without a deadline; 2.5 cm with ICP pairing at
  // the marched pixels, 1.9 cm when it paired through their copies, which on longer runs lose
  // the camera: lib/README.md).
  const double error_m = max_position_error_m(a, probe);
  INFO("largest position error " << error_m << " m, without a deadline "
                                 << max_position_error_m(unbounded, probe) << " m");
  CHECK(error_m < 0.03);
  // Frozen: the turns are the same for 3 workers and any clock.
  PipelineConfig three = config;
  three.workers = 3;
  const Run b = run(three, ClockKind::steady);
  REQUIRE(same_bits(a, b));
  for (std::size_t i = 0; i < a.stats.size(); ++i) {
    REQUIRE(a.stats[i].deadline.fusion_skipped == b.stats[i].deadline.fusion_skipped);
    REQUIRE(a.stats[i].deadline.raycast_skipped == b.stats[i].deadline.raycast_skipped);
  }
}

TEST_CASE("when neither turn fits, frames only track, never more than the cap in a row") {
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const Run unbounded = run(small_config(probe, 1), ClockKind::model);
  const double deadline_ms = kTrackOnlyShare * deadline_for(unbounded);
  const PipelineConfig config = frozen_config(probe, deadline_ms);
  const int cap = config.deadline.max_track_only_frames;
  REQUIRE(cap > 0);
  const Run a = run(config, ClockKind::model);
  REQUIRE(a.allocations == 0);
  int track_only = 0, run_length = 0, turns = 0;
  for (std::size_t i = 1; i < a.stats.size(); ++i) {
    CAPTURE(i);
    const FrameStats& s = a.stats[i];
    const DeadlineReport& d = s.deadline;
    REQUIRE(s.track_attempted);
    if (d.deepest == DeadlineStep::track_only) {
      REQUIRE(d.fusion_skipped);
      REQUIRE(d.raycast_skipped);
      REQUIRE(s.integration.blocks_touched == 0);
      REQUIRE(s.free_space.node_visits == 0);
      REQUIRE(s.raycast.steps == 0);
      REQUIRE(++run_length <= cap);
      ++track_only;
      if (!d.infeasible) REQUIRE(s.times.total_ms <= deadline_ms);
      continue;
    }
    // The frame after the cap fuses or casts, over D if it must.
    if (run_length == cap) REQUIRE(d.deepest == DeadlineStep::fuse_alternate);
    if (d.deepest == DeadlineStep::fuse_alternate) ++turns;
    run_length = 0;
  }
  INFO("deadline " << deadline_ms << " ms: " << track_only << " track-only frames, " << turns
                   << " turns of fusing or casting");
  REQUIRE(track_only > kFrames / 2);
  REQUIRE(turns > 0);
  PipelineConfig three = config;
  three.workers = 3;
  REQUIRE(same_bits(a, run(three, ClockKind::none)));
}

TEST_CASE("a deadline of 0, or one every frame fits in, is today's pipeline bit for bit") {
  // The pinned pose and map bits in pipeline_determinism_test.cpp hold the default config to the
  // build before deadlines existed; here the deadline's other settings must not matter when it is
  // off.
  sim::SimSource probe(small_sim(kSimFrames));
  REQUIRE(probe.open().ok());
  const Run plain = run(small_config(probe, 1), ClockKind::none);
  PipelineConfig off = small_config(probe, 2);
  off.deadline.deadline_ms = 0.0;
  off.deadline.model = machine();
  off.deadline.adapt = false;
  off.deadline.min_raycast_fraction = 0.5f;
  const Run off_run = run(off, ClockKind::model);
  REQUIRE(same_bits(plain, off_run));
  for (const FrameStats& s : off_run.stats) REQUIRE_FALSE(s.deadline.active);

  PipelineConfig generous = small_config(probe, 2);
  generous.deadline.deadline_ms = 1e4;  // 10 s a frame: never cuts
  const Run generous_run = run(generous, ClockKind::steady);
  REQUIRE(same_bits(plain, generous_run));
  for (std::size_t i = 1; i < generous_run.stats.size(); ++i) {
    REQUIRE(generous_run.stats[i].deadline.planned);
    REQUIRE(generous_run.stats[i].deadline.deepest == DeadlineStep::none);
  }
}

TEST_CASE("a bad deadline config is refused by validate and init") {
  sim::SimSource probe(small_sim(2));
  REQUIRE(probe.open().ok());
  PipelineConfig config = small_config(probe, 1);
  config.deadline.deadline_ms = std::nan("");
  ErrorText error;
  REQUIRE(validate(config, &error).code() == StatusCode::invalid_argument);
  REQUIRE(std::string(error.c_str()).find("deadline_ms") != std::string::npos);
  REQUIRE(bytes_required(config) == 0);
  config.deadline.deadline_ms = 33.0;
  config.deadline.model.safety = 0.0;
  REQUIRE(validate(config).code() == StatusCode::invalid_argument);
}

}  // namespace
}  // namespace octofuse
