// Pools far smaller than the scene refuse nothing that eviction can free: inner nodes go with
// their last block (and a full node pool evicts like a full block pool), and a free-space pool too
// small for the air around the camera forgets the farthest air, down to any radius. With a block
// store, evicted blocks come back when the camera returns.

#include "octofuse/pipeline/pipeline.hpp"

#include <algorithm>
#include <catch2/catch.hpp>
#include <map>
#include <vector>

#include "system/pipeline_support.hpp"

namespace octofuse {
namespace {

sim::SimConfig tiny_room_sim(int frames) {
  sim::SimConfig config = small_sim(frames, /*noise=*/false);
  config.scene = sim::SceneId::room;
  return config;
}

struct TinyRun {
  std::vector<FrameStats> stats;
  std::uint64_t allocations = 0;
  MapMemory end_memory;
  // Blocks in memory at the end that were read back and not integrated since, and how many of
  // those (with their finest level) differ from their stored record.
  std::size_t clean_blocks = 0;
  std::size_t clean_differing = 0;
};

// A BlockStore in memory: the newest record of each key.
class MemoryStore final : public BlockStore {
 public:
  Status put(std::uint64_t key, const std::uint8_t* record, std::size_t size) override {
    Entry& e = entries_[key];
    e.bytes.assign(record, record + size);
    e.in_memory = false;
    ++puts;
    return ok_status();
  }
  std::size_t find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi, std::uint64_t* keys,
                          std::size_t capacity) override {
    std::size_t n = 0;
    for (const auto& [key, e] : entries_) {
      const Eigen::Vector3i c = morton_decode(key);
      if (n == capacity || e.in_memory) continue;
      if ((c.array() < lo.array()).any() || (c.array() > hi.array()).any()) continue;
      keys[n++] = key;
    }
    return n;
  }
  Result<std::size_t> take(std::uint64_t key, std::uint8_t* record, std::size_t capacity) override {
    const auto it = entries_.find(key);
    if (it == entries_.end()) return StatusCode::out_of_range;
    if (it->second.bytes.size() > capacity) return StatusCode::resource_exhausted;
    std::copy(it->second.bytes.begin(), it->second.bytes.end(), record);
    it->second.in_memory = true;
    return it->second.bytes.size();
  }
  void release(std::uint64_t key) override {
    entries_[key].in_memory = false;
    ++releases;
  }
  const std::vector<std::uint8_t>* record(std::uint64_t key) const {
    const auto it = entries_.find(key);
    return it == entries_.end() ? nullptr : &it->second.bytes;
  }
  std::size_t puts = 0;
  std::size_t releases = 0;

