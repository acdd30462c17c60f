#pragma once
// Free space at adaptive resolution: what each frame saw through, stored at the coarsest octant
// that was entirely free (one node for a metre of empty air, not 512 voxels per block).
//
// Architecture. The TSDF octree (map/octree.hpp) only holds the band of +-mu around surfaces; the
// space the camera looked through is recorded here, in a second, sparse octree over the same
// cube whose nodes (FreeNode, 40 bytes) come from a fixed pool carved from the arena at reserve().
// It is kept apart from the TSDF octree so that ray-casting's empty-space skipping, the block pool
// and the TSDF octree's node layout stay as they are. Its leaves are by default the smallest
// octants of at least kAutoFreeOctant_m: a TSDF block at 1 cm (below that the blocks' TSDF says
// what is where), 4^3 blocks at 2 mm (finest_octant_voxels). Node 0 is the root; a node's children
// are node indices (kNoNode where absent), so the pool's first node_count() nodes are the whole
// state (what a saved map needs to keep).
//
// A node holds a capped count of frames that saw its whole octant free and the index of the last
// such frame; a leaf that is not wholly free may hold free halves (sub_free: its 2 x 2 x 2
// sub-cells). Reading: a point is free when some node on its root-to-leaf path has
// free_count >= 1 (the first such node from the root is the free octant), or its leaf's sub-cell
// bit is set. Carving, once per integrated frame (carve()):
//   1. a min/max pyramid of the working-resolution depth over the measured pixels (tiles of
//      2^l x 2^l pixels), with a flag for tiles holding a pixel without depth; a pixel the
//      sensor measured beyond the depth range counts as seen free out to the range's end, with
//      no surface. Beside it a range table (a 2-D sparse table: at every pixel, the range of the
//      2^t x 2^t pixels from it, t up to 6) gives any pixel rectangle's range exactly from a few
//      overlapping squares;
//   2. a depth-first walk from the root in child order. Each octant, grown by `margin_m` on every
//      side, is projected (8 corners, + 1 pixel) and compared with the range of exactly the
//      pixels of that bounding rectangle (the silhouette test below reads the pyramid tiles
//      covering it: 3 x 3 at most, up to 8 x 8 for a leaf):
//      - free: in the image, every corner in front of the camera, every pixel measured and its
//        far corner nearer than (least depth - clearance_m). The count goes up (capped at
//        max_free_count) and the walk does not descend;
//      - clear: every measured depth lies beyond it likewise, but some pixels have no depth or
//        lie outside the image; or each tile's depths lie either beyond it likewise or more
//        than occlusion_clear_m in front of it (a nearer object's silhouette crosses the view of
//        it). No depth, or a ray blocked well in front, is no evidence: a free node stays free;
//        elsewhere the walk descends to the parts wholly seen;
//      - not seen: outside the image, behind the camera, no measured pixel, or its near corner
//        beyond the farthest measured depth by more than occlusion_clear_m: unchanged;
//      - occluded: behind every measured depth by less than occlusion_clear_m. Free nodes there
//        are handed down and cleared like below, without allocating new ones;
//      - partial: a tile whose depths may lie within it, less than occlusion_clear_m in front
//        of it or less than clearance_m behind it. A free node hands its count and
//        frame down to its 8 children (allocating them) and becomes 0, so what this frame saw
//        inside it decides each child;
//      - at a leaf, each sub-cell is tested the same way (from a 3 x 3 x 3 grid of projected
//        corners with the margin's bounds): free halves are set, halves with a depth within or
//        just in front are cleared (a surface appearing in free space clears it), the others
//        keep their state. A leaf with all 8 halves free becomes a free leaf.
//   Because the octant is grown by margin_m before the test, every observed surface lies at least
//   margin_m outside any octant marked free in that frame: the distance bound of a free point is
//   margin_m + its distance to the free octant's faces.
//   Missing children are allocated only when they turn out free or need a descent.
//
// Healing: a surface seen later clears the free nodes around it (above), and the TSDF of a block
// integrated after its octant was last seen free wins over the free state; a block whose octant
// was seen free after its last integration (the object there moved away) reads free.
//
// Budgets: the walk visits at most max_node_visits octants and allocates at most max_new_nodes
// nodes per frame; past them it stops descending (octants not reached keep their state) and the
// report says so. This is step (7) of the pipeline's degradation order. The walk is serial and
// in a fixed order, so the result does not depend on the worker count.
//
// Cost: one visit projects an octant's 8 corners and reads its rectangle's range (4 squares of the
// range table for a square-ish footprint; the silhouette test adds at most 3 x 3 or 8 x 8 tile
// reads); a leaf that is not wholly free or unseen adds 27 projections and 8 sub-cell tests.
// Building the pyramid and the table took 5.6 M instructions a frame at 320 x 240 (sim:room).
// Memory: the pyramid 4/3 and the table 6 full images of 9 bytes a pixel (4.1 MB at 320 x 240).
// Octants along every surface and depth edge in view are split down to the leaves, so a frame
// visits roughly (surface seen / leaf area) x 8 octants: at 1 cm, 30-50 thousand per frame in the
// sim scenes. What it misses: air within about half a leaf plus clearance_m of a surface, and at
// the image border; those read unknown unless the TSDF band covers them.
//
// Threading: carve() and clear() must not overlap reads (the pipeline's MapGuard orders them).

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/pool.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/map/map_config.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse {

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
  // cleared: more of the air beside silhouettes reads free (sim:room 66 -> 73 % of the air in
  // view), for a costlier stage (sim:room 84 -> 137 M carving instructions per frame).
  bool exact_silhouettes = false;
  // Octants nearer than this to the camera plane are not tested (projection degenerates).
  float near_m = 0.05f;
  // When a frame leaves the pool more than 15/16 full, the pipeline forgets the free space
  // farthest from the camera (prune_to()) until the pool is at most 3/4 full, so that a long
  // mission keeps carving where the robot is; never within this distance of the camera (0 = a
  // quarter of the fusion's far_m). A pool too small for the air around the camera still refuses
  // nodes.
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
  std::uint8_t padding_[2] = {};
};

