#include "octofuse/query/map_query.hpp"

#include <algorithm>
#include <cmath>

#include "octofuse/map/interpolation.hpp"

namespace octofuse {

const char* point_state_name(PointState state) {
  switch (state) {
    case PointState::outside:
      return "outside";
    case PointState::unknown:
      return "unknown";
    case PointState::free:
      return "free";
    case PointState::near:
      return "near";
    case PointState::inside:
      return "inside";
  }
  return "unknown";
}

const char* region_state_name(RegionState state) {
  switch (state) {
    case RegionState::free:
      return "free";
    case RegionState::blocked:
      return "blocked";
    case RegionState::unknown:
      return "unknown";
  }
  return "unknown";
}

namespace {
bool finite(const Eigen::Vector3f& v) {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

// Squared distance from point q to the box [lo, hi].
float squared_distance_to_box(const Eigen::Vector3f& q, const Eigen::Vector3f& lo,
                              const Eigen::Vector3f& hi) {
  float sum = 0.0f;
  for (int a = 0; a < 3; ++a) {
    const float d = q[a] < lo[a] ? lo[a] - q[a] : q[a] > hi[a] ? q[a] - hi[a] : 0.0f;
    sum += d * d;
  }
  return sum;
}

// Distance from q to the segment [a, b].
float distance_to_segment(const Eigen::Vector3f& q, const Eigen::Vector3f& a,
                          const Eigen::Vector3f& b) {
  const Eigen::Vector3f ab = b - a;
  const float len2 = ab.squaredNorm();
  float t = len2 > 0.0f ? (q - a).dot(ab) / len2 : 0.0f;
  t = t < 0.0f ? 0.0f : t > 1.0f ? 1.0f : t;
  return (q - (a + t * ab)).norm();
}
}  // namespace

// A shape in continuous finest-voxel coordinates (Octree::point_to_voxel_f).
template <typename VoxelT>
struct MapQuery<VoxelT>::Shape {
  enum class Kind : std::uint8_t { box, sphere, capsule } kind = Kind::box;
  Eigen::Vector3f a = Eigen::Vector3f::Zero();  // box: min; sphere: centre; capsule: start
  Eigen::Vector3f b = Eigen::Vector3f::Zero();  // box: max; capsule: end
  float radius = 0.0f;
  Eigen::Vector3f lo = Eigen::Vector3f::Zero();  // bounding box
  Eigen::Vector3f hi = Eigen::Vector3f::Zero();

