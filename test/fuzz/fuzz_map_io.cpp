// The map loader: arbitrary bytes as a map file, loaded into a small map of each voxel type with
// the geometry of the seed (test/unit/map/data/small_multires_v1.ofmap), so mutated seeds get past
// the header. Every input is loaded or refused with a Status; a refused load leaves the map
// empty, and a loaded one saves back to exactly the input.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "octofuse/map/map_io.hpp"

namespace {

template <typename VoxelT>
struct FuzzMap {
  FuzzMap() {
    const octofuse::MapConfig config = octofuse::MapConfig::centred(
        Eigen::Vector3f(0.0f, 0.0f, 1.0f), 0.005f, 7, 4096, 4096 / 2 + 1024);
    const std::size_t bytes = octofuse::Octree<VoxelT>::bytes_required(config);
    buffer = std::aligned_alloc(octofuse::kArenaAlignment,
                                octofuse::align_up(bytes, octofuse::kArenaAlignment));
    octofuse::LinearArena arena(buffer, bytes);
    if (!map.reserve(arena, config).ok()) std::abort();
  }
  void* buffer = nullptr;
  octofuse::Octree<VoxelT> map;
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
void load(FuzzMap<VoxelT>& target, const std::uint8_t* data, std::size_t size) {
  octofuse::MemorySource source(data, size);
  octofuse::ErrorText error;
  octofuse::MapFileHeader header;
  const octofuse::Status status = octofuse::load_map(source, target.map, &header, &error);
  if (!status.ok()) {
    if (target.map.block_count() != 0 || target.map.node_count() != 1 || error.empty()) {
      std::abort();
    }
    return;
  }
  VectorSink again;
  octofuse::MapSaveInfo info;
  info.frames = header.frames;
  info.mu_m = header.mu_m;
  if (!octofuse::save_map(target.map, info, again).ok()) std::abort();
  if (again.data.size() != size || std::memcmp(again.data.data(), data, size) != 0) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static FuzzMap<octofuse::MultiresVoxel> multires;
  static FuzzMap<octofuse::TsdfVoxel> single;
  load(multires, data, size);
  load(single, data, size);
  octofuse::MemorySource source(data, size);
  octofuse::read_map_header(source).status().ignore();
  return 0;
}
