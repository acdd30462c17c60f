// A block that gave its finest level up takes it back from its record
// (restore_finest_from_record()): unchanged since, at scale 0 and bit for bit; otherwise at its
// scale, and refined then as the integrator does (propagate_block_down) each observed finest
// voxel moves by its parent's change since the record (eq. 5);
// bad records, a block that holds a finest level and a full pool leave the map unchanged.

#include <algorithm>
#include <catch2/catch.hpp>
#include <vector>

#include "octofuse/map/block_store.hpp"
#include "octofuse/map/detail/propagation.hpp"
#include "unit/map/octree_support.hpp"

namespace octofuse {
namespace {

constexpr float kYMax = 100.0f;

// A block at scale 0 with a varied field: every seventh finest voxel unobserved.
template <typename VoxelT>
std::uint32_t make_fine_block(Octree<VoxelT>& map, const Eigen::Vector3i& coords) {
  const Result<std::uint32_t> index = map.allocate_block(coords);
  REQUIRE(index.ok());
  VoxelBlock<VoxelT>& block = map.block(index.value());
  REQUIRE(map.acquire_finest(block).ok());
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    auto& v = block.finest_begin()[i];
    if (i % 7 == 0) continue;  // unobserved
    set_voxel_tsdf(v, static_cast<float>(i % 37) / 18.0f - 1.0f);
    set_voxel_x_last(v, voxel_tsdf(v));
    set_voxel_weight(v, 1.0f + static_cast<float>(i % 9));
  }
  block.current_scale = 0;
  block.min_scale = 0;
  block.mip_scale = 0;  // scale 1 not brought up to date yet: demotion does it
  block.last_updated_frame = 5;
  Octree<VoxelT>::update_block_summary(block);
  return index.value();
}

template <typename VoxelT>
std::vector<std::uint8_t> record_of(const VoxelBlock<VoxelT>& block) {
  std::vector<std::uint8_t> record(block_record_max_bytes<VoxelT>());
  const Result<std::size_t> size = encode_block_record(block, record.data(), record.size());
  REQUIRE(size.ok());
  record.resize(size.value());
  return record;
}

template <typename VoxelT>
std::vector<VoxelT> finest_of(const VoxelBlock<VoxelT>& block) {
  std::vector<VoxelT> finest(kBlockFinestVoxelCount);
  for (int i = 0; i < kBlockFinestVoxelCount; ++i)
    finest[static_cast<std::size_t>(i)] = block.voxel(i);
  return finest;
}

// What the integrator does to a block it fuses at scale 0 next.
template <typename VoxelT>
void refine_to_finest(VoxelBlock<VoxelT>& block) {
  for (int l = block.current_scale; l > 0; --l) propagate_block_down(block, l, kYMax);
  block.current_scale = 0;
}

// The finest voxel's parent at scale 1 (index within scale 1).
int parent_of(int finest_index) {
  const int x = finest_index % kBlockSide;
  const int y = (finest_index / kBlockSide) % kBlockSide;
  const int z = finest_index / (kBlockSide * kBlockSide);
  const int side = kBlockSide / 2;
  return x / 2 + (y / 2) * side + (z / 2) * side * side;
}

TEMPLATE_TEST_CASE("a demoted block not fused since gets its finest voxels back at scale 0",
                   "[map][store]", MultiresVoxel, Multires16Voxel) {
  using VoxelT = TestType;
  MapFixture<VoxelT> fixture(small_config(8, 64));
  Octree<VoxelT>& map = fixture.map;
  for (int keep : {1, 2}) {
    CAPTURE(keep);
    std::uint32_t index = make_fine_block(map, Eigen::Vector3i(2 + 3 * keep, 4, 6));
    const VoxelBlock<VoxelT> header = map.block(index);
    const std::vector<VoxelT> before = finest_of(map.block(index));
    const std::vector<std::uint8_t> record = record_of(map.block(index));
    REQUIRE(block_record_holds_finest<VoxelT>(record.data(), record.size()));
    if (keep == 1) {
      map.release_finest(&index, 1);
    } else {
      map.release_mid(&index, 1);
    }
    const VoxelBlock<VoxelT>& block = map.block(index);
    REQUIRE_FALSE(block.has_finest());
    REQUIRE(block.current_scale == keep);
    const std::uint32_t finest_used = map.memory().finest_used;

    REQUIRE(restore_finest_from_record(map, index, record.data(), record.size(), kYMax).ok());
    REQUIRE(block.has_finest());
    REQUIRE(block.has_mid());
    // As it was: at scale 0, its summary that of its finest voxels, every voxel the same bits
    // (the unobserved ones not filled in from their parents, as refining would).
    REQUIRE(block.current_scale == 0);
    REQUIRE(block.min_scale == 0);
    REQUIRE(block.tsdf_min == header.tsdf_min);
    REQUIRE(block.tsdf_max == header.tsdf_max);
    REQUIRE(block.tsdf_mean == header.tsdf_mean);
    REQUIRE(block.weight_mean == header.weight_mean);
    REQUIRE(map.memory().finest_used == finest_used + 1);
    const std::vector<VoxelT> after = finest_of(block);
    for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
      CAPTURE(i);
      REQUIRE(voxel_observed(after[static_cast<std::size_t>(i)]) ==
              voxel_observed(before[static_cast<std::size_t>(i)]));
      REQUIRE(voxel_tsdf(after[static_cast<std::size_t>(i)]) ==
              voxel_tsdf(before[static_cast<std::size_t>(i)]));
      REQUIRE(voxel_weight(after[static_cast<std::size_t>(i)]) ==
              voxel_weight(before[static_cast<std::size_t>(i)]));
    }
  }
}

