// Free space in a long run: a full node pool forgets the far free space and keeps carving near
// the camera, without allocating.

#include <catch2/catch.hpp>

#include "system/pose_prior_support.hpp"

namespace octofuse {
namespace {

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

}  // namespace
}  // namespace octofuse
