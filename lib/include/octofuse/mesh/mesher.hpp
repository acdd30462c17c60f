#pragma once
// Mesh extraction over the multi-resolution map: dual marching cubes (as supereight2 does, after
// Wald et al.). Why dual: every block is read at one scale (MeshConfig::read_scale), and the cell
// around each finest-grid corner point is formed by the 8 voxels (of whatever size) touching that
// point, their samples at the voxel centres. Two neighbouring cells share a face made of the same
// 4 voxels and cut it the same way, and a vertex is identified by the pair of voxels it
// interpolates, so the surface is closed across scale changes by construction, with no crack
// patching. Where a coarse voxel fills several corners the cell degenerates; triangles that
// collapse (two equal vertex indices) are dropped, which leaves the edge balance unchanged.
// Single-resolution maps take the same code with every block at scale 0.
//
// Output streams through a MeshSink, flushed block by block (and whenever the fixed batch fills).
// Memory is fixed at reserve(): the vertex de-duplication table (sized by vertex_capacity) and
// the batches; nothing is allocated while meshing.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/map/octree.hpp"
#include "octofuse/mesh/mesh.hpp"

namespace octofuse {

// The scale each multires block is meshed at (single-res maps always use scale 0).
enum class MeshReadScale : std::uint8_t {
  // The scale it was last integrated at: what ray-casting and tracking see.
  current,
  // The finest scale it was ever integrated at (min_scale), as last fused there. Detail seen up
  // close survives later far views, but fusion at coarser scales since then is not in it (lazy
  // down-propagation would add it on the next close view): for static scenes.
  finest_fused,
};

struct MeshConfig {
  std::uint32_t vertex_capacity = 1u << 20;  // unique vertices per extraction
  std::uint32_t batch_capacity = 4096;       // vertices and triangles per sink call
  MeshReadScale read_scale = MeshReadScale::current;
};

struct MeshStats {
  std::uint32_t vertices = 0;
  std::uint32_t triangles = 0;
  std::uint32_t blocks_meshed = 0;  // blocks with at least one cell producing triangles
};

// ok, or invalid_argument when a capacity is zero or vertex_capacity is above 2^30.
Status validate(const MeshConfig& config);

template <typename VoxelT>
class Mesher {
 public:
  static std::size_t bytes_required(const MeshConfig& config) {
    ArenaSizer sizer;
    Mesher probe;
    if (!probe.reserve(sizer, config).ok()) return 0;
    return sizer.bytes_used();
  }

  // invalid_argument: validate(config) failed; resource_exhausted: the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, const MeshConfig& config) {
    OCTOFUSE_TRY(validate(config));
    std::size_t table = 16;
    while (table < 2 * static_cast<std::size_t>(config.vertex_capacity)) table *= 2;
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    Result<VertexSlot*> slots = arena.template allocate_array<VertexSlot>(table, kArenaAlignment);
    OCTOFUSE_TRY(slots);
    Result<MeshVertex*> vertices = arena.template allocate_array<MeshVertex>(config.batch_capacity);
    OCTOFUSE_TRY(vertices);
    Result<MeshTriangle*> triangles =
        arena.template allocate_array<MeshTriangle>(config.batch_capacity);
    OCTOFUSE_TRY(triangles);
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    config_ = config;
    slots_ = slots.value();
    slot_mask_ = table - 1;
    vertex_batch_ = vertices.value();
    triangle_batch_ = triangles.value();
    return ok_status();
  }

  // Meshes every block of `map` in block-index order (deterministic) into `sink`. Returns the
  // totals, or: failed_precondition (not reserved), resource_exhausted (more unique vertices
  // than vertex_capacity), or the first non-ok Status from the sink. After an error what the
  // sink received is still a valid indexed mesh (a triangle only names vertices sent before
  // it), just incomplete. An empty map gives an empty mesh. Memory (bytes_required): a
  // de-duplication table of 24-byte slots, at most half full and a power of two (48 to 96 bytes
  // per unit of vertex_capacity), plus 28 bytes per unit of batch_capacity.
  Result<MeshStats> extract(const Octree<VoxelT>& map, MeshSink& sink);

  struct VertexSlot {
    std::uint64_t a = ~std::uint64_t{0};  // smaller voxel id; all ones = empty slot
    std::uint64_t b = 0;
    std::uint32_t index = 0;
    std::uint32_t padding = 0;
  };

 private:
  struct Corner;
  int read_scale(const VoxelBlock<VoxelT>& block) const;
  Status mesh_block(const Octree<VoxelT>& map, std::uint32_t block_index, MeshSink& sink,
                    MeshStats& stats);
  Result<std::uint32_t> vertex_for(const Corner& p, const Corner& q, MeshSink& sink,
                                   MeshStats& stats);
  Status flush(MeshSink& sink);

  MeshConfig config_;
  VertexSlot* slots_ = nullptr;
  std::size_t slot_mask_ = 0;
  MeshVertex* vertex_batch_ = nullptr;
  MeshTriangle* triangle_batch_ = nullptr;
  std::uint32_t vertex_batch_size_ = 0;
  std::uint32_t triangle_batch_size_ = 0;
};

extern template class Mesher<TsdfVoxel>;
extern template class Mesher<MultiresVoxel>;
extern template class Mesher<Multires16Voxel>;

}  // namespace octofuse
