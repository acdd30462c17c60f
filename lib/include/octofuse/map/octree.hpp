#pragma once
// The map: an octree over a cube of 2^d finest voxels per side. Inner nodes come from a node pool,
// leaves are mip-mapped 8^3 voxel blocks from a block pool, and a hash of block coordinates finds
// a block without walking the tree. Multires blocks take their finest level (8^3 voxels) and their
// mid level (4^3) from pools of their own only when first written at scale 0 or 1 (see
// voxel_block.hpp). All are carved from an
// arena at reserve() and never grow: when a pool is full, allocation is refused, counted and
// reported, and the map stays valid. evict_blocks() and release_finest() give memory back for
// bounded maps over unbounded areas (the pipeline decides which blocks).
//
// Inner nodes carry a summary of what is below them (mean, min and max normalised TSDF over
// observed children, mean weight), kept up to date by propagate_summaries() after integration,
// so ray-casting can skip empty space and coarse queries see the data.
//
// Threading: lookups and voxel reads/writes of distinct blocks may run concurrently; allocate(),
// clear() and propagate_summaries() must not overlap anything else.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/check.hpp"
#include "octofuse/core/parallel.hpp"
#include "octofuse/core/pool.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/map/detail/block_hash.hpp"
#include "octofuse/map/detail/mip.hpp"
#include "octofuse/map/keys.hpp"
#include "octofuse/map/map_config.hpp"
#include "octofuse/map/voxel.hpp"
#include "octofuse/map/voxel_block.hpp"

namespace octofuse {

// Aggregate of an octant's observed content. `weight_mean` 0 means nothing below was observed
// (then tsdf_min > tsdf_max and the means are defaults).
struct NodeSummary {
  float tsdf_mean = 1.0f;
  float weight_mean = 0.0f;
  float tsdf_min = 1.0f;
  float tsdf_max = -1.0f;

  bool observed() const { return weight_mean > 0.0f; }
};

struct OctreeNode {
  // Children by child index (bit 0 = +x, bit 1 = +y, bit 2 = +z): node indices, or block indices
  // for nodes at level block_level - 1; kNoIndex where not allocated.
  std::uint32_t children[8] = {kNoIndex, kNoIndex, kNoIndex, kNoIndex,
                               kNoIndex, kNoIndex, kNoIndex, kNoIndex};
  std::uint32_t parent = kNoIndex;  // kNoIndex for the root
  std::uint32_t visit_stamp = 0;    // scratch for propagate_summaries()
  std::uint64_t morton = 0;         // of the minimum corner (finest voxels)
  std::uint8_t level = 0;
  std::uint8_t removed = 0;  // scratch mark of evict_blocks(); 0 on every live node
  std::uint8_t padding_[6] = {};
  NodeSummary summary;

  Key key() const { return Key{morton, level}; }
  bool dead() const { return removed != 0; }
  bool childless() const {
    for (const std::uint32_t c : children) {
      if (c != kNoIndex) return false;
    }
    return true;
  }
};

// What one allocate() call did.
struct AllocationCounts {
  std::uint32_t new_blocks = 0;
  std::uint32_t new_nodes = 0;
  std::uint32_t already_allocated = 0;  // keys whose octant existed
  std::uint32_t refused = 0;            // keys not allocated because a pool was full
  std::uint32_t rejected = 0;           // keys outside the cube or at an invalid level
};

struct MapMemory {
  std::size_t bytes_reserved = 0;    // everything reserve() took from the arena
  std::size_t bytes_used = 0;        // the part holding allocated nodes and blocks
  std::size_t bytes_per_block = 0;   // sizeof(VoxelBlock<VoxelT>)
  std::size_t bytes_per_finest = 0;  // sizeof(FinestLevel<VoxelT>); 0 for single-res maps
  std::size_t bytes_per_mid = 0;     // sizeof(MidLevel<VoxelT>); 0 for single-res maps
  std::uint32_t blocks_used = 0;
  std::uint32_t block_capacity = 0;
  std::uint32_t nodes_used = 0;
  std::uint32_t node_capacity = 0;
  std::uint32_t finest_used = 0;  // multires blocks holding a finest level
  std::uint32_t finest_capacity = 0;
  std::uint32_t mid_used = 0;  // multires blocks holding a mid level (scale 1)
  std::uint32_t mid_capacity = 0;
  // Allocation requests (blocks, nodes, finest and mid levels) refused since reserve()/clear().
  std::uint64_t refusals = 0;
  std::uint64_t finest_refusals = 0;  // of those, finest levels
  std::uint64_t mid_refusals = 0;     // of those, mid levels
  std::uint64_t evicted = 0;          // blocks evicted since reserve()/clear()
  std::uint64_t node_refusals = 0;    // of the refusals, inner nodes (a new block's ancestors)
  std::uint64_t nodes_evicted = 0;    // inner nodes removed with their last block
};

// Where a voxel falls in the tree: the deepest allocated octant containing it. `level` is -1
// outside the cube; block_level when a block holds it (block != kNoIndex); otherwise the level
// of the deepest allocated inner node (`node`), whose child towards the voxel is absent, so the
// free octant around the voxel is octant_size_voxels(level + 1, voxel_depth) voxels wide.
struct OctantLookup {
  int level = -1;
  std::uint32_t node = kNoIndex;
  std::uint32_t block = kNoIndex;
};

template <typename VoxelT>
class Octree {
  static constexpr std::size_t kSummaryPrefetchDistance = 32;
  // Levels with at least this many nodes are summarised in kSummaryTasks fixed tasks.
  static constexpr std::size_t kParallelSummaryNodes = 4096;
  static constexpr std::size_t kSummaryTasks = 16;

