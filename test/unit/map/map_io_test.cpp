// Map persistence: a saved and loaded map is the same map (same file bytes, same mesh, same
// ray-cast, same free space and query answers, same fusion afterwards), and every kind of damage
// to a file is reported with a Status and leaves the map and free space empty rather than
// half-loaded.

#include "octofuse/map/map_io.hpp"

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "octofuse/mesh/mesher.hpp"
#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/query/map_query.hpp"
#include "octofuse/render/raycaster.hpp"
#include "support/aligned_buffer.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

constexpr int kWidth = 64;
constexpr int kHeight = 48;

class VectorSink final : public ByteSink {
 public:
  Status write(const std::uint8_t* bytes, std::size_t count) override {
    data.insert(data.end(), bytes, bytes + count);
    return ok_status();
  }
  std::vector<std::uint8_t> data;
};

// A source that hands out at most `chunk` bytes per read, to exercise the reader's buffering.
class TrickleSource final : public ByteSource {
 public:
  TrickleSource(const std::vector<std::uint8_t>& bytes, std::size_t chunk)
      : bytes_(bytes), chunk_(chunk) {}
  Result<std::size_t> read(std::uint8_t* out, std::size_t count) override {
    std::size_t n = std::min({count, chunk_, bytes_.size() - offset_});
    std::memcpy(out, bytes_.data() + offset_, n);
    offset_ += n;
    return n;
  }

 private:
  const std::vector<std::uint8_t>& bytes_;
  std::size_t chunk_;
  std::size_t offset_ = 0;
};

test::AnalyticScene scene() {
  test::AnalyticScene s;
  s.planes.push_back({Eigen::Vector3d(0.0, 0.0, -1.0), -1.6});  // a wall at z = 1.6 m
  s.planes.push_back({Eigen::Vector3d(0.0, -1.0, 0.0), -0.3});  // a floor at y = 0.3 m
  s.spheres.push_back({Eigen::Vector3d(0.15, 0.0, 0.9), 0.2});
  return s;
}

Se3d pose(int frame) {
  return test::looking_along_z(Eigen::Vector3d(0.01 * frame, -0.005 * frame, 0.0));
}

PinholeCamera camera() {
  return test::centred_camera(kWidth, kHeight, 55.0f);
}

// Depth frames of the analytic scene along pose(i), in millimetres, with ground truth.
class Frames {
 public:
  explicit Frames(int count) {
    const test::AnalyticScene s = scene();
    for (int i = 0; i < count; ++i) {
      std::vector<float> depth_m;
      s.render(camera(), pose(i), depth_m);
      std::vector<std::uint16_t> raw(depth_m.size());
      for (std::size_t p = 0; p < raw.size(); ++p) {
        raw[p] = static_cast<std::uint16_t>(std::lround(depth_m[p] * 1000.0f));
      }
      raw_.push_back(std::move(raw));
    }
  }
  DepthFrame frame(int i) const {
    DepthFrame f;
    f.depth_raw = ImageView<const std::uint16_t>(raw_[i].data(), kWidth, kHeight);
    f.metres_per_unit = 0.001f;
    f.timestamp_us = 33333 * static_cast<std::int64_t>(i + 1);
    f.sequence = static_cast<std::uint64_t>(i);
    f.has_ground_truth = true;
    f.T_W_C_ground_truth = pose(i).matrix();
    return f;
  }
  int count() const { return static_cast<int>(raw_.size()); }

 private:
  std::vector<std::vector<std::uint16_t>> raw_;
};

template <typename VoxelT>
PipelineConfig config_for(float voxel_m = 0.02f) {
  PipelineConfig c = default_pipeline_config(camera(), voxel_m, 7, 4096, Eigen::Vector3f(0, 0, 1));
  c.map_kind = map_kind_of<VoxelT>();
  c.preprocess.downsample_factor = 1;
  c.pose_source = PoseSource::ground_truth;
  c.initial_T_W_C = pose(0);
  return c;
}

// A pipeline with its buffer.
template <typename VoxelT>
struct Mapper {
  explicit Mapper(const PipelineConfig& config)
      : bytes(bytes_required(config)),
        buffer(std::aligned_alloc(kArenaAlignment, align_up(bytes + 1, kArenaAlignment))) {
    REQUIRE(bytes > 0);
    REQUIRE(pipeline.init(buffer.get(), bytes, config).ok());
  }
  void run(const Frames& frames, int from, int to) {
    for (int i = from; i < to; ++i) {
      FrameStats stats;
      const Status s = pipeline.process(frames.frame(i), &stats);
      REQUIRE((s.ok() || s.code() == StatusCode::resource_exhausted));
    }
  }
  std::size_t bytes;
  std::unique_ptr<void, test::AlignedFree> buffer;
  Pipeline<VoxelT> pipeline;
};

// A bare map reserved with `config`.
template <typename VoxelT>
struct BareMap {
  explicit BareMap(const MapConfig& config) : buffer(Octree<VoxelT>::bytes_required(config)) {
    REQUIRE(map.reserve(buffer.arena(), config).ok());
  }
  test::ArenaBuffer buffer;
  Octree<VoxelT> map;
};

template <typename VoxelT>
std::vector<std::uint8_t> save(const Octree<VoxelT>& map, std::uint64_t frames = 0,
                               float mu_m = 0.16f) {
  VectorSink sink;
  MapSaveInfo info;
  info.frames = frames;
  info.mu_m = mu_m;
  REQUIRE(save_map(map, info, sink).ok());
  return sink.data;
}

