// The vehicle's own poses as input: external (fuse at the prior), external_prior (ICP from the
// prior's motion, the prior wins past the gate or when ICP is lost), reset() and set_pose(), and
// init naming the setting that is wrong. Small sim camera, as pipeline_test.cpp.

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/sim/odometry.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/small_sim.hpp"

namespace octofuse {
namespace {

using test::small_sim;

using octofuse::test::Buffer;

PipelineConfig small_config(const sim::SimSource& source, PoseSource pose_source) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  PipelineConfig config =
      default_pipeline_config(source.intrinsics(), 0.02f, 9, 20000,
                              (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>());
  config.preprocess.downsample_factor = 1;
  config.initial_T_W_C = T_W_C0;
  config.pose_source = pose_source;
  return config;
}

struct Run {
  std::vector<Se3d> poses;
  std::vector<Se3d> truth;
  std::vector<Se3d> priors;
  std::vector<FrameStats> stats;
  std::uint64_t frames_lost = 0;
};

// Prior for frame i from the true pose i (and i itself); returns false for "no prior".
using PriorFn = bool (*)(int index, const Se3d& truth, Se3d* prior, void* context);

// Runs the first `frames` frames of a sim path of `path_frames` (0: the same) frames.
Run run(int frames, const PipelineConfig& config, PriorFn make_prior, void* context,
        int path_frames = 0) {
  sim::SimSource source(small_sim(path_frames > 0 ? path_frames : frames));
  REQUIRE(source.open().ok());
  const std::size_t bytes = bytes_required(config);
  REQUIRE(bytes > 0);
  Buffer buffer(bytes);
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes, config).ok());
  Run out;
  DepthFrame frame;
  for (int i = 0; i < frames && source.next(frame).outcome == FrameOutcome::frame; ++i) {
    Se3d truth = Se3d::Identity();
    truth.matrix() = frame.T_W_C_ground_truth;
    PosePrior prior;
    Se3d prior_T_W_C = Se3d::Identity();
    if (make_prior != nullptr && make_prior(i, truth, &prior_T_W_C, context)) {
      prior.valid = true;
      prior.T_W_C = prior_T_W_C.matrix();
    }
    FrameStats stats;
    const Status status = pipeline.process(frame, prior, &stats);
    REQUIRE((status.ok() || stats.result == FrameResult::lost));
    out.poses.push_back(pipeline.T_W_C());
    out.truth.push_back(truth);
    out.priors.push_back(prior_T_W_C);
    out.stats.push_back(stats);
  }
  out.frames_lost = pipeline.frames_lost();
  return out;
}

// RMS position error; the world is anchored at the first frame, so no alignment is needed.
double rms_position_error(const std::vector<Se3d>& poses, const std::vector<Se3d>& truth) {
  double sum = 0.0;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    sum += (poses[i].translation() - truth[i].translation()).squaredNorm();
  }
  return std::sqrt(sum / static_cast<double>(poses.size()));
}

bool prior_is_truth(int, const Se3d& truth, Se3d* prior, void*) {
  *prior = truth;
  return true;
}

TEST_CASE("external: a prior equal to the ground truth gives the ground truth, without ICP") {
  sim::SimSource probe(small_sim(30));
  REQUIRE(probe.open().ok());
  const Run r = run(30, small_config(probe, PoseSource::external), &prior_is_truth, nullptr);
  REQUIRE(r.poses.size() == 30);
  REQUIRE(r.stats[0].pose_origin == PoseOrigin::initial);
  for (std::size_t i = 0; i < r.poses.size(); ++i) {
    REQUIRE_FALSE(r.stats[i].track_attempted);
    if (i > 0) REQUIRE(r.stats[i].pose_origin == PoseOrigin::prior);
    REQUIRE((r.poses[i].matrix() - r.truth[i].matrix()).cwiseAbs().maxCoeff() < 1e-12);
  }
}

