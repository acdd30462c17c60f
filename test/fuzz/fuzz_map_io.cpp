// The map loader: arbitrary bytes as a map file, loaded into a small map and free space of each
// voxel type with the geometry and free-space settings of the seed
// (test/unit/map/data/small_multires_v2.ofmap), so mutated seeds get past the header. Every input
// is loaded or refused with a Status; a refused load leaves the map and the free space empty, and
// a loaded one saves back to exactly the input (an older version: to a current file, which loads
// and saves back to itself). check_map(), the check a save runs on what it wrote, reads every
// input without crashing, and passes every input some map loads (it checks a subset).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "octofuse/map/map_io.hpp"
#include "octofuse/query/free_space.hpp"

namespace {

template <typename VoxelT>
struct FuzzMap {
  FuzzMap() {
    const octofuse::MapConfig config = octofuse::MapConfig::centred(
        Eigen::Vector3f(0.0f, 0.0f, 1.0f), 0.005f, 7, 4096, 4096 / 2 + 1024);
    octofuse::FreeSpaceConfig free_config;  // the defaults the seed was carved with
    free_config.node_capacity = 4096;
    const std::size_t map_bytes = octofuse::Octree<VoxelT>::bytes_required(config);
    const std::size_t bytes = map_bytes + octofuse::kArenaAlignment +
                              octofuse::FreeSpace::bytes_required(free_config, config, 1, 1);
    buffer = std::aligned_alloc(octofuse::kArenaAlignment,
                                octofuse::align_up(bytes, octofuse::kArenaAlignment));
    octofuse::LinearArena arena(buffer, bytes);
    if (!map.reserve(arena, config).ok()) std::abort();
    if (!free_space.reserve(arena, free_config, config, 1, 1).ok()) std::abort();
  }
  void* buffer = nullptr;
  octofuse::Octree<VoxelT> map;
  octofuse::FreeSpace free_space;
};

class VectorSink final : public octofuse::ByteSink {
 public:
  octofuse::Status write(const std::uint8_t* bytes, std::size_t count) override {
    data.insert(data.end(), bytes, bytes + count);
    return octofuse::ok_status();
  }
  std::vector<std::uint8_t> data;
};

template <typename VoxelT>
void load(FuzzMap<VoxelT>& target, const std::uint8_t* data, std::size_t size, bool checked) {
  octofuse::MemorySource source(data, size);
  octofuse::ErrorText error;
  octofuse::MapFileHeader header;
  const octofuse::Status status =
      octofuse::load_map(source, target.map, &target.free_space, &header, &error);
  const bool free_space_empty =
      target.free_space.node_count() == 1 && target.free_space.node(0).free_count == 0;
  if (!status.ok()) {
    if (target.map.block_count() != 0 || target.map.node_count() != 1 || !free_space_empty ||
        error.empty()) {
      std::abort();
    }
    return;
  }
  if (!checked) std::abort();  // loaded, yet refused by the check that needs no map
  VectorSink again;
  octofuse::MapSaveInfo info;
  info.frames = header.frames;
  info.mu_m = header.mu_m;
  const octofuse::FreeSpace* saved_free = header.free_node_count > 0 ? &target.free_space : nullptr;
  if (!octofuse::save_map(target.map, saved_free, info, again).ok()) std::abort();
  if (header.version == octofuse::kMapFormatVersion) {
    if (again.data.size() != size) std::abort();
    if (std::memcmp(again.data.data(), data, size) == 0) return;
    // Only what scale 0 does not keep (its voxels' x_last and delta_y, saved as x and 0) may
    // differ: then, as for an older version, what is saved is a fixed point.
  }
  // An older version loads and saves as the current one, which must load back and save to the
  // same bytes again.
  octofuse::MemorySource resaved(again.data.data(), again.data.size());
  if (!octofuse::load_map(resaved, target.map, &target.free_space, &header, &error).ok()) {
    std::abort();
  }
  VectorSink twice;
  if (!octofuse::save_map(target.map, saved_free, info, twice).ok()) std::abort();
  if (twice.data != again.data) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static FuzzMap<octofuse::MultiresVoxel> multires;
  static FuzzMap<octofuse::TsdfVoxel> single;
  static FuzzMap<octofuse::Multires16Voxel> compact;
  octofuse::MemorySource check_source(data, size);
  octofuse::ErrorText check_error;
  const bool checked = octofuse::check_map(check_source, nullptr, &check_error).ok();
  if (!checked && check_error.empty()) std::abort();
  load(multires, data, size, checked);
  load(single, data, size, checked);
  load(compact, data, size, checked);
  octofuse::MemorySource source(data, size);
  octofuse::read_map_header(source).status().ignore();
  return 0;
}
