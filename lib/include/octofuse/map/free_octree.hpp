#pragma once
// The free-space octree: a second, sparse octree over the map's cube that records which octants
// frames saw wholly free, at the coarsest octant that was (one node for a metre of empty air).
// It is the data a saved map keeps and a query reads; FreeSpace (query/free_space.hpp) carves
// it from each frame's depth. lib/README.md ("Free space") describes the design.

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <type_traits>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/pool.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/map/map_config.hpp"
#include "octofuse/math/camera.hpp"

namespace octofuse {

class BlockStore;

// The smallest octant the automatic choice of FreeSpaceConfig::finest_octant_voxels takes.
inline constexpr float kAutoFreeOctant_m = 0.05f;

struct FreeSpaceConfig {
  bool enabled = true;
  // Nodes in the free-space pool (the root included); 0 = the TSDF map's node_capacity.
  std::uint32_t node_capacity = 0;
  std::uint32_t max_node_visits = 1u << 18;  // per frame
  std::uint32_t max_new_nodes = 1u << 16;    // per frame
  // Each octant is grown by this much before it is tested (0 = one finest voxel).
  float margin_m = 0.0f;
  // An octant is free only when it lies this far in front of the observed depth (0 = half the
  // TSDF truncation, set by the pipeline): depth noise must not carve into the surface.
  float clearance_m = 0.0f;
  // Free octants less than this behind the observed depth are cleared although the frame does
  // not see into them (0 = 4 mu, set by the pipeline): an object that appears where free space
  // was recorded clears it this deep behind its visible surface. Deeper parts of such an object
  // stay free until seen from elsewhere (a known limit).
  float occlusion_clear_m = 0.0f;
  std::uint8_t max_free_count = 8;
  // Side of the smallest octant carved, in finest voxels: 8 (a block), 4 or 2; or 16, 32 or 64
  // (2^3, 4^3, 8^3 blocks). Smaller octants fit more of the view's edges and the air just in front
  // of surfaces, for more node visits. 0: the smallest of 8, 16, 32 and 64 that spans at least
  // kAutoFreeOctant_m (8 voxels at 1 cm, 32 at 2 mm, where 8-voxel octants would make carving
  // cost more than the rest of the frame).
  int finest_octant_voxels = 0;
  // Leaves and sub-cells whose view holds depths both well in front of them (a nearer object's
  // silhouette, a slanted floor) and behind them are settled pixel by pixel before they are
  // cleared: more of the air beside silhouettes reads free, for a costlier stage.
  bool exact_silhouettes = false;
  // Octants nearer than this to the camera plane are not tested (projection degenerates).
  float near_m = 0.05f;
  // When a frame leaves the pool more than 15/16 full, the pipeline forgets the free space
  // farthest from the camera (prune_to()) until the pool is at most 3/4 full, so that a long
  // mission keeps carving where the robot is; not within this distance of the camera (0 = a
  // quarter of the fusion's far_m) unless the air within it alone overflows the pool. A frame whose
  // carving was refused nodes (pool full) prunes as well, to leave room for as many nodes as it
  // asked for; only a frame that asks for more than the whole pool is still refused (counted in
  // FreeSpaceReport::pool_refused).
  float prune_radius_m = 0.0f;
};

// ok, or invalid_argument for a negative or non-finite margin/clearance/occlusion/near/prune
// radius, max_free_count 0, finest_octant_voxels not 0, 2, 4, 8, 16, 32 or 64, or a zero visit
// budget.
Status validate(const FreeSpaceConfig& config);

// Octree level of the finest free-space octants, of side `octant_voxels` (2 .. 64, a power of
// two), in a map whose blocks (8 voxels) sit at `block_level`.
constexpr int free_leaf_level(int block_level, int octant_voxels) {
  int level = block_level + 3;
  for (int side = 1; side < octant_voxels; side *= 2) --level;
  return level;
}

// FreeSpaceConfig::finest_octant_voxels with 0 resolved for `map`: the smallest of 8, 16, 32 and
// 64 voxels that spans kAutoFreeOctant_m, and whose octants are below the root's children.
inline int resolve_finest_octant_voxels(int requested, const MapConfig& map) {
  if (requested != 0) return requested;
  const int block_level = map.block_level();
  int side = 8;
  while (side < 64 && static_cast<float>(side) * map.voxel_size_m < kAutoFreeOctant_m &&
         free_leaf_level(block_level, 2 * side) >= 1) {
    side *= 2;
  }
  return side;
}

// The finest-voxel corner of child `child` (bit 0: +x, bit 1: +y, bit 2: +z, as FreeNode's
// children and sub_free bits) of the octant at `min_voxel` whose children have side `half`.
inline Eigen::Vector3i child_min_voxel(const Eigen::Vector3i& min_voxel, int child, int half) {
  return min_voxel +
         Eigen::Vector3i((child & 1) ? half : 0, (child & 2) ? half : 0, (child & 4) ? half : 0);
}

struct FreeNode {
  std::uint32_t children[8] = {0xFFFFFFFFu, 0xFFFFFFFFu, 0xFFFFFFFFu, 0xFFFFFFFFu,
                               0xFFFFFFFFu, 0xFFFFFFFFu, 0xFFFFFFFFu, 0xFFFFFFFFu};
  std::uint32_t free_frame = 0;  // frame index of the last frame that saw the octant free
  std::uint8_t free_count = 0;   // frames that saw it free, capped; 0 = not known free
  // Leaves with free_count 0 only: bit x + 2 y + 4 z says the leaf's half-size sub-cell (x, y, z)
  // is wholly free, as of free_frame.
  std::uint8_t sub_free = 0;
  // On a region's node (FreeOctree::region_level()): its stored record is merged in (reload or
  // spill), so spilling it again needs no read of the store. Not part of a saved map.
  std::uint8_t region_loaded = 0;
  std::uint8_t padding_ = 0;
};

// What the free space's store did in one frame (FreeOctree::spill_and_prune(), reload_regions()).
struct FreeStoreReport {
  std::uint32_t written = 0;       // regions handed to the store
  std::uint32_t write_failed = 0;  // regions whose put() failed (their free space is forgotten)
  std::uint32_t read = 0;          // stored regions grafted back
  std::uint32_t read_failed = 0;   // stored regions damaged or unreadable (dropped)
  std::uint32_t waiting = 0;       // stored regions in reach left for a later frame (room, budget)
  std::uint32_t merged = 0;        // of those written, merged with a stored record first
  std::uint64_t bytes_written = 0;
  std::uint64_t bytes_read = 0;
};

// Where FreeOctree::reload_regions() reads stored regions back: every region that comes within
// `radius_m` of the camera, and every region whose bounding sphere reaches into the camera's view
// nearer than `far_m` (so the frame carves into the old air and clears what it now sees occupied).
struct RegionReach {
  Eigen::Vector3f camera_W = Eigen::Vector3f::Zero();
  Eigen::Matrix3f R_C_W = Eigen::Matrix3f::Identity();  // world to camera
  PinholeCamera camera;                                 // not valid(): the sphere of radius_m alone
  float radius_m = 0.0f;
  float far_m = 0.0f;
};

// The free octant containing a point, as found by FreeOctree::find().
struct FreeOctant {
  bool free = false;
  std::uint32_t free_frame = 0;
  int level = -1;                                       // tree level (root 0)
  Eigen::Vector3i min_voxel = Eigen::Vector3i::Zero();  // finest-voxel corner
  int size_voxels = 0;
};

// Node 0 is the root; a node's children are node indices (kNoNode where absent), allocated after
// their parent, so the pool's first node_count() nodes are the whole state. Reserved (and
// written) by FreeSpace; read by queries and the map I/O.
class FreeOctree {
 public:
  static constexpr std::uint32_t kNoNode = 0xFFFFFFFFu;
  // A walk's stack: at most 8 pending siblings per level.
  static constexpr int kStackCapacity = 8 * (kMaxVoxelDepth + 2);

