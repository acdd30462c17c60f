// Pipeline set-up: bytes_required is exact, and init refuses what does not fit together.

#include "octofuse/pipeline/pipeline.hpp"

#include <catch2/catch.hpp>

#include "system/pipeline_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("bytes_required is exact: init fits in it and not in one byte less") {
  sim::SimSource source(small_sim(2));
  REQUIRE(source.open().ok());
  const PipelineConfig config = small_config(source, 0.02f, 1);
  const std::size_t bytes = bytes_required(config);
  REQUIRE(bytes > 0);
  Buffer buffer(bytes);
  Pipeline<MultiresVoxel> exact;
  REQUIRE(exact.init(buffer.data, bytes, config).ok());
  REQUIRE(exact.bytes_used() == bytes);
  Pipeline<MultiresVoxel> short_one;
  REQUIRE(short_one.init(buffer.data, bytes - 1, config).code() == StatusCode::resource_exhausted);
}

TEST_CASE("init rejects a map kind that does not match the voxel type and bad configs") {
  sim::SimSource source(small_sim(2));
  REQUIRE(source.open().ok());
  PipelineConfig config = small_config(source, 0.02f, 1);
  Buffer buffer(bytes_required(config));
  config.map_kind = MapKind::single_res;
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).code() ==
          StatusCode::invalid_argument);
  Pipeline<Multires16Voxel> compact;
  REQUIRE(compact.init(buffer.data, bytes_required(config), config).code() ==
          StatusCode::invalid_argument);
  // The 16-bit weights end at 1023.98: a larger cap is refused for that map only.
  config.fusion.y_max = 2000.0f;
  config.map_kind = MapKind::multires16;
  REQUIRE(bytes_required(config) == 0);
  config.map_kind = MapKind::multires;
  REQUIRE(bytes_required(config) > 0);
  config.fusion.y_max = 100.0f;
  config.workers = 0;
  REQUIRE(bytes_required(config) == 0);
  REQUIRE(pipeline.init(buffer.data, 1 << 20, config).code() == StatusCode::invalid_argument);
  DepthFrame frame;
  FrameStats stats;
  REQUIRE(pipeline.process(frame, &stats).code() == StatusCode::failed_precondition);
}

TEST_CASE("init rejects an ICP budget of no iteration when tracking") {
  sim::SimSource source(small_sim(2));
  REQUIRE(source.open().ok());
  PipelineConfig config = small_config(source, 0.02f, 1);
  Buffer buffer(bytes_required(config));
  for (int& iterations : config.budget.icp_iterations) iterations = 0;
  Pipeline<MultiresVoxel> pipeline;
  CHECK(pipeline.init(buffer.data, bytes_required(config), config).code() ==
        StatusCode::invalid_argument);
  config.pose_source = PoseSource::ground_truth;  // ICP unused: no iteration is fine
  CHECK(pipeline.init(buffer.data, bytes_required(config), config).ok());
  config.pose_source = PoseSource::track;
  config.budget.icp_iterations[2] = 1;
  CHECK(pipeline.init(buffer.data, bytes_required(config), config).ok());
}

}  // namespace
}  // namespace octofuse
