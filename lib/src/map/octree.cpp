#include "octofuse/map/octree.hpp"

// The octree's cold code: allocation, eviction, summaries and bookkeeping, compiled once for each
// voxel type. Lookups and voxel access stay inline in the header.

namespace octofuse {

template <typename VoxelT>
void Octree<VoxelT>::clear() {
  OCTOFUSE_CHECK(reserved_);
  reset_contents(/*clear_hash=*/true);
}

template <typename VoxelT>
Status Octree<VoxelT>::allocate(const Key* keys, std::size_t count, AllocationCounts* counts) {
  OCTOFUSE_CHECK(reserved_);
  AllocationCounts local;
  AllocationPath path;
  for (std::size_t i = 0; i < count; ++i) allocate_one(keys[i], local, path);
  if (counts != nullptr) *counts = local;
  if (local.refused > 0) return StatusCode::resource_exhausted;
  if (local.rejected > 0) return StatusCode::out_of_range;
  return ok_status();
}

template <typename VoxelT>
Result<std::uint32_t> Octree<VoxelT>::allocate_block(const Eigen::Vector3i& block_coords) {
  if (!contains_block(block_coords)) return StatusCode::out_of_range;
  const std::uint32_t found = find_block_index(block_coords);
  if (found != kNoIndex) return found;
  AllocationCounts local;
  AllocationPath path;
  allocate_one(block_key(block_coords), local, path);
  if (local.refused > 0) return StatusCode::resource_exhausted;
  return find_block_index(block_coords);
}

template <typename VoxelT>
void Octree<VoxelT>::update_block_summary(Block& block) {
  const int scale = block.current_scale;
  float lo = 1.0f;
  float hi = -1.0f;
  float sum = 0.0f;
  float sum_weight = 0.0f;
  int observed = 0;
  block.with_level(scale, [&](const auto* v) {
    for (int i = 0; i < block_scale_count(scale); ++i) {
      if (!voxel_observed(v[i])) continue;
      const float t = voxel_tsdf(v[i]);
      lo = t < lo ? t : lo;
      hi = t > hi ? t : hi;
      sum += t;
      sum_weight += voxel_weight(v[i]);
      ++observed;
    }
  });
  block.tsdf_min = lo;
  block.tsdf_max = hi;
  if (observed > 0) {
    block.tsdf_mean = sum / static_cast<float>(observed);
    block.weight_mean = std::ceil(sum_weight / static_cast<float>(observed));
  }
}

template <typename VoxelT>
void Octree<VoxelT>::propagate_summaries(const std::uint32_t* block_indices, std::size_t count) {
  ++stamp_;
  std::size_t current_count = 0;
  // Blocks and nodes are scattered over large pools: load headers 2d entries ahead, and d ahead
  // (once the header has arrived) the node it points to.
  constexpr std::size_t d = kSummaryPrefetchDistance;
  for (std::size_t i = 0; i < count; ++i) {
    if (i + 2 * d < count) __builtin_prefetch(&blocks_[block_indices[i + 2 * d]].parent_node);
    if (i + d < count) __builtin_prefetch(&nodes_[blocks_[block_indices[i + d]].parent_node]);
    add_summary_node(blocks_[block_indices[i]].parent_node, current_count);
  }
  propagate_node_summaries(current_count);
}

template <typename VoxelT>
void Octree<VoxelT>::propagate_summaries_from_parents(const std::uint32_t* parent_nodes,
                                                      std::size_t count, const WorkerTeam& team) {
  ++stamp_;
  std::size_t current_count = 0;
  constexpr std::size_t d = kSummaryPrefetchDistance;
  for (std::size_t i = 0; i < count; ++i) {
    if (i + d < count && parent_nodes[i + d] != kNoIndex) {
      __builtin_prefetch(&nodes_[parent_nodes[i + d]]);
    }
    if (parent_nodes[i] != kNoIndex) add_summary_node(parent_nodes[i], current_count);
  }
  propagate_node_summaries(current_count, &team);
}

template <typename VoxelT>
void Octree<VoxelT>::evict_blocks(std::uint32_t* indices, std::size_t count) {
  OCTOFUSE_CHECK(reserved_);
  if (count == 0) return;
  std::sort(indices, indices + count, [](std::uint32_t a, std::uint32_t b) { return a > b; });
  ++stamp_;
  std::size_t parents = 0;
  std::size_t empty = 0;  // parents left without children, in scratch_c_
  const int depth = voxel_depth();
  const int leaf = block_level();
  for (std::size_t i = 0; i < count; ++i) {
    const std::uint32_t index = indices[i];
    OCTOFUSE_CHECK(index < blocks_.used() && (i == 0 || index < indices[i - 1]));
    Block& block = blocks_[index];
    if constexpr (kSplitFinest) {
      if (block.finest != nullptr) finest_.release(finest_.index_of(block.finest));
      if (block.mid != nullptr) mid_.release(mid_.index_of(block.mid));
    }
    const bool erased = hash_.erase(morton_encode(block.coords));
    OCTOFUSE_CHECK(erased);
    OctreeNode& parent = nodes_[block.parent_node];
    const int child = child_index(Key{block.morton, static_cast<std::uint8_t>(leaf)}, depth);
    OCTOFUSE_CHECK(parent.children[child] == index);
    parent.children[child] = kNoIndex;
    add_summary_node(block.parent_node, parents);
    if (parent.childless()) scratch_c_[empty++] = block.parent_node;
    const std::uint32_t last = blocks_.used() - 1;
    if (index != last) {
      Block& moved = blocks_[last];
      OctreeNode& moved_parent = nodes_[moved.parent_node];
      const int moved_child =
          child_index(Key{moved.morton, static_cast<std::uint8_t>(leaf)}, depth);
      OCTOFUSE_CHECK(moved_parent.children[moved_child] == last);
      moved_parent.children[moved_child] = index;
      const bool moved_ok = hash_.set_index(morton_encode(moved.coords), index);
      OCTOFUSE_CHECK(moved_ok);
      block = moved;
    }
    blocks_.pop_back();
  }
  propagate_node_summaries(parents, nullptr, /*reset_unobserved=*/true);
  evicted_ += count;
  remove_empty_nodes(empty);
}

template <typename VoxelT>
void Octree<VoxelT>::remove_empty_nodes(std::size_t empty_count) {
  // Mark: each listed node (left without children by eviction) goes, and so does every ancestor
  // that it leaves empty; the root stays. Summaries above are already recomputed (an empty node
  // reads unobserved), so unlinking changes no survivor's summary.
  const int depth = voxel_depth();
  std::uint32_t removed = 0;
  for (std::size_t i = 0; i < empty_count; ++i) {
    std::uint32_t n = scratch_c_[i];
    while (n != root_index() && !nodes_[n].dead() && nodes_[n].childless()) {
      OctreeNode& node = nodes_[n];
      node.removed = 1;
      ++removed;
      OctreeNode& parent = nodes_[node.parent];
      const int child = child_index(node.key(), depth);
      OCTOFUSE_CHECK(parent.children[child] == n);
      parent.children[child] = kNoIndex;
      n = node.parent;
    }
  }
  if (removed == 0) return;
  // Sweep from the top: every index above i is live when i is reached, so the last node that
  // fills a hole is live. The moved node's parent and children follow it.
  const int children_are_blocks_level = block_level() - 1;
  for (std::uint32_t i = nodes_.used(); i-- > 1;) {
    if (!nodes_[i].dead()) continue;
    const std::uint32_t last = nodes_.used() - 1;
    if (i != last) {
      const OctreeNode moved = nodes_[last];
      nodes_[i] = moved;
      nodes_[moved.parent].children[child_index(moved.key(), depth)] = i;
      for (const std::uint32_t c : moved.children) {
        if (c == kNoIndex) continue;
        if (moved.level == children_are_blocks_level) {
          blocks_[c].parent_node = i;
        } else {
          nodes_[c].parent = i;
        }
      }
    }
    nodes_.pop_back();
  }
  nodes_evicted_ += removed;
}

template <typename VoxelT>
bool Octree<VoxelT>::coarsen_block(Block& block, int scale) {
  if constexpr (kSplitFinest) {
    if (!block.integrated() || block.current_scale >= scale) return false;
    if (block.mip_scale < scale) {
      propagate_block_up(block, std::max<int>(block.mip_scale, block.current_scale), scale);
      block.mip_scale = static_cast<std::int8_t>(scale);
    }
    block.current_scale = static_cast<std::int8_t>(scale);
    update_block_summary(block);
    return true;
  } else {
    (void)block;
    (void)scale;
    return false;  // single-res blocks have no coarser levels to move to
  }
}

template <typename VoxelT>
void Octree<VoxelT>::release_finest(const std::uint32_t* indices, std::size_t count) {
  release_levels(indices, count, 1);
}

template <typename VoxelT>
void Octree<VoxelT>::release_mid(const std::uint32_t* indices, std::size_t count) {
  release_levels(indices, count, 2);
}

template <typename VoxelT>
void Octree<VoxelT>::release_levels(const std::uint32_t* indices, std::size_t count,
                                    int keep_scale) {
  OCTOFUSE_CHECK(reserved_);
  if constexpr (kSplitFinest) {
    ++stamp_;
    std::size_t parents = 0;
    for (std::size_t i = 0; i < count; ++i) {
      Block& block = blocks_[indices[i]];
      const bool finest = block.finest != nullptr;
      const bool mid = keep_scale == 2 && block.mid != nullptr;
      if (!finest && !mid) continue;
      if (coarsen_block(block, keep_scale)) add_summary_node(block.parent_node, parents);
      if (finest) {
        finest_.release(finest_.index_of(block.finest));
        block.finest = nullptr;
      }
      if (mid) {
        mid_.release(mid_.index_of(block.mid));
        block.mid = nullptr;
      }
    }
    propagate_node_summaries(parents, nullptr, /*reset_unobserved=*/true);
  } else {
    (void)indices;
    (void)count;
    (void)keep_scale;
  }
}

template <typename VoxelT>
MapMemory Octree<VoxelT>::memory() const {
  MapMemory m;
  m.bytes_reserved = bytes_reserved_;
  m.bytes_per_block = sizeof(Block);
  m.blocks_used = blocks_.used();
  m.block_capacity = blocks_.capacity();
  m.nodes_used = nodes_.used();
  m.node_capacity = nodes_.capacity();
  m.bytes_used = sizeof(Block) * m.blocks_used + sizeof(OctreeNode) * m.nodes_used;
  if constexpr (kSplitFinest) {
    m.bytes_per_finest = sizeof(Finest);
    m.finest_used = finest_.used();
    m.finest_capacity = finest_.capacity();
    m.bytes_used += sizeof(Finest) * m.finest_used;
    m.bytes_per_mid = sizeof(Mid);
    m.mid_used = mid_.used();
    m.mid_capacity = mid_.capacity();
    m.bytes_used += sizeof(Mid) * m.mid_used;
  }
  m.refusals = refusals_;
  m.finest_refusals = finest_refusals_;
  m.mid_refusals = mid_refusals_;
  m.evicted = evicted_;
  m.node_refusals = node_refusals_;
  m.nodes_evicted = nodes_evicted_;
  return m;
}

template <typename VoxelT>
void Octree<VoxelT>::reset_contents(bool clear_hash) {
  nodes_.reset();
  blocks_.reset();
  finest_.reset();
  mid_.reset();
  if (clear_hash) hash_.clear();
  refusals_ = 0;
  finest_refusals_ = 0;
  mid_refusals_ = 0;
  node_refusals_ = 0;
  evicted_ = 0;
  nodes_evicted_ = 0;
  stamp_ = 0;
  Result<std::uint32_t> root = nodes_.allocate();
  OCTOFUSE_CHECK(root.ok() && root.value() == 0);
  nodes_[0].level = 0;
  nodes_[0].morton = 0;
}

template <typename VoxelT>
void Octree<VoxelT>::allocate_one(const Key& key, AllocationCounts& counts, AllocationPath& path) {
  const int depth = voxel_depth();
  const int leaf = block_level();
  const Eigen::Vector3i corner = key_corner_voxel(key);
  if (key.level > leaf || !contains_voxel(corner)) {
    ++counts.rejected;
    return;
  }
  if (key.level == leaf && hash_.find(morton_encode(voxel_to_block(corner))) != kNoIndex) {
    ++counts.already_allocated;
    return;
  }
  if (key.level == 0) {
    ++counts.already_allocated;
    return;
  }
  // The deepest known node containing the key, above its level.
  int start = std::min(path.levels, static_cast<int>(key.level)) - 1;
  while (start > 0 &&
         (key.morton >> (3 * (depth - start))) != (path.morton >> (3 * (depth - start)))) {
    --start;
  }
  std::uint32_t node = path.node[start];
  path.morton = key.morton;
  path.levels = start + 1;
  path.fresh_from = kMaxVoxelDepth + 1;
  for (int level = start + 1; level <= key.level; ++level) {
    const Key here = parent_key_at(key, level, depth);
    const int child = child_index(here, depth);
    const std::uint32_t existing = nodes_[node].children[child];
    if (existing != kNoIndex) {
      if (level == key.level) ++counts.already_allocated;
      node = existing;
      if (level < leaf) {
        path.node[level] = node;
        path.levels = level + 1;
      }
      continue;
    }
    if (level == leaf) {
      Result<std::uint32_t> b = blocks_.allocate();
      if (!b.ok()) {
        ++counts.refused;
        ++refusals_;
        undo_new_nodes(counts, path);
        return;
      }
      Block& block = blocks_[b.value()];
      block.coords = voxel_to_block(corner);
      block.morton = here.morton;
      block.parent_node = node;
      const Status inserted = hash_.insert(morton_encode(block.coords), b.value());
      OCTOFUSE_CHECK(inserted.ok());  // the hash holds as many entries as the pool
      nodes_[node].children[child] = b.value();
      ++counts.new_blocks;
      return;
    }
    Result<std::uint32_t> n = nodes_.allocate();
    if (!n.ok()) {
      ++counts.refused;
      ++refusals_;
      ++node_refusals_;
      undo_new_nodes(counts, path);
      return;
    }
    OctreeNode& fresh = nodes_[n.value()];
    fresh.parent = node;
    fresh.morton = here.morton;
    fresh.level = static_cast<std::uint8_t>(level);
    nodes_[node].children[child] = n.value();
    ++counts.new_nodes;
    if (path.fresh_from > level) path.fresh_from = level;
    node = n.value();
    path.node[level] = node;
    path.levels = level + 1;
  }
}

template <typename VoxelT>
void Octree<VoxelT>::undo_new_nodes(AllocationCounts& counts, AllocationPath& path) {
  // A refused key leaves no childless chain behind (eviction could never free it): the nodes
  // this key created are the last ones of the pool, deepest last.
  const int depth = voxel_depth();
  for (int level = path.levels - 1; level >= path.fresh_from; --level) {
    const std::uint32_t n = path.node[level];
    OCTOFUSE_CHECK(n == nodes_.used() - 1);
    const OctreeNode& node = nodes_[n];
    nodes_[node.parent].children[child_index(node.key(), depth)] = kNoIndex;
    nodes_.pop_back();
    --counts.new_nodes;
  }
  if (path.levels > path.fresh_from) path.levels = path.fresh_from;
  path.fresh_from = kMaxVoxelDepth + 1;
}

template <typename VoxelT>
void Octree<VoxelT>::add_summary_node(std::uint32_t p, std::size_t& current_count) {
  if (nodes_[p].visit_stamp == stamp_) return;
  nodes_[p].visit_stamp = stamp_;
  scratch_a_[current_count++] = p;
}

template <typename VoxelT>
void Octree<VoxelT>::propagate_node_summaries(std::size_t current_count, const WorkerTeam* team,
                                              bool reset_unobserved) {
  constexpr std::size_t d = kSummaryPrefetchDistance;
  std::uint32_t* current = scratch_a_;
  std::uint32_t* next = scratch_b_;
  bool children_are_blocks = true;
  while (current_count > 0) {
    const bool parallel = team != nullptr && current_count >= kParallelSummaryNodes;
    if (parallel) {
      const std::uint32_t* level = current;
      const std::size_t level_count = current_count;
      const bool blocks = children_are_blocks;
      auto summarise_task = [&](std::size_t task) {
        const TaskRange r = task_range(level_count, task, kSummaryTasks);
        for (std::size_t i = r.begin; i < r.end; ++i) {
          if (i + 2 * d < r.end) __builtin_prefetch(&nodes_[level[i + 2 * d]]);
          if (i + d < r.end) prefetch_children(nodes_[level[i + d]], blocks);
          summarise_node(nodes_[level[i]], blocks, reset_unobserved);
        }
      };
      team->for_each_task(kSummaryTasks, summarise_task);
    }
    // The next level, in first-seen order (serially: the order must not depend on the tasks).
    std::size_t next_count = 0;
    for (std::size_t i = 0; i < current_count; ++i) {
      OctreeNode& n = nodes_[current[i]];
      if (!parallel) {
        // Same for the nodes of this level and, d ahead, the children they summarise.
        if (i + 2 * d < current_count) __builtin_prefetch(&nodes_[current[i + 2 * d]]);
        if (i + d < current_count) prefetch_children(nodes_[current[i + d]], children_are_blocks);
        summarise_node(n, children_are_blocks, reset_unobserved);
      } else if (i + d < current_count) {
        __builtin_prefetch(&nodes_[current[i + d]].parent);
      }
      if (n.parent == kNoIndex) continue;
      OctreeNode& p = nodes_[n.parent];
      if (p.visit_stamp == stamp_) continue;
      p.visit_stamp = stamp_;
      next[next_count++] = n.parent;
    }
    std::uint32_t* swap = current;
    current = next;
    next = swap;
    current_count = next_count;
    children_are_blocks = false;
  }
}

template <typename VoxelT>
void Octree<VoxelT>::prefetch_children(const OctreeNode& n, bool children_are_blocks) const {
  for (int c = 0; c < 8; ++c) {
    const std::uint32_t child = n.children[c];
    if (child == kNoIndex) continue;
    if (children_are_blocks) {
      __builtin_prefetch(&blocks_[child].tsdf_min);
    } else {
      __builtin_prefetch(&nodes_[child].summary);
    }
  }
}

template <typename VoxelT>
void Octree<VoxelT>::summarise_node(OctreeNode& n, bool children_are_blocks,
                                    bool reset_unobserved) {
  float sum_tsdf = 0.0f;
  float sum_weight = 0.0f;
  float lo = 1.0f;
  float hi = -1.0f;
  int observed = 0;
  for (int c = 0; c < 8; ++c) {
    const std::uint32_t child = n.children[c];
    if (child == kNoIndex) continue;
    float mean;
    float weight;
    float child_lo;
    float child_hi;
    if (children_are_blocks) {
      const Block& b = blocks_[child];
      mean = b.tsdf_mean;
      weight = b.weight_mean;
      child_lo = b.tsdf_min;
      child_hi = b.tsdf_max;
    } else {
      const NodeSummary& s = nodes_[child].summary;
      mean = s.tsdf_mean;
      weight = s.weight_mean;
      child_lo = s.tsdf_min;
      child_hi = s.tsdf_max;
    }
    if (!(weight > 0.0f)) continue;
    ++observed;
    sum_tsdf += mean;
    sum_weight += weight;
    lo = child_lo < lo ? child_lo : lo;
    hi = child_hi > hi ? child_hi : hi;
  }
  if (observed == 0) {
    if (reset_unobserved) n.summary = NodeSummary();
    return;
  }
  n.summary.tsdf_mean = sum_tsdf / static_cast<float>(observed);
  n.summary.weight_mean = std::ceil(sum_weight / static_cast<float>(observed));
  n.summary.tsdf_min = lo;
  n.summary.tsdf_max = hi;
}
template class Octree<TsdfVoxel>;
template class Octree<MultiresVoxel>;
template class Octree<Multires16Voxel>;

}  // namespace octofuse