// The map with its free space.
template <typename VoxelT>
std::vector<std::uint8_t> save(const Octree<VoxelT>& map, const FreeSpace& free_space,
                               std::uint64_t frames, float mu_m = 0.16f) {
  VectorSink sink;
  MapSaveInfo info;
  info.frames = frames;
  info.mu_m = mu_m;
  REQUIRE(save_map(map, &free_space, info, sink).ok());
  return sink.data;
}

// The free-space pool's nodes, as bytes.
std::vector<std::uint8_t> free_space_bytes(const FreeSpace& free_space) {
  std::vector<std::uint8_t> out(free_space.node_count() * sizeof(FreeNode));
  for (std::uint32_t i = 0; i < free_space.node_count(); ++i) {
    std::memcpy(out.data() + i * sizeof(FreeNode), &free_space.node(i), sizeof(FreeNode));
  }
  return out;
}

// Everything the mesher produces, as bytes.
class ByteMeshSink final : public MeshSink {
 public:
  Status add_vertices(const MeshVertex* v, std::size_t count) override {
    for (std::size_t i = 0; i < count; ++i) {
      append(v[i].p_W.data(), sizeof(float) * 3);
      append(&v[i].scale, 1);
      ++vertices;
    }
    return ok_status();
  }
  Status add_triangles(const MeshTriangle* t, std::size_t count) override {
    append(t, sizeof(MeshTriangle) * count);
    return ok_status();
  }
  std::vector<std::uint8_t> bytes;
  std::size_t vertices = 0;

 private:
  void append(const void* p, std::size_t n) {
    const auto* b = static_cast<const std::uint8_t*>(p);
    bytes.insert(bytes.end(), b, b + n);
  }
};

template <typename VoxelT>
ByteMeshSink mesh_of(const Octree<VoxelT>& map) {
  MeshConfig config;
  config.vertex_capacity = 1u << 16;
  test::ArenaBuffer buffer(Mesher<VoxelT>::bytes_required(config));
  Mesher<VoxelT> mesher;
  REQUIRE(mesher.reserve(buffer.arena(), config).ok());
  ByteMeshSink sink;
  REQUIRE(mesher.extract(map, sink).ok());
  return sink;
}

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

template <typename VoxelT>
Status load_bytes(const std::vector<std::uint8_t>& bytes, Octree<VoxelT>& map,
                  ErrorText* error = nullptr, MapFileHeader* header = nullptr) {
  MemorySource source(bytes.data(), bytes.size());
  return load_map(source, map, header, error);
}

template <typename VoxelT>
Status load_all(const std::vector<std::uint8_t>& bytes, Octree<VoxelT>& map, FreeSpace& free_space,
                ErrorText* error = nullptr, MapFileHeader* header = nullptr) {
  MemorySource source(bytes.data(), bytes.size());
  return load_map(source, map, &free_space, header, error);
}

template <typename VoxelT>
bool empty(const Octree<VoxelT>& map) {
  return map.block_count() == 0 && map.node_count() == 1 && map.memory().finest_used == 0;
}
// Cleared: the root alone, not free.
bool empty(const FreeSpace& free_space) {
  return free_space.node_count() == 1 && free_space.node(0).free_count == 0;
}

std::uint32_t get_u32(const std::vector<std::uint8_t>& f, std::size_t at) {
  return static_cast<std::uint32_t>(f[at]) | (static_cast<std::uint32_t>(f[at + 1]) << 8) |
         (static_cast<std::uint32_t>(f[at + 2]) << 16) |
         (static_cast<std::uint32_t>(f[at + 3]) << 24);
}

// Header fields' offsets and the sizes of the fixed-size records.
constexpr std::size_t kNodeCountAt = 34;
constexpr std::size_t kBlockCountAt = 38;
constexpr std::size_t kFinestCountAt = 42;
constexpr std::size_t kFreeCountAt = 54;
constexpr std::size_t kFreeMarginAt = 58;
constexpr std::size_t kFreeOctantAt = 62;
constexpr std::size_t kFreeCapAt = 63;
constexpr std::size_t kHeaderBytes = 8 + 4 + 1 + 4 + 4 + 1 + 12 + 4 + 4 + 4 + 8 + 4 + 4 + 1 + 1 + 4;
constexpr std::size_t kFreeRecordBytes = 1 + 1 + 4 + 8 * 4 + 1 + 4;

// Offsets where records start (and the file's size last), walking the layout of map_io.hpp.
std::vector<std::size_t> record_offsets(const std::vector<std::uint8_t>& f, bool multires,
                                        std::size_t voxel_bytes = 0) {
  const std::size_t header = kHeaderBytes;
  const std::uint32_t nodes = get_u32(f, kNodeCountAt);
  const std::uint32_t blocks = get_u32(f, kBlockCountAt);
  const std::uint32_t free_nodes = get_u32(f, kFreeCountAt);
  std::vector<std::size_t> at = {0, header};
  for (std::uint32_t i = 0; i < nodes; ++i) at.push_back(at.back() + 30);
  if (voxel_bytes == 0) voxel_bytes = multires ? 16 : 8;
  for (std::uint32_t i = 0; i < blocks; ++i) {
    const std::size_t start = at.back();
    const bool finest = !multires || (f[start + 16] & 1) != 0;
    at.push_back(start + 1 + 8 + 4 + 4 + 16 + (finest ? 585 : 73) * voxel_bytes + 4);
  }
  for (std::uint32_t i = 0; i < free_nodes; ++i) at.push_back(at.back() + kFreeRecordBytes);
  at.push_back(at.back() + 1 + 4 + 4 + 4 + 4);
  return at;
}

