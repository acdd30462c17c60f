#include "octofuse/mesh/mesher.hpp"

#include "octofuse/map/interpolation.hpp"
#include "octofuse/mesh/marching_cubes.hpp"

namespace octofuse {

// One corner of a dual cell: a voxel at its block's read scale, sampled at its centre.
template <typename VoxelT>
struct Mesher<VoxelT>::Corner {
  std::uint64_t id = 0;  // block index << 10 | index inside the block: unique per voxel
  float tsdf = 0.0f;
  int scale = 0;
  Eigen::Vector3f p_W = Eigen::Vector3f::Zero();
};

Status validate(const MeshConfig& config) {
  if (config.vertex_capacity == 0 || config.batch_capacity == 0) {
    return StatusCode::invalid_argument;
  }
  if (config.vertex_capacity > (1u << 30)) return StatusCode::invalid_argument;
  if (config.read_scale != MeshReadScale::current &&
      config.read_scale != MeshReadScale::finest_fused) {
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

template <typename VoxelT>
int Mesher<VoxelT>::read_scale(const VoxelBlock<VoxelT>& block) const {
  if constexpr (IsMultiresVoxel<VoxelT>::value) {
    if (config_.read_scale == MeshReadScale::finest_fused && block.integrated()) {
      const int finest = block.min_scale;
      // A block whose finest level went back to the pool reads its next scale.
      if (finest == 0 && !block.has_finest()) return 1;
      return finest > kMaxBlockScale ? kMaxBlockScale : finest;
    }
  }
  return block_read_scale(block);
}

template <typename VoxelT>
Result<MeshStats> Mesher<VoxelT>::extract(const Octree<VoxelT>& map, MeshSink& sink) {
  if (slots_ == nullptr || !map.reserved()) return StatusCode::failed_precondition;
  for (std::size_t i = 0; i <= slot_mask_; ++i) slots_[i] = VertexSlot();
  vertex_batch_size_ = 0;
  triangle_batch_size_ = 0;
  MeshStats stats;
  for (std::uint32_t b = 0; b < map.block_count(); ++b) {
    OCTOFUSE_TRY(mesh_block(map, b, sink, stats));
    // Stream block by block: the sink sees every finished block.
    OCTOFUSE_TRY(flush(sink));
  }
  return stats;
}

template <typename VoxelT>
Status Mesher<VoxelT>::flush(MeshSink& sink) {
  if (vertex_batch_size_ > 0) OCTOFUSE_TRY(sink.add_vertices(vertex_batch_, vertex_batch_size_));
  vertex_batch_size_ = 0;
  if (triangle_batch_size_ > 0) {
    OCTOFUSE_TRY(sink.add_triangles(triangle_batch_, triangle_batch_size_));
  }
  triangle_batch_size_ = 0;
  return ok_status();
}

template <typename VoxelT>
Result<std::uint32_t> Mesher<VoxelT>::vertex_for(const Corner& p, const Corner& q, MeshSink& sink,
                                                 MeshStats& stats) {
  // Canonical order, so the vertex (and its position) does not depend on which cell made it.
  const Corner& a = p.id < q.id ? p : q;
  const Corner& b = p.id < q.id ? q : p;
  std::size_t slot = static_cast<std::size_t>(
                         ((a.id * 0x9E3779B97F4A7C15ull) ^ (b.id * 0xC2B2AE3D27D4EB4Full)) >> 17) &
                     slot_mask_;
  while (true) {
    const VertexSlot& s = slots_[slot];
    if (s.a == a.id && s.b == b.id) return s.index;
    if (s.a == ~std::uint64_t{0}) break;
    slot = (slot + 1) & slot_mask_;
  }
  if (stats.vertices >= config_.vertex_capacity) return StatusCode::resource_exhausted;
  if (vertex_batch_size_ == config_.batch_capacity) OCTOFUSE_TRY(flush(sink));
  // Signs differ, so the denominator is not zero.
  const float t = a.tsdf / (a.tsdf - b.tsdf);
  MeshVertex& v = vertex_batch_[vertex_batch_size_++];
  v.p_W = a.p_W + t * (b.p_W - a.p_W);
  v.scale = static_cast<std::uint8_t>(a.scale > b.scale ? a.scale : b.scale);
  const std::uint32_t index = stats.vertices++;
  VertexSlot& s = slots_[slot];
  s.a = a.id;
  s.b = b.id;
  s.index = index;
  return index;
}

template <typename VoxelT>
Status Mesher<VoxelT>::mesh_block(const Octree<VoxelT>& map, std::uint32_t block_index,
                                  MeshSink& sink, MeshStats& stats) {
  const VoxelBlock<VoxelT>& block = map.block(block_index);
  const int scale = read_scale(block);
  const int coarse_mask = (1 << scale) - 1;
  const Eigen::Vector3i origin = block.min_voxel();

  // The cells owned by this block reach one voxel into the blocks below it on each axis.
  const VoxelBlock<VoxelT>* near_blocks[8];
  std::uint32_t near_indices[8];
  for (int n = 0; n < 8; ++n) {
    const Eigen::Vector3i offset(-((n & 1) ^ 1), -(((n >> 1) & 1) ^ 1), -(((n >> 2) & 1) ^ 1));
    near_indices[n] = n == 7 ? block_index : map.find_block_index(block.coords + offset);
    near_blocks[n] = near_indices[n] == kNoIndex ? nullptr : &map.block(near_indices[n]);
  }

  bool produced = false;
  Corner corners[8];
  for (int lz = 0; lz < kBlockSide; ++lz) {
    for (int ly = 0; ly < kBlockSide; ++ly) {
      for (int lx = 0; lx < kBlockSide; ++lx) {
        // The cell around the finest-grid point at the minimum corner of local voxel (lx,ly,lz).
        // Inside the block, a point off the block's own grid only repeats coarse voxels along an
        // axis (a flat cell without area): skip it.
        const bool interior = lx != 0 && ly != 0 && lz != 0;
        if (interior && ((lx | ly | lz) & coarse_mask) != 0) continue;
        bool complete = true;
        for (int c = 0; c < 8 && complete; ++c) {
          const int ux = lx - 1 + (c & 1);
          const int uy = ly - 1 + ((c >> 1) & 1);
          const int uz = lz - 1 + ((c >> 2) & 1);
          const int n = (ux >= 0 ? 1 : 0) | (uy >= 0 ? 2 : 0) | (uz >= 0 ? 4 : 0);
          const VoxelBlock<VoxelT>* nb = near_blocks[n];
          if (nb == nullptr) {
            complete = false;
            break;
          }
          const int s = read_scale(*nb);
          const int index = block_voxel_index_finest(ux & 7, uy & 7, uz & 7, s);
          const VoxelT& voxel = nb->voxel(index);
          if (!voxel_observed(voxel)) {
            complete = false;
            break;
          }
          corners[c].id = (static_cast<std::uint64_t>(near_indices[n]) << 10) |
                          static_cast<std::uint64_t>(index);
          corners[c].tsdf = voxel_tsdf(voxel);
          corners[c].scale = s;
        }
        if (!complete) continue;
        int inside = 0;
        for (int c = 0; c < 8; ++c) inside |= corners[c].tsdf < 0.0f ? (1 << c) : 0;
        if (inside == 0 || inside == 255) continue;
        // A cell whose corners pair up along an axis is flat: it only yields collapsed triangles.
        bool flat = false;
        for (int axis = 0; axis < 3 && !flat; ++axis) {
          bool same = true;
          for (int c = 0; c < 8 && same; ++c) {
            if ((c >> axis) & 1) continue;
            same = corners[c].id == corners[c | (1 << axis)].id;
          }
          flat = same;
        }
        if (flat) continue;
        for (int c = 0; c < 8; ++c) {
          const Eigen::Vector3i u =
              origin +
              Eigen::Vector3i(lx - 1 + (c & 1), ly - 1 + ((c >> 1) & 1), lz - 1 + ((c >> 2) & 1));
          corners[c].p_W = map.voxel_centre_W(u, corners[c].scale);
        }
        const McCase& mc = marching_cubes_case(inside);
        for (int t = 0; t < mc.triangle_count; ++t) {
          std::uint32_t idx[3];
          for (int k = 0; k < 3; ++k) {
            const std::uint8_t* edge = kMcEdgeCorners[mc.edges[t * 3 + k]];
            Result<std::uint32_t> v = vertex_for(corners[edge[0]], corners[edge[1]], sink, stats);
            if (!v.ok()) return v.status();
            idx[k] = v.value();
          }
          if (idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2]) continue;
          if (triangle_batch_size_ == config_.batch_capacity) OCTOFUSE_TRY(flush(sink));
          MeshTriangle& tri = triangle_batch_[triangle_batch_size_++];
          tri.v[0] = idx[0];
          tri.v[1] = idx[1];
          tri.v[2] = idx[2];
          ++stats.triangles;
          produced = true;
        }
      }
    }
  }
  if (produced) ++stats.blocks_meshed;
  return ok_status();
}

template class Mesher<TsdfVoxel>;
template class Mesher<MultiresVoxel>;
template class Mesher<Multires16Voxel>;

}  // namespace octofuse
