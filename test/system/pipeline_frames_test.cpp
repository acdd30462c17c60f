// Frame after frame: allocation-free, tracking within a centimetre of ground truth, budgets
// never exceeded, bad frames rejected without touching the map.

#include "octofuse/pipeline/pipeline.hpp"

#include <catch2/catch.hpp>

#include "system/pipeline_support.hpp"

namespace octofuse {
namespace {

constexpr int kWidth = test::kSmallSimWidth;  // a quarter of VGA in each direction
constexpr int kHeight = test::kSmallSimHeight;

TEST_CASE("300 frames after init allocate nothing, tracked or lost") {
  sim::SimSource source(small_sim(300));
  REQUIRE(source.open().ok());
  PipelineConfig config = small_config(source, 0.04f, 2);
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  DepthFrame frame;
  int frames = 0;
  test::AllocationScope scope;
  while (source.next(frame).outcome == FrameOutcome::frame) {
    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    REQUIRE((status.ok() || stats.result == FrameResult::lost));
    ++frames;
  }
  REQUIRE(frames == 300);
  REQUIRE(scope.allocations() == 0);
  REQUIRE(pipeline.map().memory().blocks_used > 0);
  // Free space was carved in those frames too (it is on by default).
  REQUIRE(pipeline.config().free_space.enabled);
  REQUIRE(pipeline.free_space().node_count() > 1);
}

TEST_CASE("tracking on the noiseless sim stays within a centimetre of ground truth") {
  constexpr double kMaxError_m = 0.01;
  const sim::SimConfig sim_config = small_sim(30, /*noise=*/false);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  std::vector<FrameStats> stats;
  const std::vector<Se3d> poses =
      run<MultiresVoxel>(sim_config, small_config(truth, 0.01f, 1), &stats);
  REQUIRE(poses.size() == 30);
  for (std::size_t i = 0; i < poses.size(); ++i) {
    CAPTURE(i);
    REQUIRE(stats[i].result != FrameResult::lost);
    const double error_m =
        (poses[i].translation() - truth.ground_truth_T_W_C(static_cast<int>(i)).translation())
            .norm();
    REQUIRE(error_m < kMaxError_m);
  }
}

TEST_CASE("with the reference ray-cast at half resolution tracking stays within a centimetre") {
  constexpr double kMaxError_m = 0.01;
  const sim::SimConfig sim_config = small_sim(30, /*noise=*/false);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  PipelineConfig config = small_config(truth, 0.01f, 1);
  config.budget.raycast_half = true;
  std::vector<FrameStats> stats;
  const std::vector<Se3d> poses = run<MultiresVoxel>(sim_config, config, &stats);
  REQUIRE(poses.size() == 30);
  const std::uint32_t working_pixels =
      static_cast<std::uint32_t>(config.input_camera.width / config.preprocess.downsample_factor) *
      static_cast<std::uint32_t>(config.input_camera.height / config.preprocess.downsample_factor);
  for (std::size_t i = 0; i < poses.size(); ++i) {
    CAPTURE(i);
    REQUIRE(stats[i].result != FrameResult::lost);
    // A quarter of the rays are cast, every frame.
    REQUIRE(stats[i].raycast.marched_pixels == working_pixels / 4);
    const double error_m =
        (poses[i].translation() - truth.ground_truth_T_W_C(static_cast<int>(i)).translation())
            .norm();
    REQUIRE(error_m < kMaxError_m);
  }
}

TEST_CASE("a very low budget is never exceeded and the run completes") {
  const sim::SimConfig sim_config = small_sim(30);
  sim::SimSource probe(sim_config);
  REQUIRE(probe.open().ok());
  PipelineConfig config = small_config(probe, 0.02f, 2);
  config.budget.max_new_blocks = 8;
  config.budget.max_integrated_blocks = 24;
  config.budget.raycast_steps = 4000;
  config.budget.icp_iterations[0] = 1;
  config.budget.icp_iterations[1] = 1;
  config.budget.icp_iterations[2] = 2;
  std::vector<FrameStats> stats;
  const std::vector<Se3d> poses = run<MultiresVoxel>(sim_config, config, &stats);
  REQUIRE(poses.size() == 30);
  bool any_fusion_hit = false, any_raycast_hit = false;
  for (const FrameStats& s : stats) {
    REQUIRE(s.integration.blocks_allocated <= 8);
    REQUIRE(s.integration.blocks_integrated <= 24);
    REQUIRE(s.raycast.steps <= 4000);
    if (s.track_attempted) {
      REQUIRE(s.track.iterations[0] <= 1);
      REQUIRE(s.track.iterations[1] <= 1);
      REQUIRE(s.track.iterations[2] <= 2);
    }
    any_fusion_hit = any_fusion_hit || s.integration.budget_hit;
    any_raycast_hit = any_raycast_hit || s.raycast.budget_hit();
  }
  REQUIRE(any_fusion_hit);
  REQUIRE(any_raycast_hit);
}

TEST_CASE("bad frames are rejected, counted and leave the map untouched") {
  // Noiseless 1 cm: the setting the tracking test above shows to track, so the frame after the
  // bad ones must track again.
  sim::SimSource source(small_sim(12, /*noise=*/false));
  REQUIRE(source.open().ok());
  const PipelineConfig config = small_config(source, 0.01f, 1);
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  DepthFrame frame;
  FrameStats stats;
  for (int i = 0; i < 4; ++i) {
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    REQUIRE(pipeline.process(frame, &stats).ok());
  }
  const std::uint32_t blocks_before = pipeline.map().memory().blocks_used;
  const Se3d pose_before = pipeline.T_W_C();

  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  DepthFrame wrong_size = frame;
  wrong_size.depth_raw.width = kWidth / 2;
  REQUIRE(pipeline.process(wrong_size, &stats).code() == StatusCode::invalid_argument);
  REQUIRE(stats.result == FrameResult::rejected);

  DepthFrame bad_pose = frame;
  bad_pose.T_W_C_ground_truth(0, 0) = std::numeric_limits<double>::quiet_NaN();
  REQUIRE(pipeline.process(bad_pose, &stats).code() == StatusCode::invalid_argument);

  DepthFrame not_rotation = frame;
  not_rotation.T_W_C_ground_truth.topLeftCorner<3, 3>() *= 2.0;
  REQUIRE(pipeline.process(not_rotation, &stats).code() == StatusCode::invalid_argument);

  DepthFrame old_time = frame;
  old_time.timestamp_us = 0;
  REQUIRE(pipeline.process(old_time, &stats).code() == StatusCode::invalid_argument);

  REQUIRE(pipeline.frames_rejected() == 4);
  REQUIRE(pipeline.map().memory().blocks_used == blocks_before);
  REQUIRE(pipeline.T_W_C().matrix() == pose_before.matrix());
  REQUIRE(std::strlen(pipeline.last_error()) > 0);

  // The stream goes on: the good frame the bad copies were made from is tracked.
  REQUIRE(pipeline.process(frame, &stats).ok());
  REQUIRE(stats.result == FrameResult::tracked);

  // A frame with no depth at all is accepted as a frame but neither tracked nor integrated.
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  const std::uint32_t blocks_tracked = pipeline.map().memory().blocks_used;
  std::vector<std::uint16_t> zeros(static_cast<std::size_t>(kWidth) * kHeight, 0);
  DepthFrame empty = frame;
  empty.depth_raw = ImageView<const std::uint16_t>(zeros.data(), kWidth, kHeight);
  REQUIRE(pipeline.process(empty, &stats).code() == StatusCode::data_loss);
  REQUIRE(stats.result == FrameResult::nearly_empty);
  REQUIRE(pipeline.map().memory().blocks_used == blocks_tracked);
}

}  // namespace
}  // namespace octofuse
