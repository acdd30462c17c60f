// A finest-level pool smaller than one view, with a finest-level store (set_finest_store()): each
// finest level given up for room goes to the store as the block's record, and a block about to
// fuse at scale 0 again takes its level back from it instead of an interpolated one, so the
// finest levels in memory stay closer to an unbounded run's than without the store. The same
// records for any worker count.

#include "octofuse/pipeline/pipeline.hpp"

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <vector>

#include "support/memory_store.hpp"
#include "system/pipeline_support.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.01f;

struct FinestRun {
  std::vector<FrameStats> stats;
  // Blocks that gave their finest level up (integrated at scale 0 once, none now) and of those
  // the ones whose store record holds a finest level.
  std::size_t given_up = 0;
  std::size_t given_up_stored = 0;
  // Per block key, the final finest level (blocks that hold one).
  std::vector<std::pair<std::uint64_t, std::vector<MultiresVoxel>>> finest;
};

// A multires pipeline on the sim, with a finest-level store when one is given.
struct SimPipeline {
  SimPipeline(const sim::SimConfig& sim_config, const PipelineConfig& config,
              MemoryStore* finest_store)
      : source(sim_config), buffer(bytes_required(config)) {
    REQUIRE(source.open().ok());
    REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
    if (finest_store != nullptr) REQUIRE(pipeline.set_finest_store(finest_store).ok());
  }
  sim::SimSource source;
  Buffer buffer;
  Pipeline<MultiresVoxel> pipeline;
};

FinestRun run_finest(const sim::SimConfig& sim_config, const PipelineConfig& config,
                     MemoryStore* finest_store) {
  FinestRun out;
  SimPipeline sim(sim_config, config, finest_store);
  Pipeline<MultiresVoxel>& pipeline = sim.pipeline;
  DepthFrame frame;
  while (sim.source.next(frame).outcome == FrameOutcome::frame) {
    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    REQUIRE((status.ok() || status.code() == StatusCode::resource_exhausted));
    out.stats.push_back(stats);
  }
  const Octree<MultiresVoxel>& map = pipeline.map();
  for (std::uint32_t i = 0; i < map.block_count(); ++i) {
    const VoxelBlock<MultiresVoxel>& block = map.block(i);
    const std::uint64_t key = morton_encode(block.coords);
    if (block.has_finest()) {
      std::vector<MultiresVoxel> finest(kBlockFinestVoxelCount);
      for (int k = 0; k < kBlockFinestVoxelCount; ++k) finest[k] = block.voxel(k);
      out.finest.emplace_back(key, std::move(finest));
    } else if (block.min_scale == 0) {
      ++out.given_up;
      const std::vector<std::uint8_t>* record =
          finest_store != nullptr ? finest_store->record(key) : nullptr;
      if (record != nullptr &&
          block_record_holds_finest<MultiresVoxel>(record->data(), record->size())) {
        ++out.given_up_stored;
      }
    }
  }
  std::sort(out.finest.begin(), out.finest.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  return out;
}

// Mean |TSDF difference| over the finest voxels observed in both, of the blocks both hold that
// gave their finest level up at least once (those `store` has a record of).
double finest_difference(const FinestRun& a, const FinestRun& reference, const MemoryStore& store,
                         std::size_t* voxels) {
  double sum = 0.0;
  *voxels = 0;
  auto r = reference.finest.begin();
  for (const auto& [key, levels] : a.finest) {
    if (store.record(key) == nullptr) continue;
    while (r != reference.finest.end() && r->first < key) ++r;
    if (r == reference.finest.end() || r->first != key) continue;
    for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
      const MultiresVoxel& x = levels[static_cast<std::size_t>(i)];
      const MultiresVoxel& y = r->second[static_cast<std::size_t>(i)];
      if (!voxel_observed(x) || !voxel_observed(y)) continue;
      sum += std::fabs(static_cast<double>(x.x) - static_cast<double>(y.x));
      ++*voxels;
    }
  }
  return *voxels > 0 ? sum / static_cast<double>(*voxels) : 0.0;
}