TEST_CASE("a block that fused coarser than its held level since comes back at its scale",
          "[map][store]") {
  MapFixture<MultiresVoxel> fixture(small_config(8, 64));
  Octree<MultiresVoxel>& map = fixture.map;
  std::uint32_t index = make_fine_block(map, Eigen::Vector3i(1, 1, 1));
  const std::vector<std::uint8_t> record = record_of(map.block(index));
  map.release_finest(&index, 1);
  VoxelBlock<MultiresVoxel>& block = map.block(index);
  // Fused at scale 2 since (its scale 1, the level it holds, untouched): the change is there.
  REQUIRE(Octree<MultiresVoxel>::coarsen_block(block, 2));
  MultiresVoxel* scale2 = block.level_begin(2);
  scale2[0].x = scale2[0].x - 0.125f;
  REQUIRE(restore_finest_from_record(map, index, record.data(), record.size(), kYMax).ok());
  REQUIRE(block.has_finest());
  REQUIRE(block.current_scale == 2);
}

TEST_CASE("a block recorded while it fused coarser comes back at its scale", "[map][store]") {
  MapFixture<MultiresVoxel> fixture(small_config(8, 64));
  Octree<MultiresVoxel>& map = fixture.map;
  std::uint32_t index = make_fine_block(map, Eigen::Vector3i(1, 1, 1));
  // Fused at scale 1 while it kept its finest level: the record's finest voxels lag its scale 1.
  REQUIRE(Octree<MultiresVoxel>::coarsen_block(map.block(index), 1));
  const std::vector<MultiresVoxel> before = finest_of(map.block(index));
  const std::vector<std::uint8_t> record = record_of(map.block(index));
  map.release_finest(&index, 1);
  VoxelBlock<MultiresVoxel>& block = map.block(index);
  REQUIRE(restore_finest_from_record(map, index, record.data(), record.size(), kYMax).ok());
  REQUIRE(block.current_scale == 1);  // at its scale until it is fused finer
  refine_to_finest(block);
  const std::vector<MultiresVoxel> after = finest_of(block);
  int interpolated = 0;
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    CAPTURE(i);
    if (voxel_observed(before[static_cast<std::size_t>(i)])) {
      // Its scale 1 did not change: bit for bit.
      REQUIRE(after[static_cast<std::size_t>(i)].x == before[static_cast<std::size_t>(i)].x);
      REQUIRE(after[static_cast<std::size_t>(i)].y == before[static_cast<std::size_t>(i)].y);
    } else {
      // Unobserved in the record: taken from the parents, with the parent's weight.
      REQUIRE(voxel_observed(after[static_cast<std::size_t>(i)]));
      ++interpolated;
    }
  }
  REQUIRE(interpolated == (kBlockFinestVoxelCount + 6) / 7);
}