// Rewrites the CRC of the record [begin, end) after a deliberate edit.
void reseal(std::vector<std::uint8_t>& f, std::size_t begin, std::size_t end) {
  const std::uint32_t crc = crc32(f.data() + begin, end - 4 - begin);
  for (int i = 0; i < 4; ++i) f[end - 4 + i] = static_cast<std::uint8_t>(crc >> (8 * i));
}
void put_u32(std::vector<std::uint8_t>& f, std::size_t at, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) f[at + i] = static_cast<std::uint8_t>(v >> (8 * i));
}

TEST_CASE("crc32 matches the IEEE check value and continues across calls") {
  const char* text = "123456789";
  const auto* bytes = reinterpret_cast<const std::uint8_t*>(text);
  CHECK(crc32(bytes, 9) == 0xCBF43926u);
  CHECK(crc32(bytes + 4, 5, crc32(bytes, 4)) == 0xCBF43926u);
  CHECK(crc32(bytes, 0) == 0u);
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

TEST_CASE("a 16-bit map file says so and is refused by float maps, and they by it",
          "[multires16]") {
  const Frames frames(3);
  Mapper<Multires16Voxel> q16(config_for<Multires16Voxel>());
  q16.run(frames, 0, frames.count());
  Mapper<MultiresVoxel> f32(config_for<MultiresVoxel>());
  f32.run(frames, 0, frames.count());
  const std::vector<std::uint8_t> file16 = save(q16.pipeline.map(), 3);
  const std::vector<std::uint8_t> file32 = save(f32.pipeline.map(), 3);
  REQUIRE(q16.pipeline.map().block_count() == f32.pipeline.map().block_count());
  CHECK(file16[12] == 3);  // the header's voxel type byte
  {
    MemorySource source(file16.data(), file16.size());
    const Result<MapFileHeader> header = read_map_header(source);
    REQUIRE(header.ok());
    CHECK(header.value().voxel_type == MapVoxelType::multires16);
    CHECK(std::string(map_voxel_type_name(header.value().voxel_type)) == "multires16");
  }
  // Half the voxel bytes: each block record holds 585 or 73 voxels of 8 bytes instead of 16.
  const std::vector<std::size_t> r16 = record_offsets(file16, true, 8);
  const std::vector<std::size_t> r32 = record_offsets(file32, true, 16);
  REQUIRE(r16.back() == file16.size());
  REQUIRE(r32.back() == file32.size());
  const std::uint32_t nodes = get_u32(file16, kNodeCountAt);
  const std::uint32_t blocks = get_u32(file16, kBlockCountAt);
  std::size_t voxels = 0;
  for (std::uint32_t i = 0; i < blocks; ++i) {
    const std::size_t record = r16[2 + nodes + i] - r16[1 + nodes + i];
    voxels += (record - 37) / 8;  // tag, key, state, summary and crc take 37 bytes
  }
  CHECK(voxels > 73 * blocks);  // some blocks hold a finest level
  CHECK(file32.size() - file16.size() == 8 * voxels);
  ErrorText error;
  BareMap<MultiresVoxel> float_map(config_for<MultiresVoxel>().map);
  CHECK(load_bytes(file16, float_map.map, &error).code() == StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("holds a multires16 map, this one is multires") !=
        std::string::npos);
  CHECK(empty(float_map.map));
  BareMap<TsdfVoxel> single(config_for<TsdfVoxel>().map);
  CHECK(load_bytes(file16, single.map, &error).code() == StatusCode::invalid_argument);
  CHECK(empty(single.map));
  BareMap<Multires16Voxel> compact(config_for<Multires16Voxel>().map);
  CHECK(load_bytes(file32, compact.map, &error).code() == StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("holds a multires map, this one is multires16") !=
        std::string::npos);
  CHECK(empty(compact.map));
  // The right map takes it.
  REQUIRE(load_bytes(file16, compact.map, &error).ok());
  CHECK(save(compact.map, 3) == file16);
}

TEST_CASE("a 16-bit TSDF step outside [-1, 1] in a file is data_loss", "[multires16]") {
  Mapper<Multires16Voxel> mapper(config_for<Multires16Voxel>());
  mapper.run(Frames(2), 0, 2);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), 2);
  const std::vector<std::size_t> records = record_offsets(file, true, 8);
  const std::uint32_t nodes = get_u32(file, kNodeCountAt);
  // The first block record: its first voxel's x (after the 33 bytes of key, state and summary).
  const std::size_t begin = records[1 + nodes];
  const std::size_t end = records[2 + nodes];
  REQUIRE(file[begin] == 'B');
  BareMap<Multires16Voxel> target(config_for<Multires16Voxel>().map);
  ErrorText error;
  for (const std::uint16_t bad_step : {std::uint16_t{16385}, std::uint16_t{0x8000}}) {
    CAPTURE(bad_step);
    std::vector<std::uint8_t> bad = file;
    bad[begin + 33] = static_cast<std::uint8_t>(bad_step);
    bad[begin + 34] = static_cast<std::uint8_t>(bad_step >> 8);
    reseal(bad, begin, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("out of range") != std::string::npos);
    CHECK(empty(target.map));
  }
  // The largest valid steps load.
  std::vector<std::uint8_t> edge = file;
  edge[begin + 33] = 0x00;
  edge[begin + 34] = 0xC0;  // -16384
  reseal(edge, begin, end);
  CHECK(load_bytes(edge, target.map, &error).ok());
}