 public:
  using Voxel = VoxelT;
  using Block = VoxelBlock<VoxelT>;
  using Finest = FinestLevel<VoxelT>;
  using FinestVoxel = FinestVoxelT<VoxelT>;
  using Mid = MidLevel<VoxelT>;
  static constexpr bool kSplitFinest = Block::kSplitFinest;
  // Worst-case bytes per block (block plus its finest and mid levels), for sizing a pool from a
  // memory budget with the default finest and mid capacities.
  static constexpr std::size_t kBytesPerBlockWorstCase =
      sizeof(Block) + (kSplitFinest ? sizeof(Finest) + sizeof(Mid) : 0);

  // Exactly what reserve() takes from a LinearArena whose current offset is
  // kArenaAlignment-aligned.
  static std::size_t bytes_required(const MapConfig& config) {
    ArenaSizer sizer;
    Octree probe;
    if (!probe.reserve(sizer, config).ok()) return 0;
    return sizer.bytes_used();
  }

  // Carves the pools, hash and scratch from `arena` (LinearArena or ArenaSizer) and creates the
  // root. invalid_argument: validate(config) failed; resource_exhausted: the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, const MapConfig& config) {
    OCTOFUSE_TRY(validate(config));
    const std::size_t start = arena.bytes_used();
    // Keep every reservation aligned so the sizer's count is exact for any starting offset.
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    OCTOFUSE_TRY(nodes_.reserve(arena, config.node_capacity));
    OCTOFUSE_TRY(blocks_.reserve(arena, config.block_capacity));
    if constexpr (kSplitFinest) {
      OCTOFUSE_TRY(finest_.reserve(arena, config.effective_finest_capacity()));
      OCTOFUSE_TRY(mid_.reserve(arena, config.effective_mid_capacity()));
    }
    OCTOFUSE_TRY(hash_.reserve(arena, config.block_capacity));
    Result<std::uint32_t*> a = arena.template allocate_array<std::uint32_t>(config.node_capacity);
    OCTOFUSE_TRY(a);
    Result<std::uint32_t*> b = arena.template allocate_array<std::uint32_t>(config.node_capacity);
    OCTOFUSE_TRY(b);
    Result<std::uint32_t*> c = arena.template allocate_array<std::uint32_t>(config.node_capacity);
    OCTOFUSE_TRY(c);
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    scratch_a_ = a.value();
    scratch_b_ = b.value();
    scratch_c_ = c.value();
    config_ = config;
    bytes_reserved_ = arena.bytes_used() - start;
    // A sizer hands out no memory: nothing to initialise, and the octree stays unusable.
    if constexpr (!std::is_same_v<Arena, ArenaSizer>) {
      reserved_ = true;
      reset_contents(/*clear_hash=*/false);
    }
    return ok_status();
  }

