#include "octofuse/map/free_octree.hpp"

#include <cmath>

namespace octofuse {

Status validate(const FreeSpaceConfig& config) {
  const bool finite = std::isfinite(config.margin_m) && std::isfinite(config.clearance_m) &&
                      std::isfinite(config.occlusion_clear_m) && std::isfinite(config.near_m) &&
                      std::isfinite(config.prune_radius_m);
  if (!finite || config.margin_m < 0.0f || config.clearance_m < 0.0f ||
      config.occlusion_clear_m < 0.0f || config.near_m < 0.0f || config.prune_radius_m < 0.0f) {
    return StatusCode::invalid_argument;
  }
  const int octant = config.finest_octant_voxels;
  if (octant != 0 && octant != 2 && octant != 4 && octant != 8 && octant != 16 && octant != 32 &&
      octant != 64) {
    return StatusCode::invalid_argument;
  }
  if (config.max_free_count == 0 || config.max_node_visits == 0) {
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

void FreeOctree::clear() {
  OCTOFUSE_CHECK(reserved_);
  nodes_.reset();
  const Result<std::uint32_t> root = nodes_.allocate();
  OCTOFUSE_CHECK(root.ok() && root.value() == 0);
}

Status FreeOctree::begin_restore(std::uint32_t count) {
  if (!reserved_) return StatusCode::failed_precondition;
  clear();
  if (count == 0 || count > nodes_.capacity()) return StatusCode::resource_exhausted;
  for (std::uint32_t i = 1; i < count; ++i) {
    const Result<std::uint32_t> fresh = nodes_.allocate();
    OCTOFUSE_CHECK(fresh.ok() && fresh.value() == i);
  }
  return ok_status();
}

std::uint32_t FreeOctree::walk_within(const Eigen::Vector3f& centre_W, float keep_radius_m,
                                      bool mark) {
  if (mark) {
    for (std::uint32_t i = 0; i < nodes_.used(); ++i) remap_[i] = 0;
    remap_[0] = 1;
  }
  // A depth-first walk that does not enter octants wholly beyond the radius; every node has one
  // parent, so the nodes entered (and the root) are the ones that stay.
  struct Entry {
    std::uint32_t node;
    int level;
    Eigen::Vector3i min_voxel;
  };
  Entry stack[kStackCapacity];
  int top = 0;
  stack[top++] = Entry{0, 0, Eigen::Vector3i::Zero()};
  const int depth = map_.voxel_depth;
  const float voxel = map_.voxel_size_m;
  const float radius_sq = keep_radius_m * keep_radius_m;
  std::uint32_t kept = 1;
  while (top > 0) {
    const Entry e = stack[--top];
    const int half = 1 << (depth - e.level - 1);
    for (int c = 0; c < 8; ++c) {
      const std::uint32_t child = nodes_[e.node].children[c];
      if (child == kNoNode) continue;
      const Eigen::Vector3i child_min = child_min_voxel(e.min_voxel, c, half);
      const Eigen::Vector3f lo_W = map_.origin_W + child_min.cast<float>() * voxel;
      const Eigen::Vector3f hi_W =
          lo_W + Eigen::Vector3f::Constant(static_cast<float>(half) * voxel);
      const Eigen::Vector3f nearest = centre_W.cwiseMax(lo_W).cwiseMin(hi_W);
      if (!((nearest - centre_W).squaredNorm() <= radius_sq)) continue;
      ++kept;
      if (mark) remap_[child] = 1;
      if (e.level + 1 < leaf_level_) stack[top++] = Entry{child, e.level + 1, child_min};
    }
  }
  return kept;
}

std::uint32_t FreeOctree::prune_to(const Eigen::Vector3f& centre_W, std::uint32_t max_nodes,
                                   float min_radius_m) {
  if (!reserved_ || nodes_.used() <= max_nodes) return 0;
  // The largest radius (to 1 %) that keeps at most max_nodes, not below min_radius_m unless the
  // air within min_radius_m alone overflows max_nodes: then the floor gives way (down to the
  // root alone), so a pool of any size keeps room for the next frame's carving.
  float lo = min_radius_m;
  float hi = 2.0f * map_.size_m();
  if (walk_within(centre_W, lo, false) > max_nodes) {
    hi = lo;
    lo = 0.0f;
  }
  for (int step = 0; step < 24 && hi - lo > 0.01f * hi; ++step) {
    const float mid = 0.5f * (lo + hi);
    if (walk_within(centre_W, mid, false) <= max_nodes) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  return prune(centre_W, lo);
}

std::uint32_t FreeOctree::prune(const Eigen::Vector3f& centre_W, float keep_radius_m) {
  if (!reserved_) return 0;
  const std::uint32_t count = nodes_.used();
  walk_within(centre_W, keep_radius_m, true);
  // New indices in the old order, then move each kept node down (never up: new <= old).
  std::uint32_t kept = 0;
  for (std::uint32_t i = 0; i < count; ++i) remap_[i] = remap_[i] != 0 ? kept++ : kNoNode;
  for (std::uint32_t i = 0; i < count; ++i) {
    if (remap_[i] == kNoNode) continue;
    FreeNode node = nodes_[i];
    for (std::uint32_t& child : node.children) {
      if (child != kNoNode) child = remap_[child];
    }
    nodes_[remap_[i]] = node;
  }
  for (std::uint32_t i = kept; i < count; ++i) nodes_.pop_back();
  return count - kept;
}

FreeOctant FreeOctree::find(const Eigen::Vector3i& voxel) const {
  FreeOctant out;
  if (!reserved_) return out;
  const int depth = map_.voxel_depth;
  const int n = 1 << depth;
  if (voxel.x() < 0 || voxel.y() < 0 || voxel.z() < 0 || voxel.x() >= n || voxel.y() >= n ||
      voxel.z() >= n) {
    return out;
  }
  const int leaf = leaf_level();
  std::uint32_t index = 0;
  for (int level = 0;; ++level) {
    const FreeNode& node = nodes_[index];
    if (node.free_count > 0) {
      const int size = 1 << (depth - level);
      out.free = true;
      out.free_frame = node.free_frame;
      out.level = level;
      out.size_voxels = size;
      out.min_voxel = Eigen::Vector3i(voxel.x() & ~(size - 1), voxel.y() & ~(size - 1),
                                      voxel.z() & ~(size - 1));
      return out;
    }
    if (level == leaf) {
      if (node.sub_free == 0) return out;
      const int leaf_size = 1 << (depth - level);
      const Eigen::Vector3i in_leaf(voxel.x() & (leaf_size - 1), voxel.y() & (leaf_size - 1),
                                    voxel.z() & (leaf_size - 1));
      const Eigen::Vector3i cell = in_leaf / sub_cell_voxels_;
      if (((node.sub_free >> (cell.x() + 2 * cell.y() + 4 * cell.z())) & 1u) == 0) return out;
      out.free = true;
      out.free_frame = node.free_frame;
      out.level = level + 1;
      out.size_voxels = sub_cell_voxels_;
      out.min_voxel = (voxel - in_leaf) + cell * sub_cell_voxels_;
      return out;
    }
    const int bit = depth - level - 1;
    const int child = ((voxel.x() >> bit) & 1) | (((voxel.y() >> bit) & 1) << 1) |
                      (((voxel.z() >> bit) & 1) << 2);
    index = node.children[child];
    if (index == kNoNode) return out;
  }
}

}  // namespace octofuse
