// Distance queries while mapping: a planner thread asks the distance field while Pipeline::process
// runs on the main thread and the field's rebuilds publish every few frames. Every answer must
// equal what a serial run's field gave for the map version the answer says it is from: never a
// half-built field. Run under ThreadSanitizer by the `tsan` preset.

#include <atomic>
#include <map>
#include <thread>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/small_sim.hpp"

namespace octofuse {
namespace {

constexpr int kFrames = 12;

PipelineConfig esdf_config_for(const sim::SimSource& source) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  const Eigen::Vector3f ahead = (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>();
  PipelineConfig config = default_pipeline_config(source.intrinsics(), 0.04f, 8, 20000, ahead);
  config.preprocess.downsample_factor = 1;
  config.pose_source = PoseSource::ground_truth;
  config.initial_T_W_C = T_W_C0;
  config.esdf.enabled = true;
  config.esdf.cells_per_side = 32;
  config.esdf.cell_voxels = 2;
  config.esdf.centre_W = ahead;
  config.esdf.max_cell_steps = 40000;  // a rebuild (3 x 32^3) over 3 frames
  return config;
}

std::vector<Eigen::Vector3f> probes(const sim::SimSource& source) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 32; ++i) {
    const Eigen::Vector3d p =
        T_W_C0 * Eigen::Vector3d(0.1 * std::sin(i), 0.05 * i - 0.8, 0.4 + 0.05 * i);
    points.push_back(p.cast<float>());
  }
  return points;
}

using Answers = std::map<std::uint64_t, std::vector<float>>;  // map version -> distance per probe

TEST_CASE("distance queries from another thread see whole fields only") {
  sim::SimSource serial_source(test::small_sim(kFrames));
  REQUIRE(serial_source.open().ok());
  const PipelineConfig config = esdf_config_for(serial_source);
  const std::vector<Eigen::Vector3f> points = probes(serial_source);

  // Serial: the field's answers for every version it published.
  Answers expected;
  {
    test::Buffer buffer(bytes_required(config));
    Pipeline<MultiresVoxel> pipeline;
    REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
    DepthFrame frame;
    while (serial_source.next(frame).outcome == FrameOutcome::frame) {
      REQUIRE(pipeline.process(frame, nullptr).ok());
      std::vector<EsdfAnswer> out(points.size());
      REQUIRE(pipeline.esdf().distances(points.data(), points.size(), out.data()).ok());
      std::vector<float>& d = expected[out[0].map_version];
      d.clear();
      for (const EsdfAnswer& a : out) d.push_back(a.has_distance ? a.distance_m : -1.0f);
    }
  }
  REQUIRE(expected.size() >= 3);

  sim::SimSource source(test::small_sim(kFrames));
  REQUIRE(source.open().ok());
  test::Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  std::atomic<bool> done{false};
  Answers seen;
  long asked = 0;
  std::thread planner([&]() {
    std::vector<EsdfAnswer> out(points.size());
    while (!done.load(std::memory_order_acquire)) {
      if (!pipeline.esdf().distances(points.data(), points.size(), out.data()).ok()) continue;
      std::vector<float>& d = seen[out[0].map_version];
      d.clear();
      for (const EsdfAnswer& a : out) d.push_back(a.has_distance ? a.distance_m : -1.0f);
      ++asked;
    }
  });
  DepthFrame frame;
  while (source.next(frame).outcome == FrameOutcome::frame) {
    REQUIRE(pipeline.process(frame, nullptr).ok());
  }
  done.store(true, std::memory_order_release);
  planner.join();
  REQUIRE(asked > 0);
  for (const auto& [version, distances] : seen) {
    CAPTURE(version);
    REQUIRE(expected.count(version) == 1);
    REQUIRE(distances == expected.at(version));
  }
}

}  // namespace
}  // namespace octofuse