TEST_CASE("external: a frame without a prior is lost, the pose stays") {
  sim::SimSource probe(small_sim(6));
  REQUIRE(probe.open().ok());
  const Run r = run(
      6, small_config(probe, PoseSource::external),
      [](int index, const Se3d& truth, Se3d* prior, void*) {
        *prior = truth;
        return index != 3;
      },
      nullptr);
  REQUIRE(r.stats[3].result == FrameResult::lost);
  REQUIRE(r.stats[3].pose_origin == PoseOrigin::none);
  REQUIRE(r.poses[3].matrix() == r.poses[2].matrix());
  REQUIRE(r.stats[4].pose_origin == PoseOrigin::prior);
  REQUIRE(r.frames_lost == 1);
}

struct Drift {
  sim::DriftingOdometry odometry;
  Se3d T_W_O = Se3d::Identity();
};

bool drifting_prior(int index, const Se3d& truth, Se3d* prior, void* context) {
  Drift& drift = *static_cast<Drift*>(context);
  const Se3d T_O_C = drift.odometry.next(truth);
  if (index == 0) drift.T_W_O = truth * T_O_C.inverse();  // the first frame anchors the world
  *prior = drift.T_W_O * T_O_C;
  return true;
}

TEST_CASE("external_prior with a drifting odometry beats the odometry alone and loses nothing") {
  // 120 frames of the desk's 300-frame path (1.8 cm per frame, as a hand-held camera).
  constexpr int kFrames = 120;
  sim::SimSource probe(small_sim(300));
  REQUIRE(probe.open().ok());
  // 5 %/m and 1 deg/m: enough drift over the desk's path to tell the two apart clearly.
  sim::OdometryDriftConfig drift_config;
  drift_config.drift_per_m = 0.05;
  drift_config.drift_rad_per_m = 0.02;
  drift_config.noise_m = 0.002;
  drift_config.noise_rad = 0.002;
  Drift drift{sim::DriftingOdometry(drift_config), Se3d::Identity()};
  const Run r =
      run(kFrames, small_config(probe, PoseSource::external_prior), &drifting_prior, &drift, 300);
  const double odometry_rms_m = rms_position_error(r.priors, r.truth);
  const double fused_rms_m = rms_position_error(r.poses, r.truth);
  CAPTURE(odometry_rms_m, fused_rms_m, drift.odometry.distance_m());
  REQUIRE(drift.odometry.distance_m() > 0.5);
  REQUIRE(r.frames_lost == 0);
  REQUIRE(odometry_rms_m > 0.01);
  REQUIRE(fused_rms_m < 0.5 * odometry_rms_m);
  std::size_t by_icp = 0;
  for (std::size_t i = 1; i < r.stats.size(); ++i) {
    REQUIRE(r.stats[i].has_prediction);
    if (r.stats[i].pose_origin == PoseOrigin::icp) ++by_icp;
  }
  REQUIRE(by_icp == r.stats.size() - 1);  // the noise stays well inside the gate
}

TEST_CASE("external_prior: a corrupted prior trips the gate and the frame says so") {
  sim::SimSource probe(small_sim(300));
  REQUIRE(probe.open().ok());
  const PipelineConfig config = small_config(probe, PoseSource::external_prior);
  const Run r = run(
      12, config,
      [](int index, const Se3d& truth, Se3d* prior, void*) {
        *prior = truth;
        // A 10 cm jump on frame 6 only: the motions into and out of it are both wrong.
        if (index == 6) prior->translation() += Eigen::Vector3d(0.10, 0.0, 0.0);
        return true;
      },
      nullptr, 300);
  for (int i = 1; i < 12; ++i) {
    CAPTURE(i, r.stats[i].prior_gap_m);
    if (i == 6) {
      REQUIRE(r.stats[i].pose_origin == PoseOrigin::prior_gate);
      REQUIRE(r.stats[i].prior_gap_m > config.prior_gate_m);
      REQUIRE(r.stats[i].prior_gap_m > 0.05);  // ICP stays with the depth, well away from it
      // The prediction won: the previous pose moved by the prior's (corrupted) motion.
      const Se3d expected = r.poses[5] * r.priors[5].inverse() * r.priors[6];
      REQUIRE((r.poses[6].translation() - expected.translation()).norm() < 1e-9);
    } else {
      // Frame 7 too: its prediction starts from frame 6's pose and prior, which agree.
      REQUIRE(r.stats[i].pose_origin == PoseOrigin::icp);
      REQUIRE(r.stats[i].prior_gap_m < config.prior_gate_m);
    }
  }
}

