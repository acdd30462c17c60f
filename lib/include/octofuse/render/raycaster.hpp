#pragma once
// Ray-casting the map from a camera (paper section 4.4) into a SurfaceMap in the world frame, the
// model ICP tracks against: each ray skips unallocated octants and the depth ranges nothing is
// allocated in, samples by multi-resolution trilinear interpolation (map/interpolation.hpp) and
// finds the zero crossing. Rows are independent and each gets a fixed share of the step budget,
// so the result does not depend on the worker count. lib/README.md ("Ray-casting") describes the
// march, the tile ranges, the budget and half resolution.

#include <cstddef>
#include <cstdint>
#include <limits>

#include <Eigen/Core>

#include "octofuse/core/parallel.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/image/surface_map.hpp"
#include "octofuse/map/octree.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/render/shade.hpp"

namespace octofuse {

struct RaycastConfig {
  int width = 320;  // working resolution
  int height = 240;
  float near_m = 0.4f;  // along the optical axis
  float far_m = 4.0f;
  float mu_m = 0.08f;             // truncation distance the map was fused with
  std::uint64_t step_budget = 0;  // march steps per frame over all pixels; 0 = unbounded
  int pixel_stride = 1;           // 1: every pixel; 2: half resolution (lib/README.md)
};

struct RaycastStats {
  std::uint64_t steps = 0;  // march steps taken (samples and empty-space jumps)
  std::uint32_t valid_pixels = 0;
  std::uint32_t budget_cut_pixels = 0;      // left invalid because their row's step share ran out
  std::uint32_t marched_pixels = 0;         // pixels marched or skipped (not filled from another)
  std::uint32_t scale_pixels[4] = {};       // valid pixels per interpolation scale
  std::uint32_t guided_pixels = 0;          // rays started at their guide depth
  std::uint32_t guide_fallback_pixels = 0;  // of those, marched again from the near end
  std::uint32_t miss_skipped_pixels = 0;    // unguided, missed last cast, not their turn
  std::uint32_t guided_misses = 0;          // guided pixels that found no surface at all

  bool budget_hit() const { return budget_cut_pixels > 0; }
};

// Side of the tiles of the depth-range image, in pixels.
inline constexpr int kRangeTile_px = 8;

// Depth along the optical axis (metres) of everything allocated that projects into a tile; empty
// when z_min_m > z_max_m.
struct TileDepthRange {
  // Empty as constructed, so widening is a plain min / max.
  float z_min_m = std::numeric_limits<float>::max();
  float z_max_m = -std::numeric_limits<float>::max();

  bool empty() const { return !(z_min_m <= z_max_m); }
};

// ok, or invalid_argument for a non-positive size, near/far not 0 < near < far, mu not > 0, a
// pixel_stride other than 1 or 2.
Status validate(const RaycastConfig& config);

template <typename VoxelT>
class Raycaster {
 public:
  // Exactly what reserve() takes from a LinearArena with a kArenaAlignment-aligned offset.
  static std::size_t bytes_required(const RaycastConfig& config) {
    ArenaSizer sizer;
    Raycaster probe;
    if (!probe.reserve(sizer, config).ok()) return 0;
    return sizer.bytes_used();
  }