  bool reserved() const { return reserved_; }
  // Nothing known free: the root alone.
  void clear();
  // Writes the pages of the next `nodes` nodes the pool will hand out (IndexPool::prefault).
  void prefault(std::uint32_t nodes) { nodes_.prefault(nodes); }

  // Forgets every octant lying wholly farther than `keep_radius_m` from `centre_W` (its subtree
  // with it: what was free there reads unknown again) and compacts the pool in place, keeping
  // the order of the nodes that stay (children after their parents). Returns the nodes dropped.
  // O(node_count()), no allocation; the root always stays.
  std::uint32_t prune(const Eigen::Vector3f& centre_W, float keep_radius_m);
  // prune() with the largest radius, to 1 %, that leaves at most `max_nodes`, no less than
  // `min_radius_m` when that radius leaves at most `max_nodes` (else the radius may shrink to 0;
  // then the octants containing centre_W may still exceed `max_nodes`). Nothing when at most
  // `max_nodes` are used. Up to 26 walks over the pool.
  std::uint32_t prune_to(const Eigen::Vector3f& centre_W, std::uint32_t max_nodes,
                         float min_radius_m);

  // --- Free space beyond memory. With a store, the tree is cut into regions, octants 3 levels
  // above the leaves (8 x 8 x 8 leaves; at least the root's children): pruning keeps or forgets
  // whole regions, and hands each forgotten one to the store as one record (its subtree; a region
  // under a forgotten free octant as that octant's state), keyed by the Morton code of its
  // corner's block coordinates (block_store.hpp's interface, on its own store). reload_regions()
  // grafts stored regions back when the camera returns. Merging keeps the tree's own node
  // wherever both have one (memory is newer), so nothing the tree cleared comes back free; stored
  // air the tree has no node for is added, aged to frame 0 below a node the tree re-made.
  int region_level() const { return region_level_; }
  int region_voxels() const { return 1 << (map_.voxel_depth - region_level_); }
  // Levels of a region below its node (the leaves' level less the region's, where the cube
  // allows), its most nodes, and the most bytes one region record takes.
  static constexpr int kRegionLevels = 3;
  static constexpr std::size_t kRegionMaxNodes =
      ((std::size_t{1} << (3 * (kRegionLevels + 1))) - 1) / 7;
  static constexpr std::size_t kRegionRecordMaxBytes = 8 + 7 * kRegionMaxNodes + 4;
  static_assert(kRegionMaxNodes == 1 + 8 + 64 + 512, "the record's u16 node count holds it");
  // The node count a region record's head states (0 when it is shorter than its head); for
  // sizing a tree to graft records into. The graft checks the whole record.
  static std::uint32_t region_record_nodes(const std::uint8_t* record, std::size_t size) {
    return size < 8 ? 0 : record[6] | (static_cast<std::uint32_t>(record[7]) << 8);
  }
  // prune() / prune_to() that first writes every forgotten region to `store` (null: prune()).
  // A negative radius forgets every region (Pipeline::reset()).
  std::uint32_t spill_and_prune(const Eigen::Vector3f& centre_W, float keep_radius_m,
                                BlockStore* store, FreeStoreReport* report);
  std::uint32_t spill_and_prune_to(const Eigen::Vector3f& centre_W, std::uint32_t max_nodes,
                                   float min_radius_m, BlockStore* store, FreeStoreReport* report);
  // Grafts back stored regions within `reach`, nearest first, at most `max_reads`, while the pool
  // stays below `max_nodes` (the rest wait: FreeStoreReport::waiting). At most
  // kReloadKeyCapacity stored regions are looked at per call (those with the lowest keys).
  void reload_regions(const RegionReach& reach, BlockStore& store, std::uint32_t max_reads,
                      std::uint32_t max_nodes, FreeStoreReport* report);
  // Grafts one region record into the tree (as reload_regions() does): ok, data_loss (not a
  // valid record of this tree; the tree unchanged), resource_exhausted (no room; unchanged).
  // Nodes added below a node the tree already had (air it re-made since the record was written)
  // count as seen free at frame 0, older than any block: they never override a surface.
  Status graft_region_record(std::uint64_t region_key, const std::uint8_t* record,
                             std::size_t size);