TEST_CASE("an implausibly far or fast prior is dropped; the frame goes on without it") {
  sim::SimSource probe(small_sim(300));
  REQUIRE(probe.open().ok());
  for (PoseSource mode : {PoseSource::external_prior, PoseSource::external}) {
    CAPTURE(static_cast<int>(mode));
    const PipelineConfig config = small_config(probe, mode);
    const Run r = run(
        12, config,
        [](int index, const Se3d& truth, Se3d* prior, void*) {
          *prior = truth;
          // A jump of 1000 km on frame 4, coordinates of 1e300 on frame 8, and a 90-degree turn
          // within one frame on frame 10: corrupt or unit-confused odometry.
          if (index == 4) prior->translation() += Eigen::Vector3d(1e6, 0.0, 0.0);
          if (index == 8) prior->translation().x() = 1e300;
          if (index == 10) {
            prior->linear() = prior->linear() *
                              Eigen::AngleAxisd(1.6, Eigen::Vector3d::UnitY()).toRotationMatrix();
          }
          return true;
        },
        nullptr, 300);
    int dropped = 0;
    for (int i = 0; i < 12; ++i) {
      CAPTURE(i);
      const bool bad = i == 4 || i == 8 || i == 10;
      REQUIRE(r.stats[i].prior_dropped == bad);
      REQUIRE(r.stats[i].has_prior == !bad);
      REQUIRE(r.stats[i].result != FrameResult::rejected);
      dropped += r.stats[i].prior_dropped ? 1 : 0;
      if (mode == PoseSource::external_prior || !bad) {
        // Tracked (or fused at the prior) near the truth; never at the corrupt pose.
        REQUIRE((r.poses[i].translation() - r.truth[i].translation()).norm() < 0.02);
      } else {
        // Odometry only, no usable prior: lost, the pose stays where it was.
        REQUIRE(r.stats[i].result == FrameResult::lost);
      }
    }
    REQUIRE(dropped == 3);
  }
}

// The noise that weighs the prior after `frames` frames of an odometry with `noise` (m and rad)
// of white noise per pose and no drift.
std::pair<double, double> seen_noise(double noise, int estimate_frames, int frames = 60) {
  // The default path's speed (300 frames): its own third differences are far below a millimetre.
  sim::SimSource source(small_sim(300));
  REQUIRE(source.open().ok());
  PipelineConfig config = small_config(source, PoseSource::external_prior);
  config.prior_noise_estimate_frames = estimate_frames;
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  sim::OdometryDriftConfig odometry_config;
  odometry_config.drift_per_m = 0.0;
  odometry_config.drift_rad_per_m = 0.0;
  odometry_config.noise_m = noise;
  odometry_config.noise_rad = noise;
  sim::DriftingOdometry odometry(odometry_config);
  DepthFrame frame;
  for (int i = 0; i < frames && source.next(frame).outcome == FrameOutcome::frame; ++i) {
    Se3d truth = Se3d::Identity();
    truth.matrix() = frame.T_W_C_ground_truth;
    PosePrior prior;
    prior.valid = true;
    prior.T_W_C = odometry.next(truth).matrix();
    FrameStats stats;
    const Status status = pipeline.process(frame, prior, &stats);
    REQUIRE((status.ok() || stats.result == FrameResult::lost));
  }
  return {pipeline.prior_noise_m(), pipeline.prior_noise_rad()};
}

TEST_CASE("an odometry noisier than stated is weighed by the noise it shows, never less") {
  const PipelineConfig defaults;
  // 4 mm and 4 mrad per pose: 5.7 mm and 5.7 mrad on one frame's motion, against 1.5 stated.
  const auto noisy = seen_noise(0.004, 20);
  CHECK(noisy.first == Approx(0.004 * std::sqrt(2.0)).epsilon(0.3));
  CHECK(noisy.second == Approx(0.004 * std::sqrt(2.0)).epsilon(0.3));
  // Quieter than stated: the stated noise stands.
  const auto quiet = seen_noise(0.0002, 20);
  CHECK(quiet.first == defaults.prior_noise_m);
  CHECK(quiet.second == defaults.prior_noise_rad);
  // Estimation off, or too few frames seen: the stated noise.
  CHECK(seen_noise(0.004, 0).first == defaults.prior_noise_m);
  CHECK(seen_noise(0.004, 100, 40).first == defaults.prior_noise_m);
}