  // Whether the shape may touch the cell [lo, hi] (exact for boxes and spheres; for capsules a
  // superset, which only makes the answer more cautious).
  bool touches(const Eigen::Vector3f& cell_lo, const Eigen::Vector3f& cell_hi) const {
    for (int i = 0; i < 3; ++i) {
      if (cell_hi[i] < lo[i] || cell_lo[i] > hi[i]) return false;
    }
    if (kind == Kind::box) return true;
    if (kind == Kind::sphere)
      return squared_distance_to_box(a, cell_lo, cell_hi) <= radius * radius;
    const Eigen::Vector3f centre = 0.5f * (cell_lo + cell_hi);
    const float half_diagonal = 0.5f * (cell_hi - cell_lo).norm();
    return distance_to_segment(centre, a, b) <= radius + half_diagonal;
  }
};

template <typename VoxelT>
PointAnswer MapQuery<VoxelT>::point_unguarded(const Eigen::Vector3f& p_W) const {
  PointAnswer out;
  if (version_ != nullptr) out.map_version = *version_;
  const Eigen::Vector3i voxel = map_->point_to_voxel(p_W);
  if (!map_->contains_voxel(voxel)) {
    out.state = PointState::outside;
    return out;
  }
  FreeOctant octant;
  if (free_ != nullptr) octant = free_->find(voxel);
  const VoxelBlock<VoxelT>* block = map_->find_block_at_voxel(voxel);
  const bool tsdf_current =
      block != nullptr && (!octant.free || block->last_updated_frame >= octant.free_frame);
  if (tsdf_current) {
    TsdfSample sample;
    float tsdf = 2.0f;  // > 1: not observed
    if (sample_tsdf(*map_, p_W, block, sample)) {
      tsdf = sample.tsdf;
      if (tsdf > -1.0f && tsdf < 1.0f) {
        out.gradient = sample.gradient * mu_m_;
        out.has_gradient = true;
      }
    } else {
      const VoxelT& v = block->at_voxel(voxel, block_read_scale(*block));
      if (voxel_observed(v)) tsdf = voxel_tsdf(v);
    }
    if (tsdf <= 1.0f) {
      if (tsdf <= -1.0f) {
        out.state = PointState::inside;
        out.distance_m = -mu_m_;
      } else if (tsdf < 1.0f) {
        out.state = PointState::near;
        out.distance_m = tsdf * mu_m_;
        // The TSDF holds distances along camera rays, which exceed the Euclidean distance by
        // 1 / cos(incidence) on slanted surfaces; the gradient's length is that factor.
        const float slope = out.gradient.norm();
        if (out.has_gradient && slope > 1.0f) {
          out.distance_m /= slope;
          out.gradient /= slope;
        }
      } else {
        out.state = PointState::free;
      }
      if (out.state != PointState::near) {
        out.gradient = Eigen::Vector3f::Zero();
        out.has_gradient = false;
      }
      if (out.state != PointState::free) return out;
      // Truncated positive: at least mu from a surface along the camera rays that saw it, which
      // on slanted surfaces says little about the Euclidean distance. Free only where carving
      // saw it free.
      if (!octant.free) {
        out.state = PointState::unknown;
        return out;
      }
    }
  }
  if (octant.free) {
    // Distance to the octant's faces, plus the margin every surface kept from it.
    const float voxel_m = map_->voxel_size_m();
    const Eigen::Vector3f q = map_->point_to_voxel_f(p_W);
    const Eigen::Vector3f lo = octant.min_voxel.cast<float>();
    const Eigen::Vector3f hi =
        lo + Eigen::Vector3f::Constant(static_cast<float>(octant.size_voxels));
    const float inner = std::min((q - lo).minCoeff(), (hi - q).minCoeff());
    out.state = PointState::free;
    // A frame whose rays all missed a thin object (thinner than the ray spacing) carves through
    // it, and that octant is newer than the object's blocks; the blocks still bound the distance.
    const float bound = free_->margin_m() / voxel_m + std::max(inner, 0.0f);
    out.distance_m = surface_clearance_voxels(q, bound) * voxel_m;
    return out;
  }
  return out;
}

template <typename VoxelT>
float MapQuery<VoxelT>::surface_clearance_voxels(const Eigen::Vector3f& q, float limit) const {
  // Blocks that may hold a surface: an observed voxel at or behind one (tsdf <= 0). Each is grown
  // by one voxel of its scale, for a surface whose voxels behind it lie across the block's face.
  struct Entry {
    std::uint32_t node;
    int level;
    Eigen::Vector3i min_voxel;
  };
  // At most 7 pending per level above the blocks, and 8 from the last.
  constexpr int kCapacity = 8 * (kMaxVoxelDepth + 2);
  Entry stack[kCapacity];
  const int depth = map_->voxel_depth();
  const int block_level = map_->block_level();
  // The most any block is grown (a voxel of the coarsest scale).
  const float max_grow = static_cast<float>(kBlockSide);
  float best = limit;
  // Start at the deepest node holding every voxel within reach (most of the walk otherwise).
  const float reach = limit + max_grow + 1.0f;
  const int n = map_->voxels_per_side();
  Eigen::Vector3i r0;
  Eigen::Vector3i r1;
  for (int a = 0; a < 3; ++a) {
    r0[a] = std::max(0, static_cast<int>(std::floor(q[a] - reach)));
    r1[a] = std::min(n - 1, static_cast<int>(std::floor(q[a] + reach)));
  }
  std::uint32_t start = Octree<VoxelT>::root_index();
  int start_level = 0;
  Eigen::Vector3i start_min = Eigen::Vector3i::Zero();
  while (start_level + 1 < block_level) {
    const int bit = depth - start_level - 1;
    if ((r0.x() >> bit) != (r1.x() >> bit) || (r0.y() >> bit) != (r1.y() >> bit) ||
        (r0.z() >> bit) != (r1.z() >> bit)) {
      break;
    }
    const int c =
        ((r0.x() >> bit) & 1) | (((r0.y() >> bit) & 1) << 1) | (((r0.z() >> bit) & 1) << 2);
    const std::uint32_t next = map_->node(start).children[c];
    if (next == kNoIndex) return best;  // no block anywhere within reach
    start_min = child_min_voxel(start_min, c, 1 << bit);
    start = next;
    ++start_level;
  }
  int top = 0;
  stack[top++] = Entry{start, start_level, start_min};
  while (top > 0) {
    const Entry e = stack[--top];
    const int half = 1 << (depth - e.level - 1);
    const bool blocks = e.level + 1 == block_level;
    const OctreeNode& node = map_->node(e.node);
    for (int c = 0; c < 8; ++c) {
      const std::uint32_t child = node.children[c];
      if (child == kNoIndex) continue;
      const Eigen::Vector3i child_min = child_min_voxel(e.min_voxel, c, half);
      const Eigen::Vector3f lo = child_min.cast<float>();
      float grow = max_grow;
      if (blocks) {
        const VoxelBlock<VoxelT>& b = map_->block(child);
        if (!b.integrated() || !(b.tsdf_min <= 0.0f)) continue;
        grow = static_cast<float>(1 << b.current_scale);
      }
      const Eigen::Vector3f g = Eigen::Vector3f::Constant(grow);
      const float d2 = squared_distance_to_box(
          q, lo - g, lo + Eigen::Vector3f::Constant(static_cast<float>(half)) + g);
      if (!(d2 < best * best)) continue;
      if (blocks) {
        best = std::sqrt(d2);
      } else if (top < kCapacity) {
        stack[top++] = Entry{child, e.level + 1, child_min};
      } else {
        return 0.0f;  // cannot happen (8 per level); cautious
      }
    }
  }
  return best;
}

template <typename VoxelT>
Result<PointAnswer> MapQuery<VoxelT>::point(const Eigen::Vector3f& p_W) const {
  if (!finite(p_W)) return StatusCode::invalid_argument;
  SharedHold hold(guard_);
  return point_unguarded(p_W);
}

template <typename VoxelT>
RegionAnswer MapQuery<VoxelT>::region(const Shape& shape, const QueryLimits& limits) const {
  RegionAnswer out;
  if (version_ != nullptr) out.map_version = *version_;
  const float n = static_cast<float>(map_->voxels_per_side());
  for (int a = 0; a < 3; ++a) {
    if (!(shape.lo[a] >= 0.0f && shape.hi[a] < n)) {
      out.state = RegionState::unknown;  // a part lies outside the map
      return out;
    }
  }
  const int depth = map_->voxel_depth();
  const int leaf = free_ != nullptr ? free_->leaf_level() : map_->block_level();
  const float mu_voxels = mu_m_ / map_->voxel_size_m();
  bool unknown = false;
  bool stopped = false;
  auto spend = [&]() {
    if (out.visits >= limits.max_visits) {
      stopped = true;
      return false;
    }
    ++out.visits;
    return true;
  };
  // Reads the voxels of `block` inside the cell [cell_lo, cell_hi) that the shape touches.
  // region_free: the cell was seen free (then unobserved voxels are free). False when blocked.
  auto check_block = [&](const VoxelBlock<VoxelT>& block, bool region_free,
                         const Eigen::Vector3f& cell_lo, const Eigen::Vector3f& cell_hi) {
    const int scale = block_read_scale(block);
    const int side = block_scale_side(scale);
    const float size = static_cast<float>(1 << scale);
    const Eigen::Vector3f origin = block.min_voxel().template cast<float>();
    // Blocked within the voxel's half-diagonal plus one finest voxel.
    const float blocked_below = 0.8660254f * size + 1.0f;
    for (int z = 0; z < side; ++z) {
      for (int y = 0; y < side; ++y) {
        for (int x = 0; x < side; ++x) {
          const Eigen::Vector3f lo =
              origin +
              Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)) *
                  size;
          const Eigen::Vector3f hi = lo + Eigen::Vector3f::Constant(size);
          if ((hi.array() <= cell_lo.array()).any() || (lo.array() >= cell_hi.array()).any()) {
            continue;
          }
          if (!shape.touches(lo, hi)) continue;
          if (!spend()) return true;
          const VoxelT v = block.at(x, y, z, scale);
          if (voxel_observed(v)) {
            const float t = voxel_tsdf(v);
            if (t < 1.0f && t * mu_voxels <= blocked_below) return false;
          }
          // Free only where carving saw free space (the TSDF's distances are along camera rays).
          if (!region_free) unknown = true;
        }
      }
    }
    return true;
  };
  // The blocks inside the cell [cell_lo, cell_lo + cell_size) the shape touches. free_frame >= 0:
  // the cell was seen free then. Returns false when blocked.
  auto check_blocks = [&](const Eigen::Vector3i& cell_lo, int cell_size, bool region_free,
                          std::uint32_t free_frame) {
    Eigen::Vector3i b0;
    Eigen::Vector3i b1;
    for (int a = 0; a < 3; ++a) {
      const int lo = std::max(cell_lo[a], static_cast<int>(std::floor(shape.lo[a])));
      const int hi =
          std::min(cell_lo[a] + cell_size - 1, static_cast<int>(std::floor(shape.hi[a])));
      if (lo > hi) return true;
      b0[a] = lo >> kBlockSideLog2;
      b1[a] = hi >> kBlockSideLog2;
    }
    for (int bz = b0.z(); bz <= b1.z(); ++bz) {
      for (int by = b0.y(); by <= b1.y(); ++by) {
        for (int bx = b0.x(); bx <= b1.x(); ++bx) {
          const Eigen::Vector3i coords(bx, by, bz);
          const Eigen::Vector3f lo = (coords * kBlockSide).cast<float>();
          if (!shape.touches(lo, lo + Eigen::Vector3f::Constant(static_cast<float>(kBlockSide)))) {
            continue;
          }
          if (!spend()) return true;
          const VoxelBlock<VoxelT>* block = map_->find_block(coords);
          if (block == nullptr) {
            if (!region_free) unknown = true;
            continue;
          }
          if (region_free && block->last_updated_frame < free_frame) continue;
          const Eigen::Vector3f cell_lo_f = cell_lo.cast<float>();
          if (!check_block(*block, region_free, cell_lo_f,
                           cell_lo_f + Eigen::Vector3f::Constant(static_cast<float>(cell_size)))) {
            return false;
          }
          if (stopped) return true;
        }
      }
    }
    return true;
  };

