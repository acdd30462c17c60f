// Map persistence: a saved and loaded map is the same map (same file bytes, same mesh, same
// ray-cast), and fusion goes on in it as in an uninterrupted run.

#include "octofuse/map/map_io.hpp"

#include <catch2/catch.hpp>

#include "unit/map/map_io_support.hpp"

namespace octofuse {
namespace {

// Vertices, normals and scales of a ray-cast from `T_W_C`, as bytes.
template <typename VoxelT>
std::vector<std::uint8_t> raycast_of(const Octree<VoxelT>& map, const PipelineConfig& pc,
                                     const Se3d& T_W_C) {
  RaycastConfig config;
  config.width = kWidth;
  config.height = kHeight;
  config.mu_m = pc.fusion.mu_m;
  test::ArenaBuffer buffer(Raycaster<VoxelT>::bytes_required(config));
  Raycaster<VoxelT> raycaster;
  REQUIRE(raycaster.reserve(buffer.arena(), config).ok());
  const Result<RaycastStats> stats = raycaster.raycast(map, camera(), T_W_C, WorkerTeam());
  REQUIRE(stats.ok());
  REQUIRE(stats.value().valid_pixels > kWidth * kHeight / 2);
  std::vector<std::uint8_t> out;
  const SurfaceMap s = raycaster.surface_W();
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const auto* v = reinterpret_cast<const std::uint8_t*>(s.vertices(x, y).data());
      const auto* n = reinterpret_cast<const std::uint8_t*>(s.normals(x, y).data());
      out.insert(out.end(), v, v + 12);
      out.insert(out.end(), n, n + 12);
      out.push_back(raycaster.scale_image()(x, y));
    }
  }
  return out;
}

TEMPLATE_TEST_CASE("a loaded map is the saved one: same bytes, mesh and ray-cast", "", TsdfVoxel,
                   MultiresVoxel, Multires16Voxel) {
  const PipelineConfig config = config_for<TestType>();
  const Frames frames(6);
  Mapper<TestType> mapper(config);
  mapper.run(frames, 0, frames.count());
  const Octree<TestType>& original = mapper.pipeline.map();
  REQUIRE(original.block_count() > 20);
  if constexpr (IsMultiresVoxel<TestType>::value) {
    // Both kinds of multires block: with and without a finest level.
    REQUIRE(original.memory().finest_used > 0);
    REQUIRE(original.memory().finest_used < original.block_count());
  }
  const std::vector<std::uint8_t> file = save(original, mapper.pipeline.frame_count());

  BareMap<TestType> loaded(config.map);
  MapFileHeader header;
  ErrorText error;
  // Reads of any size: the reader must not depend on how the source splits the bytes.
  for (std::size_t chunk : {std::size_t{1}, std::size_t{7}, std::size_t{1} << 20}) {
    TrickleSource source(file, chunk);
    const Status s = load_map(source, loaded.map, &header, &error);
    INFO(error.c_str());
    REQUIRE(s.ok());
  }
  CHECK(header.version == kMapFormatVersion);
  CHECK(header.frames == 6);
  CHECK(header.mu_m == 0.16f);
  CHECK(header.block_count == original.block_count());
  CHECK(header.node_count == original.node_count());
  CHECK(loaded.map.block_count() == original.block_count());
  CHECK(loaded.map.node_count() == original.node_count());
  CHECK(loaded.map.memory().finest_used == original.memory().finest_used);
  for (std::uint32_t i = 0; i < original.block_count(); ++i) {
    REQUIRE(loaded.map.find_block_index(original.block(i).coords) == i);
    REQUIRE(loaded.map.block(i).parent_node == original.block(i).parent_node);
  }
  CHECK(save(loaded.map, 6) == file);

  const ByteMeshSink mesh_a = mesh_of(original);
  const ByteMeshSink mesh_b = mesh_of(loaded.map);
  CHECK(mesh_a.vertices > 100);
  CHECK(mesh_a.bytes == mesh_b.bytes);
  for (const Se3d& T : {pose(5), pose(0), test::looking_along_z(Eigen::Vector3d(0.1, 0.05, 0.2))}) {
    CHECK(raycast_of(original, config, T) == raycast_of(loaded.map, config, T));
  }
}

TEST_CASE("a map that evicted blocks saves and loads whole: same bytes, mesh and ray-cast") {
  const PipelineConfig config = config_for<MultiresVoxel>();
  const Frames frames(6);
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(frames, 0, frames.count());
  Octree<MultiresVoxel>& original = mapper.pipeline.map();
  // Every third block, finest levels among them: holes the compaction fills, nodes left empty.
  std::vector<std::uint32_t> evict;
  for (std::uint32_t i = 0; i < original.block_count(); i += 3) evict.push_back(i);
  const std::uint32_t before = original.block_count();
  const std::uint32_t finest_before = original.memory().finest_used;
  original.evict_blocks(evict.data(), evict.size());
  REQUIRE(original.block_count() == before - evict.size());
  REQUIRE(original.memory().finest_used < finest_before);
  const std::vector<std::uint8_t> file = save(original, 6);

  BareMap<MultiresVoxel> loaded(config.map);
  ErrorText error;
  TrickleSource source(file, std::size_t{1} << 20);
  const Status s = load_map(source, loaded.map, nullptr, &error);
  INFO(error.c_str());
  REQUIRE(s.ok());
  CHECK(save(loaded.map, 6) == file);
  const ByteMeshSink mesh_a = mesh_of(original);
  CHECK(mesh_a.vertices > 100);
  CHECK(mesh_a.bytes == mesh_of(loaded.map).bytes);
  for (const Se3d& T : {pose(5), pose(0)}) {
    CHECK(raycast_of(original, config, T) == raycast_of(loaded.map, config, T));
  }
}

