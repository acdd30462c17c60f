// Queries while mapping: a planner thread asks points and boxes while Pipeline::process runs on
// the main thread. Every answer must equal the answer a serial run gives after the frame the
// answer says it reflects (PointAnswer::map_version): never a torn, half-integrated map. Built and
// run under ThreadSanitizer by the `tsan` preset, which also proves the guard orders every access.

#include <atomic>
#include <cstdlib>
#include <thread>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/small_sim.hpp"

namespace octofuse {
namespace {

constexpr int kFrames = 16;

using octofuse::test::Buffer;

PipelineConfig config_for(const sim::SimSource& source) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  PipelineConfig config =
      default_pipeline_config(source.intrinsics(), 0.04f, 8, 20000,
                              (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>());
  config.preprocess.downsample_factor = 1;
  config.pose_source = PoseSource::ground_truth;
  config.initial_T_W_C = T_W_C0;
  return config;
}

// Probe points on a line through the view, and probe boxes along it.
std::vector<Eigen::Vector3f> probes(const sim::SimSource& source) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 48; ++i) {
    const double along = 0.2 + 0.06 * i;
    const Eigen::Vector3d p = T_W_C0 * Eigen::Vector3d(0.1 * std::sin(i), 0.05 * i - 1.2, along);
    points.push_back(p.cast<float>());
  }
  return points;
}

struct Answer {
  std::uint64_t version = 0;
  int probe = 0;
  bool is_box = false;
  int state = 0;
  float distance_m = 0.0f;
};

Answer ask(const MapQuery<MultiresVoxel>& query, const std::vector<Eigen::Vector3f>& points,
           int probe, bool is_box) {
  Answer a;
  a.probe = probe;
  a.is_box = is_box;
  const Eigen::Vector3f& p = points[static_cast<std::size_t>(probe)];
  if (is_box) {
    const Result<RegionAnswer> r =
        query.box(p - Eigen::Vector3f::Constant(0.15f), p + Eigen::Vector3f::Constant(0.15f));
    a.version = r.value().map_version;
    a.state = static_cast<int>(r.value().state);
  } else {
    const Result<PointAnswer> r = query.point(p);
    a.version = r.value().map_version;
    a.state = static_cast<int>(r.value().state);
    a.distance_m = r.value().distance_m;
  }
  return a;
}

TEST_CASE("queries from another thread see the map after whole frames only") {
  sim::SimSource probe_source(test::small_sim(kFrames, /*noise=*/false));
  REQUIRE(probe_source.open().ok());
  const PipelineConfig config = config_for(probe_source);
  const std::vector<Eigen::Vector3f> points = probes(probe_source);
  const int count = static_cast<int>(points.size());

  // Serial reference: every probe's answer after each frame (version v = v frames fused).
  std::vector<std::vector<Answer>> expected;
  {
    sim::SimSource source(test::small_sim(kFrames, /*noise=*/false));
    REQUIRE(source.open().ok());
    Buffer buffer(bytes_required(config));
    Pipeline<MultiresVoxel> pipeline;
    REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
    auto record = [&]() {
      std::vector<Answer> row;
      for (int i = 0; i < count; ++i) {
        row.push_back(ask(pipeline.query(), points, i, false));
        row.push_back(ask(pipeline.query(), points, i, true));
      }
      expected.push_back(row);
    };
    record();
    DepthFrame frame;
    while (source.next(frame).outcome == FrameOutcome::frame) {
      FrameStats stats;
      REQUIRE(pipeline.process(frame, &stats).ok());
      record();
    }
  }
  REQUIRE(expected.size() == kFrames + 1);
  // The answers change as the map grows: the comparison can tell versions apart.
  int changed = 0;
  for (std::size_t i = 0; i < expected[0].size(); ++i) {
    if (expected[0][i].state != expected.back()[i].state) ++changed;
  }
  REQUIRE(changed > 10);

  // Concurrent run: the planner asks round-robin until the mapper is done.
  sim::SimSource source(test::small_sim(kFrames, /*noise=*/false));
  REQUIRE(source.open().ok());
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  std::atomic<bool> done{false};
  // At most kPerVersion answers kept per map version, so a slow first frame cannot fill the
  // record with answers from the empty map.
  constexpr std::size_t kPerVersion = 2048;
  std::vector<Answer> seen;
  seen.reserve((kFrames + 1) * kPerVersion);
  std::thread planner([&]() {
    const MapQuery<MultiresVoxel> query = pipeline.query();
    std::vector<std::size_t> kept(kFrames + 1, 0);
    int next = 0;
    while (!done.load(std::memory_order_acquire)) {
      const Answer a = ask(query, points, next % count, (next / count) % 2 == 1);
      ++next;
      if (a.version > static_cast<std::uint64_t>(kFrames)) {
        seen.push_back(a);  // out of range: recorded so the check below fails
        break;
      }
      if (kept[a.version] < kPerVersion) {
        ++kept[a.version];
        seen.push_back(a);
      }
    }
  });
  DepthFrame frame;
  int processed = 0;
  while (source.next(frame).outcome == FrameOutcome::frame) {
    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    if (!status.ok()) break;
    ++processed;
  }
  done.store(true, std::memory_order_release);
  planner.join();
  REQUIRE(processed == kFrames);

  REQUIRE(seen.size() > 0);
  std::uint64_t highest = 0;
  for (const Answer& a : seen) {
    REQUIRE(a.version <= static_cast<std::uint64_t>(kFrames));
    const Answer& want =
        expected[a.version][static_cast<std::size_t>(2 * a.probe + (a.is_box ? 1 : 0))];
    REQUIRE(a.state == want.state);
    REQUIRE(a.distance_m == want.distance_m);
    highest = std::max(highest, a.version);
  }
  // The planner did run while mapping went on.
  REQUIRE(highest > 0);
}

}  // namespace
}  // namespace octofuse