TEST_CASE("the prior's motion limits") {
  const PriorMotionLimits limits = PipelineConfig().prior_motion;
  const Se3d origin = Se3d::Identity();
  Se3d moved = Se3d::Identity();
  moved.translation() = Eigen::Vector3d(3.0, 0.0, 0.0);
  // 100 m/s plus 0.1 m: 3 m in 1/30 s is plausible (3.43 m allowed), in 1/60 s not (1.77 m).
  CHECK_FALSE(prior_motion_implausible(origin, moved, 1.0 / 30.0, limits));
  CHECK(prior_motion_implausible(origin, moved, 1.0 / 60.0, limits));
  // No time between the two (or time going back): the slack alone.
  moved.translation() = Eigen::Vector3d(0.09, 0.0, 0.0);
  CHECK_FALSE(prior_motion_implausible(origin, moved, -1.0, limits));
  moved.translation() = Eigen::Vector3d(0.11, 0.0, 0.0);
  CHECK(prior_motion_implausible(origin, moved, 0.0, limits));
  double moved_m = 0.0;
  double turned_rad = 0.0;
  Se3d turned = Se3d::Identity();
  turned.linear() = Eigen::AngleAxisd(1.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  // 30 rad/s plus 0.2 rad: 1 rad in 1/30 s is plausible (1.2 rad allowed), in 1/100 s not.
  CHECK_FALSE(prior_motion_implausible(origin, turned, 1.0 / 30.0, limits, &moved_m, &turned_rad));
  CHECK(turned_rad == Approx(1.0));
  CHECK(prior_motion_implausible(origin, turned, 0.01, limits));
  Se3d far = Se3d::Identity();
  far.translation() = Eigen::Vector3d(0.0, -2e6, 0.0);
  CHECK(prior_position_implausible(far, limits));
  far.translation() = Eigen::Vector3d(0.0, -9e5, 0.0);
  CHECK_FALSE(prior_position_implausible(far, limits));
}

TEST_CASE("external_prior: a frame ICP loses is fused at the prior, not lost") {
  sim::SimSource probe(small_sim(10));
  REQUIRE(probe.open().ok());
  PipelineConfig config = small_config(probe, PoseSource::track);
  config.track.lost_max_rms_m = 0.0f;  // every ICP result counts as lost
  const Run tracked = run(10, config, nullptr, nullptr);
  REQUIRE(tracked.frames_lost == 9);
  REQUIRE(tracked.stats[1].result == FrameResult::lost);
  const std::uint32_t blocks_without_prior = tracked.stats.back().memory.blocks_used;

  config.pose_source = PoseSource::external_prior;
  const Run r = run(10, config, &prior_is_truth, nullptr);
  REQUIRE(r.frames_lost == 0);
  for (std::size_t i = 1; i < r.stats.size(); ++i) {
    REQUIRE(r.stats[i].track_attempted);
    REQUIRE_FALSE(r.stats[i].track.tracked());
    REQUIRE(r.stats[i].result == FrameResult::tracked);
    REQUIRE(r.stats[i].pose_origin == PoseOrigin::prior_lost);
    REQUIRE(r.stats[i].integration.blocks_integrated > 0);
    REQUIRE((r.poses[i].translation() - r.truth[i].translation()).norm() < 1e-9);
  }
  REQUIRE(r.stats.back().memory.blocks_used > blocks_without_prior);
}

TEST_CASE("frames with a prior allocate nothing, ICP pulled or gated, nor does reset()") {
  sim::SimSource source(small_sim(300));
  REQUIRE(source.open().ok());
  PipelineConfig config = small_config(source, PoseSource::external_prior);
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  DepthFrame frame;
  FrameStats stats;
  std::uint64_t origins[7] = {};
  test::AllocationScope scope;
  for (int i = 0; i < 40; ++i) {
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    PosePrior prior;
    prior.valid = true;
    prior.T_W_C = frame.T_W_C_ground_truth;
    if (i == 20) prior.T_W_C(0, 3) += 0.1;  // trips the gate
    REQUIRE(pipeline.process(frame, prior, &stats).ok());
    ++origins[static_cast<int>(stats.pose_origin)];
  }
  REQUIRE(pipeline.reset().ok());
  REQUIRE(scope.allocations() == 0);
  REQUIRE(origins[static_cast<int>(PoseOrigin::icp)] > 30);
  REQUIRE(origins[static_cast<int>(PoseOrigin::prior_gate)] >= 1);
}

TEST_CASE("a prior that is not rigid or not finite rejects the frame and changes nothing") {
  sim::SimSource source(small_sim(300));
  REQUIRE(source.open().ok());
  const PipelineConfig config = small_config(source, PoseSource::external_prior);
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  DepthFrame frame;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  FrameStats stats;
  PosePrior first;
  first.valid = true;
  first.T_W_C = frame.T_W_C_ground_truth;
  REQUIRE(pipeline.process(frame, first, &stats).ok());
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  const Se3d before = pipeline.T_W_C();
  PosePrior bad;
  bad.valid = true;
  bad.T_W_C = frame.T_W_C_ground_truth;
  bad.T_W_C(0, 0) *= 1.5;
  REQUIRE(pipeline.process(frame, bad, &stats).code() == StatusCode::invalid_argument);
  REQUIRE(stats.result == FrameResult::rejected);
  REQUIRE(std::strstr(pipeline.last_error(), "prior") != nullptr);
  bad.T_W_C = frame.T_W_C_ground_truth;
  bad.T_W_C(1, 3) = std::nan("");
  REQUIRE(pipeline.process(frame, bad, &stats).code() == StatusCode::invalid_argument);
  REQUIRE(pipeline.frames_rejected() == 2);
  REQUIRE(pipeline.T_W_C().matrix() == before.matrix());
  // The same frame with a good prior is accepted: the rejections left the time state alone.
  PosePrior good;
  good.valid = true;
  good.T_W_C = frame.T_W_C_ground_truth;
  REQUIRE(pipeline.process(frame, good, &stats).ok());
  REQUIRE(stats.result == FrameResult::tracked);
  REQUIRE(stats.pose_origin == PoseOrigin::icp);
}

TEST_CASE("reset() forgets the map and starts over: the same frames give the same poses") {
  constexpr int kFrames = 12;
  sim::SimSource source(small_sim(300));
  REQUIRE(source.open().ok());
  const PipelineConfig config = small_config(source, PoseSource::track);
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.reset().code() == StatusCode::failed_precondition);
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  std::vector<Se3d> first_pass, second_pass;
  DepthFrame frame;
  FrameStats stats;
  for (int i = 0; i < kFrames; ++i) {
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    REQUIRE(pipeline.process(frame, &stats).ok());
    REQUIRE(stats.result == (i == 0 ? FrameResult::first : FrameResult::tracked));
    first_pass.push_back(pipeline.T_W_C());
  }
  const std::uint32_t blocks = pipeline.map().memory().blocks_used;
  REQUIRE(blocks > 0);
  const std::size_t bytes_used = pipeline.bytes_used();
  // Some air in front of the first camera was carved free; the reset forgets it too.
  REQUIRE(pipeline.free_space().node_count() > 1);

  test::AllocationScope scope;
  REQUIRE(pipeline.reset().ok());
  REQUIRE(pipeline.set_pose(config.initial_T_W_C).ok());
  REQUIRE(pipeline.reset().ok());
  REQUIRE(scope.allocations() == 0);
  REQUIRE(pipeline.map().memory().blocks_used == 0);
  REQUIRE(pipeline.free_space().node_count() == 1);  // the root alone
  REQUIRE(pipeline.bytes_used() == bytes_used);
  REQUIRE(pipeline.T_W_C().matrix().isApprox(config.initial_T_W_C.matrix(), 1e-12));

  source.close();
  REQUIRE(source.open().ok());  // the timestamps start again
  for (int i = 0; i < kFrames; ++i) {
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    REQUIRE(pipeline.process(frame, &stats).ok());
    REQUIRE(stats.result == (i == 0 ? FrameResult::first : FrameResult::tracked));
    second_pass.push_back(pipeline.T_W_C());
  }
  REQUIRE(second_pass.size() == first_pass.size());
  for (std::size_t i = 0; i < first_pass.size(); ++i) {
    REQUIRE(std::memcmp(first_pass[i].matrix().data(), second_pass[i].matrix().data(),
                        sizeof(double) * 16) == 0);
  }
  REQUIRE(pipeline.map().memory().blocks_used == blocks);
}