  bool reserved() const { return reserved_; }
  // Forgets every block and node (keeps the root); memory stays reserved.
  void clear();
  // Writes the pages of the next `blocks` blocks, finest and mid levels and nodes the pools will
  // hand out (IndexPool::prefault), so the first frames pay no first-touch page faults for them.
  void prefault(std::uint32_t blocks) {
    nodes_.prefault(blocks);
    blocks_.prefault(blocks);
    finest_.prefault(blocks);
    mid_.prefault(blocks);
  }

  const MapConfig& config() const { return config_; }
  int voxel_depth() const { return config_.voxel_depth; }
  int block_level() const { return config_.block_level(); }
  float voxel_size_m() const { return config_.voxel_size_m; }
  int voxels_per_side() const { return config_.voxels_per_side(); }

  // --- Coordinates. Voxel (i,j,k) spans origin + [i, i+1) * voxel_size; its sample is its centre.
  bool contains_voxel(const Eigen::Vector3i& voxel) const {
    const int n = voxels_per_side();
    return voxel.x() >= 0 && voxel.y() >= 0 && voxel.z() >= 0 && voxel.x() < n && voxel.y() < n &&
           voxel.z() < n;
  }
  bool contains_point(const Eigen::Vector3f& p_W) const {
    return contains_voxel(point_to_voxel(p_W));
  }
  // Continuous voxel coordinates: voxel (i,j,k)'s centre is at (i+0.5, j+0.5, k+0.5).
  Eigen::Vector3f point_to_voxel_f(const Eigen::Vector3f& p_W) const {
    return (p_W - config_.origin_W) / config_.voxel_size_m;
  }
  // Finest voxel containing p_W (floor); may lie outside the cube (check contains_voxel).
  Eigen::Vector3i point_to_voxel(const Eigen::Vector3f& p_W) const {
    const Eigen::Vector3f v = point_to_voxel_f(p_W);
    // Clamp before the cast so far-away or non-finite points cannot overflow an int.
    const float limit = 4.0f * static_cast<float>(voxels_per_side());
    auto to_int = [limit](float f) {
      if (!(f > -limit)) return -1;
      if (!(f < limit)) return static_cast<int>(limit);
      return static_cast<int>(std::floor(f));
    };
    return {to_int(v.x()), to_int(v.y()), to_int(v.z())};
  }
  // out_of_range when p_W is outside the cube (or not finite).
  Result<Eigen::Vector3i> voxel_of_point(const Eigen::Vector3f& p_W) const {
    const Eigen::Vector3i v = point_to_voxel(p_W);
    if (!contains_voxel(v)) return StatusCode::out_of_range;
    return v;
  }
  // Centre of the voxel at `scale` (0 = finest; 0..voxel_depth) containing finest voxel `voxel`.
  Eigen::Vector3f voxel_centre_W(const Eigen::Vector3i& voxel, int scale = 0) const {
    const Eigen::Vector3i snapped = snap_to_scale(voxel, scale);
    const float half = 0.5f * static_cast<float>(1 << scale);
    return config_.origin_W +
           (snapped.cast<float>() + Eigen::Vector3f::Constant(half)) * config_.voxel_size_m;
  }
  Eigen::Vector3f block_centre_W(const Eigen::Vector3i& block_coords) const {
    return config_.origin_W +
           (block_coords.cast<float>() * 8.0f + Eigen::Vector3f::Constant(4.0f)) *
               config_.voxel_size_m;
  }
  bool contains_block(const Eigen::Vector3i& block_coords) const {
    const int n = voxels_per_side() >> kBlockSideLog2;
    return block_coords.x() >= 0 && block_coords.y() >= 0 && block_coords.z() >= 0 &&
           block_coords.x() < n && block_coords.y() < n && block_coords.z() < n;
  }
  Key block_key(const Eigen::Vector3i& block_coords) const {
    return Key{morton_encode(block_to_voxel(block_coords)),
               static_cast<std::uint8_t>(block_level())};
  }

