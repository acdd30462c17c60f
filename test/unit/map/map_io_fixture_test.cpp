// The committed map files (test/unit/map/data): what every build writes, and what every build
// must still load.

#include "octofuse/map/map_io.hpp"

#include <catch2/catch.hpp>

#include "unit/map/map_io_support.hpp"

namespace octofuse {
namespace {

// The cross-architecture fixture: a small map with its free space that every build must write
// byte for byte and load to the same mesh and free space. To regenerate it after a deliberate
// format or fusion change, run
//   OCTOFUSE_WRITE_MAP_FIXTURE=1 build/host-release/test/unit_map "[fixture]"
// and commit test/unit/map/data/small_multires_v2.ofmap. small_multires_v1.ofmap, the same map
// saved in format version 1 by an earlier build, stays: every build must still load it.
TEST_CASE("the committed small map is what every build writes and loads", "[fixture]") {
  // 5 mm voxels seen from 0.7 m and further integrate at scales 1-2 (no 8 KiB finest levels),
  // and a few blocks and free-space nodes per frame keep the file small.
  PipelineConfig config = config_for<MultiresVoxel>(0.005f);
  config.budget.max_new_blocks = 12;
  config.free_space.max_new_nodes = 100;
  config.free_space.finest_octant_voxels = 8;  // as the fixtures were saved (automatic: 16)
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(1), 0, 1);
  const std::vector<std::uint8_t> written =
      save(mapper.pipeline.map(), mapper.pipeline.free_space(), 1, config.fusion.mu_m);
  const std::string path =
      std::string(OCTOFUSE_SOURCE_DIR) + "/test/unit/map/data/small_multires_v2.ofmap";
  const char* regenerate = std::getenv("OCTOFUSE_WRITE_MAP_FIXTURE");
  if (regenerate != nullptr && regenerate[0] == '1') {
    std::ofstream out(path, std::ios::binary);
    out.write(reinterpret_cast<const char*>(written.data()),
              static_cast<std::streamsize>(written.size()));
    REQUIRE(out.good());
  }
  std::ifstream in(path, std::ios::binary);
  REQUIRE(in.good());
  const std::vector<std::uint8_t> committed((std::istreambuf_iterator<char>(in)),
                                            std::istreambuf_iterator<char>());
  CHECK(committed.size() < 20480);
  CHECK(written == committed);
  Mapper<MultiresVoxel> loaded(config);
  ErrorText error;
  REQUIRE(load_all(committed, loaded.pipeline.map(), loaded.pipeline.free_space(), &error).ok());
  CHECK(loaded.pipeline.map().block_count() == mapper.pipeline.map().block_count());
  int free_octants = 0;
  for (std::uint32_t i = 0; i < loaded.pipeline.free_space().node_count(); ++i) {
    free_octants += loaded.pipeline.free_space().node(i).free_count > 0 ? 1 : 0;
  }
  CHECK(free_octants > 10);
  CHECK(free_space_bytes(loaded.pipeline.free_space()) ==
        free_space_bytes(mapper.pipeline.free_space()));
  const ByteMeshSink mesh = mesh_of(loaded.pipeline.map());
  CHECK(mesh.vertices > 0);
  CHECK(mesh.bytes == mesh_of(mapper.pipeline.map()).bytes);
}

TEST_CASE("a version 1 map file still loads: the same TSDF, free space without sub-cells",
          "[fixture]") {
  PipelineConfig config = config_for<MultiresVoxel>(0.005f);
  config.budget.max_new_blocks = 12;
  config.free_space.max_new_nodes = 100;
  config.free_space.finest_octant_voxels = 8;  // as the fixtures were saved (automatic: 16)
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(1), 0, 1);
  std::ifstream in(std::string(OCTOFUSE_SOURCE_DIR) + "/test/unit/map/data/small_multires_v1.ofmap",
                   std::ios::binary);
  REQUIRE(in.good());
  const std::vector<std::uint8_t> v1((std::istreambuf_iterator<char>(in)),
                                     std::istreambuf_iterator<char>());
  REQUIRE(v1.size() > 12);
  REQUIRE(v1[8] == 1);  // the version's low byte
  Mapper<MultiresVoxel> loaded(config);
  ErrorText error;
  REQUIRE(load_all(v1, loaded.pipeline.map(), loaded.pipeline.free_space(), &error).ok());
  const FreeSpace& free_space = loaded.pipeline.free_space();
  int free_octants = 0;
  for (std::uint32_t i = 0; i < free_space.node_count(); ++i) {
    REQUIRE(free_space.node(i).sub_free == 0);
    free_octants += free_space.node(i).free_count > 0 ? 1 : 0;
  }
  CHECK(free_octants > 10);
  // Fusion did not change between the versions: the same blocks, the same mesh.
  CHECK(loaded.pipeline.map().block_count() == mapper.pipeline.map().block_count());
  CHECK(mesh_of(loaded.pipeline.map()).bytes == mesh_of(mapper.pipeline.map()).bytes);
}

}  // namespace
}  // namespace octofuse
