#include "octofuse/pipeline/mapper.hpp"

#include <new>

#include "octofuse/core/arena.hpp"

namespace octofuse {
namespace {

MeshConfig mesh_config(std::uint32_t vertex_capacity) {
  MeshConfig config;
  config.vertex_capacity = vertex_capacity;
  return config;
}

}  // namespace

PipelineConfig pipeline_config(const PinholeCamera& camera, const MapperSettings& settings) {
  const Se3d& T_W_C0 = settings.first_T_W_C;
  const Eigen::Vector3f centre_W =
      (T_W_C0 * Eigen::Vector3d(0.0, 0.0, static_cast<double>(settings.centre_ahead_m)))
          .cast<float>();
  PipelineConfig config = default_pipeline_config(
      camera, settings.voxel_size_m, voxel_depth_for(settings.map_size_m, settings.voxel_size_m),
      settings.max_blocks, centre_W);
  config.initial_T_W_C = T_W_C0;
  config.initial_pose_from_ground_truth = settings.use_ground_truth_pose;
  config.workers = settings.threads;
  config.free_space.enabled = settings.free_space;
  return config;
}

template <typename VoxelT>
Mapper<VoxelT>::Memory::~Memory() {
  if (data != nullptr) ::operator delete(data, std::align_val_t(kArenaAlignment));
}

template <typename VoxelT>
Status Mapper<VoxelT>::init(const PinholeCamera& camera, const MapperSettings& settings,
                            Clock clock) {
  PipelineConfig config = pipeline_config(camera, settings);
  config.map_kind = map_kind_of<VoxelT>();
  return init(config, settings.mesh_vertex_capacity, settings.mesh_triangle_capacity, clock);
}

template <typename VoxelT>
Status Mapper<VoxelT>::init(const PipelineConfig& config, std::uint32_t mesh_vertex_capacity,
                            std::uint32_t mesh_triangle_capacity, Clock clock) {
  own_error_ = true;
  if (memory_.data != nullptr) {
    error_.set("the mapper is initialised already");
    return Status(StatusCode::failed_precondition);
  }
  if (!validate(config, &error_).ok()) return Status(StatusCode::invalid_argument);
  const std::size_t pipeline_bytes = align_up(bytes_required(config), kArenaAlignment);
  if (pipeline_bytes == 0) {
    error_.set("bytes_required() is 0 for this configuration");
    return Status(StatusCode::invalid_argument);
  }
  // The mesher's tables and the mesh after the pipeline's buffer, sized as they will be carved.
  const bool mesh = mesh_vertex_capacity > 0;
  ArenaSizer sizer;
  if (mesh) {
    const MeshConfig meshing = mesh_config(mesh_vertex_capacity);
    if (!validate(meshing).ok() || mesh_triangle_capacity == 0) {
      error_.set("mesh capacities: %u vertices, %u triangles (both > 0, vertices <= 2^30)",
                 mesh_vertex_capacity, mesh_triangle_capacity);
      return Status(StatusCode::invalid_argument);
    }
    Mesher<VoxelT> probe;
    OCTOFUSE_TRY(probe.reserve(sizer, meshing));
    OCTOFUSE_TRY(MeshBuffer::reserve(sizer, mesh_vertex_capacity, mesh_triangle_capacity));
  }
  const std::size_t bytes = pipeline_bytes + align_up(sizer.bytes_used(), kArenaAlignment);
  memory_.data = ::operator new(bytes, std::align_val_t(kArenaAlignment), std::nothrow);
  if (memory_.data == nullptr) {
    error_.set("cannot reserve %zu bytes", bytes);
    return Status(StatusCode::resource_exhausted);
  }
  bytes_ = bytes;
  if (mesh) {
    LinearArena arena(static_cast<std::uint8_t*>(memory_.data) + pipeline_bytes,
                      bytes - pipeline_bytes);
    OCTOFUSE_TRY(mesher_.reserve(arena, mesh_config(mesh_vertex_capacity)));
    Result<MeshBuffer> buffer =
        MeshBuffer::reserve(arena, mesh_vertex_capacity, mesh_triangle_capacity);
    OCTOFUSE_TRY(buffer);
    mesh_ = buffer.value();
    have_mesh_memory_ = true;
  }
  own_error_ = false;  // from here on the pipeline says what went wrong
  return pipeline_.init(memory_.data, pipeline_bytes, config, clock);
}

template <typename VoxelT>
Result<const MeshBuffer*> Mapper<VoxelT>::extract_mesh() {
  if (!have_mesh_memory_) {
    own_error_ = true;
    error_.set("no mesh memory (mesh_vertex_capacity was 0)");
    return Status(StatusCode::failed_precondition);
  }
  mesh_.clear();
  const Result<MeshStats> meshed = mesher_.extract(pipeline_.map(), mesh_);
  if (!meshed.ok()) {
    own_error_ = true;
    error_.set("meshing stopped (%s): %u vertices, %u triangles fit", meshed.status().name(),
               static_cast<unsigned>(mesh_.vertices().size()),
               static_cast<unsigned>(mesh_.triangles().size()));
    return meshed.status();
  }
  own_error_ = false;
  return static_cast<const MeshBuffer*>(&mesh_);
}

template class Mapper<TsdfVoxel>;
template class Mapper<MultiresVoxel>;
template class Mapper<Multires16Voxel>;

}  // namespace octofuse