  // The free octant containing finest voxel `voxel` (inside the cube), or free = false with, in
  // min_voxel and size_voxels, the octant around it known to hold no free voxel (size 0 outside
  // the cube): a caller walking a grid asks again only once it leaves either.
  FreeOctant find(const Eigen::Vector3i& voxel) const;

  const FreeSpaceConfig& config() const { return config_; }
  const MapConfig& map_config() const { return map_; }
  float margin_m() const { return margin_m_; }
  // Level of the smallest octants (the blocks' level for finest_octant_voxels 8).
  int leaf_level() const { return leaf_level_; }
  // A leaf's 2 x 2 x 2 sub-cells, each of sub_cell_voxels() finest voxels on a side.
  int sub_cell_voxels() const { return sub_cell_voxels_; }
  std::uint32_t node_count() const { return nodes_.used(); }
  std::uint32_t node_capacity() const { return nodes_.capacity(); }
  const FreeNode& node(std::uint32_t index) const { return nodes_[index]; }
  std::size_t bytes_used() const { return sizeof(FreeNode) * nodes_.used(); }
  std::size_t bytes_reserved() const { return bytes_reserved_; }

  // For the map loader (map/map_io.hpp), which rebuilds a saved free space in pool order:
  // clear(), then `count` empty nodes (the root included) for restore_node() to fill. Children
  // must get higher indices than their parents, as carving allocates them. failed_precondition
  // when not reserved; resource_exhausted when the pool holds fewer (it is left cleared).
  Status begin_restore(std::uint32_t count);
  FreeNode& restore_node(std::uint32_t index) { return nodes_[index]; }

