// Block records from a store (what a BlockStore hands back) on arbitrary bytes:
// restore_block_record() into an empty map, or restore_finest_from_record() onto a block of the
// record's key that gave its finest level up. Either succeeds with a sound block (a restored one
// encodes back to the input; a finest level restored refines to finite values in range) or is
// refused with the map as it was. Input: a flag byte (bit 0: put a right CRC on the record, so
// mutations reach the field checks; bit 1: restore a finest level instead of a block), then the
// record.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "octofuse/map/block_store.hpp"
#include "octofuse/map/detail/propagation.hpp"
#include "octofuse/map/keys.hpp"
#include "octofuse/map/map_io.hpp"

namespace {

using octofuse::MultiresVoxel;
using Map = octofuse::Octree<MultiresVoxel>;
using Block = octofuse::VoxelBlock<MultiresVoxel>;

struct FuzzMap {
  FuzzMap() {
    // 5 mm voxels, a cube of 2^7 voxels (16 blocks a side).
    const octofuse::MapConfig config =
        octofuse::MapConfig::centred(Eigen::Vector3f(0.0f, 0.0f, 1.0f), 0.005f, 7, 64, 256);
    bytes = Map::bytes_required(config);
    buffer = std::aligned_alloc(octofuse::kArenaAlignment,
                                octofuse::align_up(bytes, octofuse::kArenaAlignment));
    octofuse::LinearArena arena(buffer, bytes);
    if (!map.reserve(arena, config).ok()) std::abort();
  }
  std::size_t bytes = 0;
  void* buffer = nullptr;
  Map map;
};

bool voxel_sound(const MultiresVoxel& v) {
  return std::isfinite(v.x) && v.x >= -1.0f && v.x <= 1.0f && std::isfinite(v.y) && v.y >= 0.0f;
}

void restore_block(Map& map, const std::uint8_t* record, std::size_t size) {
  map.clear();
  const octofuse::Result<std::uint32_t> index = octofuse::restore_block_record(map, record, size);
  if (!index.ok()) {
    if (map.block_count() != 0) std::abort();
    return;
  }
  std::vector<std::uint8_t> again(octofuse::block_record_max_bytes<MultiresVoxel>());
  const octofuse::Result<std::size_t> written =
      octofuse::encode_block_record(map.block(index.value()), again.data(), again.size());
  if (!written.ok() || written.value() != size) std::abort();
  if (std::memcmp(again.data(), record, size) == 0) return;
  // Only what scale 0 does not keep (its voxels' x_last and delta_y, written as x and 0) may
  // differ: the record written is a fixed point.
  map.clear();
  const octofuse::Result<std::uint32_t> again_index =
      octofuse::restore_block_record(map, again.data(), written.value());
  if (!again_index.ok()) std::abort();
  std::vector<std::uint8_t> third(again.size());
  const octofuse::Result<std::size_t> third_size =
      octofuse::encode_block_record(map.block(again_index.value()), third.data(), third.size());
  if (!third_size.ok() || third_size.value() != size ||
      std::memcmp(third.data(), again.data(), size) != 0) {
    std::abort();
  }
}

void restore_finest(Map& map, const std::uint8_t* record, std::size_t size) {
  map.clear();
  // The block the record names (its key follows the tag), where the key is one: at scale 1 with
  // a mid level, as demotion leaves a block.
  std::uint64_t morton = 0;
  if (size >= 9) {
    for (int i = 0; i < 8; ++i) morton |= std::uint64_t{record[1 + i]} << (8 * i);
  }
  const Eigen::Vector3i coords = octofuse::voxel_to_block(octofuse::morton_decode(morton));
  const octofuse::Result<std::uint32_t> allocated = map.allocate_block(coords);
  if (!allocated.ok()) return;
  Block& block = map.block(allocated.value());
  if (!map.acquire_mid(block).ok()) std::abort();
  for (int i = octofuse::kBlockFinestVoxelCount; i < octofuse::kBlockVoxelCount; ++i) {
    MultiresVoxel& v = block.level_voxel(i);
    v.x = static_cast<float>(i % 17) / 8.0f - 1.0f;
    v.x_last = v.x;
    v.y = static_cast<float>(i % 5);
  }
  block.current_scale = 1;
  block.min_scale = 0;
  block.mip_scale = 1;
  std::vector<std::uint8_t> before(sizeof(Block));
  std::memcpy(before.data(), &block, sizeof(Block));
  std::vector<MultiresVoxel> mid_before(block.level_begin(1),
                                        block.level_begin(1) + octofuse::kBlockMidVoxelCount);
  const octofuse::Status restored =
      octofuse::restore_finest_from_record(map, allocated.value(), record, size, 100.0f);
  if (!restored.ok()) {
    if (std::memcmp(before.data(), &block, sizeof(Block)) != 0 ||
        std::memcmp(mid_before.data(), block.level_begin(1),
                    sizeof(MultiresVoxel) * octofuse::kBlockMidVoxelCount) != 0 ||
        map.memory().finest_used != 0) {
      std::abort();
    }
    return;
  }
  if (!block.has_finest() || block.current_scale != 1) std::abort();
  octofuse::propagate_block_down(block, 1, 100.0f);
  for (int i = 0; i < octofuse::kBlockVoxelCount; ++i) {
    const MultiresVoxel& v = block.voxel(i);
    if (v.y > 0.0f && !voxel_sound(v)) std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static FuzzMap target;
  if (size < 1) return 0;
  const std::uint8_t flags = data[0];
  std::vector<std::uint8_t> record(data + 1, data + size);
  if ((flags & 1u) != 0 && record.size() >= 4) {
    const std::uint32_t crc = octofuse::crc32(record.data(), record.size() - 4);
    for (int i = 0; i < 4; ++i)
      record[record.size() - 4 + i] = static_cast<std::uint8_t>(crc >> (8 * i));
  }
  if ((flags & 2u) != 0) {
    restore_finest(target.map, record.data(), record.size());
  } else {
    restore_block(target.map, record.data(), record.size());
  }
  return 0;
}