  // --- Allocation.
  // Allocates the octants for `keys` (any order, duplicates allowed but wasteful): a key at
  // block_level gets a voxel block, a key above it an inner node (level 0 is the root, which
  // always exists); missing ancestors are created on the way. Keys are processed in the given
  // order, which fixes the pool indices (pass them sorted for a canonical map).
  // Returns ok; resource_exhausted when a pool refused at least one key (those keys are skipped,
  // everything else is allocated and existing data is untouched); out_of_range when some key
  // lay outside the cube or below block_level (skipped) and nothing was refused.
  Status allocate(const Key* keys, std::size_t count, AllocationCounts* counts = nullptr);
  // The block at `block_coords`, allocated if needed: its index, or out_of_range (outside the
  // cube) / resource_exhausted (pool full).
  Result<std::uint32_t> allocate_block(const Eigen::Vector3i& block_coords);

  // --- Finest and mid levels (multires). Gives `block` its finest level if it has none (and its
  // mid level first: scale 0's mean lives at scale 1), initialised unobserved: ok (also when it
  // had one, and always for single-res maps), or resource_exhausted when a pool is full (counted
  // in refusals; the block keeps what it had). Not thread-safe, like allocate(); levels return to
  // their pools when the block is evicted and on clear().
  Status acquire_finest(Block& block) {
    if constexpr (kSplitFinest) {
      if (block.finest != nullptr) return ok_status();
      OCTOFUSE_TRY(acquire_mid(block));
      Result<std::uint32_t> f = finest_.allocate();
      if (!f.ok()) {
        ++refusals_;
        ++finest_refusals_;
        return StatusCode::resource_exhausted;
      }
      block.finest = &finest_[f.value()];
    }
    return ok_status();
  }
  // Counts `count` finest levels refused without asking the pool: it had fewer free than blocks
  // asking, and the caller served the others first.
  void count_finest_refusals(std::uint32_t count) {
    refusals_ += count;
    finest_refusals_ += count;
  }
  // The same for the mid level (scale 1) alone.
  Status acquire_mid(Block& block) {
    if constexpr (kSplitFinest) {
      if (block.mid != nullptr) return ok_status();
      Result<std::uint32_t> m = mid_.allocate();
      if (!m.ok()) {
        ++refusals_;
        ++mid_refusals_;
        return StatusCode::resource_exhausted;
      }
      block.mid = &mid_[m.value()];
    }
    return ok_status();
  }

  // --- Lookup (O(1) through the hash).
  std::uint32_t find_block_index(const Eigen::Vector3i& block_coords) const {
    if (!contains_block(block_coords)) return kNoIndex;
    return hash_.find(morton_encode(block_coords));
  }
  // Same, by the Morton code of block coordinates inside the cube (morton_encode(block_coords)),
  // for callers that already have it; prefetch_block() starts loading its hash slot.
  std::uint32_t find_block_index_morton(std::uint64_t block_morton) const {
    return hash_.find(block_morton);
  }
  void prefetch_block(std::uint64_t block_morton) const { hash_.prefetch(block_morton); }
  Block* find_block(const Eigen::Vector3i& block_coords) {
    const std::uint32_t i = find_block_index(block_coords);
    return i == kNoIndex ? nullptr : &blocks_[i];
  }
  const Block* find_block(const Eigen::Vector3i& block_coords) const {
    const std::uint32_t i = find_block_index(block_coords);
    return i == kNoIndex ? nullptr : &blocks_[i];
  }
  Block* find_block_at_voxel(const Eigen::Vector3i& voxel) {
    return contains_voxel(voxel) ? find_block(voxel_to_block(voxel)) : nullptr;
  }
  const Block* find_block_at_voxel(const Eigen::Vector3i& voxel) const {
    return contains_voxel(voxel) ? find_block(voxel_to_block(voxel)) : nullptr;
  }
  Block* find_block_at_point(const Eigen::Vector3f& p_W) {
    return find_block_at_voxel(point_to_voxel(p_W));
  }
  const Block* find_block_at_point(const Eigen::Vector3f& p_W) const {
    return find_block_at_voxel(point_to_voxel(p_W));
  }
  // The block with this key (key.level must be block_level), or null.
  const Block* find_block(const Key& key) const {
    if (key.level != block_level()) return nullptr;
    return find_block_at_voxel(key_corner_voxel(key));
  }
  Block* find_block(const Key& key) {
    if (key.level != block_level()) return nullptr;
    return find_block_at_voxel(key_corner_voxel(key));
  }