  // Carves the output images and per-row counters. invalid_argument: validate(config) failed;
  // resource_exhausted: the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, const RaycastConfig& config) {
    OCTOFUSE_TRY(validate(config));
    const std::size_t pixels =
        static_cast<std::size_t>(config.width) * static_cast<std::size_t>(config.height);
    const std::size_t rows = static_cast<std::size_t>(config.height);
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    Result<Eigen::Vector3f*> vertices = arena.template allocate_array<Eigen::Vector3f>(pixels);
    OCTOFUSE_TRY(vertices);
    Result<Eigen::Vector3f*> normals = arena.template allocate_array<Eigen::Vector3f>(pixels);
    OCTOFUSE_TRY(normals);
    Result<std::uint8_t*> scales = arena.template allocate_array<std::uint8_t>(pixels);
    OCTOFUSE_TRY(scales);
    Result<RaycastStats*> row_stats =
        arena.template allocate_array<RaycastStats>(rows, kArenaAlignment);
    OCTOFUSE_TRY(row_stats);
    const int tiles_x = (config.width + kRangeTile_px - 1) / kRangeTile_px;
    const int tiles_y = (config.height + kRangeTile_px - 1) / kRangeTile_px;
    const std::size_t tiles = static_cast<std::size_t>(tiles_x) * static_cast<std::size_t>(tiles_y);
    Result<TileDepthRange*> ranges = arena.template allocate_array<TileDepthRange>(tiles);
    OCTOFUSE_TRY(ranges);
    OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
    config_ = config;
    surface_W_.vertices = ImageView<Eigen::Vector3f>(vertices.value(), config.width, config.height);
    surface_W_.normals = ImageView<Eigen::Vector3f>(normals.value(), config.width, config.height);
    scale_ = ImageView<std::uint8_t>(scales.value(), config.width, config.height);
    row_stats_ = row_stats.value();
    guided_casts_ = 0;
    ranges_ = ImageView<TileDepthRange>(ranges.value(), tiles_x, tiles_y);
    return ok_status();
  }

  // Ray-casts `map` from the camera at T_W_C (camera to world). `camera` must have the reserved
  // width and height. Returns the frame's stats, or invalid_argument (camera invalid or of
  // another size, pose not finite, guide of another size) / failed_precondition (not reserved).
  // Allocates nothing.
  //
  // `guide_depth_m` (optional, the reserved size, depth along the optical axis, no data = 0 or
  // NaN): the depth just fused from this pose. A guided ray starts mu / 2 in front of its guide
  // depth instead of at the near end of its tile, and keeps that start only when the first voxel it
  // reads there is observed and positive (and, where mu spans fewer than 5 voxels of the scale, its
  // first trilinear sample too); otherwise (or when it reads no voxel at all) it is marched again
  // in full. It returns the surface nearest the guide from the front, or none: a
  // stale surface further in front that the fused view did not see is not reported.
  // In a guided cast, a pixel without a guide depth whose ray found nothing in the previous cast
  // (no vertex) stays empty, and is marched only every 4th guided cast, pixels taking turns
  // ((x + y + cast) mod 4): such rays cost several guided ones and mostly cross what the sensor
  // never measured. The result so depends on the previous cast; the pipeline's sequence of casts
  // is the same for the same input, so its results still are.
  Result<RaycastStats> raycast(const Octree<VoxelT>& map, const PinholeCamera& camera,
                               const Se3d& T_W_C, const WorkerTeam& team,
                               ImageView<const float> guide_depth_m = {});

  // The next guided cast marches every pixel, as the first one does (after a reset of the map).
  void forget_previous_cast() { guided_casts_ = 0; }

  const RaycastConfig& config() const { return config_; }
  // Changes the per-frame step budget between frames (0 = unbounded; a frame deadline sets it).
  void set_step_budget(std::uint64_t steps) { config_.step_budget = steps; }
  // Between frames: 1 (every pixel) or 2 (half resolution, lib/README.md); other values are 1.
  void set_pixel_stride(int stride) { config_.pixel_stride = stride == 2 ? 2 : 1; }
  // Valid until the next raycast().
  SurfaceMap surface_W() const { return surface_W_; }
  ImageView<const std::uint8_t> scale_image() const { return scale_; }

  // The last raycast()'s tile depth ranges.
  ImageView<const TileDepthRange> depth_ranges() const { return ranges_; }

 private:
  RaycastConfig config_;
  SurfaceMap surface_W_;
  ImageView<std::uint8_t> scale_;
  RaycastStats* row_stats_ = nullptr;
  ImageView<TileDepthRange> ranges_;
  std::uint32_t guided_casts_ = 0;  // guided raycast() calls so far (the turns of the retries)
};

extern template class Raycaster<TsdfVoxel>;
extern template class Raycaster<MultiresVoxel>;
extern template class Raycaster<Multires16Voxel>;

}  // namespace octofuse