// A dozen blocks, with and without finest levels: small enough to load thousands of times.
PipelineConfig corruption_config() {
  PipelineConfig config = config_for<MultiresVoxel>(0.01f);
  config.budget.max_new_blocks = 10;
  config.map.finest_capacity = 12;  // the others stay at scale 1 without a finest level
  return config;
}

TEST_CASE("truncation anywhere is data_loss and leaves the map empty") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  INFO(mapper.pipeline.map().memory().finest_used << " of " << mapper.pipeline.map().block_count());
  REQUIRE(mapper.pipeline.map().memory().finest_used > 0);
  REQUIRE(mapper.pipeline.map().memory().finest_used < mapper.pipeline.map().block_count());
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map());
  const std::vector<std::size_t> records = record_offsets(file, true);
  REQUIRE(records.back() == file.size());

  // At and around every record boundary, every byte of the header and first nodes, and a
  // stride through the block records.
  std::vector<std::size_t> cuts;
  for (std::size_t r : records) {
    for (std::size_t d : {std::size_t{0}, std::size_t{1}, std::size_t{3}, std::size_t{4}}) {
      if (r >= d) cuts.push_back(r - d);
      cuts.push_back(r + d);
    }
  }
  for (std::size_t i = 0; i < 200; ++i) cuts.push_back(i);
  for (std::size_t i = 0; i < file.size(); i += 211) cuts.push_back(i);

  BareMap<MultiresVoxel> target(config.map);
  int tried = 0;
  for (std::size_t cut : cuts) {
    if (cut >= file.size()) continue;
    REQUIRE(load_bytes(file, target.map).ok());  // full beforehand: failure must clear it
    const std::vector<std::uint8_t> part(file.begin(), file.begin() + cut);
    ErrorText error;
    const Status s = load_bytes(part, target.map, &error);
    INFO("cut at " << cut << ": " << error.c_str());
    REQUIRE(s.code() == StatusCode::data_loss);
    REQUIRE(empty(target.map));
    REQUIRE(std::strstr(error.c_str(), "truncated") != nullptr);
    // The check a save runs on what it wrote refuses it the same way.
    MemorySource checked(part.data(), part.size());
    REQUIRE(check_map(checked).code() == StatusCode::data_loss);
    ++tried;
  }
  CHECK(tried > 300);
}

TEST_CASE("a flipped bit anywhere is caught and leaves the map empty") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map());
  BareMap<MultiresVoxel> target(config.map);
  std::vector<std::size_t> positions;
  for (std::size_t r : record_offsets(file, true)) {
    for (std::size_t d = 0; d < 12; ++d) positions.push_back(r + d);
  }
  for (std::size_t i = 0; i < file.size(); i += 97) positions.push_back(i);
  for (std::size_t at : positions) {
    if (at >= file.size()) continue;
    for (int bit : {0, 7}) {
      std::vector<std::uint8_t> bad = file;
      bad[at] = static_cast<std::uint8_t>(bad[at] ^ (1u << bit));
      ErrorText error;
      const Status s = load_bytes(bad, target.map, &error);
      INFO("byte " << at << " bit " << bit << ": " << error.c_str());
      REQUIRE(!s.ok());
      REQUIRE(empty(target.map));
      if (at >= 12) REQUIRE(s.code() == StatusCode::data_loss);
      MemorySource checked(bad.data(), bad.size());
      REQUIRE(check_map(checked).code() == s.code());
    }
  }
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

TEST_CASE("header fields out of range are refused by name, on load and before a save") {
  MapFileHeader good;
  good.voxel_size_m = 0.01f;
  good.mu_m = 0.08f;
  good.voxel_depth = 10;
  good.node_count = 1;
  REQUIRE(validate_map_header(good).ok());
  struct Case {
    const char* what;
    void (*spoil)(MapFileHeader&);
  };
  const Case cases[] = {
      {"voxel size", [](MapFileHeader& h) { h.voxel_size_m = 1e-9f; }},
      {"voxel size", [](MapFileHeader& h) { h.voxel_size_m = std::nanf(""); }},
      {"voxel size", [](MapFileHeader& h) { h.voxel_size_m = 1e6f; }},
      {"mu", [](MapFileHeader& h) { h.mu_m = 0.0f; }},
      {"mu", [](MapFileHeader& h) { h.mu_m = std::numeric_limits<float>::infinity(); }},
      {"voxel depth", [](MapFileHeader& h) { h.voxel_depth = 30; }},
      {"origin", [](MapFileHeader& h) { h.origin_W.x() = 1e30f; }},
      {"origin", [](MapFileHeader& h) { h.origin_W.z() = std::nanf(""); }},
      {"frame count", [](MapFileHeader& h) { h.frames = ~std::uint64_t{0}; }},
      {"counts", [](MapFileHeader& h) { h.node_count = 0; }},
      {"free-space octants",
       [](MapFileHeader& h) {
         h.free_node_count = 1;
         h.free_margin_m = 0.01f;
         h.free_max_count = 8;
         h.free_octant_voxels = 128;
       }},
  };
  for (const Case& c : cases) {
    MapFileHeader h = good;
    c.spoil(h);
    ErrorText error;
    CHECK(validate_map_header(h, &error).code() == StatusCode::data_loss);
    INFO(error.c_str());
    CHECK(std::string(error.c_str()).find(c.what) != std::string::npos);
  }

  // A save whose header would be refused writes nothing and says why.
  const PipelineConfig config = config_for<MultiresVoxel>();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(1), 0, 1);
  MapSaveInfo info;
  info.mu_m = config.fusion.mu_m;
  info.frames = kMaxSavedFrames + 1;
  VectorSink sink;
  ErrorText error;
  CHECK(save_map(mapper.pipeline.map(), info, sink).code() == StatusCode::invalid_argument);
  CHECK(save_map(mapper.pipeline.map(), nullptr, info, sink, &error).code() ==
        StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("frame count") != std::string::npos);
  CHECK(sink.data.empty());
  // At the bound it saves, checks and loads.
  info.frames = kMaxSavedFrames;
  REQUIRE(save_map(mapper.pipeline.map(), nullptr, info, sink, &error).ok());
  MemorySource source(sink.data.data(), sink.data.size());
  CHECK(check_map(source, nullptr, &error).ok());
}

