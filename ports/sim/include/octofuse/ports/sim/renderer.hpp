#pragma once
// Renders a Scene into a depth image by exact ray-primitive intersection. Per frame it projects
// each primitive's bounds and lists it only in the 16x16-pixel screen tiles it can cover, so a
// pixel tests a handful of primitives instead of all of them. Storage comes from an arena at init.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/ports/sim/scene.hpp"

namespace octofuse::sim {

struct RenderOptions {
  float max_range_m = 10.0f;      // no surface beyond this (depth 0)
  float lateral_sigma_px = 0.0f;  // gaussian jitter of each pixel's ray (sensor lateral noise)
  std::uint64_t jitter_key = 0;   // seeds the jitter; same key -> same image
};

struct RenderStats {
  std::uint64_t primitive_tests = 0;  // ray-primitive intersections computed
  std::uint32_t hit_pixels = 0;
  std::uint32_t visible_primitives = 0;  // primitives that survived culling
};

class SceneRenderer {
 public:
  static constexpr int kTileSize = 16;

  // Reserves storage for `camera`-sized images and up to Scene::kMaxPrimitives primitives.
  // Returns ok, invalid_argument (camera not valid()), resource_exhausted (arena too small).
  template <typename Arena>
  Status reserve(Arena& arena, const PinholeCamera& camera) {
    if (!camera.valid()) return StatusCode::invalid_argument;
    camera_ = camera;
    tiles_x_ = (camera.width + kTileSize - 1) / kTileSize;
    tiles_y_ = (camera.height + kTileSize - 1) / kTileSize;
    const std::size_t tiles = static_cast<std::size_t>(tiles_x_) * tiles_y_;
    OCTOFUSE_TRY_ASSIGN(tile_lists_, arena.template allocate_array<std::uint16_t>(
                                         tiles * Scene::kMaxPrimitives, kArenaAlignment));
    OCTOFUSE_TRY_ASSIGN(tile_counts_,
                        arena.template allocate_array<std::uint16_t>(tiles, kArenaAlignment));
    OCTOFUSE_TRY_ASSIGN(frame_primitives_, arena.template allocate_array<FramePrimitive>(
                                               Scene::kMaxPrimitives, kArenaAlignment));
    ready_ = true;
    return ok_status();
  }

  // Depth along the optical axis in metres (0 where no surface is within max_range_m) and, when
  // `cos_incidence` is not empty, |cos| of the angle between ray and surface normal (0 where no
  // surface). Both views must be camera-sized.
  // Returns ok, failed_precondition (reserve() not done), invalid_argument (view sizes, a
  // non-finite or non-rigid pose).
  Status render(const Scene& scene, const Se3d& T_W_C, const RenderOptions& options,
                ImageView<float> depth_m, ImageView<float> cos_incidence);

  const RenderStats& last_stats() const { return stats_; }
  const PinholeCamera& camera() const { return camera_; }

 private:
  // A primitive as seen from this frame's camera: ray directions map with M_P_C, the camera
  // centre sits at o_P.
  struct FramePrimitive {
    Eigen::Matrix3d R_P_C;
    Eigen::Vector3d o_P;
    const Primitive* primitive;
  };

  void bin_primitives(const Scene& scene, const Se3d& T_W_C, int margin_px);

  PinholeCamera camera_;
  int tiles_x_ = 0;
  int tiles_y_ = 0;
  std::uint16_t* tile_lists_ = nullptr;  // tile t's list starts at t * kMaxPrimitives
  std::uint16_t* tile_counts_ = nullptr;
  FramePrimitive* frame_primitives_ = nullptr;
  bool ready_ = false;
  RenderStats stats_;
};

}  // namespace octofuse::sim