 protected:
  // FreeSpace::reserve() carves, in this order: the node pool (reserve_nodes()), its own scratch,
  // the prune scratch (reserve_prune_scratch()); then finish_reserve().
  template <typename Arena>
  Status reserve_nodes(Arena& arena, const FreeSpaceConfig& config, const MapConfig& map);
  template <typename Arena>
  Status reserve_prune_scratch(Arena& arena);
  template <typename Arena>
  void finish_reserve(Arena& arena, std::size_t start);

  static constexpr std::uint8_t kAllSubCells = 0xFF;

  FreeSpaceConfig config_;
  MapConfig map_;
  IndexPool<FreeNode> nodes_;
  float margin_m_ = 0.0f;
  int leaf_level_ = 0;
  int region_level_ = 1;
  int sub_cell_voxels_ = 4;

 private:
  // A region's subtree in preorder (children by increasing child index).
  struct RegionNode {
    std::uint8_t child_mask = 0;
    std::uint8_t free_count = 0;
    std::uint8_t sub_free = 0;
    std::uint32_t free_frame = 0;
  };
  struct RegionTree {
    RegionNode* nodes = nullptr;  // kRegionMaxNodes
    std::uint32_t count = 0;
  };
  void region_from_tree(std::uint32_t node, int level, RegionTree& out) const;
  std::size_t encode_region(const RegionTree& tree, std::uint8_t* out) const;
  bool decode_region(const std::uint8_t* record, std::size_t size, RegionTree& out) const;
  void spill_region(std::uint32_t node, const Eigen::Vector3i& min_voxel, const FreeNode* inherited,
                    BlockStore& store, FreeStoreReport& report);
  void spill_below(std::uint32_t node, int level, const Eigen::Vector3i& min_voxel,
                   const FreeNode* inherited, BlockStore& store, FreeStoreReport& report);
  // A new node as child `child` of `parent`: empty, or with `from`'s state (its frame 0 when
  // `aged`). The pool must have room.
  std::uint32_t add_child(std::uint32_t parent, int child, const RegionNode* from, bool aged);
  std::uint32_t graft(std::uint32_t node, const RegionTree& tree, std::uint32_t at, bool fresh,
                      bool aged);
  static std::uint32_t skip_subtree(const RegionTree& tree, std::uint32_t at);
  static void merge_at(const RegionTree& a, std::uint32_t& ia, const RegionTree* b,
                       std::uint32_t& ib, RegionTree& out, bool aged);
  // a and b merged, a's nodes winning (memory over store).
  static void merge_regions(const RegionTree& a, const RegionTree& b, RegionTree& out);
  static constexpr std::size_t kReloadKeyCapacity = 1024;
  struct RegionCandidate {
    float distance_m;
    std::uint64_t key;
  };
  RegionCandidate* reload_candidates_ = nullptr;  // kReloadKeyCapacity
  std::uint64_t* reload_keys_ = nullptr;          // kReloadKeyCapacity
  std::uint64_t region_key(const Eigen::Vector3i& min_voxel) const;