TEST_CASE("finest levels given up for room go to the store and come back from it", "[store]") {
  const sim::SimConfig sim_config = small_sim(60, /*noise=*/true);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  PipelineConfig config = small_config(truth, kVoxel_m, 1);
  config.pose_source = PoseSource::ground_truth;
  const FinestRun unbounded = run_finest(sim_config, config, nullptr);
  std::uint32_t view_finest = 0;  // most blocks one frame fused at scale 0
  for (const FrameStats& s : unbounded.stats) {
    view_finest = std::max(view_finest, s.integration.blocks_per_scale[0]);
  }
  INFO("largest view " << view_finest << " finest levels, scene "
                       << unbounded.stats.back().memory.finest_used);
  REQUIRE(view_finest > 100);

  config.map.finest_capacity = view_finest * 3 / 5;
  config.eviction.enabled = true;
  config.budget.max_store_reads = 64;
  const FinestRun forgetting = run_finest(sim_config, config, nullptr);
  MemoryStore store;
  const FinestRun stored = run_finest(sim_config, config, &store);

  std::uint64_t written = 0, read = 0, waiting = 0, demoted = 0;
  for (std::size_t i = 0; i < stored.stats.size(); ++i) {
    const StoreReport& r = stored.stats[i].store;
    CAPTURE(i);
    REQUIRE(r.finest_write_failed == 0);
    REQUIRE(r.finest_read_failed == 0);
    REQUIRE(r.finest_read <= config.budget.max_store_reads);
    REQUIRE((r.finest_waiting == 0 || r.finest_read == config.budget.max_store_reads));
    REQUIRE(r.finest_written == stored.stats[i].eviction.demoted);  // every demoted block
    // The same demotions as without the store: the store changes what comes back, not the room.
    REQUIRE(stored.stats[i].memory.finest_used <= config.map.finest_capacity);
    written += r.finest_written;
    read += r.finest_read;
    waiting += r.finest_waiting;
    demoted += stored.stats[i].eviction.demoted;
  }
  INFO(written << " finest records written, " << read << " read back, " << waiting
               << " block-frames waited");
  REQUIRE(written > 0);
  REQUIRE(read > 0);
  REQUIRE(store.puts == written);
  // Every block that gave its finest level up has it in the store.
  REQUIRE(stored.given_up > 0);
  REQUIRE(stored.given_up_stored == stored.given_up);

  // The finest levels in memory at the end of the blocks that gave theirs up at some point,
  // against the unbounded run's: closer with the store (levels read back) than without (levels
  // interpolated from scale 1 on their return). The same blocks give their levels up in both
  // runs (the store changes what comes back, not the room).
  std::size_t voxels_forgetting = 0, voxels_stored = 0;
  const double d_forgetting = finest_difference(forgetting, unbounded, store, &voxels_forgetting);
  const double d_stored = finest_difference(stored, unbounded, store, &voxels_stored);
  INFO("mean |x - x_unbounded| " << d_stored << " with the store (" << voxels_stored << " voxels), "
                                 << d_forgetting << " without (" << voxels_forgetting << ")");
  REQUIRE(voxels_stored > 200);
  REQUIRE(voxels_forgetting > 200);
  REQUIRE(d_stored < d_forgetting);

  // The same records for two workers.
  config.workers = 2;
  MemoryStore store_two;
  const FinestRun two = run_finest(sim_config, config, &store_two);
  REQUIRE(store_two.puts == store.puts);
  for (const auto& [key, levels] : stored.finest) {
    (void)levels;
    const std::vector<std::uint8_t>* a = store.record(key);
    const std::vector<std::uint8_t>* b = store_two.record(key);
    REQUIRE((a == nullptr) == (b == nullptr));
    if (a != nullptr) REQUIRE(*a == *b);
  }
  REQUIRE(two.finest.size() == stored.finest.size());
  for (std::size_t i = 0; i < two.finest.size(); ++i) {
    REQUIRE(two.finest[i].first == stored.finest[i].first);
    REQUIRE(std::memcmp(two.finest[i].second.data(), stored.finest[i].second.data(),
                        sizeof(MultiresVoxel) * kBlockFinestVoxelCount) == 0);
  }
}

