// Block records for a BlockStore: a block encoded and restored into another map holds the same
// state, creating its inner nodes; a damaged record, a block already in memory and a full pool
// leave the map unchanged.

#include "octofuse/map/block_store.hpp"

#include <catch2/catch.hpp>
#include <cstring>
#include <vector>

#include "octofuse/map/map_io.hpp"
#include "unit/map/octree_support.hpp"

namespace octofuse {
namespace {

template <typename VoxelT>
void fill_block(Octree<VoxelT>& map, VoxelBlock<VoxelT>& block, int scale) {
  if (scale == 0) REQUIRE(map.acquire_finest(block).ok());
  if (scale == 1) REQUIRE(map.acquire_mid(block).ok());
  for (int i = block.first_stored_voxel(); i < kBlockVoxelCount; ++i) {
    VoxelT v = block.voxel(i);
    set_voxel_tsdf(v, static_cast<float>(i % 41) / 20.0f - 1.0f);
    set_voxel_weight(v, 1.0f + static_cast<float>(i % 5));
    block.set_voxel(i, v);
  }
  block.current_scale = static_cast<std::int8_t>(scale);
  block.min_scale = static_cast<std::int8_t>(scale);
  block.mip_scale = static_cast<std::int8_t>(scale);
  block.last_updated_frame = 77;
  Octree<VoxelT>::update_block_summary(block);
}

TEMPLATE_TEST_CASE("a block record restores the block's whole state in another map", "[map][store]",
                   MultiresVoxel, Multires16Voxel, TsdfVoxel) {
  using VoxelT = TestType;
  MapFixture<VoxelT> a(small_config(8, 64));
  MapFixture<VoxelT> b(small_config(8, 64));
  const bool split = VoxelBlock<VoxelT>::kSplitFinest;
  for (int scale : {0, 1, 2}) {
    CAPTURE(scale);
    const Eigen::Vector3i coords(3 + 4 * scale, 17, 30);
    Result<std::uint32_t> index = a.map.allocate_block(coords);
    REQUIRE(index.ok());
    VoxelBlock<VoxelT>& block = a.map.block(index.value());
    fill_block(a.map, block, split ? scale : 0);
    std::vector<std::uint8_t> record(block_record_max_bytes<VoxelT>());
    const Result<std::size_t> size = encode_block_record(block, record.data(), record.size());
    REQUIRE(size.ok());
    REQUIRE(encode_block_record(block, record.data(), size.value() - 1).status().code() ==
            StatusCode::resource_exhausted);

    // Damaged anywhere: data_loss, nothing allocated.
    const std::uint32_t nodes = b.map.node_count();
    for (std::size_t at : {std::size_t{0}, std::size_t{5}, size.value() / 2, size.value() - 1}) {
      std::vector<std::uint8_t> bad(record.begin(), record.begin() + size.value());
      bad[at] ^= 0x10;
      REQUIRE(restore_block_record(b.map, bad.data(), bad.size()).status().code() ==
              StatusCode::data_loss);
      REQUIRE(b.map.node_count() == nodes);
    }
    REQUIRE(restore_block_record(b.map, record.data(), size.value() - 3).status().code() ==
            StatusCode::data_loss);

    const Result<std::uint32_t> restored = restore_block_record(b.map, record.data(), size.value());
    REQUIRE(restored.ok());
    REQUIRE(b.map.node_count() > nodes);  // its inner nodes came back with it
    const VoxelBlock<VoxelT>& got = b.map.block(restored.value());
    REQUIRE(got.coords == coords);
    REQUIRE(got.current_scale == block.current_scale);
    REQUIRE(got.min_scale == block.min_scale);
    REQUIRE(got.mip_scale == block.mip_scale);
    REQUIRE(got.last_updated_frame == 77u);
    REQUIRE(got.tsdf_mean == block.tsdf_mean);
    REQUIRE(got.has_finest() == block.has_finest());
    // A block never fused finer than scale 2 comes back without a mid level, as it left.
    REQUIRE(got.has_mid() == block.has_mid());
    REQUIRE(got.has_mid() == (!split || scale <= 1));
    const VoxelBlock<VoxelT>& source = block;
    for (int i = 0; i < kBlockVoxelCount; ++i) {
      REQUIRE(voxel_tsdf(got.voxel(i)) == voxel_tsdf(source.voxel(i)));
      REQUIRE(voxel_weight(got.voxel(i)) == voxel_weight(source.voxel(i)));
    }
    // Already in memory: refused, untouched.
    REQUIRE(restore_block_record(b.map, record.data(), size.value()).status().code() ==
            StatusCode::failed_precondition);
  }
}

TEST_CASE("with the finest-level pool full a block comes back at scale 1, brought up to date",
          "[map][store]") {
  MapFixture<MultiresVoxel> a(small_config(8, 64));
  MapConfig full_config = small_config(8, 64);
  full_config.finest_capacity = 1;
  MapFixture<MultiresVoxel> b(full_config);
  Result<std::uint32_t> index = a.map.allocate_block(Eigen::Vector3i(1, 2, 3));
  REQUIRE(index.ok());
  VoxelBlock<MultiresVoxel>& block = a.map.block(index.value());
  fill_block(a.map, block, 0);
  block.mip_scale = 0;  // scale 1 not yet brought up to date from scale 0
  std::vector<std::uint8_t> record(block_record_max_bytes<MultiresVoxel>());
  const Result<std::size_t> size = encode_block_record(block, record.data(), record.size());
  REQUIRE(size.ok());
  // Fill b's one finest level.
  Result<std::uint32_t> other = b.map.allocate_block(Eigen::Vector3i(5, 5, 5));
  REQUIRE(other.ok());
  REQUIRE(b.map.acquire_finest(b.map.block(other.value())).ok());
  const Result<std::uint32_t> restored = restore_block_record(b.map, record.data(), size.value());
  REQUIRE(restored.ok());
  const VoxelBlock<MultiresVoxel>& got = b.map.block(restored.value());
  REQUIRE_FALSE(got.has_finest());
  REQUIRE(got.current_scale == 1);
  REQUIRE(got.mip_scale == 1);
  // Scale 1 holds the weighted means of the finest voxels: as release_finest() makes them.
  a.map.release_finest(&index.value(), 1);
  for (int i = kBlockFinestVoxelCount; i < kBlockVoxelCount; ++i) {
    REQUIRE(got.voxel(i).x == a.map.block(index.value()).voxel(i).x);
    REQUIRE(got.voxel(i).y == a.map.block(index.value()).voxel(i).y);
  }
  REQUIRE(got.tsdf_mean == a.map.block(index.value()).tsdf_mean);
}

TEST_CASE(
    "with the mid-level pool full a stored block comes back at scale 2, as release_mid leaves it",
    "[map][store]") {
  MapFixture<MultiresVoxel> a(small_config(8, 64));
  MapConfig full_config = small_config(8, 64);
  full_config.mid_capacity = 1;
  MapFixture<MultiresVoxel> b(full_config);
  // Fill b's one mid level.
  Result<std::uint32_t> other = b.map.allocate_block(Eigen::Vector3i(5, 5, 5));
  REQUIRE(other.ok());
  REQUIRE(b.map.acquire_mid(b.map.block(other.value())).ok());
  for (int scale : {0, 1}) {
    CAPTURE(scale);
    Result<std::uint32_t> index = a.map.allocate_block(Eigen::Vector3i(1 + 4 * scale, 2, 3));
    REQUIRE(index.ok());
    VoxelBlock<MultiresVoxel>& block = a.map.block(index.value());
    fill_block(a.map, block, scale);
    block.mip_scale = static_cast<std::int8_t>(scale);  // coarser levels not yet brought up
    std::vector<std::uint8_t> record(block_record_max_bytes<MultiresVoxel>());
    const Result<std::size_t> size = encode_block_record(block, record.data(), record.size());
    REQUIRE(size.ok());
    const Result<std::uint32_t> restored = restore_block_record(b.map, record.data(), size.value());
    REQUIRE(restored.ok());
    const VoxelBlock<MultiresVoxel>& got = b.map.block(restored.value());
    REQUIRE_FALSE(got.has_finest());
    REQUIRE_FALSE(got.has_mid());
    REQUIRE(got.current_scale == 2);
    REQUIRE(got.mip_scale == 2);
    REQUIRE(b.map.memory().mid_used == 1u);
    REQUIRE(b.map.memory().finest_used == 0u);
    // Scales 2 and 3 as release_mid() makes them from the same block.
    a.map.release_mid(&index.value(), 1);
    const VoxelBlock<MultiresVoxel>& reference = a.map.block(index.value());
    for (int i = block_scale_offset(2); i < kBlockVoxelCount; ++i) {
      REQUIRE(got.voxel(i).x == reference.voxel(i).x);
      REQUIRE(got.voxel(i).y == reference.voxel(i).y);
    }
    REQUIRE(got.tsdf_mean == reference.tsdf_mean);
  }
}

// A finest voxel keeps its TSDF and weight alone; records keep their format, writing it with
// x_last = x and delta_y = 0. A record of a build that kept both at scale 0 still restores, with
// the same TSDF and weight.
TEST_CASE(
    "a finest level's record holds x_last = x and delta_y = 0, and one with other values "
    "restores the TSDF and weight",
    "[map][store]") {
  MapFixture<MultiresVoxel> a(small_config(8, 64));
  MapFixture<MultiresVoxel> b(small_config(8, 64));
  const Result<std::uint32_t> index = a.map.allocate_block({2, 2, 2});
  REQUIRE(index.ok());
  const VoxelBlock<MultiresVoxel>& block = a.map.block(index.value());
  fill_block(a.map, a.map.block(index.value()), 0);
  std::vector<std::uint8_t> record(block_record_max_bytes<MultiresVoxel>());
  const Result<std::size_t> size = encode_block_record(block, record.data(), record.size());
  REQUIRE(size.ok());
  record.resize(size.value());
  // Tag, Morton code, frame, three scales, flags, summary: 33 bytes; then 16 a float voxel
  // (x, x_last, y, delta_y), the finest level first; the record's CRC-32 last.
  constexpr std::size_t kFirstVoxel = 33;
  auto f32_at = [&record](std::size_t at) {
    std::uint32_t bits = 0;
    for (int k = 0; k < 4; ++k) bits |= std::uint32_t{record[at + k]} << (8 * k);
    float value;
    std::memcpy(&value, &bits, sizeof value);
    return value;
  };
  auto put_f32 = [&record](std::size_t at, float value) {
    std::uint32_t bits;
    std::memcpy(&bits, &value, sizeof bits);
    for (int k = 0; k < 4; ++k) record[at + k] = static_cast<std::uint8_t>(bits >> (8 * k));
  };
  auto put_crc = [&record] {
    const std::uint32_t crc = crc32(record.data(), record.size() - 4);
    for (int k = 0; k < 4; ++k) {
      record[record.size() - 4 + k] = static_cast<std::uint8_t>(crc >> (8 * k));
    }
  };
  const std::vector<std::uint8_t> written = record;
  put_crc();
  REQUIRE(record == written);  // the CRC covers the bytes before it
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    const std::size_t at = kFirstVoxel + 16 * static_cast<std::size_t>(i);
    CAPTURE(i);
    REQUIRE(f32_at(at) == block.finest_begin()[i].x);
    REQUIRE(f32_at(at + 4) == f32_at(at));  // x_last
    REQUIRE(f32_at(at + 8) == block.finest_begin()[i].y);
    REQUIRE(f32_at(at + 12) == 0.0f);  // delta_y
  }
  // As a build that kept an interval at scale 0 may have written it.
  for (int i = 0; i < kBlockFinestVoxelCount; i += 3) {
    const std::size_t at = kFirstVoxel + 16 * static_cast<std::size_t>(i);
    put_f32(at + 4, -0.5f);
    put_f32(at + 12, 7.0f);
  }
  put_crc();
  const Result<std::uint32_t> restored = restore_block_record(b.map, record.data(), record.size());
  REQUIRE(restored.ok());
  const VoxelBlock<MultiresVoxel>& got = b.map.block(restored.value());
  REQUIRE(got.has_finest());
  for (int i = 0; i < kBlockFinestVoxelCount; ++i) {
    CAPTURE(i);
    REQUIRE(got.finest_begin()[i].x == block.finest_begin()[i].x);
    REQUIRE(got.finest_begin()[i].y == block.finest_begin()[i].y);
  }
  // And it is written back as this build writes it.
  std::vector<std::uint8_t> again(block_record_max_bytes<MultiresVoxel>());
  const Result<std::size_t> again_size = encode_block_record(got, again.data(), again.size());
  REQUIRE(again_size.ok());
  again.resize(again_size.value());
  CHECK(again == written);
}

TEST_CASE("a record's scale-1 voxels come back whenever they hold anything", "[map][store]") {
  // A block at scale 2 whose scale 1 is not unobserved (what no integration writes, but a record
  // may hold): the restored block takes a mid level and keeps them.
  MapFixture<MultiresVoxel> a(small_config(8, 64));
  MapFixture<MultiresVoxel> b(small_config(8, 64));
  const Result<std::uint32_t> index = a.map.allocate_block({2, 2, 2});
  REQUIRE(index.ok());
  VoxelBlock<MultiresVoxel>& block = a.map.block(index.value());
  fill_block(a.map, block, 2);
  REQUIRE(a.map.acquire_mid(block).ok());
  block.level_at(1, 2, 3, 1) = MultiresVoxel{0.25f, 0.25f, 3.0f, 0.0f};
  std::vector<std::uint8_t> record(block_record_max_bytes<MultiresVoxel>());
  const Result<std::size_t> size = encode_block_record(block, record.data(), record.size());
  REQUIRE(size.ok());
  const Result<std::uint32_t> restored = restore_block_record(b.map, record.data(), size.value());
  REQUIRE(restored.ok());
  const VoxelBlock<MultiresVoxel>& got = b.map.block(restored.value());
  REQUIRE(got.has_mid());
  CHECK(got.at(1, 2, 3, 1).x == 0.25f);
  CHECK(got.at(1, 2, 3, 1).y == 3.0f);
  CHECK(b.map.memory().mid_used == 1);
}

}  // namespace
}  // namespace octofuse