TEST_CASE("a refined block's finest voxels move by their parent's change since the record",
          "[map][store]") {
  MapFixture<MultiresVoxel> fixture(small_config(8, 64));
  Octree<MultiresVoxel>& map = fixture.map;
  std::uint32_t index = make_fine_block(map, Eigen::Vector3i(1, 1, 1));
  const std::vector<MultiresVoxel> before = finest_of(map.block(index));
  const std::vector<std::uint8_t> record = record_of(map.block(index));
  map.release_finest(&index, 1);
  VoxelBlock<MultiresVoxel>& block = map.block(index);
  // What the block learned at scale 1 after giving its finest level up: parent 0 moved by
  // +0.25 and gained 3 samples, parent 5 by -0.5 and 200 (past the cap); the rest unchanged.
  // The change is measured against the record, not the block's x_last and delta_y.
  MultiresVoxel* mid = block.level_begin(1);
  const MultiresVoxel parent0 = mid[0];
  const MultiresVoxel parent5 = mid[5];
  mid[0].x = parent0.x + 0.25f;
  mid[0].y = parent0.y + 3.0f;
  mid[5].x = parent5.x - 0.5f;
  mid[5].y = parent5.y + 200.0f;
  // Parent 3 kept its value; its own interval bookkeeping says nothing about the record.
  mid[3].x_last = -0.9f;
  mid[3].delta_y = 7.0f;
  REQUIRE(restore_finest_from_record(map, index, record.data(), record.size(), kYMax).ok());
  REQUIRE(block.current_scale == 1);
  refine_to_finest(block);
  const MultiresFinestVoxel* finest = block.finest_begin();
  int moved = 0;
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    const MultiresVoxel& was = before[static_cast<std::size_t>(i)];
    if (!voxel_observed(was)) continue;
    CAPTURE(i);
    const int p = parent_of(i);
    if (p == 0) {
      REQUIRE(finest[i].x == std::clamp(was.x + ((parent0.x + 0.25f) - parent0.x), -1.0f, 1.0f));
      REQUIRE(finest[i].y == std::min(kYMax, was.y + 3.0f));
      ++moved;
    } else if (p == 5) {
      REQUIRE(finest[i].x == std::clamp(was.x + ((parent5.x - 0.5f) - parent5.x), -1.0f, 1.0f));
      REQUIRE(finest[i].y == std::min(kYMax, was.y + 200.0f));
      ++moved;
    } else {
      REQUIRE(finest[i].x == was.x);
      REQUIRE(finest[i].y == was.y);
    }
    // Every level's interval restarts.
    REQUIRE(mid[p].x_last == mid[p].x);
    REQUIRE(mid[p].delta_y == 0.0f);
  }
  REQUIRE(moved > 8);
}

TEST_CASE("a block that gave its mid level up too refines through the record's scale 1",
          "[map][store]") {
  MapFixture<MultiresVoxel> fixture(small_config(8, 64));
  Octree<MultiresVoxel>& map = fixture.map;
  std::uint32_t index = make_fine_block(map, Eigen::Vector3i(1, 1, 1));
  // A twin demoted to scale 1 only: its scale 1 is the record's, as demotion makes it.
  std::uint32_t twin = make_fine_block(map, Eigen::Vector3i(2, 1, 1));
  const std::vector<MultiresVoxel> before = finest_of(map.block(index));
  const std::vector<std::uint8_t> record = record_of(map.block(index));
  map.release_mid(&index, 1);
  map.release_finest(&twin, 1);
  const MultiresVoxel* scale1 = map.block(twin).level_begin(1);
  VoxelBlock<MultiresVoxel>& block = map.block(index);
  REQUIRE(block.current_scale == 2);
  REQUIRE_FALSE(block.has_mid());
  // Scale-2 voxel 0 (the 4 x 4 x 4 finest corner) moved by -0.125 since.
  MultiresVoxel* scale2 = block.level_begin(2);
  const float x2 = scale2[0].x;
  scale2[0].x = x2 - 0.125f;
  REQUIRE(restore_finest_from_record(map, index, record.data(), record.size(), kYMax).ok());
  REQUIRE(block.has_mid());
  REQUIRE(block.current_scale == 2);
  refine_to_finest(block);
  const MultiresFinestVoxel* finest = block.finest_begin();
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    const MultiresVoxel& was = before[static_cast<std::size_t>(i)];
    if (!voxel_observed(was)) continue;
    CAPTURE(i);
    const int p = parent_of(i);
    const int x = i % kBlockSide, y = (i / kBlockSide) % kBlockSide, z = i / 64;
    if (x < 4 && y < 4 && z < 4) {
      const float x1 = scale1[p].x;
      const float moved1 = std::clamp(x1 + ((x2 - 0.125f) - x2), -1.0f, 1.0f);
      REQUIRE(finest[i].x == std::clamp(was.x + (moved1 - x1), -1.0f, 1.0f));
    } else {
      REQUIRE(finest[i].x == was.x);
    }
    REQUIRE(finest[i].y == was.y);
  }
}

