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
  PipelineConfig config = small_config(truth, 0.01f, 1);
  config.budget.raycast_half = false;  // every pixel; the default half is the test below
  std::vector<FrameStats> stats;
  const std::vector<Se3d> poses = run<MultiresVoxel>(sim_config, config, &stats);
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
  REQUIRE(config.budget.raycast_half);  // the default
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

TEST_CASE("the view cast shows every pixel and leaves the reference and the tracking as they are") {
  // The noiseless sim at 1 cm, which the test above shows to track at half resolution.
  const sim::SimConfig sim_config = small_sim(30, /*noise=*/false);
  sim::SimSource source(sim_config);
  REQUIRE(source.open().ok());
  PipelineConfig config = small_config(source, 0.01f, 2);
  REQUIRE(config.budget.raycast_half);
  config.view_cast = true;
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  // An independent cast at every pixel of the same map from the same pose, guided by the same
  // depth, called as often (a guided cast's skipped misses depend on the one before).
  RaycastConfig full;
  full.width = pipeline.working_camera().width;
  full.height = pipeline.working_camera().height;
  full.near_m = config.validator.near_m;
  full.far_m = config.validator.far_m;
  full.mu_m = config.fusion.mu_m;
  const std::size_t cast_bytes = Raycaster<MultiresVoxel>::bytes_required(full);
  Buffer cast_buffer(cast_bytes);
  LinearArena cast_arena(cast_buffer.data, cast_bytes);
  Raycaster<MultiresVoxel> expected;
  REQUIRE(expected.reserve(cast_arena, full).ok());
  auto same = [](const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
    return std::memcmp(a.data(), b.data(), sizeof(Eigen::Vector3f)) == 0;
  };
  std::vector<Se3d> poses;
  DepthFrame frame;
  int odd_pixels_differing = 0;
  while (source.next(frame).outcome == FrameOutcome::frame) {
    FrameStats stats;
    REQUIRE(pipeline.process(frame, &stats).ok());
    poses.push_back(pipeline.T_W_C());
    const ConstSurfaceMap reference = pipeline.surface_W();
    REQUIRE(reference.pixel_stride == 2);
    std::vector<Eigen::Vector3f> reference_before;
    for (int y = 0; y < full.height; ++y) {
      for (int x = 0; x < full.width; ++x) reference_before.push_back(reference.vertices(x, y));
    }
    REQUIRE(pipeline.cast_view().ok());
    const ConstSurfaceMap view = pipeline.view_surface_W();
    REQUIRE(&view.vertices(0, 0) != &reference.vertices(0, 0));
    REQUIRE(view.pixel_stride == 1);
    REQUIRE(stats.result != FrameResult::lost);
    REQUIRE_FALSE(pipeline.reference_guide_depth_m().empty());
    REQUIRE(expected
                .raycast(pipeline.map(), pipeline.working_camera(), pipeline.reference_T_W_C(),
                         pipeline.team(), pipeline.reference_guide_depth_m())
                .ok());
    const SurfaceMap want = expected.surface_W();
    for (int y = 0; y < full.height; ++y) {
      for (int x = 0; x < full.width; ++x) {
        CAPTURE(x, y);
        // Bit for bit what a cast at every pixel gives.
        REQUIRE(view.valid(x, y) == want.valid(x, y));
        REQUIRE(same(view.normals(x, y), want.normals(x, y)));
        if (want.valid(x, y)) REQUIRE(same(view.vertices(x, y), want.vertices(x, y)));
        // The reference is as the frame left it.
        REQUIRE(same(reference.vertices(x, y),
                     reference_before[static_cast<std::size_t>(y * full.width + x)]));
        if (((x | y) & 1) != 0 && view.valid(x, y) && reference.valid(x, y) &&
            !same(view.vertices(x, y), reference.vertices(x, y))) {
          ++odd_pixels_differing;
        }
      }
    }
  }
  REQUIRE(poses.size() == 30);
  // The view is not the reference's copies: pixels between marched ones are cast themselves.
  REQUIRE(odd_pixels_differing > 1000);
  // Casting views between frames changes nothing the pipeline computes.
  REQUIRE(bit_identical(poses, run<MultiresVoxel>(sim_config, config)));
  // Without a view cast reserved, the view is the reference cast.
  PipelineConfig plain = config;
  plain.view_cast = false;
  REQUIRE(bytes_required(plain) < bytes_required(config));
  Buffer plain_buffer(bytes_required(plain));
  Pipeline<MultiresVoxel> without;
  REQUIRE(without.init(plain_buffer.data, bytes_required(plain), plain).ok());
  sim::SimSource again(sim_config);
  REQUIRE(again.open().ok());
  REQUIRE(again.next(frame).outcome == FrameOutcome::frame);
  FrameStats first;
  REQUIRE(without.process(frame, &first).ok());
  REQUIRE(without.cast_view().ok());
  REQUIRE(&without.view_surface_W().vertices(0, 0) == &without.surface_W().vertices(0, 0));
  // A frame that does not cast the reference (rejected here) leaves no guide for the view.
  DepthFrame empty_frame = frame;
  empty_frame.depth_raw = ImageView<const std::uint16_t>();
  FrameStats rejected;
  REQUIRE_FALSE(pipeline.process(empty_frame, &rejected).ok());
  REQUIRE(pipeline.reference_guide_depth_m().empty());
  REQUIRE(pipeline.cast_view().ok());
  REQUIRE(&pipeline.view_surface_W().vertices(0, 0) != &pipeline.surface_W().vertices(0, 0));
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
