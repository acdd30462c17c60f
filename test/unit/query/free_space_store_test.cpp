// Free space beyond memory: pruning with a store hands forgotten regions to it, reloading grafts
// them back with the same answers, and merging keeps the tree's own nodes over stored ones.

#include <algorithm>
#include <catch2/catch.hpp>
#include <vector>

#include "octofuse/query/free_space.hpp"
#include "support/memory_store.hpp"
#include "unit/query/query_support.hpp"

namespace octofuse {
namespace {

struct Snapshot {
  std::vector<Eigen::Vector3i> voxels;
  std::vector<std::uint32_t> free_frames;  // of the voxels read free
};

// Every 4th voxel of the cube that reads free, with the frame that last saw it free.
Snapshot free_voxels(const FreeSpace& space) {
  Snapshot s;
  const int n = 1 << space.map_config().voxel_depth;
  for (int z = 0; z < n; z += 4) {
    for (int y = 0; y < n; y += 4) {
      for (int x = 0; x < n; x += 4) {
        const FreeOctant o = space.find(Eigen::Vector3i(x, y, z));
        if (!o.free) continue;
        s.voxels.emplace_back(x, y, z);
        s.free_frames.push_back(o.free_frame);
      }
    }
  }
  return s;
}

void require_tree_whole(const FreeSpace& space) {
  const std::uint32_t count = space.node_count();
  std::vector<int> parents(count, 0);
  for (std::uint32_t i = 0; i < count; ++i) {
    for (std::uint32_t child : space.node(i).children) {
      if (child == FreeSpace::kNoNode) continue;
      REQUIRE(child > i);
      REQUIRE(child < count);
      ++parents[child];
    }
  }
  for (std::uint32_t i = 1; i < count; ++i) REQUIRE(parents[i] == 1);
}

void two_views(Mapper& m) {
  m.fuse(wall_at(kWall_m));
  Se3d side = Se3d::Identity();
  side.translation() = Eigen::Vector3d(1.5, 0.0, 0.0);
  m.fuse(wall_at(kWall_m), side);
}

void reload_all(Mapper& m, MemoryStore& store, FreeStoreReport* report) {
  RegionReach reach;
  reach.camera_W = Eigen::Vector3f(0.0f, 0.0f, 1.5f);
  reach.radius_m = 100.0f;
  m.free_space.reload_regions(reach, store, 1u << 20, m.free_space.node_capacity(), report);
}

TEST_CASE("pruned free space goes to the store by region and comes back with the same answers") {
  Mapper m;
  two_views(m);
  const Snapshot before = free_voxels(m.free_space);
  REQUIRE(before.voxels.size() > 1000);

  MemoryStore store;
  FreeStoreReport spilled;
  const std::uint32_t dropped =
      m.free_space.spill_and_prune(Eigen::Vector3f(1.5f, 0.0f, 0.0f), 1.4f, &store, &spilled);
  REQUIRE(dropped > 0);
  REQUIRE(spilled.written > 0);
  REQUIRE(spilled.write_failed == 0);
  REQUIRE(spilled.merged == 0);
  REQUIRE(ask(m, -0.3f, 0.0f, 1.2f).state == PointState::unknown);
  REQUIRE(free_voxels(m.free_space).voxels.size() < before.voxels.size());

  FreeStoreReport read;
  reload_all(m, store, &read);
  REQUIRE(read.read == spilled.written);
  REQUIRE(read.read_failed == 0);
  REQUIRE(read.waiting == 0);
  REQUIRE(store.taken() == spilled.written);
  const Snapshot after = free_voxels(m.free_space);
  REQUIRE(after.voxels == before.voxels);
  REQUIRE(after.free_frames == before.free_frames);
  REQUIRE(ask(m, -0.3f, 0.0f, 1.2f).state == PointState::free);
  require_tree_whole(m.free_space);

  // Everything out (a negative radius) and back: still the same; regions read back need no
  // second read when spilled again.
  FreeStoreReport all_out;
  m.free_space.spill_and_prune(Eigen::Vector3f::Zero(), -1.0f, &store, &all_out);
  REQUIRE(m.free_space.node_count() == 1);
  REQUIRE(all_out.merged == 0);
  REQUIRE(store.taken() == 0);
  FreeStoreReport all_in;
  reload_all(m, store, &all_in);
  REQUIRE(all_in.read == all_out.written);
  const Snapshot again = free_voxels(m.free_space);
  REQUIRE(again.voxels == before.voxels);
  REQUIRE(again.free_frames == before.free_frames);
}

TEST_CASE("air carved again before its region is read back is merged, the newer nodes winning") {
  Mapper m;
  two_views(m);
  const Snapshot before = free_voxels(m.free_space);
  MemoryStore store;
  FreeStoreReport out;
  m.free_space.spill_and_prune(Eigen::Vector3f::Zero(), -1.0f, &store, &out);
  REQUIRE(out.written > 0);

  // The first view again, with nothing read back: the tree holds this frame's air only.
  m.fuse(wall_at(kWall_m));
  const Snapshot fresh = free_voxels(m.free_space);
  REQUIRE(fresh.voxels.size() < before.voxels.size());
  FreeStoreReport merged;
  m.free_space.spill_and_prune(Eigen::Vector3f::Zero(), -1.0f, &store, &merged);
  REQUIRE(merged.merged > 0);

  FreeStoreReport in;
  reload_all(m, store, &in);
  REQUIRE(in.read_failed == 0);
  const Snapshot after = free_voxels(m.free_space);
  // The stored air comes back where the newer frame made no node; nothing reads free that
  // neither the stored tree nor the newer frame had free; the newer frame's air keeps its frame.
  REQUIRE(after.voxels.size() >
          fresh.voxels.size() + (before.voxels.size() - fresh.voxels.size()) / 2);
  for (const Eigen::Vector3i& v : after.voxels) {
    const bool known =
        std::find(before.voxels.begin(), before.voxels.end(), v) != before.voxels.end() ||
        std::find(fresh.voxels.begin(), fresh.voxels.end(), v) != fresh.voxels.end();
    REQUIRE(known);
  }
  for (std::size_t i = 0; i < fresh.voxels.size(); ++i) {
    const FreeOctant o = m.free_space.find(fresh.voxels[i]);
    REQUIRE(o.free);
    REQUIRE(o.free_frame == fresh.free_frames[i]);
  }
  // Stored air added below nodes the newer frame made is aged to frame 0 (older than any block);
  // regions the newer frame never touched come back with their frames.
  std::size_t aged = 0;
  for (std::size_t i = 0; i < before.voxels.size(); ++i) {
    const Eigen::Vector3i& v = before.voxels[i];
    if (std::find(fresh.voxels.begin(), fresh.voxels.end(), v) != fresh.voxels.end()) continue;
    const FreeOctant o = m.free_space.find(v);
    if (!o.free) continue;
    REQUIRE((o.free_frame == 0 || o.free_frame == before.free_frames[i]));
    aged += o.free_frame == 0 && before.free_frames[i] == 1 ? 1 : 0;
  }
  REQUIRE(aged > 0);
  require_tree_whole(m.free_space);
}

TEST_CASE("a damaged or foreign region record is refused and leaves the tree as it was") {
  Mapper m;
  two_views(m);
  MemoryStore store;
  FreeStoreReport out;
  m.free_space.spill_and_prune(Eigen::Vector3f(1.5f, 0.0f, 0.0f), 1.4f, &store, &out);
  REQUIRE(out.written > 0);
  // The largest record: a region with air in it.
  std::uint64_t keys[256];
  const std::size_t found =
      store.find_in_box(Eigen::Vector3i::Zero(), Eigen::Vector3i::Constant(1 << 20), keys, 256);
  REQUIRE(found > 0);
  std::uint64_t key = keys[0];
  for (std::size_t i = 1; i < found; ++i) {
    if (store.record(keys[i])->size() > store.record(key)->size()) key = keys[i];
  }
  std::vector<std::uint8_t> record = *store.record(key);
  const std::uint32_t count = m.free_space.node_count();
  const Snapshot before = free_voxels(m.free_space);

  for (std::size_t at = 0; at < record.size(); at += 3) {
    std::vector<std::uint8_t> bad = record;
    bad[at] ^= 0x41;
    REQUIRE(m.free_space.graft_region_record(key, bad.data(), bad.size()).code() ==
            StatusCode::data_loss);
  }
  for (std::size_t size = 0; size < record.size(); ++size) {
    REQUIRE(m.free_space.graft_region_record(key, record.data(), size).code() ==
            StatusCode::data_loss);
  }
  // A key that is not a region's corner.
  REQUIRE(m.free_space.graft_region_record(key + 1, record.data(), record.size()).code() ==
          StatusCode::data_loss);
  REQUIRE(m.free_space.node_count() == count);
  REQUIRE(free_voxels(m.free_space).voxels == before.voxels);
  // The record itself grafts.
  REQUIRE(m.free_space.graft_region_record(key, record.data(), record.size()).ok());
  REQUIRE(free_voxels(m.free_space).voxels.size() > before.voxels.size());
}

// A store whose writes or reads fail on demand (a full or failing medium), over a MemoryStore.
class FailingStore final : public BlockStore {
 public:
  Status put(std::uint64_t key, const std::uint8_t* record, std::size_t size) override {
    if (fail_put) return StatusCode::unavailable;
    return inner.put(key, record, size);
  }
  std::size_t find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi, std::uint64_t* keys,
                          std::size_t capacity) override {
    return inner.find_in_box(lo, hi, keys, capacity);
  }
  bool holds(std::uint64_t key) override { return inner.holds(key); }
  Result<std::size_t> take(std::uint64_t key, std::uint8_t* record, std::size_t capacity) override {
    if (fail_take) return StatusCode::data_loss;
    return inner.take(key, record, capacity);
  }
  void release(std::uint64_t key) override { inner.release(key); }
  MemoryStore inner;
  bool fail_put = false;
  bool fail_take = false;
};

TEST_CASE("a store that fails writes or reads costs that air, counted, and nothing else") {
  Mapper m;
  two_views(m);
  FailingStore store;
  store.fail_put = true;
  FreeStoreReport out;
  const std::uint32_t dropped =
      m.free_space.spill_and_prune(Eigen::Vector3f(1.5f, 0.0f, 0.0f), 1.4f, &store, &out);
  REQUIRE(dropped > 0);
  REQUIRE(out.written == 0);
  REQUIRE(out.write_failed > 0);
  require_tree_whole(m.free_space);
  // Nothing was stored: nothing comes back, and nothing fails.
  FreeStoreReport in;
  RegionReach reach;
  reach.camera_W = Eigen::Vector3f(0.0f, 0.0f, 1.5f);
  reach.radius_m = 100.0f;
  m.free_space.reload_regions(reach, store, 1u << 20, m.free_space.node_capacity(), &in);
  REQUIRE(in.read == 0);
  REQUIRE(in.read_failed == 0);
  REQUIRE(ask(m, -0.3f, 0.0f, 1.2f).state == PointState::unknown);

  // Stored, then unreadable: each region is counted as failed and the tree stays as it was.
  Mapper again;
  two_views(again);
  FailingStore failing;
  FreeStoreReport stored;
  again.free_space.spill_and_prune(Eigen::Vector3f(1.5f, 0.0f, 0.0f), 1.4f, &failing, &stored);
  REQUIRE(stored.written > 0);
  const std::uint32_t count = again.free_space.node_count();
  failing.fail_take = true;
  FreeStoreReport unreadable;
  again.free_space.reload_regions(reach, failing, 1u << 20, again.free_space.node_capacity(),
                                  &unreadable);
  REQUIRE(unreadable.read == 0);
  REQUIRE(unreadable.read_failed == stored.written);
  REQUIRE(again.free_space.node_count() == count);
  require_tree_whole(again.free_space);
}

}  // namespace
}  // namespace octofuse