  // The voxel at `scale` containing finest voxel `voxel`, or null when outside the cube or in an
  // unallocated block; scale 1-3 for multires maps (scale 0 is finest_voxel()), 0-3 otherwise.
  // Reads whatever that scale holds (see the block's current_scale; scale 1 of a block without a
  // mid level reads as unobserved). The non-const overload gives the block its mid level for
  // scale 1 (null when the mid pool is full), so it must not overlap other calls, like
  // allocate().
  const VoxelT* voxel(const Eigen::Vector3i& voxel, int scale) const {
    OCTOFUSE_CHECK(scale >= (kSplitFinest ? 1 : 0) && scale <= kMaxBlockScale);
    const Block* b = find_block_at_voxel(voxel);
    return b == nullptr ? nullptr : level_voxel(*b, voxel, scale);
  }
  VoxelT* voxel(const Eigen::Vector3i& voxel, int scale) {
    OCTOFUSE_CHECK(scale >= (kSplitFinest ? 1 : 0) && scale <= kMaxBlockScale);
    Block* b = find_block_at_voxel(voxel);
    if (b == nullptr) return nullptr;
    if (scale == 1 && !acquire_mid(*b).ok()) return nullptr;  // a write at scale 1 needs it
    return level_voxel(*b, voxel, scale);
  }
  // The finest voxel `voxel`, or null as above; scale 0 of a block without a finest level reads
  // as unobserved. The non-const overload gives the block its finest level (null when the finest
  // pool is full), under the same terms as voxel().
  const FinestVoxel* finest_voxel(const Eigen::Vector3i& voxel) const {
    const Block* b = find_block_at_voxel(voxel);
    return b == nullptr ? nullptr : b->finest_begin() + finest_index(voxel);
  }
  FinestVoxel* finest_voxel(const Eigen::Vector3i& voxel) {
    Block* b = find_block_at_voxel(voxel);
    if (b == nullptr || !acquire_finest(*b).ok()) return nullptr;
    return b->finest_begin() + finest_index(voxel);
  }
  // The voxel at any scale 0..3 by value (a finest voxel as Block::voxel() reads it), or false as
  // above.
  bool read_voxel(const Eigen::Vector3i& voxel, int scale, VoxelT* out) const {
    OCTOFUSE_CHECK(scale >= 0 && scale <= kMaxBlockScale);
    const Block* b = find_block_at_voxel(voxel);
    if (b == nullptr) return false;
    *out = b->at_voxel(voxel, scale);
    return true;
  }
  // Index of finest voxel `voxel` in its block's scale 0, and the voxel of level `scale` (> 0 for
  // multires) containing it.
  static int finest_index(const Eigen::Vector3i& voxel) {
    return block_voxel_index(voxel.x() & 7, voxel.y() & 7, voxel.z() & 7, 0);
  }
  template <typename B>
  static auto level_voxel(B& block, const Eigen::Vector3i& voxel, int scale) {
    return block.level_begin(scale) +
           (block_voxel_index_finest(voxel.x() & 7, voxel.y() & 7, voxel.z() & 7, scale) -
            block_scale_offset(scale));
  }
  // The neighbour `step` voxels of scale `scale` away (crosses block borders), or null.
  const VoxelT* neighbour(const Eigen::Vector3i& voxel, int scale,
                          const Eigen::Vector3i& step) const {
    return this->voxel(snap_to_scale(voxel, scale) + step * (1 << scale), scale);
  }