TEST_CASE("foreign, newer, other-type, mismatched and oversized files are told apart") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map());
  const std::vector<std::size_t> records = record_offsets(file, true);
  const std::size_t header_end = records[1];
  BareMap<MultiresVoxel> target(config.map);
  ErrorText error;

  SECTION("wrong magic") {
    std::vector<std::uint8_t> bad = file;
    std::memcpy(bad.data(), "PLYFORMA", 8);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()).find("not an octofuse map") != std::string::npos);
    const std::vector<std::uint8_t> text = {'p', 'l', 'y', '\n'};
    CHECK(load_bytes(text, target.map, &error).code() == StatusCode::data_loss);
    CHECK(load_bytes(std::vector<std::uint8_t>(), target.map, &error).code() ==
          StatusCode::data_loss);
  }
  SECTION("a newer version, whatever follows") {
    std::vector<std::uint8_t> bad = file;
    put_u32(bad, 8, kMapFormatVersion + 1);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::out_of_range);
    CHECK(std::string(error.c_str()).find("newer") != std::string::npos);
    MemorySource source(bad.data(), bad.size());
    CHECK(read_map_header(source).status().code() == StatusCode::out_of_range);
  }
  SECTION("the other voxel type") {
    BareMap<TsdfVoxel> single(config.map);
    CHECK(load_bytes(file, single.map, &error).code() == StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()).find("multires") != std::string::npos);
    CHECK(empty(single.map));
  }
  SECTION("an unknown voxel type") {
    std::vector<std::uint8_t> bad = file;
    bad[12] = 9;
    reseal(bad, 0, header_end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
  }
  SECTION("a different geometry than the map's") {
    MapConfig other = config.map;
    other.origin_W.x() += 0.5f;
    BareMap<MultiresVoxel> shifted(other);
    CHECK(load_bytes(file, shifted.map, &error).code() == StatusCode::invalid_argument);
    other = config.map;
    other.voxel_depth = 8;
    BareMap<MultiresVoxel> deeper(other);
    CHECK(load_bytes(file, deeper.map, &error).code() == StatusCode::invalid_argument);
  }
  SECTION("pools too small for the file") {
    MapConfig small = config.map;
    small.block_capacity = mapper.pipeline.map().block_count() - 1;
    BareMap<MultiresVoxel> tiny(small);
    CHECK(load_bytes(file, tiny.map, &error).code() == StatusCode::resource_exhausted);
    CHECK(std::string(error.c_str()).find("needs") != std::string::npos);
    CHECK(empty(tiny.map));
  }
  SECTION("absurd counts") {
    for (std::size_t field : {kNodeCountAt, kBlockCountAt, kFinestCountAt, kFreeCountAt}) {
      std::vector<std::uint8_t> bad = file;
      put_u32(bad, field, 0xFFFFFFF0u);
      reseal(bad, 0, header_end);
      CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    }
    std::vector<std::uint8_t> no_root = file;
    put_u32(no_root, kNodeCountAt, 0);
    reseal(no_root, 0, header_end);
    CHECK(load_bytes(no_root, target.map, &error).code() == StatusCode::data_loss);
  }
  SECTION("counts that disagree with the records") {
    std::vector<std::uint8_t> bad = file;
    put_u32(bad, kBlockCountAt, mapper.pipeline.map().block_count() - 1);
    reseal(bad, 0, header_end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(empty(target.map));
  }
  SECTION("non-finite or out-of-range values, even with a valid checksum") {
    const std::size_t block = records[records.size() - 3];  // the last block record
    const std::size_t end = records[records.size() - 2];
    const float bad_values[] = {std::numeric_limits<float>::quiet_NaN(),
                                std::numeric_limits<float>::infinity(), 1.5f, -2.0f};
    for (float v : bad_values) {
      std::uint32_t bits;
      std::memcpy(&bits, &v, 4);
      std::vector<std::uint8_t> bad = file;
      put_u32(bad, block + 1 + 8 + 4 + 4 + 16, bits);  // the first voxel's TSDF
      reseal(bad, block, end);
      CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
      CHECK(std::string(error.c_str()).find("out of range") != std::string::npos);
      bad = file;
      put_u32(bad, records[1] + 10, bits);  // the root's summary
      reseal(bad, records[1], records[2]);
      CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    }
  }
  SECTION("bad keys and states, even with a valid checksum") {
    const std::size_t block = records[records.size() - 3];
    const std::size_t end = records[records.size() - 2];
    std::vector<std::uint8_t> bad = file;
    bad[block + 1] |= 1;  // not block-aligned
    reseal(bad, block, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    bad = file;
    std::memcpy(&bad[block + 1], &file[records[records.size() - 4] + 1], 8);  // a duplicate
    reseal(bad, block, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    bad = file;
    bad[block + 13] = 5;  // current scale 5
    reseal(bad, block, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    bad = file;
    bad[records[2] + 1] = 0;  // a second root
    reseal(bad, records[2], records[3]);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(empty(target.map));
  }
  SECTION("bytes after the end record") {
    std::vector<std::uint8_t> bad = file;
    bad.push_back(0);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("extra bytes") != std::string::npos);
    CHECK(empty(target.map));
  }
}

// Answers of point and region queries over a grid through the cube, as bytes (state, distance,
// gradient), with how many points were free and near.
struct QueryAnswers {
  std::vector<std::uint8_t> bytes;
  std::vector<PointAnswer> points;
  int free = 0;
  int near = 0;
};
template <typename VoxelT>
QueryAnswers answers_of(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m) {
  const MapQuery<VoxelT> query(map, free_space, mu_m);
  QueryAnswers out;
  auto append = [&](const void* p, std::size_t n) {
    const auto* b = static_cast<const std::uint8_t*>(p);
    out.bytes.insert(out.bytes.end(), b, b + n);
  };
  for (float z = -0.05f; z < 1.8f; z += 0.037f) {
    for (float y = -0.5f; y < 0.4f; y += 0.041f) {
      for (float x = -0.6f; x < 0.6f; x += 0.043f) {
        const Result<PointAnswer> a = query.point(Eigen::Vector3f(x, y, z));
        REQUIRE(a.ok());
        append(&a.value().state, 1);
        append(&a.value().distance_m, 4);
        append(a.value().gradient.data(), 12);
        out.points.push_back(a.value());
        out.free += a.value().state == PointState::free ? 1 : 0;
        out.near += a.value().state == PointState::near ? 1 : 0;
      }
    }
  }
  for (float z = 0.2f; z < 1.6f; z += 0.1f) {
    const Eigen::Vector3f c(0.0f, 0.0f, z);
    const Result<RegionAnswer> box =
        query.box(c - Eigen::Vector3f::Constant(0.1f), c + Eigen::Vector3f::Constant(0.1f));
    const Result<RegionAnswer> swept =
        query.swept_sphere(c, c + Eigen::Vector3f(0.3f, 0.0f, 0.2f), 0.05f);
    REQUIRE((box.ok() && swept.ok()));
    append(&box.value().state, 1);
    append(&swept.value().state, 1);
  }
  return out;
}

TEMPLATE_TEST_CASE("free space is saved and loaded: same nodes, same query answers", "", TsdfVoxel,
                   MultiresVoxel, Multires16Voxel) {
  const PipelineConfig config = config_for<TestType>();
  REQUIRE(config.free_space.enabled);
  const Frames frames(6);
  Mapper<TestType> mapper(config);
  mapper.run(frames, 0, frames.count());
  const FreeSpace& original = mapper.pipeline.free_space();
  REQUIRE(original.node_count() > 50);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), original, 6);

  Mapper<TestType> loaded(config);
  MapFileHeader header;
  ErrorText error;
  for (std::size_t chunk : {std::size_t{1}, std::size_t{13}, std::size_t{1} << 20}) {
    TrickleSource source(file, chunk);
    const Status s =
        load_map(source, loaded.pipeline.map(), &loaded.pipeline.free_space(), &header, &error);
    INFO(error.c_str());
    REQUIRE(s.ok());
  }
  CHECK(header.free_node_count == original.node_count());
  CHECK(header.free_margin_m == original.margin_m());
  CHECK(header.free_octant_voxels == 8);
  CHECK(header.free_max_count == 8);
  CHECK(free_space_bytes(loaded.pipeline.free_space()) == free_space_bytes(original));
  CHECK(save(loaded.pipeline.map(), loaded.pipeline.free_space(), 6) == file);

  // The loaded pipeline answers every query as the saved one, and the grid reaches both the free
  // air in front of the wall and the band around the surfaces.
  const float mu_m = config.fusion.mu_m;
  const QueryAnswers before = answers_of(mapper.pipeline.map(), &original, mu_m);
  const QueryAnswers after = answers_of(loaded.pipeline.map(), &loaded.pipeline.free_space(), mu_m);
  // Only carved free octants answer free (the TSDF's +1 alone is unknown), about 100 of the grid.
  CHECK(before.free > 100);
  CHECK(before.near > 100);
  CHECK(before.free == after.free);
  CHECK(before.bytes == after.bytes);
  // Free space decides many of those answers: without it they are unknown, or free with a
  // smaller distance bound (from the TSDF alone).
  const QueryAnswers tsdf_only = answers_of(mapper.pipeline.map(), nullptr, mu_m);
  int from_free_space = 0;
  for (std::size_t i = 0; i < before.points.size(); ++i) {
    const PointAnswer& a = before.points[i];
    const PointAnswer& b = tsdf_only.points[i];
    from_free_space +=
        a.state == PointState::free && (b.state != PointState::free || b.distance_m != a.distance_m)
            ? 1
            : 0;
  }
  CHECK(from_free_space > 50);

  // A reader that does not keep free space checks its records and skips them.
  BareMap<TestType> bare(config.map);
  REQUIRE(load_bytes(file, bare.map, &error).ok());
  CHECK(save(bare.map, 6) == save(mapper.pipeline.map(), 6));
}

TEST_CASE("a map saved without free space loads, and leaves the free space knowing nothing") {
  const PipelineConfig config = config_for<MultiresVoxel>();
  const Frames frames(3);
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(frames, 0, frames.count());
  REQUIRE(mapper.pipeline.free_space().node_count() > 50);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), 3);
  MapFileHeader header;
  {
    MemorySource source(file.data(), file.size());
    REQUIRE(read_map_header(source).ok());
  }

  // Into a pipeline that already knows free space: it is cleared, not kept from before.
  Mapper<MultiresVoxel> target(config);
  target.run(frames, 0, 2);
  REQUIRE(!empty(target.pipeline.free_space()));
  ErrorText error;
  REQUIRE(
      load_all(file, target.pipeline.map(), target.pipeline.free_space(), &error, &header).ok());
  CHECK(header.free_node_count == 0);
  CHECK(header.free_margin_m == 0.0f);
  CHECK(empty(target.pipeline.free_space()));
  CHECK(save(target.pipeline.map(), 3) == file);
  const QueryAnswers answers =
      answers_of(target.pipeline.map(), &target.pipeline.free_space(), config.fusion.mu_m);
  CHECK(answers.bytes == answers_of(mapper.pipeline.map(), nullptr, config.fusion.mu_m).bytes);

  // A pipeline without free space saves files without it, and loads files with it.
  PipelineConfig off = config;
  off.free_space.enabled = false;
  Mapper<MultiresVoxel> no_free(off);
  no_free.run(frames, 0, frames.count());
  const std::vector<std::uint8_t> with_free =
      save(mapper.pipeline.map(), mapper.pipeline.free_space(), 3);
  REQUIRE(load_bytes(with_free, no_free.pipeline.map(), &error).ok());
  CHECK(save(no_free.pipeline.map(), 3) == file);
  FreeSpace unreserved;
  CHECK(load_all(with_free, no_free.pipeline.map(), unreserved).code() ==
        StatusCode::failed_precondition);
}

