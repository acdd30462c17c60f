#pragma once
// Pre-processing of one depth frame for tracking and fusion: down-sample the validated input (in
// metres, 0 = invalid) to the working resolution, optionally bilateral-filter it, and build a
// 3-level pyramid of depth, camera-frame vertices and normals. Level 0 is the working resolution,
// level l has (width >> l) x (height >> l) pixels. Every buffer is carved from an arena at init:
//
//   DepthPreprocessor pre;
//   ArenaSizer sizer;  pre.reserve(sizer, config, 640, 480);   // sizer.bytes_used() is exact
//   LinearArena arena(buffer, bytes);  pre.reserve(arena, config, 640, 480);
//   pre.process(depth_m, camera_vga, team);  // per frame, no allocation
//   const DepthPyramid& live = pre.pyramid();

#include <cstddef>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/parallel.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/depth_filters.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/image/surface_map.hpp"
#include "octofuse/math/camera.hpp"

namespace octofuse {

inline constexpr int kPyramidLevels = 3;

struct PreprocessConfig {
  int downsample_factor = 2;       // input -> working resolution: 1, 2 or 4 (VGA -> QVGA)
  float downsample_band_m = 0.1f;  // samples farther than this from the block median drop
  bool bilateral = false;          // filter the working-resolution depth
  float bilateral_sigma_space_px = 4.0f;
  float bilateral_sigma_range_m = 0.1f;
  float pyramid_band_m = 0.1f;  // depth-difference gate of the 2x2 half-sampling
  // Depth jump (at level 0) above which a pixel gets no normal; doubled per level, since a
  // coarser pixel spans twice the surface.
  float normal_max_depth_jump_m = 0.1f;

  // True when every field is in range (factor 1/2/4, finite positive sigmas, non-negative gates).
  bool valid() const;
};

struct DepthPyramid {
  ImageView<float> depth_m[kPyramidLevels];
  ImageView<Eigen::Vector3f> vertices_C[kPyramidLevels];  // zero where depth is invalid
  ImageView<Eigen::Vector3f> normals_C[kPyramidLevels];   // unit, towards the camera; zero = none
  PinholeCamera camera[kPyramidLevels];                   // intrinsics of each level

  // The level as a surface map in the camera frame (what ICP takes as the live view).
  ConstSurfaceMap surface_C(int level) const {
    ConstSurfaceMap m;
    m.vertices = vertices_C[level];
    m.normals = normals_C[level];
    return m;
  }
};

class DepthPreprocessor {
 public:
  // Carves the buffers for an input of `input_width` x `input_height` pixels from `arena` (a
  // LinearArena or an ArenaSizer). Returns invalid_argument for a bad config or an input size
  // that does not divide into factor * 4 (the coarsest level must have whole pixels), and
  // resource_exhausted when the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, const PreprocessConfig& config, int input_width, int input_height);

  // Pre-processes one frame. `depth_m` is the input image (input_width x input_height, metres;
  // 0, negative or non-finite samples are invalid) and `input_camera` its intrinsics (same size).
  // Returns ok; invalid_argument for a size or camera mismatch or a non-finite camera (the pyramid
  // is then unchanged); failed_precondition before a successful reserve().
  Status process(ImageView<const float> depth_m, const PinholeCamera& input_camera,
                 const WorkerTeam& team);

  const DepthPyramid& pyramid() const { return pyramid_; }
  const PreprocessConfig& config() const { return config_; }
  int width() const { return width_; }  // working resolution (level 0)
  int height() const { return height_; }

 private:
  PreprocessConfig config_;
  DepthPyramid pyramid_;
  ImageView<float> unfiltered_;  // level-0 depth before the bilateral filter (only when enabled)
  int input_width_ = 0;
  int input_height_ = 0;
  int width_ = 0;
  int height_ = 0;
  bool reserved_ = false;
};

template <typename Arena>
Status DepthPreprocessor::reserve(Arena& arena, const PreprocessConfig& config, int input_width,
                                  int input_height) {
  reserved_ = false;
  if (!config.valid() || input_width <= 0 || input_height <= 0) {
    return StatusCode::invalid_argument;
  }
  const int divisor = config.downsample_factor << (kPyramidLevels - 1);
  if (input_width % divisor != 0 || input_height % divisor != 0) {
    return StatusCode::invalid_argument;
  }
  const int w0 = input_width / config.downsample_factor;
  const int h0 = input_height / config.downsample_factor;
  DepthPyramid pyramid;
  ImageView<float> unfiltered;
  if (config.bilateral) {
    Result<float*> buffer =
        arena.template allocate_array<float>(static_cast<std::size_t>(w0) * h0, kArenaAlignment);
    if (!buffer.ok()) return buffer.status();
    unfiltered = ImageView<float>(buffer.value(), w0, h0);
  }
  for (int level = 0; level < kPyramidLevels; ++level) {
    const int w = w0 >> level;
    const int h = h0 >> level;
    const std::size_t n = static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
    Result<float*> depth = arena.template allocate_array<float>(n, kArenaAlignment);
    if (!depth.ok()) return depth.status();
    Result<Eigen::Vector3f*> vertices =
        arena.template allocate_array<Eigen::Vector3f>(n, kArenaAlignment);
    if (!vertices.ok()) return vertices.status();
    Result<Eigen::Vector3f*> normals =
        arena.template allocate_array<Eigen::Vector3f>(n, kArenaAlignment);
    if (!normals.ok()) return normals.status();
    pyramid.depth_m[level] = ImageView<float>(depth.value(), w, h);
    pyramid.vertices_C[level] = ImageView<Eigen::Vector3f>(vertices.value(), w, h);
    pyramid.normals_C[level] = ImageView<Eigen::Vector3f>(normals.value(), w, h);
  }
  config_ = config;
  pyramid_ = pyramid;
  unfiltered_ = unfiltered;
  input_width_ = input_width;
  input_height_ = input_height;
  width_ = w0;
  height_ = h0;
  reserved_ = pyramid.depth_m[0].data != nullptr;  // an ArenaSizer hands out no memory
  return ok_status();
}

}  // namespace octofuse