  // Deepest allocated octant containing `voxel` (see OctantLookup).
  OctantLookup lookup(const Eigen::Vector3i& voxel) const {
    if (!contains_voxel(voxel)) return OctantLookup{};
    return lookup_from(voxel, 0, 0);
  }
  // The same walk started at inner node `start_node` of level `start_level` (< block_level),
  // which must contain `voxel` (inside the cube): callers that keep a nearby node skip the top
  // of the tree.
  OctantLookup lookup_from(const Eigen::Vector3i& voxel, std::uint32_t start_node,
                           int start_level) const {
    OctantLookup out;
    const int depth = voxel_depth();
    std::uint32_t node = start_node;
    for (int level = start_level;; ++level) {
      const int bit = depth - level - 1;
      const int child = ((voxel.x() >> bit) & 1) | (((voxel.y() >> bit) & 1) << 1) |
                        (((voxel.z() >> bit) & 1) << 2);
      const std::uint32_t next = nodes_[node].children[child];
      if (level + 1 == block_level()) {
        out.level = next == kNoIndex ? level : level + 1;
        out.node = node;
        out.block = next;
        return out;
      }
      if (next == kNoIndex) {
        out.level = level;
        out.node = node;
        return out;
      }
      node = next;
    }
  }
  // Inner node with this key (level < block_level), or kNoIndex.
  std::uint32_t find_node_index(const Key& key) const {
    if (key.level >= block_level()) return kNoIndex;
    const Eigen::Vector3i corner = key_corner_voxel(key);
    if (!contains_voxel(corner)) return kNoIndex;
    std::uint32_t node = 0;
    for (int level = 0; level < key.level; ++level) {
      node =
          nodes_[node]
              .children[child_index(parent_key_at(key, level + 1, voxel_depth()), voxel_depth())];
      if (node == kNoIndex) return kNoIndex;
    }
    return node;
  }
  static constexpr std::uint32_t root_index() { return 0; }
  const OctreeNode& node(std::uint32_t index) const { return nodes_[index]; }
  // Sets an inner node's summary as a saved map recorded it (map_io.hpp restores maps with it),
  // so a loaded map skips empty space exactly as the saved one did.
  void restore_node_summary(std::uint32_t index, const NodeSummary& summary) {
    nodes_[index].summary = summary;
  }

  // --- Iteration. Blocks are numbered 0..block_count()-1 in allocation order (evict_blocks()
  // moves the last blocks into the holes), which is deterministic for a deterministic sequence of
  // allocate() and evict_blocks() calls.
  std::uint32_t block_count() const { return blocks_.used(); }
  Block& block(std::uint32_t index) { return blocks_[index]; }
  const Block& block(std::uint32_t index) const { return blocks_[index]; }
  std::uint32_t node_count() const { return nodes_.used(); }
  template <typename Fn>
  void for_each_block(Fn&& fn) {
    for (std::uint32_t i = 0; i < block_count(); ++i) fn(blocks_[i]);
  }
  template <typename Fn>
  void for_each_block(Fn&& fn) const {
    for (std::uint32_t i = 0; i < block_count(); ++i) fn(blocks_[i]);
  }

  // --- Summaries.
  // Recomputes a block's header summary (tsdf_min/max/mean, weight_mean) over the observed
  // voxels at its current scale.
  static void update_block_summary(Block& block);
  // Moves an integrated block that is finer than `scale` to `scale`: that level is first brought
  // up to date from the coarsest one that is (mip_scale), then the header summary describes it.
  // Needs the levels it reads (release_finest/release_mid and restore_block_record() call it
  // before giving them back). Multires only. Returns whether the block changed.
  static bool coarsen_block(Block& block, int scale);
  // Refreshes the summaries of every inner node above the given blocks, bottom-up to the root
  // (each node once). A block contributes its header summary (tsdf_mean, weight_mean,
  // tsdf_min/max); a node contributes its summary. Means are over observed children only; a node
  // whose children are all unobserved keeps its summary.
  void propagate_summaries(const std::uint32_t* block_indices, std::size_t count);
  // The same, given the blocks' parent nodes (their parent_node, in the same order; kNoIndex
  // entries are skipped): callers that have read the headers already save a pass over them.
  // Wide levels are summarised in fixed tasks over `team` (each node only reads its children and
  // writes its own summary, so the result does not depend on the worker count).
  void propagate_summaries_from_parents(const std::uint32_t* parent_nodes, std::size_t count,
                                        const WorkerTeam& team = WorkerTeam());