TEST_CASE("set_pose() relocalises: before the first frame, and after a jump in the stream") {
  sim::SimSource source(small_sim(300));
  REQUIRE(source.open().ok());
  const PipelineConfig config = small_config(source, PoseSource::track);
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.set_pose(Se3d::Identity()).code() == StatusCode::failed_precondition);
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());

  Eigen::Matrix4d not_rigid = Eigen::Matrix4d::Identity();
  not_rigid(2, 2) = 2.0;
  Se3d bad = Se3d::Identity();
  bad.matrix() = not_rigid;
  REQUIRE(pipeline.set_pose(bad).code() == StatusCode::invalid_argument);

  // Before the first frame: the first frame keeps the given pose, not its ground truth.
  Se3d start = source.ground_truth_T_W_C(0);
  start.translation() += Eigen::Vector3d(0.0, 0.0, 0.05);
  REQUIRE(pipeline.set_pose(start).ok());
  DepthFrame frame;
  FrameStats stats;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  REQUIRE(pipeline.process(frame, &stats).ok());
  REQUIRE(stats.result == FrameResult::first);
  REQUIRE((pipeline.T_W_C().translation() - start.translation()).norm() < 1e-12);

  // Map the first 30 frames from the true start instead.
  REQUIRE(pipeline.reset().ok());
  source.close();
  REQUIRE(source.open().ok());
  for (int i = 0; i < 30; ++i) {
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    REQUIRE(pipeline.process(frame, &stats).ok());
  }
  // Skip ahead: the camera is elsewhere; relocalise to where it is and track on from there.
  for (int i = 30; i < 120; ++i) REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  Se3d relocalised = Se3d::Identity();
  relocalised.matrix() = frame.T_W_C_ground_truth;
  REQUIRE((pipeline.T_W_C().translation() - relocalised.translation()).norm() > 0.2);
  REQUIRE(pipeline.set_pose(relocalised).ok());
  REQUIRE(pipeline.T_W_C().matrix().isApprox(relocalised.matrix(), 1e-12));
  REQUIRE(pipeline.reference_T_W_C().matrix() == pipeline.T_W_C().matrix());
  REQUIRE(pipeline.process(frame, &stats).ok());
  REQUIRE(stats.result == FrameResult::tracked);
  Se3d truth = Se3d::Identity();
  truth.matrix() = frame.T_W_C_ground_truth;
  REQUIRE((pipeline.T_W_C().translation() - truth.translation()).norm() < 0.02);  // a voxel
}