struct FreeSpaceReport {
  std::uint32_t node_visits = 0;
  std::uint32_t new_nodes = 0;
  std::uint32_t marked_free = 0;  // octants marked free this frame
  std::uint32_t cleared = 0;      // free octants handed down or cleared
  std::uint32_t refused = 0;      // node allocations refused (pool full or budget)
  std::uint32_t pruned = 0;       // nodes forgotten after this frame to make room (prune())
  bool budget_hit = false;        // visits or allocations ran out
  std::uint32_t nodes_used = 0;   // after this frame
  std::size_t bytes_used = 0;     // nodes_used * sizeof(FreeNode)
};

// The free octant containing a point, as found by FreeSpace::find().
struct FreeOctant {
  bool free = false;
  std::uint32_t free_frame = 0;
  int level = -1;                                       // tree level (root 0)
  Eigen::Vector3i min_voxel = Eigen::Vector3i::Zero();  // finest-voxel corner
  int size_voxels = 0;
};

class FreeSpace {
 public:
  static constexpr std::uint32_t kNoNode = 0xFFFFFFFFu;
  // The walk's stack: at most 8 pending siblings per level.
  static constexpr int kStackCapacity = 8 * (kMaxVoxelDepth + 2);

  // Carves the pool and the depth pyramid (for `width` x `height` working images) from `arena`.
  // invalid_argument: bad config or map config; resource_exhausted: the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, const FreeSpaceConfig& config, const MapConfig& map, int width,
                 int height);

  // Bytes reserve() takes for this config (0 if invalid).
  static std::size_t bytes_required(const FreeSpaceConfig& config, const MapConfig& map, int width,
                                    int height) {
    ArenaSizer sizer;
    FreeSpace probe;
    if (!probe.reserve(sizer, config, map, width, height).ok()) return 0;
    return sizer.bytes_used();
  }

  bool reserved() const { return reserved_; }
  void clear();

  // Records what `depth_m` (working resolution, metres, 0 invalid) seen from T_W_C with
  // `camera` shows free. `frame` is the pipeline's frame index. Never allocates.
  // `beyond_range` (empty, or working resolution): pixels without depth whose sensor measured a
  // surface beyond the depth range. Each is evidence that its ray is free out to `beyond_free_m`
  // (the range's far end) but not of a surface there: it lets octants in front of it be free,
  // and neither clears nor occludes anything behind (a room whose far wall lies out of range
  // still carves the air in front of the camera).
  FreeSpaceReport carve(ImageView<const float> depth_m, const PinholeCamera& camera,
                        const Se3d& T_W_C, std::uint32_t frame,
                        ImageView<const std::uint8_t> beyond_range = {},
                        float beyond_free_m = 0.0f);

  // Forgets every octant lying wholly farther than `keep_radius_m` from `centre_W` (its subtree
  // with it: what was free there reads unknown again) and compacts the pool in place, keeping
  // the order of the nodes that stay (children after their parents). Returns the nodes dropped.
  // O(node_count()), no allocation; the root always stays.
  std::uint32_t prune(const Eigen::Vector3f& centre_W, float keep_radius_m);
  // prune() with the largest radius, to 1 %, that leaves at most `max_nodes`, but no less than
  // `min_radius_m` (then more may stay). Nothing when at most `max_nodes` are used. Up to 25
  // walks over the pool.
  std::uint32_t prune_to(const Eigen::Vector3f& centre_W, std::uint32_t max_nodes,
                         float min_radius_m);

  // The free octant containing finest voxel `voxel` (inside the cube), or free = false.
  FreeOctant find(const Eigen::Vector3i& voxel) const;

  const FreeSpaceConfig& config() const { return config_; }
  // The last carved frame's depths over pixels [u0, u1] x [v0, v1] (clipped to the image; empty
  // after clipping reads as nothing measured): the least depth seen free to (kNoDepth: none;
  // pixels measured beyond the range count with the range's end), the greatest measured surface
  // depth (0: none) and whether some pixel had no depth. What carving compares octants with, from
  // at most a few reads of the range table; public for tests and tools.
  struct PixelRange {
    float lo_m = kNoDepth;
    float hi_m = 0.0f;
    bool any_invalid = false;
  };
  PixelRange pixel_range(int u0, int v0, int u1, int v1) const;
  static constexpr float kNoDepth = 1e30f;

  // Changes the node-visit budget between frames (a frame deadline sets it); 0 reads as 1.
  void set_visit_budget(std::uint32_t max_node_visits) {
    config_.max_node_visits = max_node_visits > 0 ? max_node_visits : 1u;
  }
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
  // must get higher indices than their parents, as carve() allocates them. failed_precondition
  // when not reserved; resource_exhausted when the pool holds fewer (it is left cleared).
  Status begin_restore(std::uint32_t count);
  FreeNode& restore_node(std::uint32_t index) { return nodes_[index]; }

 private:
  // free: wholly in view, every pixel measured beyond it; clear: every measured pixel beyond it
  // but some not measured or outside the image; not_seen; partial: a measured depth within it;
  // occluded: behind every measured depth; straddle: across the camera plane (no footprint).
  enum class Seen : std::uint8_t { free, clear, not_seen, partial, occluded, straddle };
  // room_m (optional): how far the farthest measured depth in the footprint lies beyond the
  // octant's nearest point.
  // How closely an octant is looked at: coarse (it descends anyway), a leaf or a leaf's
  // sub-cell (final answers).
  enum class Look : std::uint8_t { coarse, leaf, sub_cell };
  Seen classify(const Eigen::Vector3i& min_voxel, int size_voxels, Look look, float* room_m) const;
  Seen classify_footprint(float z_min, float z_max, float u_min, float u_max, float v_min,
                          float v_max, Look look, float* room_m) const;
  // The partial answer of a leaf or sub-cell whose window holds depths both in front of and
  // behind the zone, settled pixel by pixel where the tiles of `level` covering its footprint
  // [u0, u1] x [v0, v1] do not settle it (FreeSpaceConfig::exact_silhouettes).
  Seen refine_footprint(int level, int u0, int v0, int u1, int v1, float zone_lo, float zone_hi,
                        bool inside) const;
  struct SubCellUpdate {
    std::uint8_t set = 0;    // sub-cells this frame saw wholly free
    std::uint8_t clear = 0;  // sub-cells with a measured depth within or just before them
  };
  SubCellUpdate classify_sub_cells(const Eigen::Vector3i& leaf_min_voxel) const;
  void build_pyramid(ImageView<const float> depth_m, ImageView<const std::uint8_t> beyond_range,
                     float beyond_free_m);
  // Levels 1 .. table_levels_ - 1 of the range table, from the pyramid's level 0.
  void build_range_table();
  // Level t of the range table, a full image each (level 0 is the pyramid's level 0).
  float* table_min(int t) const { return t == 0 ? depth_min_ : table_min_ + table_offset(t); }
  float* table_max(int t) const { return t == 0 ? depth_max_ : table_max_ + table_offset(t); }
  std::uint8_t* table_invalid(int t) const {
    return t == 0 ? depth_invalid_ : table_invalid_ + table_offset(t);
  }
  std::size_t table_offset(int t) const {
    return static_cast<std::size_t>(t - 1) * static_cast<std::size_t>(width_) *
           static_cast<std::size_t>(height_);
  }
  // The depth range of exactly the pixels [u0, u1] x [v0, v1] (inside the image), from at most
  // a few overlapping squares of the range table (ceil(w / s) x ceil(h / s) reads, s the largest
  // tabled power of two not above the shorter side; 4 for a square-ish footprint).
  PixelRange rect_range(int u0, int v0, int u1, int v1) const;
  // Whether one of those tiles' ranges overlaps [zone_lo, zone_hi]: a surface may lie within
  // the octant, or the octant just behind one.
  bool any_tile_in_zone(int level, int u0, int v0, int u1, int v1, float zone_lo,
                        float zone_hi) const;
  // Nodes within keep_radius_m of centre_W (the root and every node whose octant comes that close
  // and whose parent stays); with `mark`, remap_[i] = 1 for those, 0 for the others.
  std::uint32_t walk_within(const Eigen::Vector3f& centre_W, float keep_radius_m, bool mark);
  static constexpr std::uint8_t kAllSubCells = 0xFF;

  FreeSpaceConfig config_;
  MapConfig map_;
  IndexPool<FreeNode> nodes_;
  // Depth min/max pyramid: level l is ceil(w / 2^l) x ceil(h / 2^l), stored back to back.
  static constexpr int kMaxPyramidLevels = 16;
  // Range table (a 2-D sparse table): level t >= 1 holds, at every pixel (x, y), the range of the
  // 2^t x 2^t pixels from it (cut at the image's edges), so any rectangle's range is the merge of
  // a few overlapping squares. Level 0 is the pyramid's level 0. Each level is a full image.
  static constexpr int kMaxTableLevels = 7;  // squares up to 64 pixels
  float* table_min_ = nullptr;               // levels 1 .. table_levels_ - 1, back to back
  float* table_max_ = nullptr;
  std::uint8_t* table_invalid_ = nullptr;
  int table_levels_ = 1;
  float* depth_min_ = nullptr;
  float* depth_max_ = nullptr;
  std::uint8_t* depth_invalid_ = nullptr;  // 1: some pixel of the tile has no depth
  std::uint32_t* remap_ = nullptr;         // prune(): old node index -> new one
  int level_count_ = 0;
  int level_width_[kMaxPyramidLevels] = {};
  int level_height_[kMaxPyramidLevels] = {};
  std::size_t level_offset_[kMaxPyramidLevels] = {};
  int width_ = 0;
  int height_ = 0;
  float margin_m_ = 0.0f;
  float clearance_m_ = 0.0f;
  float occlusion_clear_m_ = 0.0f;
  int leaf_level_ = 0;
  int sub_cell_voxels_ = 4;
  // Per-frame projection (set by carve()).
  Eigen::Matrix3f R_C_W_ = Eigen::Matrix3f::Identity();
  Eigen::Vector3f t_C_W_ = Eigen::Vector3f::Zero();
  PinholeCamera camera_;
  std::size_t bytes_reserved_ = 0;
  bool reserved_ = false;
};