  // --- Eviction (bounded memory over unbounded areas). Removes the blocks at the given pool
  // indices (distinct, each < block_count(); the array is sorted in place): their space reads as
  // unallocated (unknown) again, their finest levels return to the finest pool, and the summaries
  // of the nodes above them are recomputed from what remains (a node left with nothing observed
  // below it reads unobserved). The block pool stays dense: each hole takes the last block
  // (indices are processed from the highest down, so the result depends only on the set, not on
  // the order given). Inner nodes left without children go with their last block (and come back
  // with it, through allocate()); the node pool stays dense the same way (the last node moves
  // into each hole, its parent and children follow), so a node's index may then be below its
  // parent's (save_map() writes parents first regardless). Not thread-safe, like allocate().
  void evict_blocks(std::uint32_t* indices, std::size_t count);
  // Multires: gives the finest levels of the blocks at the given pool indices back to the finest
  // pool, keeping the blocks at scale 1 (scale 1 is brought up to date from scale 0 first, the
  // block summaries and the node summaries above are recomputed). A block refines again, by
  // down-propagation, when it next integrates at scale 0 and the pool lends it a level. Blocks
  // without a finest level are left alone; single-res maps: nothing happens. Not thread-safe.
  void release_finest(const std::uint32_t* indices, std::size_t count);
  // The same one level further: the blocks give back their finest and mid levels and keep scale 2
  // (brought up to date from the finest scale they hold first).
  void release_mid(const std::uint32_t* indices, std::size_t count);

  // Blocks removed by evict_blocks() since reserve()/clear().
  std::uint64_t evicted() const { return evicted_; }
  // Inner nodes removed by evict_blocks() (with their last block) since reserve()/clear().
  std::uint64_t nodes_evicted() const { return nodes_evicted_; }

  // --- Memory.
  MapMemory memory() const;
  std::uint64_t refusals() const { return refusals_; }

 private:
  void reset_contents(bool clear_hash);
  // release_finest() (keep_scale 1) and release_mid() (2).
  void release_levels(const std::uint32_t* indices, std::size_t count, int keep_scale);

  // The inner nodes on the way to the last key allocate_one() walked to: node[l] is the node of
  // level l containing `morton`, for l < levels. Sorted keys share most of their way, so the next
  // walk starts at the deepest node both contain instead of at the root (a miss per level).
  struct AllocationPath {
    std::uint32_t node[kMaxVoxelDepth + 1] = {0};
    std::uint64_t morton = 0;
    int levels = 1;                       // the root contains every key
    int fresh_from = kMaxVoxelDepth + 1;  // first level whose node the current key created
  };

  void allocate_one(const Key& key, AllocationCounts& counts, AllocationPath& path);
  // Removes the nodes the current key created (a pool refused it further down).
  void undo_new_nodes(AllocationCounts& counts, AllocationPath& path);

  // Appends node p to the first level of a summary pass unless this pass has it already.
  void add_summary_node(std::uint32_t p, std::size_t& current_count);
  // Summarises the nodes in scratch_a_ (parents of blocks), then their parents, up to the root.
  // reset_unobserved: a node with nothing observed below reads unobserved (after eviction)
  // instead of keeping its summary.
  void propagate_node_summaries(std::size_t current_count, const WorkerTeam* team = nullptr,
                                bool reset_unobserved = false);

  void prefetch_children(const OctreeNode& n, bool children_are_blocks) const;
  // Removes the nodes listed in scratch_c_ (left childless by eviction) and the ancestors each
  // leaves childless, keeping the node pool dense.
  void remove_empty_nodes(std::size_t empty_count);

  void summarise_node(OctreeNode& n, bool children_are_blocks, bool reset_unobserved);

  MapConfig config_;
  IndexPool<OctreeNode> nodes_;
  IndexPool<Block> blocks_;
  IndexPool<Finest> finest_;  // multires only (capacity 0 otherwise)
  IndexPool<Mid> mid_;        // multires only (capacity 0 otherwise)
  BlockHash hash_;
  std::uint32_t* scratch_a_ = nullptr;
  std::uint32_t* scratch_b_ = nullptr;
  std::uint32_t* scratch_c_ = nullptr;
  std::size_t bytes_reserved_ = 0;
  std::uint64_t refusals_ = 0;
  std::uint64_t finest_refusals_ = 0;
  std::uint64_t mid_refusals_ = 0;
  std::uint64_t node_refusals_ = 0;
  std::uint64_t evicted_ = 0;
  std::uint64_t nodes_evicted_ = 0;
  std::uint32_t stamp_ = 0;
  bool reserved_ = false;
};

extern template class Octree<TsdfVoxel>;
extern template class Octree<MultiresVoxel>;
extern template class Octree<Multires16Voxel>;

}  // namespace octofuse
