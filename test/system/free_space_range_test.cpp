// Free space from pixels the sensor measured beyond the depth range, through the whole pipeline:
// the validator marks them, the pipeline halves the mask to the working resolution, carving takes
// each as its ray seen free out to the range's end. The camera looks along +z at a wall 1.5 m
// away on its left half and 3 m away (beyond a 2 m range) on its right half; the same frames
// with the far half turned into "no return" (raw 0) carve nothing in front of it.

#include <catch2/catch.hpp>
#include <cstdint>
#include <vector>

#include "octofuse/pipeline/pipeline.hpp"
#include "support/aligned_buffer.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

using octofuse::test::Buffer;

constexpr int kWidth = 160;
constexpr int kHeight = 120;
constexpr float kVoxel_m = 0.02f;
constexpr float kFar_m = 2.0f;

PinholeCamera camera() {
  return test::centred_camera(kWidth, kHeight, 131.25f);
}

struct Answers {
  PointState near_half = PointState::outside;  // in front of the 1.5 m wall
  std::vector<PointState> far_half;            // in front of the 3 m wall, 1.0 to 1.8 m deep
  std::uint64_t beyond_pixels = 0;
};

Answers run(bool far_half_no_return) {
  PipelineConfig config =
      default_pipeline_config(camera(), kVoxel_m, 9, 20000, Eigen::Vector3f(0.0f, 0.0f, 1.5f));
  config.pose_source = PoseSource::ground_truth;
  config.validator.far_m = kFar_m;
  config.fusion.far_m = kFar_m;
  REQUIRE(config.preprocess.downsample_factor == 2);
  const std::size_t bytes = bytes_required(config);
  REQUIRE(bytes > 0);
  Buffer buffer(bytes);
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes, config).ok());

  // Millimetres; the far half's wall at 3 m, or no measurement there.
  std::vector<std::uint16_t> raw(static_cast<std::size_t>(kWidth * kHeight));
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      raw[static_cast<std::size_t>(y * kWidth + x)] =
          x < kWidth / 2 ? 1500 : (far_half_no_return ? 0 : 3000);
    }
  }
  Answers out;
  for (int i = 0; i < 3; ++i) {
    DepthFrame frame;
    frame.depth_raw = ImageView<const std::uint16_t>(raw.data(), kWidth, kHeight);
    frame.metres_per_unit = 0.001f;
    frame.timestamp_us = 1000 + 33333 * i;
    frame.sequence = static_cast<std::uint64_t>(i);
    frame.has_ground_truth = true;
    FrameStats stats;
    REQUIRE(pipeline.process(frame, &stats).ok());
    out.beyond_pixels += stats.input.beyond_far_pixels;
  }
  const MapQuery<MultiresVoxel> query = pipeline.query();
  out.near_half = query.point(Eigen::Vector3f(-0.4f, 0.0f, 1.0f)).value().state;
  for (float z = 1.0f; z <= 1.8f; z += 0.1f) {
    out.far_half.push_back(query.point(Eigen::Vector3f(0.4f, 0.0f, z)).value().state);
  }
  // Nothing at or past the range's end less the clearance (mu / 2) is free.
  for (float z = 2.0f - 0.5f * config.fusion.mu_m; z <= 3.2f; z += 0.02f) {
    REQUIRE(query.point(Eigen::Vector3f(0.4f, 0.0f, z)).value().state != PointState::free);
  }
  return out;
}

TEST_CASE("pixels measured beyond the range carve the air in front of it through the pipeline") {
  const Answers measured = run(false);
  REQUIRE(measured.beyond_pixels == 3u * (kWidth / 2) * kHeight);
  REQUIRE(measured.near_half == PointState::free);
  for (const PointState state : measured.far_half) REQUIRE(state == PointState::free);

  const Answers no_return = run(true);
  REQUIRE(no_return.beyond_pixels == 0);
  REQUIRE(no_return.near_half == PointState::free);
  for (const PointState state : no_return.far_half) REQUIRE(state == PointState::unknown);
}

}  // namespace
}  // namespace octofuse