  struct Entry {
    std::uint32_t node;
    int level;
    Eigen::Vector3i min_voxel;
  };
  Entry stack[FreeSpace::kStackCapacity];
  int top = 0;
  if (free_ != nullptr && free_->reserved()) {
    stack[top++] = Entry{0, 0, Eigen::Vector3i::Zero()};
  } else if (!check_blocks(Eigen::Vector3i::Zero(), 1 << depth, false, 0)) {
    out.state = RegionState::blocked;
    return out;
  }
  while (top > 0 && !stopped) {
    const Entry e = stack[--top];
    if (!spend()) break;
    const int size = 1 << (depth - e.level);
    const FreeNode& node = free_->node(e.node);
    if (node.free_count > 0 || e.level == leaf) {
      bool region_free = node.free_count > 0;
      if (!region_free && node.sub_free != 0) {
        // A leaf with free sub-cells: free where the shape touches only those.
        const int half = size / 2;
        region_free = true;
        for (int c = 0; c < 8 && region_free; ++c) {
          if ((node.sub_free >> c) & 1u) continue;
          const Eigen::Vector3i sub_lo = child_min_voxel(e.min_voxel, c, half);
          const Eigen::Vector3f lo = sub_lo.cast<float>();
          if (shape.touches(lo, lo + Eigen::Vector3f::Constant(static_cast<float>(half)))) {
            region_free = false;
          }
        }
      }
      if (!check_blocks(e.min_voxel, size, region_free, node.free_frame)) {
        out.state = RegionState::blocked;
        return out;
      }
      continue;
    }
    const int half = size / 2;
    for (int c = 7; c >= 0; --c) {
      const Eigen::Vector3i child_lo = child_min_voxel(e.min_voxel, c, half);
      const Eigen::Vector3f lo = child_lo.cast<float>();
      if (!shape.touches(lo, lo + Eigen::Vector3f::Constant(static_cast<float>(half)))) continue;
      const std::uint32_t child = node.children[c];
      if (child != FreeSpace::kNoNode) {
        stack[top++] = Entry{child, e.level + 1, child_lo};
      } else if (!check_blocks(child_lo, half, false, 0)) {
        out.state = RegionState::blocked;
        return out;
      }
      if (stopped) break;
    }
  }
  if (stopped) {
    out.budget_hit = true;
    out.state = RegionState::unknown;
    return out;
  }
  out.state = unknown ? RegionState::unknown : RegionState::free;
  return out;
}

