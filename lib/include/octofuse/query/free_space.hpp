#pragma once
// Free-space carving: records what each frame saw through in the free-space octree
// (map/free_octree.hpp), testing each octant against the depth range of exactly the pixels of its
// footprint (image/detail/depth_range_table.hpp). lib/README.md ("Free space") describes the walk,
// the classes an octant falls in, the budgets and what it misses.
//
// Threading: carve(), clear() and prune() must not overlap reads (the pipeline's MapGuard orders
// them).

#include <algorithm>
#include <cstddef>
#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/image/detail/depth_range_table.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/map/free_octree.hpp"
#include "octofuse/map/map_config.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse {

struct FreeSpaceReport {
  std::uint32_t node_visits = 0;
  std::uint32_t new_nodes = 0;
  std::uint32_t marked_free = 0;   // octants marked free this frame
  std::uint32_t cleared = 0;       // free octants handed down or cleared
  std::uint32_t refused = 0;       // node allocations refused (pool full or budget)
  std::uint32_t pool_refused = 0;  // of those, because the node pool was full
  // New nodes not made because they lay beyond the distance from the camera within which the
  // frame's carving fits the pool's room (the farthest air is forgotten first; not a refusal).
  std::uint32_t far_dropped = 0;
  // Leaves not classified and leaves' sub-cell looks not taken because the centre's pixel showed
  // they could change nothing (the same tree as taking them).
  std::uint32_t looks_skipped = 0;
  std::uint32_t pruned = 0;      // nodes forgotten after this frame to make room (prune())
  bool budget_hit = false;       // visits or allocations ran out
  std::uint32_t nodes_used = 0;  // after this frame
  std::size_t bytes_used = 0;    // nodes_used * sizeof(FreeNode)
};

// The free-space octree and the carving that writes it.
class FreeSpace : public FreeOctree {
 public:
  // Carves the pool and the depth range table (for `width` x `height` working images) from
  // `arena`. invalid_argument: bad config or map config; resource_exhausted: the arena is too
  // small.
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

  // The last carved frame's depth range over pixels [u0, u1] x [v0, v1] (clipped to the image):
  // what carving compares octants with; public for tests and tools.
  using PixelRange = DepthRangeTable::Range;
  static constexpr float kNoDepth = DepthRangeTable::kNoDepth;
  PixelRange pixel_range(int u0, int v0, int u1, int v1) const;

  // true: every leaf the walk reaches is classified and every sub-cell look taken, without the
  // shortcuts that skip those that can change nothing (FreeSpaceReport::looks_skipped); the same
  // tree, for tests that check that.
  void set_exhaustive(bool exhaustive) { exhaustive_ = exhaustive; }

  // Changes the node-visit budget between frames (a frame deadline sets it); 0 reads as 1.
  void set_visit_budget(std::uint32_t max_node_visits) {
    config_.max_node_visits = max_node_visits > 0 ? max_node_visits : 1u;
  }

 private:
  // free: wholly in view, every pixel measured beyond it; clear: every measured pixel beyond it
  // but some not measured or outside the image; not_seen; partial: a measured depth within it;
  // occluded: behind every measured depth; straddle: across the camera plane (no footprint).
  enum class Seen : std::uint8_t { free, clear, not_seen, partial, occluded, straddle };
  // depths (optional): how far the farthest measured depth in the footprint lies beyond the
  // octant's nearest point (room_m), and that depth (far_m; 0: none).
  struct FootprintDepths {
    float room_m = 0.0f;
    float far_m = 0.0f;
  };
  // How closely an octant is looked at: coarse (it descends anyway), a leaf or a leaf's
  // sub-cell (final answers).
  enum class Look : std::uint8_t { coarse, leaf, sub_cell };
  Seen classify(const Eigen::Vector3i& min_voxel, int size_voxels, Look look,
                FootprintDepths* depths) const;
  Seen classify_footprint(float z_min, float z_max, float u_min, float u_max, float v_min,
                          float v_max, Look look, FootprintDepths* depths) const;
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
  // Sub-cells are tested with boxes of half-side margin_m * this around their corners.
  static constexpr float kSubCellGrowth = 1.7320508f;  // sqrt(3)
  // Every octant or sub-cell with the octant's centre as a point can be free this frame only if
  // this holds (false: none can): the pixel the centre projects to, which each such footprint
  // holds (footprints are grown by a pixel), in the image, measured, and seen more than the
  // clearance beyond the centre's depth + `behind_m` (what each one's far bound exceeds the
  // centre's depth by at least); and `far_m` (the farthest surface in a footprint holding that
  // pixel, kNoDepth: not known) or a ray measured beyond the range as far. True at the camera
  // plane.
  bool centre_seen_beyond(const Eigen::Vector3i& min_voxel, int size_voxels, float behind_m,
                          float far_m) const;
  // The walk from the root. counting: nothing is written and histogram[b] gets the nodes the
  // walk would make at distance band b; otherwise nodes are made only in bands below `bands`.
  void walk(std::uint32_t frame, bool counting, std::uint32_t bands, FreeSpaceReport& report,
            std::uint32_t* histogram);
  // An octant's distance from the camera's voxel in finest octants (its nearest voxel), capped
  // at kDistanceBands - 1.
  std::uint32_t distance_band(const Eigen::Vector3i& min_voxel, int size) const;
  static constexpr std::uint32_t kDistanceBands = 256;

  DepthRangeTable ranges_;
  int width_ = 0;
  int height_ = 0;
  float clearance_m_ = 0.0f;
  float occlusion_clear_m_ = 0.0f;
  bool exhaustive_ = false;
  float beyond_free_m_ = 0.0f;  // this frame's, 0 without rays measured beyond the range
  // Per-frame projection (set by carve()).
  Eigen::Matrix3f R_C_W_ = Eigen::Matrix3f::Identity();
  Eigen::Vector3f t_C_W_ = Eigen::Vector3f::Zero();
  PinholeCamera camera_;
  Eigen::Vector3i camera_voxel_ = Eigen::Vector3i::Zero();
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
  OCTOFUSE_TRY(reserve_nodes(arena, config, map));
  OCTOFUSE_TRY(ranges_.reserve(arena, width, height));
  OCTOFUSE_TRY(reserve_prune_scratch(arena));
  OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
  width_ = width;
  height_ = height;
  config_ = config;
  map_ = map;
  margin_m_ = config.margin_m > 0.0f ? config.margin_m : map.voxel_size_m;
  clearance_m_ = config.clearance_m;
  occlusion_clear_m_ = config.occlusion_clear_m;
  config_.finest_octant_voxels = resolve_finest_octant_voxels(config.finest_octant_voxels, map);
  leaf_level_ = free_leaf_level(map.block_level(), config_.finest_octant_voxels);
  region_level_ = std::max(1, leaf_level_ - kRegionLevels);
  sub_cell_voxels_ = config_.finest_octant_voxels / 2;
  finish_reserve(arena, start);
  return ok_status();
}

}  // namespace octofuse