// Over `frames` frames that all show the sim's first view (ground-truth pose): per block, the
// frames after which it held a finest level and whether it may hold the surface at the end
// (VoxelBlock::may_hold_surface()), and the shortest run of such frames that ended before the
// last frame (a turn given up).
struct OneViewTurns {
  std::vector<std::uint32_t> held;
  std::vector<std::uint8_t> surface;
  std::uint32_t shortest_turn = 0xFFFFFFFFu;
  std::uint32_t turns_given_up = 0;
};

OneViewTurns turns_one_view(const sim::SimConfig& sim_config, const PipelineConfig& config,
                            int frames, MemoryStore* finest_store) {
  SimPipeline sim(sim_config, config, finest_store);
  Pipeline<MultiresVoxel>& pipeline = sim.pipeline;
  DepthFrame frame;
  REQUIRE(sim.source.next(frame).outcome == FrameOutcome::frame);
  OneViewTurns out;
  std::vector<std::uint32_t> run;  // per block, the frames of its current turn
  for (int f = 0; f < frames; ++f) {
    frame.timestamp_us = f * 33333;
    frame.sequence = static_cast<std::uint64_t>(f);
    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    REQUIRE((status.ok() || status.code() == StatusCode::resource_exhausted));
    const Octree<MultiresVoxel>& map = pipeline.map();
    out.held.resize(map.block_count(), 0);
    run.resize(map.block_count(), 0);
    for (std::uint32_t i = 0; i < map.block_count(); ++i) {
      if (map.block(i).has_finest()) {
        ++out.held[i];
        ++run[i];
      } else if (run[i] > 0) {
        out.shortest_turn = std::min(out.shortest_turn, run[i]);
        ++out.turns_given_up;
        run[i] = 0;
      }
    }
  }
  const Octree<MultiresVoxel>& map = pipeline.map();
  for (std::uint32_t i = 0; i < map.block_count(); ++i) {
    out.surface.push_back(map.block(i).may_hold_surface() ? 1 : 0);
  }
  return out;
}

