// Which priors are believed: implausibly far or fast ones dropped, noisier odometry weighed by
// the noise it shows, motion limits, priors that are not rigid or finite rejected, and init
// naming the setting that is wrong.

#include <catch2/catch.hpp>

#include "system/pose_prior_support.hpp"

namespace octofuse {
namespace {

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