template <typename Arena>
Status FreeSpace::reserve(Arena& arena, const FreeSpaceConfig& config, const MapConfig& map,
                          int width, int height) {
  OCTOFUSE_TRY(validate(config));
  OCTOFUSE_TRY(validate(map));
  if (width < 1 || height < 1) return StatusCode::invalid_argument;
  if (free_leaf_level(map.block_level(),
                      resolve_finest_octant_voxels(config.finest_octant_voxels, map)) < 1) {
    return StatusCode::invalid_argument;  // octants as large as the root's children or larger
  }
  const std::size_t start = arena.bytes_used();
  OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
  const std::uint32_t capacity =
      config.node_capacity != 0 ? config.node_capacity : map.node_capacity;
  OCTOFUSE_TRY(nodes_.reserve(arena, capacity));
  std::size_t total = 0;
  int levels = 0;
  int w = width;
  int h = height;
  for (;;) {
    if (levels == kMaxPyramidLevels) return StatusCode::invalid_argument;
    level_width_[levels] = w;
    level_height_[levels] = h;
    level_offset_[levels] = total;
    total += static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
    ++levels;
    if (w == 1 && h == 1) break;
    w = (w + 1) / 2;
    h = (h + 1) / 2;
  }
  Result<float*> lo = arena.template allocate_array<float>(total, kArenaAlignment);
  OCTOFUSE_TRY(lo);
  Result<float*> hi = arena.template allocate_array<float>(total, kArenaAlignment);
  OCTOFUSE_TRY(hi);
  Result<std::uint8_t*> invalid =
      arena.template allocate_array<std::uint8_t>(total, kArenaAlignment);
  OCTOFUSE_TRY(invalid);
  int table_levels = 1;
  while (table_levels < kMaxTableLevels && (2 << (table_levels - 1)) <= std::min(width, height)) {
    ++table_levels;
  }
  const std::size_t table_total = static_cast<std::size_t>(table_levels - 1) *
                                  static_cast<std::size_t>(width) *
                                  static_cast<std::size_t>(height);
  Result<float*> table_lo = arena.template allocate_array<float>(table_total, kArenaAlignment);
  OCTOFUSE_TRY(table_lo);
  Result<float*> table_hi = arena.template allocate_array<float>(table_total, kArenaAlignment);
  OCTOFUSE_TRY(table_hi);
  Result<std::uint8_t*> table_invalid =
      arena.template allocate_array<std::uint8_t>(table_total, kArenaAlignment);
  OCTOFUSE_TRY(table_invalid);
  Result<std::uint32_t*> remap = arena.template allocate_array<std::uint32_t>(capacity);
  OCTOFUSE_TRY(remap);
  OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
  depth_min_ = lo.value();
  depth_max_ = hi.value();
  depth_invalid_ = invalid.value();
  remap_ = remap.value();
  table_min_ = table_lo.value();
  table_max_ = table_hi.value();
  table_invalid_ = table_invalid.value();
  table_levels_ = table_levels;
  level_count_ = levels;
  width_ = width;
  height_ = height;
  config_ = config;
  map_ = map;
  margin_m_ = config.margin_m > 0.0f ? config.margin_m : map.voxel_size_m;
  clearance_m_ = config.clearance_m;
  occlusion_clear_m_ = config.occlusion_clear_m;
  config_.finest_octant_voxels = resolve_finest_octant_voxels(config.finest_octant_voxels, map);
  leaf_level_ = free_leaf_level(map.block_level(), config_.finest_octant_voxels);
  sub_cell_voxels_ = config_.finest_octant_voxels / 2;
  bytes_reserved_ = arena.bytes_used() - start;
  if constexpr (!std::is_same_v<Arena, ArenaSizer>) {
    reserved_ = true;
    clear();
  }
  return ok_status();
}

}  // namespace octofuse
