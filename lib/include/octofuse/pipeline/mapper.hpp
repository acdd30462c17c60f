#pragma once
// The way in for a first program: settings by name with working defaults, and a Mapper that owns
// all its memory (one allocation in init(), none after), fuses depth frames and meshes the map.
//
//   MapperSettings settings;                 // 2 cm voxels, a 5.12 m cube, 40000 blocks
//   settings.first_T_W_C = first_pose;       // the cube is placed ahead of it
//   Mapper<> mapper;
//   if (!mapper.init(camera, settings).ok()) ... mapper.last_error() ...
//   while (source.next(frame) ...) mapper.process(frame, &stats);
//   mapper.query().point(p_W);                // what the map says about a point
//   Result<const MeshBuffer*> mesh = mapper.extract_mesh();
//
// Anything the settings do not name: edit pipeline_config(camera, settings) and pass the config to
// init(); Pipeline (pipeline.hpp) is the same loop over a buffer the caller provides.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/mesh/mesh.hpp"
#include "octofuse/mesh/mesher.hpp"
#include "octofuse/pipeline/pipeline.hpp"

namespace octofuse {

struct MapperSettings {
  float voxel_size_m = 0.02f;  // the finest voxel's edge
  // Side of the mapped cube, rounded up to voxel_size_m times a power of two (5.12 m: 2^8 voxels).
  float map_size_m = 5.12f;
  // The cube is centred this far ahead of the first camera, along its view, so what the camera
  // sees is inside it.
  float centre_ahead_m = 1.5f;
  std::uint32_t max_blocks = 40000;  // the block pool (8^3 voxels each): the map's memory
  int threads = 1;                   // worker threads, 1 to 64; the results are the same for any
  // The first camera pose in the world. The cube is placed from it; the first frame's ground
  // truth, when it has one, then takes its place unless use_ground_truth_pose is false.
  Se3d first_T_W_C = Se3d::Identity();
  bool use_ground_truth_pose = true;
  bool free_space = true;  // carve free space, so queries can answer "free"
  // What extract_mesh() can hold (0 vertices: no mesh memory is reserved).
  std::uint32_t mesh_vertex_capacity = 1u << 18;
  std::uint32_t mesh_triangle_capacity = 1u << 19;
};

// The PipelineConfig the settings stand for: default_pipeline_config() for the camera, the cube
// (voxel depth from map_size_m, centre from first_T_W_C) and the named fields. Its map_kind is
// multires; Mapper<VoxelT>::init(camera, settings) sets the one for VoxelT.
PipelineConfig pipeline_config(const PinholeCamera& camera, const MapperSettings& settings);

template <typename VoxelT = MultiresVoxel>
class Mapper {
 public:
  Mapper() = default;
  Mapper(const Mapper&) = delete;
  Mapper& operator=(const Mapper&) = delete;

  // Reserves everything the mapper will use, in one allocation (the pipeline's buffer of
  // bytes_required(), the mesher's tables and the mesh), and starts the pipeline.
  // invalid_argument: bad settings or config (last_error() names it); resource_exhausted: the
  // memory could not be had; failed_precondition: called twice.
  Status init(const PinholeCamera& camera, const MapperSettings& settings = {}, Clock clock = {});
  Status init(const PipelineConfig& config, std::uint32_t mesh_vertex_capacity,
              std::uint32_t mesh_triangle_capacity, Clock clock = {});

  // Pipeline::process: ok (stats->result says tracked, first, lost or nearly_empty) or why not.
  Status process(const DepthFrame& frame, FrameStats* stats) {
    return pipeline_.process(frame, stats);
  }
  Status process(const DepthFrame& frame, const PosePrior& prior, FrameStats* stats) {
    return pipeline_.process(frame, prior, stats);
  }

  // Meshes the whole map, each block at its current scale, into the mapper's mesh (replacing the
  // last one): its vertices and triangles, valid until the next call. resource_exhausted when the
  // mesh outgrew the capacities (raise them), failed_precondition without mesh memory.
  Result<const MeshBuffer*> extract_mesh();

  MapQuery<VoxelT> query() const { return pipeline_.query(); }
  const Se3d& T_W_C() const { return pipeline_.T_W_C(); }
  const Octree<VoxelT>& map() const { return pipeline_.map(); }
  Pipeline<VoxelT>& pipeline() { return pipeline_; }
  const Pipeline<VoxelT>& pipeline() const { return pipeline_; }
  const char* last_error() const { return own_error_ ? error_.c_str() : pipeline_.last_error(); }
  // The bytes init() reserved.
  std::size_t bytes_reserved() const { return bytes_; }

 private:
  // The one allocation, kArenaAlignment-aligned; declared first so it is freed last, after the
  // pipeline (and its worker team) that uses it has stopped.
  struct Memory {
    Memory() = default;
    Memory(const Memory&) = delete;
    Memory& operator=(const Memory&) = delete;
    ~Memory();
    void* data = nullptr;
  };

  Memory memory_;
  std::size_t bytes_ = 0;
  Pipeline<VoxelT> pipeline_;
  Mesher<VoxelT> mesher_;
  MeshBuffer mesh_;
  bool have_mesh_memory_ = false;
  ErrorText error_;
  bool own_error_ = false;
};

extern template class Mapper<TsdfVoxel>;
extern template class Mapper<MultiresVoxel>;
extern template class Mapper<Multires16Voxel>;

}  // namespace octofuse