TEST_CASE("damaged free-space records are data_loss and leave map and free space empty") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  const FreeSpace& free_space = mapper.pipeline.free_space();
  const std::uint32_t count = free_space.node_count();
  REQUIRE(count > 20);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), free_space, 2);
  const std::vector<std::size_t> records = record_offsets(file, true);
  REQUIRE(records.back() == file.size());
  const std::size_t free_begin = records[records.size() - 2 - count];
  auto free_at = [&](std::uint32_t i) { return free_begin + i * kFreeRecordBytes; };
  auto child_at = [&](std::uint32_t i, int c) { return free_at(i) + 6 + 4 * c; };
  auto reseal_free = [&](std::vector<std::uint8_t>& f, std::uint32_t i) {
    reseal(f, free_at(i), free_at(i) + kFreeRecordBytes);
  };
  REQUIRE(file[free_at(0)] == 'F');

  Mapper<MultiresVoxel> target(config);
  FreeSpace& loaded = target.pipeline.free_space();
  // Loads `bad` over a full map: it must fail with `code` and `what`, leaving both empty.
  auto expect_refused = [&](const std::vector<std::uint8_t>& bad, StatusCode code,
                            const char* what) {
    REQUIRE(load_all(file, target.pipeline.map(), loaded).ok());
    REQUIRE(!empty(loaded));
    ErrorText error;
    const Status s = load_all(bad, target.pipeline.map(), loaded, &error);
    INFO(error.c_str());
    CHECK(s.code() == code);
    CHECK(std::strstr(error.c_str(), what) != nullptr);
    CHECK(empty(target.pipeline.map()));
    CHECK(empty(loaded));
  };

  SECTION("truncated and flipped bits anywhere in the free-space records") {
    for (std::uint32_t i = 0; i < count; i += 1 + count / 40) {
      for (std::size_t d : {std::size_t{0}, std::size_t{1}, std::size_t{7}, std::size_t{41}}) {
        const std::size_t at = free_at(i) + d;
        expect_refused(std::vector<std::uint8_t>(file.begin(), file.begin() + at),
                       StatusCode::data_loss, "truncated");
        std::vector<std::uint8_t> bad = file;
        bad[at] = static_cast<std::uint8_t>(bad[at] ^ 0x10);
        expect_refused(bad, StatusCode::data_loss, "free-space record");
      }
    }
  }
  SECTION("fields out of range, even with a valid checksum") {
    std::vector<std::uint8_t> bad = file;
    bad[free_at(count - 1) + 1] = 9;  // count above the cap of 8
    reseal_free(bad, count - 1);
    expect_refused(bad, StatusCode::data_loss, "cap");
    bad = file;
    put_u32(bad, free_at(1) + 2, 2);  // frame 2 of a map saved after frames 0 and 1
    reseal_free(bad, 1);
    expect_refused(bad, StatusCode::data_loss, "frame");
    bad = file;
    put_u32(bad, child_at(0, 0), count);  // past the last node
    reseal_free(bad, 0);
    expect_refused(bad, StatusCode::data_loss, "child index out of range");
    std::uint32_t last_parent = 0;
    int last_slot = -1;
    for (std::uint32_t i = 0; i < count; ++i) {
      for (int c = 0; c < 8; ++c) {
        if (free_space.node(i).children[c] == count - 1) {
          last_parent = i;
          last_slot = c;
        }
      }
    }
    REQUIRE(last_slot >= 0);
    bad = file;
    put_u32(bad, child_at(count - 1, 0), last_parent);  // a child before its parent: a cycle
    reseal_free(bad, count - 1);
    expect_refused(bad, StatusCode::data_loss, "child index out of range");
    bad = file;
    bad[free_at(0) + 6 + 4 * 8] = 0x01;  // free sub-cells on the root
    reseal_free(bad, 0);
    expect_refused(bad, StatusCode::data_loss, "sub-cells");
  }
  SECTION("records that do not form one tree") {
    // Parents and levels, from the root.
    std::vector<std::uint32_t> parent(count, FreeSpace::kNoNode);
    std::vector<int> level(count, 0);
    for (std::uint32_t i = 0; i < count; ++i) {
      for (std::uint32_t child : free_space.node(i).children) {
        if (child == FreeSpace::kNoNode) continue;
        REQUIRE(child > i);
        parent[child] = i;
        level[child] = level[i] + 1;
      }
    }
    const std::uint32_t last = count - 1;
    const std::uint32_t p = parent[last];
    REQUIRE(p != FreeSpace::kNoNode);
    int slot = 0;
    while (free_space.node(p).children[slot] != last) ++slot;

    std::vector<std::uint8_t> bad = file;
    put_u32(bad, child_at(p, slot), FreeSpace::kNoNode);  // the last node loses its parent
    reseal_free(bad, p);
    expect_refused(bad, StatusCode::data_loss, "without a parent");

    // The last node also becomes the child of an earlier node with a free slot: two parents.
    std::uint32_t other = FreeSpace::kNoNode;
    int free_slot = -1;
    for (std::uint32_t i = 0; i < last && other == FreeSpace::kNoNode; ++i) {
      for (int c = 0; c < 8; ++c) {
        if (i != p && level[i] < free_space.leaf_level() &&
            free_space.node(i).children[c] == FreeSpace::kNoNode) {
          other = i;
          free_slot = c;
          break;
        }
      }
    }
    REQUIRE(other != FreeSpace::kNoNode);
    bad = file;
    put_u32(bad, child_at(other, free_slot), last);
    reseal_free(bad, other);
    expect_refused(bad, StatusCode::data_loss, "two parents");

    // ... or moves under an earlier node at the finest octant level: below the leaves.
    std::uint32_t leaf = FreeSpace::kNoNode;
    for (std::uint32_t i = 1; i < last; ++i) {
      if (level[i] == free_space.leaf_level()) {
        leaf = i;
        break;
      }
    }
    REQUIRE(leaf != FreeSpace::kNoNode);
    bad = file;
    put_u32(bad, child_at(p, slot), FreeSpace::kNoNode);
    reseal_free(bad, p);
    put_u32(bad, child_at(leaf, 0), last);
    reseal_free(bad, leaf);
    expect_refused(bad, StatusCode::data_loss, "below the finest octant level");
  }
  SECTION("counts and settings in the header") {
    const std::size_t header_end = records[1];
    std::vector<std::uint8_t> bad = file;
    put_u32(bad, kFreeCountAt, count + 1);
    reseal(bad, 0, header_end);
    expect_refused(bad, StatusCode::data_loss, "wrong record tag");
    bad = file;
    put_u32(bad, kFreeCountAt, count - 1);
    reseal(bad, 0, header_end);
    expect_refused(bad, StatusCode::data_loss, "");
    for (std::size_t at : {kFreeOctantAt, kFreeCapAt}) {
      bad = file;
      bad[at] = at == kFreeOctantAt ? 3 : 0;
      reseal(bad, 0, header_end);
      expect_refused(bad, StatusCode::data_loss,
                     at == kFreeOctantAt ? "free-space octants of 3 voxels" : "count cap 0");
    }
    const float bad_margins[] = {std::numeric_limits<float>::quiet_NaN(), -0.01f, 0.0f};
    for (float margin : bad_margins) {
      std::uint32_t bits;
      std::memcpy(&bits, &margin, 4);
      bad = file;
      put_u32(bad, kFreeMarginAt, bits);
      reseal(bad, 0, header_end);
      expect_refused(bad, StatusCode::data_loss, "free-space margin");
    }
    bad = file;
    put_u32(bad, records[records.size() - 2] + 9, count - 1);  // the end record's free count
    reseal(bad, records[records.size() - 2], records.back());
    expect_refused(bad, StatusCode::data_loss, "end record");
  }
  SECTION("other settings or a smaller pool than the file's") {
    PipelineConfig wider = config;
    wider.free_space.margin_m = 2.0f * config.map.voxel_size_m;
    Mapper<MultiresVoxel> other(wider);
    ErrorText error;
    CHECK(load_all(file, other.pipeline.map(), other.pipeline.free_space(), &error).code() ==
          StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()).find("margin") != std::string::npos);
    CHECK(empty(other.pipeline.map()));
    CHECK(empty(other.pipeline.free_space()));
    PipelineConfig finer = config;
    finer.free_space.finest_octant_voxels = 4;
    Mapper<MultiresVoxel> finer_mapper(finer);
    CHECK(load_all(file, finer_mapper.pipeline.map(), finer_mapper.pipeline.free_space()).code() ==
          StatusCode::invalid_argument);
    PipelineConfig small = config;
    small.free_space.node_capacity = count - 1;
    Mapper<MultiresVoxel> small_mapper(small);
    CHECK(load_all(file, small_mapper.pipeline.map(), small_mapper.pipeline.free_space(), &error)
              .code() == StatusCode::resource_exhausted);
    CHECK(std::string(error.c_str()).find("free-space nodes") != std::string::npos);
    CHECK(empty(small_mapper.pipeline.map()));
    CHECK(empty(small_mapper.pipeline.free_space()));
  }
  SECTION("saving refuses free space that the loader would refuse") {
    VectorSink sink;
    MapSaveInfo info;
    info.mu_m = 0.16f;
    info.frames = 1;  // frame 1 was carved too
    CHECK(save_map(mapper.pipeline.map(), &free_space, info, sink).code() ==
          StatusCode::invalid_argument);
    FreeSpace unreserved;
    info.frames = 2;
    CHECK(save_map(mapper.pipeline.map(), &unreserved, info, sink).code() ==
          StatusCode::failed_precondition);
  }
}

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