 private:
  struct Entry {
    std::vector<std::uint8_t> bytes;
    bool in_memory = false;
  };
  std::map<std::uint64_t, Entry> entries_;
};

TinyRun run_tiny(const sim::SimConfig& sim_config, const PipelineConfig& config,
                 MemoryStore* store = nullptr) {
  TinyRun out;
  sim::SimSource source(sim_config);
  REQUIRE(source.open().ok());
  Buffer buffer(bytes_required(config));
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  if (store != nullptr) REQUIRE(pipeline.set_block_store(store).ok());
  out.stats.reserve(static_cast<std::size_t>(sim_config.frame_count));
  DepthFrame frame;
  test::AllocationScope scope;
  while (source.next(frame).outcome == FrameOutcome::frame) {
    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    REQUIRE((status.ok() || status.code() == StatusCode::resource_exhausted));
    out.stats.push_back(stats);
  }
  out.allocations = scope.allocations();
  out.end_memory = pipeline.map().memory();
  if (store != nullptr) {
    std::vector<std::uint8_t> record(block_record_max_bytes<MultiresVoxel>());
    const Octree<MultiresVoxel>& map = pipeline.map();
    for (std::uint32_t i = 0; i < map.block_count(); ++i) {
      const VoxelBlock<MultiresVoxel>& block = map.block(i);
      if (block.stored_clean == 0) continue;
      ++out.clean_blocks;
      if (block.finest == nullptr) continue;  // restored demoted: the record holds more
      const Result<std::size_t> size = encode_block_record(block, record.data(), record.size());
      REQUIRE(size.ok());
      const std::vector<std::uint8_t>* stored = store->record(morton_encode(block.coords));
      REQUIRE(stored != nullptr);
      if (!std::equal(stored->begin(), stored->end(), record.begin(),
                      record.begin() + size.value()) ||
          stored->size() != size.value()) {
        ++out.clean_differing;
      }
    }
  }
  return out;
}

TEST_CASE("tiny node and free-space pools evict and forget instead of refusing", "[tiny_pools]") {
  constexpr int kFrames = 40;
  constexpr float kVoxel_m = 0.02f;
  const sim::SimConfig sim_config = tiny_room_sim(kFrames);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  // Ground-truth poses: the pools, not tracking, are under test.
  PipelineConfig probe_config = small_config(truth, kVoxel_m, 1);
  probe_config.pose_source = PoseSource::ground_truth;
  const TinyRun unbounded = run_tiny(sim_config, probe_config);
  std::uint32_t view_blocks = 0;
  std::uint32_t view_free_nodes = 0;
  for (const FrameStats& s : unbounded.stats) {
    view_blocks = std::max(view_blocks, s.integration.blocks_integrated);
    view_free_nodes = std::max(view_free_nodes, s.free_space.new_nodes);
  }
  const std::uint32_t scene_nodes = unbounded.end_memory.nodes_used;
  const std::uint32_t scene_blocks = unbounded.end_memory.blocks_used;
  INFO("scene " << scene_blocks << " blocks, " << scene_nodes << " nodes; largest view "
                << view_blocks << " blocks; most free-space nodes one frame made "
                << view_free_nodes);

  PipelineConfig config = probe_config;
  config.eviction.enabled = true;
  // Blocks for the whole scene, inner nodes for well under it: only the node pool can fill.
  config.map.block_capacity = scene_blocks + 16;
  config.map.node_capacity = scene_nodes / 2;
  // A free-space pool for less than twice the most one frame carved: it filled within frames
  // before (pruning only when 15/16 full, to 3/4 of the pool).
  config.free_space.node_capacity = view_free_nodes * 3 / 2;
  const TinyRun tiny = run_tiny(sim_config, config);
  REQUIRE(tiny.allocations == 0);
  std::uint64_t node_refusals = 0;
  std::uint64_t evicted = 0;
  std::uint64_t pruned = 0;
  std::uint64_t free_refused = 0;
  for (std::size_t i = 0; i < tiny.stats.size(); ++i) {
    const FrameStats& s = tiny.stats[i];
    CAPTURE(i);
    REQUIRE(s.memory.nodes_used <= config.map.node_capacity);
    node_refusals += s.integration.node_refusals;
    evicted += s.eviction.evicted;
    pruned += s.free_space.pruned;
    // A refusing frame leaves room for as many nodes as it asked for.
    free_refused += s.free_space.pool_refused;
  }

  REQUIRE(node_refusals == 0);  // the node pool never refused: eviction freed nodes first
  REQUIRE(tiny.end_memory.node_refusals == 0);
  REQUIRE(tiny.end_memory.nodes_evicted > 0);
  REQUIRE(evicted > 0);
  REQUIRE(pruned > 0);
  REQUIRE(free_refused == 0);  // the free-space pool forgot far air in time, never refused
}

TEST_CASE("with a block store, evicted blocks come back when the camera returns", "[store]") {
  // One orbit of the room: the walls seen first leave the view, are evicted, and come back into
  // view at the end of the orbit.
  constexpr int kFrames = 60;
  constexpr float kVoxel_m = 0.02f;
  const sim::SimConfig sim_config = tiny_room_sim(kFrames);
  sim::SimSource truth(sim_config);
  REQUIRE(truth.open().ok());
  PipelineConfig config = small_config(truth, kVoxel_m, 1);
  config.pose_source = PoseSource::ground_truth;
  const TinyRun unbounded = run_tiny(sim_config, config);
  std::uint32_t view_blocks = 0;
  for (const FrameStats& s : unbounded.stats) {
    view_blocks = std::max(view_blocks, s.integration.blocks_integrated);
  }
  config.map.block_capacity = view_blocks * 8 / 5;
  config.eviction.enabled = true;
  config.budget.max_store_reads = 4096;
  MemoryStore store;
  const TinyRun stored = run_tiny(sim_config, config, &store);  // (the test's store allocates)
  std::uint64_t written = 0, unchanged = 0, read = 0, remapped = 0, read_late = 0, refused = 0;
  for (std::size_t i = 0; i < stored.stats.size(); ++i) {
    const StoreReport& r = stored.stats[i].store;
    REQUIRE(r.write_failed == 0);
    REQUIRE(r.read_failed == 0);
    written += r.written;
    unchanged += r.unchanged;
    // No new block refused in this orbit (blocks, not finest levels).
    refused +=
        stored.stats[i].integration.pool_refusals - stored.stats[i].integration.finest_refusals;
    read += r.read;
    remapped += r.remapped;
    if (i >= stored.stats.size() * 3 / 4) read_late += r.read;
  }
  INFO("written " << written << ", unchanged " << unchanged << ", read back " << read << " ("
                  << read_late << " in the last quarter), re-mapped before they came back "
                  << remapped);
  // Every evicted block is written, or was read back and not integrated since (its record is
  // still its state: no write).
  REQUIRE(written + unchanged == stored.end_memory.evicted);
  REQUIRE(store.puts == written);
  REQUIRE(store.releases >= unchanged);
  REQUIRE(stored.clean_differing == 0);
  REQUIRE(refused == 0);
  REQUIRE(unchanged > 0);  // walls read back at the end of the orbit and evicted again unseen
  REQUIRE(read_late > 0);  // the first walls came back at the end of the orbit
  REQUIRE(read >= 2 * remapped);  // most came back before integration mapped them afresh
}

}  // namespace
}  // namespace octofuse