TEMPLATE_TEST_CASE("fusing on in a loaded map gives the map of an uninterrupted run", "", TsdfVoxel,
                   MultiresVoxel, Multires16Voxel) {
  // Ground-truth poses: the loaded run's first frame takes the same pose the uninterrupted run
  // had, so every later integration and carving is the same and so must be the maps and their
  // free space.
  const PipelineConfig config = config_for<TestType>();
  const Frames frames(10);
  Mapper<TestType> whole(config);
  whole.run(frames, 0, 10);

  Mapper<TestType> first_half(config);
  first_half.run(frames, 0, 5);
  const std::vector<std::uint8_t> saved =
      save(first_half.pipeline.map(), first_half.pipeline.free_space(),
           first_half.pipeline.frame_count());

  Mapper<TestType> resumed(config);
  MapFileHeader header;
  REQUIRE(load_all(saved, resumed.pipeline.map(), resumed.pipeline.free_space(), nullptr, &header)
              .ok());
  REQUIRE(resumed.pipeline.resume_frame_count(header.frames).ok());
  CHECK(resumed.pipeline.resume_frame_count(1).code() == StatusCode::failed_precondition);
  resumed.run(frames, 5, 10);
  CHECK(resumed.pipeline.frame_count() == 10);
  CHECK(save(resumed.pipeline.map(), resumed.pipeline.free_space(), 10) ==
        save(whole.pipeline.map(), whole.pipeline.free_space(), 10));
  CHECK(resumed.pipeline.free_space().node_count() > first_half.pipeline.free_space().node_count());
}

// Fuses `frames` into a pipeline of `config`, saves it, checks the bytes (check_map) and loads
// them into a second pipeline of the same config, which must then save the same bytes.
template <typename VoxelT>
void expect_saved_map_loads(const PipelineConfig& config, const Frames& frames) {
  Mapper<VoxelT> mapper(config);
  mapper.run(frames, 0, frames.count());
  const bool with_free = config.free_space.enabled;
  const FreeSpace* free_space = with_free ? &mapper.pipeline.free_space() : nullptr;
  MapSaveInfo info;
  info.frames = mapper.pipeline.frame_count();
  info.mu_m = config.fusion.mu_m;
  VectorSink sink;
  ErrorText error;
  REQUIRE(save_map(mapper.pipeline.map(), free_space, info, sink, &error).ok());
  INFO(error.c_str());
  MemorySource checked(sink.data.data(), sink.data.size());
  MapFileHeader header;
  REQUIRE(check_map(checked, &header, &error).ok());
  CHECK(header.block_count == mapper.pipeline.map().block_count());
  Mapper<VoxelT> target(config);
  MemorySource source(sink.data.data(), sink.data.size());
  REQUIRE(load_map(source, target.pipeline.map(),
                   with_free ? &target.pipeline.free_space() : nullptr, nullptr, &error)
              .ok());
  VectorSink again;
  REQUIRE(save_map(target.pipeline.map(), with_free ? &target.pipeline.free_space() : nullptr, info,
                   again)
              .ok());
  CHECK(again.data == sink.data);
}

TEST_CASE(
    "every map a pipeline can save loads back: voxel types and sizes, cubes, free space, "
    "full pools") {
  // Each voxel size picks its own free-space octants (8 voxels at 1 cm and up, 16 at 5 mm, 32 at
  // 2 mm, 64 at 1 mm); pools of 64 blocks fill on the first frame.
  const Frames frames(3);
  int cases = 0;
  for (float voxel_m : {0.001f, 0.002f, 0.005f, 0.01f, 0.02f, 0.05f, 0.2f}) {
    for (int depth : {7, 11}) {
      for (bool free_space : {true, false}) {
        for (std::uint32_t blocks : {64u, 2048u}) {
          INFO("voxel " << voxel_m << " m, depth " << depth << ", free space " << free_space << ", "
                        << blocks << " blocks");
          PipelineConfig c = config_for<MultiresVoxel>(voxel_m);
          c.map = MapConfig::centred(Eigen::Vector3f(0, 0, 1), voxel_m, depth, blocks, blocks);
          c.map.finest_capacity = blocks / 2;
          c.free_space.enabled = free_space;
          expect_saved_map_loads<MultiresVoxel>(c, frames);
          c.map_kind = map_kind_of<Multires16Voxel>();
          expect_saved_map_loads<Multires16Voxel>(c, frames);
          c.map_kind = map_kind_of<TsdfVoxel>();
          expect_saved_map_loads<TsdfVoxel>(c, frames);
          cases += 3;
        }
      }
    }
  }
  // Free-space octants chosen by hand, from 2 voxels up.
  for (int octant : {2, 4, 8, 16, 32, 64}) {
    INFO(octant << "-voxel octants");
    PipelineConfig c = config_for<MultiresVoxel>(0.01f);
    c.map = MapConfig::centred(Eigen::Vector3f(0, 0, 1), 0.01f, 10, 2048, 2048);
    c.free_space.finest_octant_voxels = octant;
    expect_saved_map_loads<MultiresVoxel>(c, frames);
    ++cases;
  }
  CHECK(cases == 7 * 2 * 2 * 2 * 3 + 6);
}

}  // namespace
}  // namespace octofuse