TEST_CASE("a full free-space pool forgets the far free space and keeps carving near the camera") {
  constexpr int kFrames = 40;
  constexpr std::uint32_t kCapacity = 2200;
  sim::SimSource source(small_sim(kFrames));
  REQUIRE(source.open().ok());
  // Fused at the true poses: this coarse 40-frame path moves too fast to track throughout.
  PipelineConfig config = small_config(source, PoseSource::ground_truth);
  config.free_space.node_capacity = kCapacity;
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  DepthFrame frame;
  FrameStats stats;
  std::uint64_t pruned = 0;
  test::AllocationScope scope;
  for (int i = 0; i < kFrames; ++i) {
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    REQUIRE(pipeline.process(frame, &stats).ok());
    REQUIRE((stats.result == FrameResult::first || stats.result == FrameResult::tracked));
    REQUIRE(pipeline.free_space().node_count() <= kCapacity);
    if (stats.free_space.pruned > 0) {
      REQUIRE(stats.free_space.nodes_used == pipeline.free_space().node_count());
    }
    pruned += stats.free_space.pruned;
  }
  REQUIRE(scope.allocations() == 0);
  REQUIRE(pruned > 0);
  // The air in front of the last camera, within 1.3 m, was carved and kept by the pruning.
  const Se3d T_W_C = pipeline.T_W_C();
  int free_points = 0;
  for (int k = 0; k < 400; ++k) {
    const double t = 0.3 + 0.05 * (k % 20);
    const double x = 0.05 * (k / 20 % 5) - 0.1;
    const double y = 0.05 * (k / 100) - 0.1;
    const Eigen::Vector3d p_W = T_W_C * Eigen::Vector3d(x * t, y * t, t);
    const Result<PointAnswer> a = pipeline.query().point(p_W.cast<float>());
    REQUIRE(a.ok());
    free_points += a.value().state == PointState::free ? 1 : 0;
  }
  REQUIRE(free_points > 0);
}

