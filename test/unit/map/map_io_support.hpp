#pragma once
// What the map persistence tests share: an analytic scene seen along a short path, a pipeline
// with its buffer, and saving, loading, meshing and ray-casting maps in memory.

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

inline test::AnalyticScene scene() {
  test::AnalyticScene s;
  s.planes.push_back({Eigen::Vector3d(0.0, 0.0, -1.0), -1.6});  // a wall at z = 1.6 m
  s.planes.push_back({Eigen::Vector3d(0.0, -1.0, 0.0), -0.3});  // a floor at y = 0.3 m
  s.spheres.push_back({Eigen::Vector3d(0.15, 0.0, 0.9), 0.2});
  return s;
}

inline Se3d pose(int frame) {
  return test::looking_along_z(Eigen::Vector3d(0.01 * frame, -0.005 * frame, 0.0));
}

inline PinholeCamera camera() {
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
  explicit Mapper(const PipelineConfig& config) : bytes(bytes_required(config)), buffer(bytes) {
    REQUIRE(bytes > 0);
    REQUIRE(pipeline.init(buffer.data, bytes, config).ok());
  }
  void run(const Frames& frames, int from, int to) {
    for (int i = from; i < to; ++i) {
      FrameStats stats;
      const Status s = pipeline.process(frames.frame(i), &stats);
      REQUIRE((s.ok() || s.code() == StatusCode::resource_exhausted));
    }
  }
  std::size_t bytes;
  test::Buffer buffer;
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
inline std::vector<std::uint8_t> free_space_bytes(const FreeSpace& free_space) {
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
inline bool empty(const FreeSpace& free_space) {
  return free_space.node_count() == 1 && free_space.node(0).free_count == 0;
}

inline std::uint32_t get_u32(const std::vector<std::uint8_t>& f, std::size_t at) {
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
inline std::vector<std::size_t> record_offsets(const std::vector<std::uint8_t>& f, bool multires,
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
inline void reseal(std::vector<std::uint8_t>& f, std::size_t begin, std::size_t end) {
  const std::uint32_t crc = crc32(f.data() + begin, end - 4 - begin);
  for (int i = 0; i < 4; ++i) f[end - 4 + i] = static_cast<std::uint8_t>(crc >> (8 * i));
}
inline void put_u32(std::vector<std::uint8_t>& f, std::size_t at, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) f[at + i] = static_cast<std::uint8_t>(v >> (8 * i));
}

// A dozen blocks, with and without finest levels: small enough to load thousands of times.
inline PipelineConfig corruption_config() {
  PipelineConfig config = config_for<MultiresVoxel>(0.01f);
  config.budget.max_new_blocks = 10;
  config.map.finest_capacity = 12;  // the others stay at scale 1 without a finest level
  return config;
}

}  // namespace
}  // namespace octofuse
