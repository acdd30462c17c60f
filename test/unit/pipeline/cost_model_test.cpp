// The frame deadline's planner and model (pipeline/cost_model.hpp) against hand-computed plans:
// what fits stays, what does not is cut in the degradation order down to each floor, and the
// model learns rates from times that are a known function of the work.

#include "octofuse/pipeline/cost_model.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <limits>
#include <string>

namespace octofuse {
namespace {

// A 100 x 100 working image: level pixels 10000, 2500, 625.
constexpr int kSide = 100;
constexpr int kIcp[kPyramidLevels] = {4, 5, 10};
constexpr double kTolerance_ms = 1e-9;

CostModel hand_model() {
  CostModel m;
  // Fixed parts 2 ms in all: 1 for the frame and a quarter for each stage.
  m.fixed_ms = 1.0;
  m.icp = {0.25, 100.0};  // one finest iteration: 1 ms
  m.integrate = {0.25, 10.0};
  m.raycast = {0.25, 50.0};
  m.free_space = {0.25, 200.0};
  return m;
}

DeadlineConfig hand_config(double deadline_ms) {
  DeadlineConfig c;
  c.deadline_ms = deadline_ms;
  c.model = hand_model();
  c.adapt = false;
  c.demand_growth = 1.0f;  // budgets equal to the demand, so the sums below are exact
  // Floors as the hand computations below assume (not the defaults).
  c.min_icp_iterations[0] = 1;
  c.min_icp_iterations[1] = 1;
  c.min_icp_iterations[2] = 2;
  c.min_voxel_fraction = 0.25f;
  c.min_raycast_fraction = 0.25f;
  c.min_free_space_fraction = 0.0f;
  return c;
}

// One frame that integrated 1e6 voxels, marched 2e5 steps and visited 1e4 free-space octants
// (10 + 10 + 2 ms), none of them cut; ICP at the configured 4, 5, 10 costs 5.875 ms.
FrameObservation demand_frame() {
  FrameObservation o;
  o.icp = {true, false, 58750.0, 5.875};
  o.integrate = {true, false, 1e6, 10.0};
  o.raycast = {true, false, 2e5, 10.0};
  o.free_space = {true, false, 1e4, 2.0};
  o.total_ms = 29.875;
  return o;
}

// The frame after demand_frame(); `last_steps`: false keeps the ladder at its floors (no turns of
// fusion and casting, no track-only frames).
DeadlineReport plan_for(double deadline_ms, bool last_steps = false) {
  DeadlineController controller;
  DeadlineConfig config = hand_config(deadline_ms);
  config.fuse_alternate = last_steps;
  config.track_only = last_steps;
  controller.reset(config, kIcp, kSide, kSide, true, true);
  controller.observe(demand_frame(), controller.plan());
  return controller.plan();
}

TEST_CASE("no plan before the first frame shows its demand; off does nothing") {
  DeadlineController controller;
  controller.reset(hand_config(10.0), kIcp, kSide, kSide, true, true);
  const DeadlineReport first = controller.plan();
  CHECK(first.active);
  CHECK_FALSE(first.planned);
  CHECK(first.icp_iterations[0] == 4);
  CHECK(first.max_voxel_updates == 0);

  controller.reset(hand_config(0.0), kIcp, kSide, kSide, true, true);
  controller.observe(demand_frame(), controller.plan());
  const DeadlineReport off = controller.plan();
  CHECK_FALSE(off.active);
  CHECK_FALSE(off.planned);
  CHECK(off.raycast_steps == 0);
}

TEST_CASE("a frame that fits keeps the configured budgets") {
  const DeadlineReport r = plan_for(40.0);
  REQUIRE(r.planned);
  CHECK(r.deepest == DeadlineStep::none);
  CHECK(r.predicted_ms == Approx(29.875).margin(kTolerance_ms));
  CHECK(r.icp_iterations_given_up == 0);
  CHECK(r.max_voxel_updates == 0);  // 0: the configured budget applies
  CHECK(r.raycast_steps == 0);
  CHECK(r.free_space_visits == 0);
}

TEST_CASE("a small overrun is taken from ICP's finest level first") {
  // 2.875 ms over 25 available: three finest iterations (1 ms each).
  const DeadlineReport r = plan_for(27.0);
  REQUIRE(r.planned);
  CHECK(r.deepest == DeadlineStep::icp);
  CHECK(r.icp_iterations[0] == 1);
  CHECK(r.icp_iterations[1] == 5);
  CHECK(r.icp_iterations[2] == 10);
  CHECK(r.icp_iterations_given_up == 3);
  CHECK(r.max_voxel_updates == 1000000);
  CHECK(r.raycast_steps == 200000);
  CHECK(r.free_space_visits == 10000);
  CHECK(r.predicted_ms == Approx(26.875).margin(kTolerance_ms));
  CHECK_FALSE(r.infeasible);
}

TEST_CASE("a finest ICP level that takes half the checkerboard's pixels costs half as much") {
  // Against a half-resolution reference the finest passes take a quarter of the pixels (share
  // 0.5): one finest iteration is 0.5 ms, ICP at 4, 5, 10 is 3.875 ms, and the frame 27.875 ms.
  DeadlineController controller;
  controller.reset(hand_config(27.0), kIcp, kSide, kSide, true, true, 0.5);
  controller.observe(demand_frame(), controller.plan());
  const DeadlineReport r = controller.plan();
  REQUIRE(r.planned);
  // 0.875 ms over 25 available: two finest iterations (where a full share gives up three).
  CHECK(r.deepest == DeadlineStep::icp);
  CHECK(r.icp_iterations[0] == 2);
  CHECK(r.icp_iterations[1] == 5);
  CHECK(r.icp_iterations_given_up == 2);
  CHECK(r.predicted_ms == Approx(26.875).margin(kTolerance_ms));
  controller.reset(hand_config(40.0), kIcp, kSide, kSide, true, true, 0.5);
  controller.observe(demand_frame(), controller.plan());
  CHECK(controller.plan().predicted_ms == Approx(27.875).margin(kTolerance_ms));
}

TEST_CASE("a larger overrun takes ICP and voxels to their floors, then ray-casts at half size") {
  // 14.875 ms over 13 available: ICP gives 3 + 1 + 0.5 ms at floors 1, 1, 2; voxel updates
  // give 7.5 ms down to a quarter; the 2.875 ms left cost a half-resolution ray-cast, which
  // marches a quarter of the rays: 50000 steps, 7.5 ms less.
  const DeadlineReport r = plan_for(15.0);
  REQUIRE(r.planned);
  CHECK(r.deepest == DeadlineStep::raycast_half);
  CHECK(r.icp_iterations[0] == 1);
  CHECK(r.icp_iterations[1] == 1);
  CHECK(r.icp_iterations[2] == 2);
  CHECK(r.icp_iterations_given_up == 15);
  CHECK(r.max_voxel_updates == 250000);
  CHECK(r.raycast_half);
  CHECK(r.raycast_steps == 50000);
  CHECK(r.free_space_visits == 10000);
  CHECK(r.predicted_ms == Approx(10.375).margin(1e-9));
  CHECK_FALSE(r.infeasible);
}

TEST_CASE("without half resolution, allocation and then the ray-cast's steps come next") {
  // As above, 2.875 ms over after the voxels: allocation at every other pixel gives 0.1875 ms
  // (three quarters of integration's fixed part), the full ray-cast's steps the other 2.6875 ms,
  // 53750 of them.
  DeadlineConfig config = hand_config(15.0);
  config.raycast_half_resolution = false;
  DeadlineController controller;
  controller.reset(config, kIcp, kSide, kSide, true, true);
  controller.observe(demand_frame(), controller.plan());
  const DeadlineReport r = controller.plan();
  REQUIRE(r.planned);
  CHECK(r.deepest == DeadlineStep::raycast);
  CHECK_FALSE(r.raycast_half);
  CHECK(r.allocation_half);
  CHECK(r.max_voxel_updates == 250000);
  CHECK(r.raycast_steps == 146250);
  CHECK(r.predicted_ms == Approx(15.0).margin(1e-3));

  config.allocation_half = false;  // and without either, all 2.875 ms from the steps
  controller.reset(config, kIcp, kSide, kSide, true, true);
  controller.observe(demand_frame(), controller.plan());
  const DeadlineReport steps_only = controller.plan();
  CHECK(steps_only.deepest == DeadlineStep::raycast);
  CHECK_FALSE(steps_only.allocation_half);
  CHECK(steps_only.raycast_steps == 142500);
}

TEST_CASE("then allocation at every other pixel, the half-resolution steps, free-space visits") {
  // 20.875 ms over 7 available: ICP and voxels at their floors and the half-resolution cast
  // leave 1.375 ms over; allocation at every other pixel gives 0.1875 ms of it and 23750 of
  // the 50000 steps the rest.
  const DeadlineReport r = plan_for(9.0);
  REQUIRE(r.planned);
  CHECK(r.deepest == DeadlineStep::raycast);
  CHECK(r.raycast_half);
  CHECK(r.allocation_half);
  CHECK(r.raycast_steps == 26250);
  CHECK(r.free_space_visits == 10000);
  CHECK(r.predicted_ms == Approx(9.0).margin(1e-3));
  CHECK_FALSE(r.infeasible);
}

TEST_CASE("after free space, voxel updates are cut again to their deeper floor") {
  // 2 - 0.1875 (allocation) + 1.375 (ICP at 1, 1, 2) + 2.5 + 0.625 + 0.0002 ms at the floors
  // before this step: 0.3127 ms over 6, 31270 voxel updates.
  const DeadlineReport r = plan_for(6.0);
  REQUIRE(r.planned);
  CHECK_FALSE(r.infeasible);
  CHECK(r.deepest == DeadlineStep::voxel_updates_deep);
  CHECK(r.free_space_visits == 1);
  CHECK(static_cast<double>(r.max_voxel_updates) == Approx(218730.0).margin(1.0));
  CHECK(r.predicted_ms == Approx(6.0).margin(1e-3));
}

TEST_CASE("below the floors the plan says infeasible and keeps the floors") {
  const DeadlineReport r = plan_for(5.0);
  REQUIRE(r.planned);
  CHECK(r.infeasible);
  CHECK_FALSE(r.fusion_skipped);
  CHECK(r.deepest == DeadlineStep::voxel_updates_deep);
  CHECK(r.max_voxel_updates == 125000);  // an eighth of the demand
  CHECK(r.raycast_half);
  CHECK(r.allocation_half);
  CHECK(r.raycast_steps == 12500);  // a quarter of the half-resolution 50000
  CHECK(r.free_space_visits == 1);
  // 2 - 0.1875 (allocation) + 1.375 (ICP at 1, 1, 2) + 1.25 + 0.625 + 0.0002 ms.
  CHECK(r.predicted_ms == Approx(5.0627).margin(1e-9));
}

TEST_CASE("as the deadline shrinks the steps are cut in the documented order") {
  int previous = 0;
  for (double deadline_ms = 40.0; deadline_ms > 1.0; deadline_ms -= 0.25) {
    CAPTURE(deadline_ms);
    const DeadlineReport r = plan_for(deadline_ms, true);
    const int step = static_cast<int>(r.deepest);
    if (step >= static_cast<int>(DeadlineStep::fuse_alternate)) {
      // Below every floor: first a turn of fusing, then tracking alone.
      REQUIRE(step >= previous);
      previous = step;
      CHECK(r.raycast_skipped);
      CHECK(r.fusion_skipped == (r.deepest == DeadlineStep::track_only));
      CHECK(plan_for(deadline_ms, false).infeasible);
      if (!r.infeasible) CHECK(r.predicted_ms <= deadline_ms + kTolerance_ms);
      continue;
    }
    REQUIRE(step >= previous);
    previous = step;
    // A step is cut only when every earlier one is at its floor.
    if (step > static_cast<int>(DeadlineStep::icp)) {
      CHECK(r.icp_iterations[0] == 1);
      CHECK(r.icp_iterations[1] == 1);
      CHECK(r.icp_iterations[2] == 2);
    }
    if (step > static_cast<int>(DeadlineStep::voxel_updates) &&
        step < static_cast<int>(DeadlineStep::voxel_updates_deep)) {
      CHECK(r.max_voxel_updates == 250000);
    }
    if (step == static_cast<int>(DeadlineStep::voxel_updates_deep)) {
      CHECK(r.max_voxel_updates < 250000);
      CHECK(r.max_voxel_updates >= 125000);
      CHECK(r.free_space_visits == 1);
    }
    CHECK(r.raycast_half == (step >= static_cast<int>(DeadlineStep::raycast_half)));
    CHECK(r.allocation_half == (step >= static_cast<int>(DeadlineStep::allocation_half)));
    if (step > static_cast<int>(DeadlineStep::raycast)) CHECK(r.raycast_steps == 12500);
    if (!r.infeasible) CHECK(r.predicted_ms <= deadline_ms + kTolerance_ms);
  }
  CHECK(previous == static_cast<int>(DeadlineStep::track_only));
}

// A frame that ran what `plan` said, each stage at its demand_frame() units within its budget.
FrameObservation frame_as_planned(const DeadlineReport& plan) {
  FrameObservation o = demand_frame();
  if (plan.fusion_skipped) o.integrate = o.free_space = StageObservation{};
  if (plan.raycast_skipped) o.raycast = StageObservation{};
  o.total_ms = plan.predicted_ms;
  return o;
}

TEST_CASE("below the floors, frames take turns fusing and casting, each ladder over its stages") {
  DeadlineController controller;
  controller.reset(hand_config(5.0), kIcp, kSide, kSide, true, true);
  controller.observe(demand_frame(), controller.plan());
  // The floors need 5.0627 ms (above). The frame after one that cast fuses: fixed 1.75 ms, ICP at
  // its floors 1.375, voxels 2.5 at their first floor, allocation halved (-0.1875), free space
  // at one visit (0.0002 ms): 0.4377 ms over, 43770 voxel updates off the deeper cut.
  const DeadlineReport fuse = controller.plan();
  CHECK(fuse.deepest == DeadlineStep::fuse_alternate);
  CHECK_FALSE(fuse.infeasible);
  CHECK_FALSE(fuse.fusion_skipped);
  CHECK(fuse.raycast_skipped);
  CHECK(fuse.allocation_half);
  CHECK(fuse.free_space_visits == 1);
  CHECK(static_cast<double>(fuse.max_voxel_updates) == Approx(206230.0).margin(1.0));
  CHECK(fuse.predicted_ms == Approx(5.0).margin(1e-3));
  // The next casts: fixed 1.5 ms, ICP 1.375, the half-resolution 50000 steps (2.5 ms) cut by
  // 7500 to fit; its voxel budgets are not cut (it integrates nothing).
  controller.observe(frame_as_planned(fuse), fuse);
  const DeadlineReport cast = controller.plan();
  CHECK(cast.deepest == DeadlineStep::fuse_alternate);
  CHECK_FALSE(cast.infeasible);
  CHECK(cast.fusion_skipped);
  CHECK_FALSE(cast.raycast_skipped);
  CHECK(cast.raycast_half);
  CHECK_FALSE(cast.allocation_half);
  CHECK(static_cast<double>(cast.raycast_steps) == Approx(42500.0).margin(1.0));
  CHECK(cast.predicted_ms == Approx(5.0).margin(1e-3));
  // And the turns go on.
  controller.observe(frame_as_planned(cast), cast);
  const DeadlineReport again = controller.plan();
  CHECK_FALSE(again.fusion_skipped);
  CHECK(again.raycast_skipped);
  // Switched off, the plan stays at the floors, infeasible.
  const DeadlineReport off = plan_for(5.0, false);
  CHECK(off.deepest == DeadlineStep::voxel_updates_deep);
  CHECK(off.infeasible);
  CHECK_FALSE(off.fusion_skipped);
  CHECK_FALSE(off.raycast_skipped);
}

TEST_CASE("when neither turn fits, frames only track, a bounded run of them at a time") {
  DeadlineController controller;
  DeadlineConfig config = hand_config(3.0);
  config.max_track_only_frames = 3;
  controller.reset(config, kIcp, kSide, kSide, true, true);
  controller.observe(demand_frame(), controller.plan());
  // ICP at its floors alone (1.375 ms) is over what the fusing turn leaves (3 - 1.75); tracking
  // only costs 1.25 ms and ICP above its floors.
  for (int frame = 0; frame < 3; ++frame) {
    CAPTURE(frame);
    const DeadlineReport r = controller.plan();
    CHECK(r.deepest == DeadlineStep::track_only);
    CHECK(r.fusion_skipped);
    CHECK(r.raycast_skipped);
    CHECK_FALSE(r.infeasible);
    CHECK(r.icp_iterations[0] == 1);
    CHECK(r.predicted_ms <= 3.0 + kTolerance_ms);  // ICP cut only as far as needed
    controller.observe(frame_as_planned(r), r);
  }
  // The fourth fuses, over the deadline, and the map moves on; then the run starts again.
  const DeadlineReport fuse = controller.plan();
  CHECK(fuse.deepest == DeadlineStep::fuse_alternate);
  CHECK(fuse.infeasible);
  CHECK_FALSE(fuse.fusion_skipped);
  CHECK(fuse.raycast_skipped);
  controller.observe(frame_as_planned(fuse), fuse);
  const DeadlineReport next = controller.plan();
  CHECK(next.deepest == DeadlineStep::track_only);
  // A track-only frame keeps the turn: the frame the cap lets through after it casts.
  for (int frame = 0; frame < 3; ++frame) {
    const DeadlineReport r = controller.plan();
    REQUIRE(r.deepest == DeadlineStep::track_only);
    controller.observe(frame_as_planned(r), r);
  }
  const DeadlineReport cast = controller.plan();
  CHECK(cast.fusion_skipped);
  CHECK_FALSE(cast.raycast_skipped);
  // Without the step, the fusing turn runs infeasible.
  config.track_only = false;
  controller.reset(config, kIcp, kSide, kSide, true, true);
  controller.observe(demand_frame(), controller.plan());
  const DeadlineReport no_track_only = controller.plan();
  CHECK(no_track_only.deepest == DeadlineStep::fuse_alternate);
  CHECK(no_track_only.infeasible);
}

TEST_CASE("an adapting model learns each stage's line from times that follow the work") {
  // Each stage costs a fixed part plus a rate per unit; the units vary from frame to frame as
  // budgets and views do, which shows the slope apart from the fixed part.
  DeadlineConfig config = hand_config(1000.0);
  config.adapt = true;
  DeadlineController controller;
  controller.reset(config, kIcp, kSide, kSide, true, true);
  const StageCost icp{0.5, 200.0}, voxels{3.0, 5.0}, steps{4.0, 100.0}, visits{0.1, 300.0};
  constexpr double kFixed_ms = 1.5;
  for (int frame = 0; frame < 200; ++frame) {
    const DeadlineReport plan = controller.plan();
    const double scale = 1.0 + 0.25 * static_cast<double>(frame % 4);
    FrameObservation o;
    o.timed = true;
    o.icp = {true, false, 58750.0 * scale, icp.ms(58750.0 * scale)};
    o.integrate = {true, false, 1e6 * scale, voxels.ms(1e6 * scale)};
    o.raycast = {true, false, 2e5 / scale, steps.ms(2e5 / scale)};
    o.free_space = {true, false, 1e4 * scale, visits.ms(1e4 * scale)};
    o.total_ms = kFixed_ms + o.icp.ms + o.integrate.ms + o.raycast.ms + o.free_space.ms;
    controller.observe(o, plan);
  }
  const CostModel& m = controller.model();
  constexpr double kRelative = 1e-9;
  CHECK(m.icp.ms_per_munit == Approx(icp.ms_per_munit).epsilon(kRelative));
  CHECK(m.icp.fixed_ms == Approx(icp.fixed_ms).epsilon(kRelative));
  CHECK(m.integrate.ms_per_munit == Approx(voxels.ms_per_munit).epsilon(kRelative));
  CHECK(m.integrate.fixed_ms == Approx(voxels.fixed_ms).epsilon(kRelative));
  CHECK(m.raycast.ms_per_munit == Approx(steps.ms_per_munit).epsilon(kRelative));
  CHECK(m.raycast.fixed_ms == Approx(steps.fixed_ms).epsilon(kRelative));
  CHECK(m.free_space.ms_per_munit == Approx(visits.ms_per_munit).epsilon(kRelative));
  CHECK(m.free_space.fixed_ms == Approx(visits.fixed_ms).epsilon(kRelative));
  CHECK(m.fixed_ms == Approx(kFixed_ms).epsilon(1e-6));
  CHECK(m.safety == 1.0);  // never over 1000 ms

  // Units that do not vary keep the rate and put the line through their mean.
  DeadlineController steady;
  steady.reset(config, kIcp, kSide, kSide, true, true);
  for (int frame = 0; frame < 50; ++frame) {
    FrameObservation o = demand_frame();
    o.timed = true;
    o.raycast.ms = 12.0;  // 2e5 steps: 2 ms over the starting line's 10.25
    steady.observe(o, steady.plan());
  }
  CHECK(steady.model().raycast.ms_per_munit == 50.0);
  CHECK(steady.model().raycast.fixed_ms == Approx(2.0));
}

TEST_CASE("frames with allocation halved still teach the full march's line") {
  // Integration's fixed part is its allocation march: at every other pixel a quarter of it.
  DeadlineConfig config = hand_config(1000.0);
  config.adapt = true;
  DeadlineController controller;
  controller.reset(config, kIcp, kSide, kSide, true, true);
  const StageCost voxels{3.0, 5.0};
  for (int frame = 0; frame < 400; ++frame) {
    DeadlineReport plan = controller.plan();
    plan.allocation_half = frame % 2 == 1;
    const double units = 1e6 * (1.0 + 0.25 * static_cast<double>(frame % 4));
    FrameObservation o = demand_frame();
    o.timed = true;
    o.integrate = {true, false, units, voxels.ms(units)};
    if (plan.allocation_half) o.integrate.ms -= 0.75 * voxels.fixed_ms;
    controller.observe(o, plan);
  }
  CHECK(controller.model().integrate.fixed_ms == Approx(voxels.fixed_ms).epsilon(1e-3));
  CHECK(controller.model().integrate.ms_per_munit == Approx(voxels.ms_per_munit).epsilon(1e-3));
}

TEST_CASE("a stage held at one unit keeps a sane rate through a burst of load") {
  // Free space at its floor (one visit) for long after it last carved, a frame slowed by load,
  // then one of 64 visits as quick as the rest: the slope through the recent frames comes out
  // negative. The rate stays the last one, not the frames' time per unit (75 000 ms per million
  // visits here), which would keep the stage at its floor for good.
  DeadlineConfig config = hand_config(1000.0);
  config.adapt = true;
  DeadlineController controller;
  controller.reset(config, kIcp, kSide, kSide, true, true);
  auto carve = [&](double visits, double ms) {
    FrameObservation o;
    o.timed = true;
    o.total_ms = ms;
    o.free_space = {true, false, visits, ms};
    controller.observe(o, controller.plan());
  };
  for (int i = 0; i < 20; ++i) carve(1e4, 2.1);  // 0.1 ms and 200 ms per million visits
  for (int i = 0; i < 300; ++i) carve(1.0, 0.1);
  carve(1.0, 4.1);
  carve(1.0, 0.1);
  carve(1.0, 0.1);
  carve(64.0, 0.1);
  for (int i = 0; i < 20; ++i) carve(1.0, 0.1);
  CHECK(controller.model().free_space.ms_per_munit < 1000.0);
  CHECK(controller.model().free_space.ms_per_munit > 50.0);
  CHECK(validate(controller.model()).ok());
}

TEST_CASE("a frozen model reads no time; overruns raise an adapting model's safety factor") {
  DeadlineController frozen;
  frozen.reset(hand_config(10.0), kIcp, kSide, kSide, true, true);
  FrameObservation slow = demand_frame();
  slow.timed = true;
  slow.total_ms = 1000.0;
  slow.raycast.ms = 900.0;
  frozen.observe(slow, frozen.plan());
  frozen.observe(slow, frozen.plan());
  CHECK(frozen.model().raycast.ms_per_munit == hand_model().raycast.ms_per_munit);
  CHECK(frozen.model().raycast.fixed_ms == hand_model().raycast.fixed_ms);
  CHECK(frozen.model().safety == 1.0);

  DeadlineConfig config = hand_config(10.0);
  config.adapt = true;
  DeadlineController adapting;
  adapting.reset(config, kIcp, kSide, kSide, true, true);
  adapting.observe(slow, adapting.plan());  // unplanned: the safety factor stays
  CHECK(adapting.model().safety == 1.0);
  DeadlineReport met = adapting.plan();
  met.infeasible = false;
  adapting.observe(slow, met);
  CHECK(adapting.model().safety == Approx(1.2));
  DeadlineReport below_floors = met;
  below_floors.infeasible = true;  // the floors alone did not fit: no fault of the model
  adapting.observe(slow, below_floors);
  CHECK(adapting.model().safety == Approx(1.2));
  FrameObservation quick = slow;
  quick.total_ms = 5.0;
  adapting.observe(quick, below_floors);  // within the deadline, feasible or not: it falls
  CHECK(adapting.model().safety == Approx(1.2 * 0.999));
  for (int i = 0; i < 100; ++i) adapting.observe(slow, met);
  CHECK(adapting.model().safety == 16.0);
  CHECK(validate(adapting.model()).ok());
}

TEST_CASE("bad deadline settings and models are refused with a reason") {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  ErrorText error;
  for (const double bad : {-1.0, nan, inf, 2e5}) {
    DeadlineConfig c;
    c.deadline_ms = bad;
    CHECK(validate(c, &error).code() == StatusCode::invalid_argument);
  }
  CHECK(std::string(error.c_str()).find("deadline_ms") != std::string::npos);
  for (const double bad : {0.0, -1.0, nan, inf, 2e6}) {
    CostModel m;
    m.raycast.ms_per_munit = bad;
    CHECK(validate(m, &error).code() == StatusCode::invalid_argument);
  }
  for (const double bad : {-1.0, nan, inf, 2e6}) {
    CostModel m;
    m.integrate.fixed_ms = bad;
    CHECK(validate(m, &error).code() == StatusCode::invalid_argument);
  }
  {
    CostModel m;
    m.free_space.fixed_ms = 0.0;  // a fixed part may be nothing
    CHECK(validate(m).ok());
  }
  for (const double bad : {0.5, 17.0, nan}) {
    CostModel m;
    m.safety = bad;
    CHECK(validate(m, &error).code() == StatusCode::invalid_argument);
  }
  DeadlineConfig c;
  c.min_raycast_fraction = 1.5f;
  CHECK_FALSE(validate(c).ok());
  c = DeadlineConfig{};
  c.min_icp_iterations[1] = -1;
  CHECK_FALSE(validate(c).ok());
  c = DeadlineConfig{};
  c.demand_growth = 0.5f;
  CHECK_FALSE(validate(c).ok());
  c = DeadlineConfig{};
  c.max_track_only_frames = -1;
  CHECK_FALSE(validate(c, &error).ok());
  CHECK(std::string(error.c_str()).find("max_track_only_frames") != std::string::npos);
  CHECK(validate(DeadlineConfig{}).ok());
}

}  // namespace
}  // namespace octofuse
