#include "octofuse/map/free_octree.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "octofuse/map/block_store.hpp"
#include "octofuse/map/detail/little_endian.hpp"
#include "octofuse/map/keys.hpp"
#include "octofuse/map/map_io.hpp"

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
                                      bool mark, bool whole_regions) {
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
  if (keep_radius_m < 0.0f) return kept;
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
      const bool in_kept_region = whole_regions && e.level + 1 > region_level_;
      if (!in_kept_region && !((nearest - centre_W).squaredNorm() <= radius_sq)) continue;
      ++kept;
      if (mark) remap_[child] = 1;
      if (e.level + 1 < leaf_level_) stack[top++] = Entry{child, e.level + 1, child_min};
    }
  }
  return kept;
}

std::uint32_t FreeOctree::prune_to(const Eigen::Vector3f& centre_W, std::uint32_t max_nodes,
                                   float min_radius_m) {
  return spill_and_prune_to(centre_W, max_nodes, min_radius_m, nullptr, nullptr);
}

std::uint32_t FreeOctree::spill_and_prune_to(const Eigen::Vector3f& centre_W,
                                             std::uint32_t max_nodes, float min_radius_m,
                                             BlockStore* store, FreeStoreReport* report) {
  if (!reserved_ || nodes_.used() <= max_nodes) return 0;
  const bool whole_regions = store != nullptr;
  // The largest radius (to 1 %) that keeps at most max_nodes, not below min_radius_m unless the
  // air within min_radius_m alone overflows max_nodes: then the floor gives way (down to the
  // root alone), so a pool of any size keeps room for the next frame's carving.
  float lo = min_radius_m;
  float hi = 2.0f * map_.size_m();
  if (walk_within(centre_W, lo, false, whole_regions) > max_nodes) {
    hi = lo;
    lo = 0.0f;
  }
  for (int step = 0; step < 24 && hi - lo > 0.01f * hi; ++step) {
    const float mid = 0.5f * (lo + hi);
    if (walk_within(centre_W, mid, false, whole_regions) <= max_nodes) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  return spill_and_prune(centre_W, lo, store, report);
}

std::uint32_t FreeOctree::prune(const Eigen::Vector3f& centre_W, float keep_radius_m) {
  return spill_and_prune(centre_W, keep_radius_m, nullptr, nullptr);
}

std::uint32_t FreeOctree::spill_and_prune(const Eigen::Vector3f& centre_W, float keep_radius_m,
                                          BlockStore* store, FreeStoreReport* report) {
  if (!reserved_) return 0;
  walk_within(centre_W, keep_radius_m, true, store != nullptr);
  if (store != nullptr) {
    FreeStoreReport unused;
    spill_below(0, 0, Eigen::Vector3i::Zero(), nullptr, *store, report ? *report : unused);
  }
  return compact();
}

std::uint32_t FreeOctree::compact() {
  const std::uint32_t count = nodes_.used();
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

// --- Regions: the store's records.

namespace {

constexpr std::uint8_t kRegionMagic[4] = {'O', 'F', 'R', 'G'};
constexpr std::uint8_t kRegionVersion = 1;
constexpr std::size_t kRegionHeadBytes = 8;  // magic, version, levels below the root, node count
constexpr std::size_t kRegionNodeBytes = 7;  // child mask, free count, sub-cells, free frame

using detail::get_u32;
using detail::put_u32;
bool is_region_corner(const Eigen::Vector3i& min_voxel, int side) {
  return (min_voxel.x() & (side - 1)) == 0 && (min_voxel.y() & (side - 1)) == 0 &&
         (min_voxel.z() & (side - 1)) == 0;
}
// The child (bits as FreeNode::children) of the octant at `level` that holds finest voxel `voxel`.
int child_towards(const Eigen::Vector3i& voxel, int level, int voxel_depth) {
  const int bit = voxel_depth - level - 1;
  return ((voxel.x() >> bit) & 1) | (((voxel.y() >> bit) & 1) << 1) |
         (((voxel.z() >> bit) & 1) << 2);
}
int popcount8(std::uint8_t v) {
  int n = 0;
  for (; v != 0; v = static_cast<std::uint8_t>(v & (v - 1))) ++n;
  return n;
}

}  // namespace

std::uint64_t FreeOctree::region_key(const Eigen::Vector3i& min_voxel) const {
  return morton_encode(min_voxel / 8);
}

void FreeOctree::region_from_tree(std::uint32_t node, int level, RegionTree& out) const {
  const FreeNode& n = nodes_[node];
  RegionNode& r = out.nodes[out.count++];
  r.free_count = n.free_count;
  r.sub_free = n.sub_free;
  r.free_frame = n.free_frame;
  r.child_mask = 0;
  if (level >= leaf_level_) return;
  for (int c = 0; c < 8; ++c) {
    if (n.children[c] == kNoNode) continue;
    r.child_mask = static_cast<std::uint8_t>(r.child_mask | (1u << c));
    region_from_tree(n.children[c], level + 1, out);
  }
}

std::size_t FreeOctree::encode_region(const RegionTree& tree, std::uint8_t* out) const {
  std::memcpy(out, kRegionMagic, 4);
  out[4] = kRegionVersion;
  out[5] = static_cast<std::uint8_t>(leaf_level_ - region_level_);
  out[6] = static_cast<std::uint8_t>(tree.count & 0xFF);
  out[7] = static_cast<std::uint8_t>(tree.count >> 8);
  std::uint8_t* p = out + kRegionHeadBytes;
  for (std::uint32_t i = 0; i < tree.count; ++i, p += kRegionNodeBytes) {
    const RegionNode& r = tree.nodes[i];
    p[0] = r.child_mask;
    p[1] = r.free_count;
    p[2] = r.sub_free;
    put_u32(p + 3, r.free_frame);
  }
  put_u32(p, crc32(out, static_cast<std::size_t>(p - out)));
  return static_cast<std::size_t>(p - out) + 4;
}

bool FreeOctree::decode_region(const std::uint8_t* record, std::size_t size,
                               RegionTree& out) const {
  if (size < kRegionHeadBytes + kRegionNodeBytes + 4) return false;
  if (std::memcmp(record, kRegionMagic, 4) != 0 || record[4] != kRegionVersion) return false;
  if (record[5] != leaf_level_ - region_level_) return false;
  const std::uint32_t count = region_record_nodes(record, size);
  if (count == 0 || count > kRegionMaxNodes) return false;
  if (size != kRegionHeadBytes + kRegionNodeBytes * count + 4) return false;
  if (crc32(record, size - 4) != get_u32(record + size - 4)) return false;
  // The masks must describe exactly `count` nodes in preorder, none below the leaves.
  std::uint32_t pending[kRegionLevels];  // children still to come per open level
  int open = 0;
  const std::uint8_t* p = record + kRegionHeadBytes;
  const int max_depth = leaf_level_ - region_level_;
  for (std::uint32_t i = 0; i < count; ++i, p += kRegionNodeBytes) {
    while (open > 0 && pending[open - 1] == 0) --open;
    if (i > 0 && open == 0) return false;  // nodes after the tree ended
    const int depth = open;
    if (open > 0) --pending[open - 1];
    RegionNode& r = out.nodes[i];
    r.child_mask = p[0];
    r.free_count = p[1];
    r.sub_free = p[2];
    r.free_frame = get_u32(p + 3);
    if (r.child_mask != 0) {
      if (depth >= max_depth) return false;
      pending[open++] = static_cast<std::uint32_t>(popcount8(r.child_mask));
    }
    if (r.sub_free != 0 && depth != max_depth) return false;
    if (r.free_count > config_.max_free_count) return false;
  }
  while (open > 0 && pending[open - 1] == 0) --open;
  if (open != 0) return false;  // children announced, not given
  out.count = count;
  return true;
}

std::uint32_t FreeOctree::skip_subtree(const RegionTree& tree, std::uint32_t at) {
  std::uint32_t pending = 1;
  while (pending > 0) {
    pending += static_cast<std::uint32_t>(popcount8(tree.nodes[at++].child_mask));
    --pending;
  }
  return at;
}

void FreeOctree::merge_at(const RegionTree& a, std::uint32_t& ia, const RegionTree* b,
                          std::uint32_t& ib, RegionTree& out, bool aged) {
  // a's node wins; below a node of a's that is not free, b's children a lacks are added, aged
  // (seen free at frame 0: older than any block).
  const RegionNode& na = a.nodes[ia++];
  const RegionNode* nb = b != nullptr ? &b->nodes[ib++] : nullptr;
  const bool with_b = nb != nullptr && na.free_count == 0;
  const std::uint8_t mask_b = nb != nullptr ? nb->child_mask : 0;
  const std::uint32_t at = out.count++;
  out.nodes[at] = na;
  if (aged) out.nodes[at].free_frame = 0;
  if (with_b) out.nodes[at].child_mask = static_cast<std::uint8_t>(na.child_mask | mask_b);
  std::uint32_t none = 0;
  for (int c = 0; c < 8; ++c) {
    const bool in_a = (na.child_mask & (1u << c)) != 0;
    const bool in_b = (mask_b & (1u << c)) != 0;
    if (in_a && in_b && with_b) {
      merge_at(a, ia, b, ib, out, aged);
    } else if (in_a) {
      merge_at(a, ia, nullptr, none, out, aged);
      if (in_b) ib = skip_subtree(*b, ib);
    } else if (in_b && with_b) {
      merge_at(*b, ib, nullptr, none, out, /*aged=*/true);
    } else if (in_b) {
      ib = skip_subtree(*b, ib);
    }
  }
}

void FreeOctree::merge_regions(const RegionTree& a, const RegionTree& b, RegionTree& out) {
  out.count = 0;
  std::uint32_t ia = 0;
  std::uint32_t ib = 0;
  merge_at(a, ia, &b, ib, out, /*aged=*/false);
}

std::uint32_t FreeOctree::add_child(std::uint32_t parent, int child, const RegionNode* from,
                                    bool aged) {
  const Result<std::uint32_t> made = nodes_.allocate();
  OCTOFUSE_CHECK(made.ok());  // room was checked for the whole record
  FreeNode& n = nodes_[made.value()];
  n = FreeNode{};
  if (from != nullptr) {
    n.free_count = from->free_count;
    n.sub_free = from->sub_free;
    n.free_frame = aged ? 0 : from->free_frame;
  }
  nodes_[parent].children[child] = made.value();
  return made.value();
}

std::uint32_t FreeOctree::graft(std::uint32_t node, const RegionTree& tree, std::uint32_t at,
                                bool fresh, bool aged) {
  // `node` is the tree's node where the record's node `at` lies. A node the tree had wins (and,
  // free, covers the record's subtree); children it lacks come from the record, whole.
  const RegionNode& r = tree.nodes[at++];
  const bool own_free = !fresh && nodes_[node].free_count > 0;
  for (int c = 0; c < 8; ++c) {
    if ((r.child_mask & (1u << c)) == 0) continue;
    if (own_free) {
      at = skip_subtree(tree, at);
      continue;
    }
    std::uint32_t child = nodes_[node].children[c];
    bool child_fresh = fresh;
    // Below a node the tree had, the record's air is older than what the tree re-made since.
    const bool child_aged = aged || !fresh;
    if (child == kNoNode) {
      child_fresh = true;
      child = add_child(node, c, &tree.nodes[at], child_aged);
    }
    at = graft(child, tree, at, child_fresh, child_fresh && child_aged);
  }
  return at;
}

Status FreeOctree::graft_region_record(std::uint64_t key, const std::uint8_t* record,
                                       std::size_t size) {
  if (!reserved_) return StatusCode::failed_precondition;
  if (!decode_region(record, size, region_stored_)) return StatusCode::data_loss;
  const Eigen::Vector3i min_voxel = morton_decode(key) * 8;
  const int depth = map_.voxel_depth;
  const int side = region_voxels();
  const int n = 1 << depth;
  if ((min_voxel.array() < 0).any() || (min_voxel.array() + side > n).any() ||
      !is_region_corner(min_voxel, side)) {
    return StatusCode::data_loss;
  }
  if (nodes_.used() + region_stored_.count + static_cast<std::uint32_t>(region_level_) >
      nodes_.capacity()) {
    return StatusCode::resource_exhausted;
  }
  // Down to the region's node, making the path; a free octant above it is newer and wins.
  std::uint32_t index = 0;
  bool fresh = false;
  for (int level = 0; level < region_level_; ++level) {
    if (nodes_[index].free_count > 0) return ok_status();
    const int child = child_towards(min_voxel, level, depth);
    std::uint32_t next = nodes_[index].children[child];
    if (next == kNoNode) {
      // A path node is empty; the region's own node takes the record's root.
      fresh = level + 1 == region_level_;
      next = add_child(index, child, fresh ? &region_stored_.nodes[0] : nullptr, false);
    }
    index = next;
  }
  graft(index, region_stored_, 0, fresh, /*aged=*/false);
  nodes_[index].region_loaded = 1;
  return ok_status();
}

void FreeOctree::spill_region(std::uint32_t node, const Eigen::Vector3i& min_voxel,
                              const FreeNode* inherited, BlockStore& store,
                              FreeStoreReport& report) {
  // The tree's view of the region: its subtree, or the forgotten free octant above it.
  region_tree_.count = 0;
  if (inherited != nullptr) {
    RegionNode& r = region_tree_.nodes[region_tree_.count++];
    r = RegionNode{};
    r.free_count = inherited->free_count;
    r.free_frame = inherited->free_frame;
  } else {
    region_from_tree(node, region_level_, region_tree_);
  }
  const std::uint64_t key = region_key(min_voxel);
  const RegionTree* out = &region_tree_;
  const bool loaded = inherited == nullptr && nodes_[node].region_loaded != 0;
  if (!loaded) {
    // A stored record the tree never read back (the region was carved again from afar): merge,
    // the tree's nodes winning, so the stored air is not lost.
    const Result<std::size_t> size = store.take(key, region_record_, kRegionRecordMaxBytes);
    if (size.ok()) {
      report.bytes_read += size.value();
      if (decode_region(region_record_, size.value(), region_stored_)) {
        merge_regions(region_tree_, region_stored_, region_merged_);
        out = &region_merged_;
        ++report.merged;
      } else {
        ++report.read_failed;
      }
    }
  }
  const std::size_t bytes = encode_region(*out, region_record_);
  if (store.put(key, region_record_, bytes).ok()) {
    ++report.written;
    report.bytes_written += bytes;
  } else {
    ++report.write_failed;
  }
}

void FreeOctree::spill_below(std::uint32_t node, int level, const Eigen::Vector3i& min_voxel,
                             const FreeNode* inherited, BlockStore& store,
                             FreeStoreReport& report) {
  // `node` (kNoNode: absent, under a forgotten free octant `inherited`) lies above the regions.
  const int half = 1 << (map_.voxel_depth - level - 1);
  for (int c = 0; c < 8; ++c) {
    const std::uint32_t child = node != kNoNode ? nodes_[node].children[c] : kNoNode;
    const Eigen::Vector3i child_min = child_min_voxel(min_voxel, c, half);
    if (child == kNoNode && inherited == nullptr) continue;
    // A kept node and all it covers stay (a kept free octant covers what is below it).
    if (child != kNoNode && remap_[child] != 0) {
      if (level + 1 < region_level_ && nodes_[child].free_count == 0) {
        spill_below(child, level + 1, child_min, nullptr, store, report);
      }
      continue;
    }
    const FreeNode* free_above = inherited != nullptr ? inherited
                                 : (child != kNoNode && nodes_[child].free_count > 0)
                                     ? &nodes_[child]
                                     : nullptr;
    if (level + 1 == region_level_) {
      spill_region(child, child_min, free_above, store, report);
    } else {
      spill_below(child, level + 1, child_min, free_above, store, report);
    }
  }
}

void FreeOctree::reload_regions(const RegionReach& reach, BlockStore& store,
                                std::uint32_t max_reads, std::uint32_t max_nodes,
                                FreeStoreReport* report) {
  const bool in_view = reach.camera.valid() && reach.far_m > reach.radius_m;
  const float range_m = in_view ? reach.far_m : reach.radius_m;
  if (!reserved_ || !(range_m >= 0.0f) || !reach.camera_W.allFinite()) return;
  const float voxel = map_.voxel_size_m;
  const int side = region_voxels();
  const int n = 1 << map_.voxel_depth;
  const Eigen::Vector3f c = (reach.camera_W - map_.origin_W) / voxel;
  const float r = range_m / voxel;
  auto clamp_voxel = [n](float f) {
    if (!(f > 0.0f)) return 0;
    if (!(f < static_cast<float>(n - 1))) return n - 1;
    return static_cast<int>(f);
  };
  Eigen::Vector3i lo;
  Eigen::Vector3i hi;
  for (int a = 0; a < 3; ++a) {
    lo[a] = clamp_voxel(c[a] - r) & ~(side - 1);
    hi[a] = clamp_voxel(c[a] + r);
  }
  const std::size_t found = store.find_in_box(lo / 8, hi / 8, reload_keys_, kReloadKeyCapacity);
  // Those in reach, nearest first (ties by key: the same order on every machine).
  const float half_diagonal_m = 0.8660254f * static_cast<float>(side) * voxel;
  const float margin_px = std::max(reach.camera.fx, reach.camera.fy);
  std::size_t count = 0;
  for (std::size_t i = 0; i < found; ++i) {
    const Eigen::Vector3i min_voxel = morton_decode(reload_keys_[i]) * 8;
    if (!is_region_corner(min_voxel, side)) continue;
    const Eigen::Vector3f centre_W =
        map_.origin_W +
        (min_voxel.cast<float>() + Eigen::Vector3f::Constant(0.5f * static_cast<float>(side))) *
            voxel;
    const Eigen::Vector3f to_centre = centre_W - reach.camera_W;
    const float distance_m = to_centre.norm();
    bool wanted = distance_m - half_diagonal_m <= reach.radius_m;
    if (!wanted && in_view && distance_m - half_diagonal_m <= reach.far_m) {
      // The region's bounding sphere against the view: straddling the camera plane, or its
      // centre within the image grown by the sphere's projected radius.
      const Eigen::Vector3f p_C = reach.R_C_W * to_centre;
      if (p_C.z() <= half_diagonal_m) {
        wanted = p_C.z() > -half_diagonal_m;
      } else {
        const Eigen::Vector2f px = reach.camera.project(p_C);
        const float grow = margin_px * half_diagonal_m / p_C.z();
        wanted = px.x() >= -grow && px.y() >= -grow &&
                 px.x() <= static_cast<float>(reach.camera.width) + grow &&
                 px.y() <= static_cast<float>(reach.camera.height) + grow;
      }
    }
    if (wanted) reload_candidates_[count++] = RegionCandidate{distance_m, reload_keys_[i]};
  }
  std::sort(reload_candidates_, reload_candidates_ + count,
            [](const RegionCandidate& a, const RegionCandidate& b) {
              return a.distance_m < b.distance_m || (a.distance_m == b.distance_m && a.key < b.key);
            });
  for (std::size_t i = 0; i < count; ++i) {
    const std::uint64_t key = reload_candidates_[i].key;
    if (report->read >= max_reads ||
        nodes_.used() + kRegionMaxNodes + static_cast<std::uint32_t>(region_level_) > max_nodes) {
      report->waiting += static_cast<std::uint32_t>(count - i);
      break;
    }
    const Result<std::size_t> size = store.take(key, region_record_, kRegionRecordMaxBytes);
    if (!size.ok()) {
      ++report->read_failed;
      continue;
    }
    report->bytes_read += size.value();
    const Status grafted = graft_region_record(key, region_record_, size.value());
    if (grafted.ok()) {
      ++report->read;
    } else if (grafted.code() == StatusCode::resource_exhausted) {
      store.release(key);
      ++report->waiting;
    } else {
      // Damaged: dropped (the tree's own air, carved again, replaces it when spilled).
      ++report->read_failed;
    }
  }
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
  // Where nothing is free: the octant of `size` voxels around the voxel, which holds no free one.
  auto none_in = [&out, &voxel](int size) {
    out.size_voxels = size;
    out.min_voxel = Eigen::Vector3i(voxel.x() & ~(size - 1), voxel.y() & ~(size - 1),
                                    voxel.z() & ~(size - 1));
    return out;
  };
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
      const int leaf_size = 1 << (depth - level);
      if (node.sub_free == 0) return none_in(leaf_size);
      const Eigen::Vector3i in_leaf(voxel.x() & (leaf_size - 1), voxel.y() & (leaf_size - 1),
                                    voxel.z() & (leaf_size - 1));
      const Eigen::Vector3i cell = in_leaf / sub_cell_voxels_;
      out.size_voxels = sub_cell_voxels_;
      out.min_voxel = (voxel - in_leaf) + cell * sub_cell_voxels_;
      if (((node.sub_free >> (cell.x() + 2 * cell.y() + 4 * cell.z())) & 1u) == 0) return out;
      out.free = true;
      out.free_frame = node.free_frame;
      out.level = level + 1;
      return out;
    }
    index = node.children[child_towards(voxel, level, depth)];
    if (index == kNoNode) return none_in(1 << (depth - level - 1));
  }
}

}  // namespace octofuse
