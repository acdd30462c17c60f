// Bounded memory over a scene larger than the pools: eviction keeps tracking, gives the farthest
// blocks' mid levels back, and stays within its per-frame budget.

#include "octofuse/pipeline/pipeline.hpp"

#include <catch2/catch.hpp>
#include <limits>

#include "system/pipeline_support.hpp"

namespace octofuse {
namespace {

struct EvictionRun {
  std::vector<Se3d> poses;
  std::vector<FrameStats> stats;
  std::vector<Eigen::Vector3i> final_blocks;  // the pool's block coordinates, in pool order
  std::uint64_t allocations = 0;              // heap allocations while processing frames
  std::uint32_t final_mid_less_fine = 0;      // blocks at scale 0 or 1 without a mid level
};

EvictionRun run_evicting(const sim::SimConfig& sim_config, const PipelineConfig& config) {
  EvictionRun out;
  sim::SimSource source(sim_config);
  REQUIRE(source.open().ok());
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  out.poses.reserve(static_cast<std::size_t>(sim_config.frame_count));
  out.stats.reserve(static_cast<std::size_t>(sim_config.frame_count));
  DepthFrame frame;
  {
    test::AllocationScope scope;
    while (source.next(frame).outcome == FrameOutcome::frame) {
      FrameStats stats;
      const Status status = pipeline.process(frame, &stats);
      REQUIRE((status.ok() || status.code() == StatusCode::resource_exhausted ||
               stats.result == FrameResult::lost));
      out.poses.push_back(pipeline.T_W_C());
      out.stats.push_back(stats);
    }
    out.allocations = scope.allocations();
  }
  for (std::uint32_t i = 0; i < pipeline.map().block_count(); ++i) {
    const VoxelBlock<MultiresVoxel>& block = pipeline.map().block(i);
    out.final_blocks.push_back(block.coords);
    if (!block.has_mid() && block.integrated() && block.current_scale < 2) {
      ++out.final_mid_less_fine;
    }
  }
  return out;
}

// sim:room: one orbit inside a 6 x 5 m room looking outwards, so the walls behind the camera
// leave the view and come back; 2 cm voxels. Noiseless: at this small image and 2-3 m range the
// noisy depth puts ICP's residual at its 2 cm gate, and chance would decide which frames are lost.
sim::SimConfig room_sim(int frames) {
  sim::SimConfig config = small_sim(frames, /*noise=*/false);
  config.scene = sim::SceneId::room;
  return config;
}
constexpr float kRoomVoxel_m = 0.02f;

double rms_error_m(const std::vector<Se3d>& poses, const sim::SimSource& truth) {
  double sum = 0.0;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    sum += (poses[i].translation() - truth.ground_truth_T_W_C(static_cast<int>(i)).translation())
               .squaredNorm();
  }
  return std::sqrt(sum / static_cast<double>(poses.size()));
}

// [long]: three 400-frame runs; the cross and sanitizer presets skip it (see
// test/CMakeLists.txt), where the eviction unit tests (test/unit/map) still run.
TEST_CASE("a pool far smaller than the scene evicts instead of losing tracking, allocation-free",
          "[long]") {
  constexpr int kFrames = 400;
  const sim::SimConfig sim_config = room_sim(kFrames);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  // The unbounded run: how many blocks the whole scene takes, and the most one frame touches.
  std::vector<FrameStats> unbounded;
  const std::vector<Se3d> unbounded_poses =
      run<MultiresVoxel>(sim_config, small_config(truth, kRoomVoxel_m, 1), &unbounded);
  const std::uint32_t scene_blocks = unbounded.back().memory.blocks_used;
  std::uint32_t view_blocks = 0;
  for (const FrameStats& s : unbounded) {
    view_blocks = std::max(view_blocks, s.integration.blocks_integrated);
  }
  // Room for 1.28 views below the low-water mark, well short of the scene.
  const std::uint32_t capacity = view_blocks * 8 / 5;
  INFO("scene " << scene_blocks << " blocks, largest view " << view_blocks);
  REQUIRE(capacity < scene_blocks * 2 / 3);

  PipelineConfig config = small_config(truth, kRoomVoxel_m, 1, capacity);
  config.eviction.enabled = true;
  const EvictionRun one = run_evicting(sim_config, config);
  REQUIRE(one.allocations == 0);
  REQUIRE(one.poses.size() == static_cast<std::size_t>(kFrames));
  std::uint64_t evicted = 0;
  std::uint64_t refusals = 0;
  for (std::size_t i = 0; i < one.stats.size(); ++i) {
    const FrameStats& s = one.stats[i];
    CAPTURE(i);
    // No frame lost that the unbounded map kept.
    REQUIRE((s.result != FrameResult::lost || unbounded[i].result == FrameResult::lost));
    REQUIRE(s.memory.blocks_used <= capacity);
    // After eviction the pool is at or below its low-water mark before this frame allocates.
    if (s.eviction.triggered) {
      REQUIRE_FALSE(s.eviction.budget_hit);
      REQUIRE(s.memory.blocks_used - s.integration.blocks_allocated <= capacity * 8 / 10);
    }
    evicted += s.eviction.evicted;
    refusals += s.integration.pool_refusals;
  }
  REQUIRE(evicted >= scene_blocks - capacity);  // the scene did not fit: blocks were evicted
  REQUIRE(one.stats.back().memory.evicted == evicted);
  REQUIRE(refusals == 0);
  // As accurate as the unbounded run, within 15 % (and a millimetre).
  const double error_m = rms_error_m(one.poses, truth);
  const double unbounded_error_m = rms_error_m(unbounded_poses, truth);
  INFO("RMS error " << error_m << " m, unbounded " << unbounded_error_m << " m");
  REQUIRE(error_m <= 1.15 * unbounded_error_m + 0.001);

  // The same with two workers: the same trajectory, evictions and pool, bit for bit.
  config.workers = 2;
  const EvictionRun two = run_evicting(sim_config, config);
  REQUIRE(bit_identical(one.poses, two.poses));
  REQUIRE(one.final_blocks == two.final_blocks);
  for (std::size_t i = 0; i < one.stats.size(); ++i) {
    REQUIRE(one.stats[i].eviction.evicted == two.stats[i].eviction.evicted);
  }
}

TEST_CASE("a mid-level pool short of the scene gives the farthest blocks' mid levels back") {
  const sim::SimConfig sim_config = room_sim(200);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  std::vector<FrameStats> unbounded;
  const std::vector<Se3d> unbounded_poses =
      run<MultiresVoxel>(sim_config, small_config(truth, kRoomVoxel_m, 1), &unbounded);
  std::uint32_t view_mid = 0;  // most blocks one frame integrated at scale 1 or 0
  for (const FrameStats& s : unbounded) {
    view_mid =
        std::max(view_mid, s.integration.blocks_per_scale[0] + s.integration.blocks_per_scale[1]);
  }
  const std::uint32_t scene_mid = unbounded.back().memory.mid_used;
  const std::uint32_t capacity = view_mid * 8 / 5;
  INFO("scene " << scene_mid << " mid levels, largest view " << view_mid);
  REQUIRE(capacity < scene_mid * 2 / 3);

  PipelineConfig config = small_config(truth, kRoomVoxel_m, 1);
  config.map.mid_capacity = capacity;
  config.eviction.enabled = true;
  const EvictionRun one = run_evicting(sim_config, config);
  REQUIRE(one.allocations == 0);
  std::uint64_t demoted_mid = 0;
  for (std::size_t i = 0; i < one.stats.size(); ++i) {
    const FrameStats& s = one.stats[i];
    CAPTURE(i);
    REQUIRE((s.result != FrameResult::lost || unbounded[i].result == FrameResult::lost));
    REQUIRE(s.memory.mid_used <= capacity);
    REQUIRE(s.eviction.evicted == 0);  // the block pool holds the scene
    REQUIRE(s.eviction.demoted_mid <= s.eviction.demoted);
    REQUIRE(s.integration.pool_refusals ==
            s.integration.mid_refusals + s.integration.finest_refusals);
    demoted_mid += s.eviction.demoted_mid;
  }
  REQUIRE(demoted_mid >= scene_mid - capacity);
  REQUIRE(one.final_mid_less_fine == 0u);  // every block without a mid level is at scale 2 or 3
  const double error_m = rms_error_m(one.poses, truth);
  const double unbounded_error_m = rms_error_m(unbounded_poses, truth);
  INFO("RMS error " << error_m << " m, unbounded " << unbounded_error_m << " m");
  REQUIRE(error_m <= 1.15 * unbounded_error_m + 0.001);

  config.workers = 2;
  const EvictionRun two = run_evicting(sim_config, config);
  REQUIRE(bit_identical(one.poses, two.poses));
  for (std::size_t i = 0; i < one.stats.size(); ++i) {
    REQUIRE(one.stats[i].eviction.demoted_mid == two.stats[i].eviction.demoted_mid);
    REQUIRE(one.stats[i].memory.mid_used == two.stats[i].memory.mid_used);
  }
}

TEST_CASE("the eviction budget bounds each frame's evictions and says so") {
  const sim::SimConfig sim_config = room_sim(200);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  std::vector<FrameStats> unbounded;
  run<MultiresVoxel>(sim_config, small_config(truth, kRoomVoxel_m, 1), &unbounded);
  std::uint32_t view_blocks = 0;
  for (const FrameStats& s : unbounded) {
    view_blocks = std::max(view_blocks, s.integration.blocks_integrated);
  }
  PipelineConfig config = small_config(truth, kRoomVoxel_m, 1, view_blocks * 8 / 5);
  config.eviction.enabled = true;
  config.budget.max_evictions = 3;
  const EvictionRun run = run_evicting(sim_config, config);
  bool hit = false;
  for (const FrameStats& s : run.stats) {
    REQUIRE(s.eviction.evicted <= 3u);
    if (s.eviction.budget_hit) {
      hit = true;
      REQUIRE(s.eviction.evicted == 3u);
      REQUIRE(s.any_budget_hit());
    }
  }
  REQUIRE(hit);

  PipelineConfig bad = config;
  bad.eviction.low_water = 0.95f;  // above the high-water mark
  CHECK(bytes_required(bad) == 0u);
  bad = config;
  bad.budget.max_evictions = 0;
  CHECK(bytes_required(bad) == 0u);
  for (const float share : {-0.01f, 1.01f, std::numeric_limits<float>::quiet_NaN()}) {
    bad = config;
    bad.budget.store_read_share_integration = share;
    CHECK(bytes_required(bad) == 0u);
  }
  for (const float share : {0.0f, 1.0f}) {
    bad = config;
    bad.budget.store_read_share_integration = share;
    CHECK(bytes_required(bad) > 0u);
  }
}

}  // namespace
}  // namespace octofuse
