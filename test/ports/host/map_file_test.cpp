// Map files: the committed small map with its free space (test/unit/map/data) loads from disk,
// saves back to the same bytes through the atomic writer, and missing or damaged files name
// themselves in the error.

#include "octofuse/ports/host/map_file.hpp"

#include <catch2/catch.hpp>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "octofuse/query/free_space.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

const std::string kFixture =
    std::string(OCTOFUSE_SOURCE_DIR) + "/test/unit/map/data/small_multires_v2.ofmap";

// A map and free space reserved for what the file's header needs, with some room to spare.
struct MapFor {
  explicit MapFor(const MapFileHeader& header) {
    MapConfig config = map_config_for(header);
    config.block_capacity += 16;
    config.node_capacity += 16;
    config.finest_capacity += 16;
    FreeSpaceConfig free_config;
    free_config.node_capacity = header.free_node_count + 16;
    free_config.margin_m = header.free_margin_m;
    free_config.finest_octant_voxels = header.free_octant_voxels;
    free_config.max_free_count = static_cast<std::uint8_t>(header.free_max_count);
    const std::size_t map_bytes = Octree<MultiresVoxel>::bytes_required(config);
    const std::size_t bytes =
        map_bytes + kArenaAlignment + FreeSpace::bytes_required(free_config, config, 1, 1);
    buffer = std::aligned_alloc(kArenaAlignment, align_up(bytes, kArenaAlignment));
    LinearArena arena(buffer, bytes);
    REQUIRE(map.reserve(arena, config).ok());
    REQUIRE(free_space.reserve(arena, free_config, config, 1, 1).ok());
  }
  ~MapFor() { std::free(buffer); }
  MapFor(const MapFor&) = delete;
  MapFor& operator=(const MapFor&) = delete;
  void* buffer = nullptr;
  Octree<MultiresVoxel> map;
  FreeSpace free_space;
};

TEST_CASE("a map file loads, and saves back to the same bytes atomically", "[host][map_file]") {
  ErrorText error;
  const Result<MapFileHeader> header = host::read_map_file_header(kFixture.c_str(), &error);
  INFO(error.c_str());
  REQUIRE(header.ok());
  CHECK(header.value().version == kMapFormatVersion);
  CHECK(header.value().voxel_type == MapVoxelType::multires);
  CHECK(header.value().voxel_size_m == 0.005f);
  CHECK(header.value().voxel_depth == 7);
  CHECK(header.value().block_count > 0);
  CHECK(header.value().free_node_count > 1);

  MapFor target(header.value());
  MapFileHeader loaded_header;
  REQUIRE(
      host::load_map_file(kFixture.c_str(), target.map, &target.free_space, &loaded_header, &error)
          .ok());
  CHECK(target.map.block_count() == header.value().block_count);
  CHECK(target.free_space.node_count() == header.value().free_node_count);
  CHECK(loaded_header.frames == header.value().frames);

  const std::string dir = test::make_test_dir("map_file");
  REQUIRE(!dir.empty());
  const std::string path = dir + "/saved.ofmap";
  {
    std::ofstream old(path, std::ios::binary);
    old << "the previous map";
  }
  MapSaveInfo info;
  info.frames = loaded_header.frames;
  info.mu_m = loaded_header.mu_m;
  REQUIRE(host::save_map_file(path.c_str(), target.map, &target.free_space, info, &error).ok());
  CHECK(test::read_bytes(path) == test::read_bytes(kFixture));
  CHECK(!test::file_exists(path + ".tmp"));
  // Without its free space the file is the same but for it (smaller), and loads as well.
  REQUIRE(host::save_map_file(path.c_str(), target.map, info, &error).ok());
  CHECK(test::read_bytes(path).size() < test::read_bytes(kFixture).size());
  REQUIRE(host::load_map_file(path.c_str(), target.map, &target.free_space, &loaded_header, &error)
              .ok());
  CHECK(loaded_header.free_node_count == 0);
  CHECK(target.free_space.node_count() == 1);
}

TEST_CASE("missing, unwritable and damaged map files say which file and what is wrong",
          "[host][map_file]") {
  const std::string dir = test::make_test_dir("map_file");
  REQUIRE(!dir.empty());
  ErrorText error;
  const std::string missing = dir + "/none.ofmap";
  CHECK(host::read_map_file_header(missing.c_str(), &error).status().code() ==
        StatusCode::unavailable);
  CHECK(std::string(error.c_str()).find(missing) == 0);

  const Result<MapFileHeader> header = host::read_map_file_header(kFixture.c_str(), &error);
  REQUIRE(header.ok());
  MapFor target(header.value());
  CHECK(host::load_map_file(missing.c_str(), target.map, nullptr, &error).code() ==
        StatusCode::unavailable);

  const std::string unwritable = dir + "/no/such/folder/map.ofmap";
  MapSaveInfo info;
  info.mu_m = 0.04f;
  CHECK(host::save_map_file(unwritable.c_str(), target.map, info, &error).code() ==
        StatusCode::unavailable);
  info.mu_m = 0.0f;  // not a truncation distance: refused, nothing written
  const std::string no_mu = dir + "/no_mu.ofmap";
  CHECK(host::save_map_file(no_mu.c_str(), target.map, info, &error).code() ==
        StatusCode::invalid_argument);
  CHECK(!test::file_exists(no_mu));
  CHECK(!test::file_exists(no_mu + ".tmp"));

  // Cut in the middle of the block records, then of the free-space records: the loader names
  // the file and the record, and leaves nothing loaded.
  const std::string bytes = test::read_bytes(kFixture);
  const std::string cut = dir + "/cut.ofmap";
  for (std::size_t keep : {std::size_t{8000}, bytes.size() - 100}) {
    {
      std::ofstream out(cut, std::ios::binary);
      out.write(bytes.data(), static_cast<std::streamsize>(keep));
    }
    REQUIRE(host::load_map_file(kFixture.c_str(), target.map, &target.free_space, nullptr, &error)
                .ok());
    CHECK(
        host::load_map_file(cut.c_str(), target.map, &target.free_space, nullptr, &error).code() ==
        StatusCode::data_loss);
    const std::string message = error.c_str();
    CHECK(message.find(cut + (keep == 8000 ? ": truncated in block record"
                                           : ": truncated in free-space record")) == 0);
    CHECK(target.map.block_count() == 0);
    CHECK(target.free_space.node_count() == 1);
  }

  const std::string text = dir + "/mesh.ply";
  {
    std::ofstream out(text, std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\n";
  }
  CHECK(host::load_map_file(text.c_str(), target.map, nullptr, &error).code() ==
        StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()) == text + ": not an octofuse map (bad magic)");
}

}  // namespace
}  // namespace octofuse