  // Nodes within keep_radius_m of centre_W (the root and every node whose octant comes that close
  // and whose parent stays); with `mark`, remap_[i] = 1 for those, 0 for the others. With
  // `whole_regions`, a node below a region that stays stays too; a negative radius keeps the root.
  std::uint32_t walk_within(const Eigen::Vector3f& centre_W, float keep_radius_m, bool mark,
                            bool whole_regions);
  std::uint32_t compact();

  std::uint32_t* remap_ = nullptr;  // prune(): old node index -> new one
  // Region scratch: the tree's region, the stored one, their merge; one record.
  RegionTree region_tree_;
  RegionTree region_stored_;
  RegionTree region_merged_;
  std::uint8_t* region_record_ = nullptr;
  std::size_t bytes_reserved_ = 0;
  bool reserved_ = false;
};

template <typename Arena>
Status FreeOctree::reserve_nodes(Arena& arena, const FreeSpaceConfig& config,
                                 const MapConfig& map) {
  const std::uint32_t capacity =
      config.node_capacity != 0 ? config.node_capacity : map.node_capacity;
  return nodes_.reserve(arena, capacity);
}

template <typename Arena>
Status FreeOctree::reserve_prune_scratch(Arena& arena) {
  Result<std::uint32_t*> remap = arena.template allocate_array<std::uint32_t>(nodes_.capacity());
  OCTOFUSE_TRY(remap);
  remap_ = remap.value();
  for (RegionTree* tree : {&region_tree_, &region_stored_, &region_merged_}) {
    Result<RegionNode*> nodes = arena.template allocate_array<RegionNode>(kRegionMaxNodes);
    OCTOFUSE_TRY(nodes);
    tree->nodes = nodes.value();
  }
  Result<std::uint8_t*> record = arena.template allocate_array<std::uint8_t>(kRegionRecordMaxBytes);
  OCTOFUSE_TRY(record);
  region_record_ = record.value();
  Result<RegionCandidate*> candidates =
      arena.template allocate_array<RegionCandidate>(kReloadKeyCapacity);
  OCTOFUSE_TRY(candidates);
  reload_candidates_ = candidates.value();
  Result<std::uint64_t*> keys = arena.template allocate_array<std::uint64_t>(kReloadKeyCapacity);
  OCTOFUSE_TRY(keys);
  reload_keys_ = keys.value();
  return ok_status();
}

template <typename Arena>
void FreeOctree::finish_reserve(Arena& arena, std::size_t start) {
  bytes_reserved_ = arena.bytes_used() - start;
  if constexpr (!std::is_same_v<Arena, ArenaSizer>) {
    reserved_ = true;
    clear();
  }
}

}  // namespace octofuse