template <typename VoxelT>
Result<RegionAnswer> MapQuery<VoxelT>::box(const Eigen::Vector3f& min_W,
                                           const Eigen::Vector3f& max_W,
                                           const QueryLimits& limits) const {
  if (!finite(min_W) || !finite(max_W) || limits.max_visits == 0) {
    return StatusCode::invalid_argument;
  }
  if ((min_W.array() > max_W.array()).any()) return StatusCode::invalid_argument;
  Shape shape;
  shape.kind = Shape::Kind::box;
  shape.a = map_->point_to_voxel_f(min_W);
  shape.b = map_->point_to_voxel_f(max_W);
  shape.lo = shape.a;
  shape.hi = shape.b;
  SharedHold hold(guard_);
  return region(shape, limits);
}

template <typename VoxelT>
Result<RegionAnswer> MapQuery<VoxelT>::sphere(const Eigen::Vector3f& centre_W, float radius_m,
                                              const QueryLimits& limits) const {
  return swept_sphere(centre_W, centre_W, radius_m, limits);
}

template <typename VoxelT>
Result<RegionAnswer> MapQuery<VoxelT>::swept_sphere(const Eigen::Vector3f& a_W,
                                                    const Eigen::Vector3f& b_W, float radius_m,
                                                    const QueryLimits& limits) const {
  if (!finite(a_W) || !finite(b_W) || !std::isfinite(radius_m) || radius_m < 0.0f ||
      limits.max_visits == 0) {
    return StatusCode::invalid_argument;
  }
  Shape shape;
  shape.kind = a_W == b_W ? Shape::Kind::sphere : Shape::Kind::capsule;
  shape.a = map_->point_to_voxel_f(a_W);
  shape.b = map_->point_to_voxel_f(b_W);
  shape.radius = radius_m / map_->voxel_size_m();
  const Eigen::Vector3f r = Eigen::Vector3f::Constant(shape.radius);
  shape.lo = shape.a.cwiseMin(shape.b) - r;
  shape.hi = shape.a.cwiseMax(shape.b) + r;
  SharedHold hold(guard_);
  return region(shape, limits);
}

template class MapQuery<TsdfVoxel>;
template class MapQuery<MultiresVoxel>;
template class MapQuery<Multires16Voxel>;

}  // namespace octofuse
