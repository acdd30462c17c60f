// The free space's region records (FreeOctree::graft_region_record(), what a store hands back)
// on arbitrary bytes: a graft succeeds and leaves a whole tree, or is refused with the tree as it
// was. Input: a flag byte (bit 0: put a right CRC on the record, so mutations reach the tree
// checks), two bytes of region index (its key), then the record.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "octofuse/map/keys.hpp"
#include "octofuse/map/map_io.hpp"
#include "octofuse/query/free_space.hpp"

namespace {

struct FuzzFree {
  FuzzFree() {
    // 5 mm voxels, a cube of 2^7: leaves of 16 voxels at level 3, regions at level 1.
    config = octofuse::MapConfig::centred(Eigen::Vector3f(0.0f, 0.0f, 1.0f), 0.005f, 7, 64, 64);
    octofuse::FreeSpaceConfig free_config;
    free_config.node_capacity = 1024;
    const std::size_t bytes = octofuse::FreeSpace::bytes_required(free_config, config, 1, 1);
    buffer = std::aligned_alloc(octofuse::kArenaAlignment,
                                octofuse::align_up(bytes, octofuse::kArenaAlignment));
    octofuse::LinearArena arena(buffer, bytes);
    if (!space.reserve(arena, free_config, config, 1, 1).ok()) std::abort();
  }
  octofuse::MapConfig config;
  void* buffer = nullptr;
  octofuse::FreeSpace space;
};

void check_whole(const octofuse::FreeSpace& space) {
  const std::uint32_t count = space.node_count();
  std::vector<int> parents(count, 0);
  for (std::uint32_t i = 0; i < count; ++i) {
    for (const std::uint32_t child : space.node(i).children) {
      if (child == octofuse::FreeSpace::kNoNode) continue;
      if (child <= i || child >= count) std::abort();
      ++parents[child];
    }
  }
  for (std::uint32_t i = 1; i < count; ++i) {
    if (parents[i] != 1) std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static FuzzFree target;
  if (size < 3) return 0;
  octofuse::FreeSpace& space = target.space;
  space.clear();
  const int side = space.region_voxels();
  const int per_axis = (1 << target.config.voxel_depth) / side;
  const int index = (data[1] | (data[2] << 8)) % (per_axis * per_axis * per_axis + 1);
  const Eigen::Vector3i region(index % per_axis, index / per_axis % per_axis,
                               index / per_axis / per_axis % (per_axis + 1));
  const std::uint64_t key = octofuse::morton_encode(region * side / 8);
  std::vector<std::uint8_t> record(data + 3, data + size);
  if ((data[0] & 1) != 0 && record.size() >= 4) {
    const std::uint32_t crc = octofuse::crc32(record.data(), record.size() - 4);
    for (int i = 0; i < 4; ++i)
      record[record.size() - 4 + i] = static_cast<std::uint8_t>(crc >> (8 * i));
  }
  for (int round = 0; round < 2; ++round) {
    const std::uint32_t before = space.node_count();
    const octofuse::Status status = space.graft_region_record(key, record.data(), record.size());
    if (!status.ok() && space.node_count() != before) std::abort();
    check_whole(space);
    // The same record grafted twice adds nothing the second time.
    if (round == 1 && status.ok() && space.node_count() != before) std::abort();
    if (!status.ok()) break;
  }
  return 0;
}
