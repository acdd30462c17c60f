// reset() forgets the map and starts over; set_pose() relocalises before the first frame and
// after a jump in the stream.

#include <catch2/catch.hpp>

#include "system/pose_prior_support.hpp"

namespace octofuse {
namespace {

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

}  // namespace
}  // namespace octofuse