TEST_CASE("refining from a record refuses what it cannot do and changes nothing then",
          "[map][store]") {
  MapConfig config = small_config(8, 64);
  config.finest_capacity = 2;
  MapFixture<MultiresVoxel> fixture(config);
  Octree<MultiresVoxel>& map = fixture.map;
  std::uint32_t a = make_fine_block(map, Eigen::Vector3i(1, 1, 1));
  std::uint32_t b = make_fine_block(map, Eigen::Vector3i(2, 1, 1));
  const std::vector<std::uint8_t> record_a = record_of(map.block(a));
  const std::vector<std::uint8_t> record_b = record_of(map.block(b));
  // The block still holds its finest level.
  REQUIRE(restore_finest_from_record(map, a, record_a.data(), record_a.size(), kYMax).code() ==
          StatusCode::failed_precondition);
  map.release_finest(&a, 1);
  const std::vector<MultiresVoxel> mid_before(map.block(a).level_begin(1),
                                              map.block(a).level_begin(1) + kBlockMidVoxelCount);
  auto unchanged = [&]() {
    const VoxelBlock<MultiresVoxel>& block = map.block(a);
    REQUIRE_FALSE(block.has_finest());
    REQUIRE(block.current_scale == 1);
    for (int i = 0; i < kBlockMidVoxelCount; ++i) {
      REQUIRE(block.level_begin(1)[i].x == mid_before[static_cast<std::size_t>(i)].x);
      REQUIRE(block.level_begin(1)[i].x_last == mid_before[static_cast<std::size_t>(i)].x_last);
      REQUIRE(block.level_begin(1)[i].delta_y == mid_before[static_cast<std::size_t>(i)].delta_y);
    }
  };
  // Another block's record.
  REQUIRE(restore_finest_from_record(map, a, record_b.data(), record_b.size(), kYMax).code() ==
          StatusCode::invalid_argument);
  unchanged();
  // A record without a finest level (the block as it is now).
  const std::vector<std::uint8_t> coarse = record_of(map.block(a));
  REQUIRE_FALSE(block_record_holds_finest<MultiresVoxel>(coarse.data(), coarse.size()));
  REQUIRE(restore_finest_from_record(map, a, coarse.data(), coarse.size(), kYMax).code() ==
          StatusCode::invalid_argument);
  unchanged();
  // Damaged anywhere, or cut.
  for (std::size_t at :
       {std::size_t{0}, std::size_t{20}, record_a.size() / 2, record_a.size() - 1}) {
    std::vector<std::uint8_t> bad = record_a;
    bad[at] ^= 0x08;
    REQUIRE(restore_finest_from_record(map, a, bad.data(), bad.size(), kYMax).code() ==
            StatusCode::data_loss);
    unchanged();
  }
  REQUIRE(restore_finest_from_record(map, a, record_a.data(), record_a.size() - 2, kYMax).code() ==
          StatusCode::data_loss);
  unchanged();
  // No such block.
  REQUIRE(
      restore_finest_from_record(map, map.block_count(), record_a.data(), record_a.size(), kYMax)
          .code() == StatusCode::out_of_range);
  // The finest pool full (b holds one level, a third block the other).
  std::uint32_t c = make_fine_block(map, Eigen::Vector3i(3, 1, 1));
  (void)c;
  REQUIRE(map.memory().finest_used == map.memory().finest_capacity);
  REQUIRE(restore_finest_from_record(map, a, record_a.data(), record_a.size(), kYMax).code() ==
          StatusCode::resource_exhausted);
  unchanged();
  // Room again: it refines.
  map.release_finest(&b, 1);
  REQUIRE(restore_finest_from_record(map, a, record_a.data(), record_a.size(), kYMax).ok());
  REQUIRE(map.block(a).has_finest());
}

TEST_CASE("single-res maps have no finest level to give back", "[map][store]") {
  MapFixture<TsdfVoxel> fixture(small_config(8, 64));
  const Result<std::uint32_t> index = fixture.map.allocate_block(Eigen::Vector3i(1, 1, 1));
  REQUIRE(index.ok());
  const std::vector<std::uint8_t> record = record_of(fixture.map.block(index.value()));
  REQUIRE_FALSE(block_record_holds_finest<TsdfVoxel>(record.data(), record.size()));
  REQUIRE(
      restore_finest_from_record(fixture.map, index.value(), record.data(), record.size(), kYMax)
          .code() == StatusCode::failed_precondition);
}

}  // namespace
}  // namespace octofuse
