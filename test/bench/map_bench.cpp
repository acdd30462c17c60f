// Lookup and batch-allocation rates of the octree map (Google Benchmark).
#include <algorithm>
#include <cstdlib>
#include <memory>
#include <random>
#include <vector>

#include <benchmark/benchmark.h>

#include "octofuse/map/octree.hpp"

namespace octofuse {
namespace {

constexpr std::uint32_t kBlocks = 100000;

MapConfig bench_config() {
  return MapConfig::centred(Eigen::Vector3f::Zero(), 0.002f, 12, kBlocks, 2 * kBlocks);
}

struct Map {
  Map() : bytes(Octree<MultiresVoxel>::bytes_required(bench_config())) {
    memory.reset(static_cast<unsigned char*>(std::aligned_alloc(kArenaAlignment, bytes)));
    LinearArena arena(memory.get(), bytes);
    if (!map.reserve(arena, bench_config()).ok()) std::abort();
  }
  struct Free {
    void operator()(unsigned char* p) const { std::free(p); }
  };
  std::size_t bytes;
  std::unique_ptr<unsigned char, Free> memory;
  Octree<MultiresVoxel> map;
};

// Blocks of a few surfaces: a dense slab like a depth frame's band, in Morton order.
std::vector<Key> surface_keys(const Octree<MultiresVoxel>& map, std::size_t count) {
  std::vector<Key> keys;
  const int side = 1 << (map.voxel_depth() - 3);
  for (int z = side / 2; keys.size() < count; ++z)
    for (int y = 0; y < 200 && keys.size() < count; ++y)
      for (int x = 0; x < 250 && keys.size() < count; ++x)
        keys.push_back(map.block_key({side / 4 + x, side / 4 + y, z}));
  std::sort(keys.begin(), keys.end());
  return keys;
}

void BM_BatchAllocate(benchmark::State& state) {
  Map m;
  const std::vector<Key> keys = surface_keys(m.map, static_cast<std::size_t>(state.range(0)));
  for (auto _ : state) {
    state.PauseTiming();
    m.map.clear();
    state.ResumeTiming();
    AllocationCounts counts;
    benchmark::DoNotOptimize(m.map.allocate(keys.data(), keys.size(), &counts));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(keys.size()));
}
BENCHMARK(BM_BatchAllocate)->Arg(10000)->Arg(50000)->Unit(benchmark::kMillisecond);

void BM_FindBlockHit(benchmark::State& state) {
  Map m;
  const std::vector<Key> keys = surface_keys(m.map, 50000);
  if (!m.map.allocate(keys.data(), keys.size()).ok()) std::abort();
  std::vector<Eigen::Vector3i> queries;
  std::mt19937 rng(3);
  std::uniform_int_distribution<std::size_t> pick(0, keys.size() - 1);
  for (int i = 0; i < 4096; ++i)
    queries.push_back(voxel_to_block(key_corner_voxel(keys[pick(rng)])));
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(m.map.find_block(queries[i++ & 4095]));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_FindBlockHit);

void BM_FindBlockMiss(benchmark::State& state) {
  Map m;
  const std::vector<Key> keys = surface_keys(m.map, 50000);
  if (!m.map.allocate(keys.data(), keys.size()).ok()) std::abort();
  std::size_t i = 0;
  for (auto _ : state) {
    const int k = static_cast<int>(i++ & 1023);
    benchmark::DoNotOptimize(m.map.find_block(Eigen::Vector3i(k, 3, 5)));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_FindBlockMiss);

void BM_VoxelRead(benchmark::State& state) {
  Map m;
  const std::vector<Key> keys = surface_keys(m.map, 50000);
  if (!m.map.allocate(keys.data(), keys.size()).ok()) std::abort();
  std::vector<Eigen::Vector3i> queries;
  std::mt19937 rng(4);
  std::uniform_int_distribution<std::size_t> pick(0, keys.size() - 1);
  std::uniform_int_distribution<int> offset(0, 7);
  for (int i = 0; i < 4096; ++i) {
    queries.push_back(key_corner_voxel(keys[pick(rng)]) +
                      Eigen::Vector3i(offset(rng), offset(rng), offset(rng)));
  }
  // A read: the non-const accessor would lend blocks their finest level.
  const auto& map = m.map;
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(map.finest_voxel(queries[i++ & 4095]));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_VoxelRead);

void BM_Lookup(benchmark::State& state) {
  Map m;
  const std::vector<Key> keys = surface_keys(m.map, 50000);
  if (!m.map.allocate(keys.data(), keys.size()).ok()) std::abort();
  std::size_t i = 0;
  for (auto _ : state) {
    const int k = static_cast<int>(i++ & 4095);
    benchmark::DoNotOptimize(m.map.lookup(Eigen::Vector3i(1024 + k, 1024 + (k >> 3), 2100)));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Lookup);

}  // namespace
}  // namespace octofuse

BENCHMARK_MAIN();