TEST_CASE("init names the setting that is wrong") {
  sim::SimSource source(small_sim(1));
  REQUIRE(source.open().ok());
  const PipelineConfig good = small_config(source, PoseSource::track);
  Buffer buffer(bytes_required(good));
  struct Case {
    const char* setting;
    void (*spoil)(PipelineConfig&);
  };
  const Case cases[] = {
      {"map.voxel_size_m", [](PipelineConfig& c) { c.map.voxel_size_m = -1.0f; }},
      {"map.block_capacity", [](PipelineConfig& c) { c.map.block_capacity = 0; }},
      {"fusion.mu_m", [](PipelineConfig& c) { c.fusion.mu_m = std::nanf(""); }},
      {"workers", [](PipelineConfig& c) { c.workers = 0; }},
      {"initial_T_W_C", [](PipelineConfig& c) { c.initial_T_W_C.matrix()(0, 0) = 3.0; }},
      {"prior_gate_m", [](PipelineConfig& c) { c.prior_gate_m = -0.1; }},
      {"prior_noise_m", [](PipelineConfig& c) { c.prior_noise_m = 0.0; }},
      {"prior_noise_rad", [](PipelineConfig& c) { c.prior_noise_rad = std::nan(""); }},
      {"prior_icp_noise_floor_m", [](PipelineConfig& c) { c.prior_icp_noise_floor_m = -1e-3; }},
      {"prior_icp_pixels_per_sample",
       [](PipelineConfig& c) { c.prior_icp_pixels_per_sample = 0.0; }},
      {"prior_information_t", [](PipelineConfig& c) { c.prior_information_t = -1.0; }},
      {"prior_gap_rate", [](PipelineConfig& c) { c.prior_gap_rate = 1.5; }},
      {"prior_motion.max_", [](PipelineConfig& c) { c.prior_motion.max_speed_mps = 0.0; }},
      {"prior_motion.max_",
       [](PipelineConfig& c) { c.prior_motion.max_coordinate_m = std::nan(""); }},
      {"prior_motion.slack_", [](PipelineConfig& c) { c.prior_motion.slack_rad = -1.0; }},
      {"prior_noise_estimate_frames",
       [](PipelineConfig& c) { c.prior_noise_estimate_frames = -1; }},
      {"input_camera", [](PipelineConfig& c) { c.input_camera.fx = 0.0f; }},
  };
  for (const Case& c : cases) {
    PipelineConfig config = good;
    c.spoil(config);
    Pipeline<MultiresVoxel> pipeline;
    CAPTURE(c.setting);
    REQUIRE(pipeline.init(buffer.data, bytes_required(good), config).code() ==
            StatusCode::invalid_argument);
    CAPTURE(pipeline.last_error());
    REQUIRE(std::strstr(pipeline.last_error(), c.setting) != nullptr);
  }
  Pipeline<MultiresVoxel> small;
  REQUIRE(small.init(buffer.data, 1024, good).code() == StatusCode::resource_exhausted);
  REQUIRE(std::strstr(small.last_error(), "too small") != nullptr);
}

}  // namespace
}  // namespace octofuse