TEST_CASE("a view larger than the finest-level pool takes turns at scale 0", "[store]") {
  const sim::SimConfig sim_config = small_sim(1, /*noise=*/false);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  PipelineConfig config = small_config(truth, kVoxel_m, 1);
  config.pose_source = PoseSource::ground_truth;
  constexpr int kFrames = 40;
  const OneViewTurns unbounded = turns_one_view(sim_config, config, kFrames, nullptr);
  std::uint32_t view = 0;  // blocks the view fuses at scale 0
  for (const std::uint32_t h : unbounded.held) view += h == kFrames;
  REQUIRE(view > 100);
  REQUIRE(unbounded.turns_given_up == 0);

  // Half the view's levels: each frame eviction takes the levels held longest down to the
  // low-water mark and the frame lends them to the blocks that waited longest.
  config.map.finest_capacity = view / 2;
  config.eviction.enabled = true;
  config.budget.max_store_reads = 0xFFFFFFFFu;
  const auto check = [&](std::uint32_t turn_frames, std::uint32_t fewest_at_least,
                         std::uint32_t others_fewest_at_least) {
    config.eviction.finest_turn_frames = turn_frames;
    MemoryStore store;
    const OneViewTurns capped = turns_one_view(sim_config, config, kFrames, &store);
    // The same blocks, in the same pool order (nothing evicted whole).
    REQUIRE(capped.held.size() == unbounded.held.size());
    // Per group (0: no surface, 1: the surface, as the unbounded run ends), the fewest and most
    // frames a block held a level, and the blocks.
    std::uint32_t fewest[2] = {kFrames, kFrames}, most[2] = {0, 0}, blocks[2] = {0, 0};
    std::uint64_t sum[2] = {0, 0};
    for (std::size_t i = 0; i < capped.held.size(); ++i) {
      if (unbounded.held[i] != kFrames) continue;
      const int g = capped.surface[i];
      fewest[g] = std::min(fewest[g], capped.held[i]);
      most[g] = std::max(most[g], capped.held[i]);
      sum[g] += capped.held[i];
      ++blocks[g];
    }
    INFO("of " << view << " blocks at scale 0 (" << blocks[1] << " with the surface), with "
               << config.map.finest_capacity << " levels and turns of at least " << turn_frames
               << " frames: each surface block held one after " << fewest[1] << " to " << most[1]
               << " of " << kFrames << " frames (mean " << sum[1] / std::max(1u, blocks[1])
               << "), the others " << fewest[0] << " to " << most[0] << " (mean "
               << sum[0] / std::max(1u, blocks[0]) << "); " << capped.turns_given_up
               << " turns given up, the shortest " << capped.shortest_turn << " frames");
    // Every block had its turns, and no block many more than another.
    // The surface first: each surface block held a level most frames, more than the others
    // did, and the others still had turns.
    REQUIRE(blocks[1] > 0);
    REQUIRE(blocks[0] > 0);
    REQUIRE(fewest[1] >= fewest_at_least);
    REQUIRE(sum[1] * blocks[0] > 2 * sum[0] * blocks[1]);  // means: twice as many frames
    REQUIRE(fewest[0] >= others_fewest_at_least);
    REQUIRE(capped.turns_given_up > 0);
    REQUIRE(capped.shortest_turn >= std::max<std::uint32_t>(turn_frames, 1));
    // Each turn given up is a record; a surface block may also give its level up and take it
    // back within a frame (a record written and read) when the marks free more levels than the
    // other blocks hold.
    REQUIRE(store.puts >= capped.turns_given_up);
    return store.puts;
  };
  // Half the view's levels, a little more than its surface blocks need: every block had turns.
  const std::uint32_t churn = check(0, kFrames / 2, 1);
  // Turns of at least 10 frames: fewer records; a block that held a level keeps it 10 frames, so
  // surface blocks wait longer and blocks without the surface may not get a turn.
  const std::uint32_t churn_10 = check(10, kFrames / 4, 0);
  CHECK(churn_10 < churn);
}

TEST_CASE("a finest-level store needs eviction and a multires map", "[store]") {
  const sim::SimConfig sim_config = small_sim(2, /*noise=*/false);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  MemoryStore store;
  PipelineConfig config = small_config(truth, kVoxel_m, 1);
  {
    Buffer buffer(bytes_required(config));
    Pipeline<MultiresVoxel> pipeline;
    REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
    REQUIRE(pipeline.set_finest_store(&store).code() == StatusCode::failed_precondition);
  }
  config.eviction.enabled = true;
  {
    PipelineConfig single = config;
    single.map_kind = MapKind::single_res;
    Buffer buffer(bytes_required(single));
    Pipeline<TsdfVoxel> pipeline;
    REQUIRE(pipeline.init(buffer.data, bytes_required(single), single).ok());
    REQUIRE(pipeline.set_finest_store(&store).code() == StatusCode::failed_precondition);
    Pipeline<MultiresVoxel> multires;
    Buffer multires_buffer(bytes_required(config));
    REQUIRE(multires.init(multires_buffer.data, bytes_required(config), config).ok());
    REQUIRE(multires.set_finest_store(&store).ok());
    REQUIRE(multires.set_finest_store(nullptr).ok());
  }
}

}  // namespace
}  // namespace octofuse
