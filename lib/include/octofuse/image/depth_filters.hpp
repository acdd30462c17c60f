#pragma once
// Per-pixel depth operations used by pre-processing. Depth is in metres along the optical axis;
// 0 (or anything not finite and > 0) is "no measurement" and stays so. Each function splits the
// output rows into kImageRowTasks fixed chunks for the WorkerTeam; every output pixel depends only
// on the input, so results are bit-identical for any worker count. No function allocates.
//
// Return codes (all functions): ok; invalid_argument when a view is empty or the sizes do not
// fit together as documented (the output is then untouched).

#include <Eigen/Core>

#include "octofuse/core/parallel.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/math/camera.hpp"

namespace octofuse {

// Row chunks per image pass, independent of the worker count.
inline constexpr int kImageRowTasks = 16;
// Largest down-sampling factor (blocks of up to 4 x 4 pixels).
inline constexpr int kMaxDownsampleFactor = 4;

// True for a usable depth sample (finite and > 0).
inline bool valid_depth(float depth_m) {
  return depth_m > 0.0f && depth_m < 1e30f;
}

// Robust block average: out(x, y) summarises the `factor` x `factor` block of `in` starting at
// (factor * x, factor * y). Of the block's valid samples, those within `band_m` of their (lower)
// median are averaged, so a block straddling a depth edge takes the nearer side instead of a
// value floating between surfaces; a block without valid samples gives 0. Factor 1 copies and
// sanitises (non-finite or negative -> 0). Needs factor in {1, 2, 4}, band_m >= 0 and
// out.width * factor <= in.width, out.height * factor <= in.height.
Status downsample_depth(ImageView<const float> in, ImageView<float> out, int factor, float band_m,
                        const WorkerTeam& team);

// 5 x 5 bilateral filter: weights exp(-r^2 / (2 sigma_space^2)) * exp(-dd^2 / (2 sigma_range^2))
// over valid neighbours; an invalid centre stays invalid (no hole filling), and neighbours across
// a step much larger than sigma_range barely contribute, so edges stay sharp. Needs in and out of
// the same size, not aliased, and both sigmas > 0.
Status bilateral_filter(ImageView<const float> in, ImageView<float> out, float sigma_space_px,
                        float sigma_range_m, const WorkerTeam& team);

// Camera-frame vertex of every pixel (camera.back_project); zero where the depth is invalid.
// Needs depth, vertices_C and camera of the same size.
Status depth_to_vertices(ImageView<const float> depth_m, const PinholeCamera& camera,
                         ImageView<Eigen::Vector3f> vertices_C, const WorkerTeam& team);

// Unit normals from central differences, oriented towards the camera (into free space, like TSDF
// gradients): n = (v(x, y+1) - v(x, y-1)) x (v(x+1, y) - v(x-1, y)), normalised. Zero (invalid)
// on the image border, where the centre or any of the four neighbours has no depth, or where a
// neighbour's depth differs from the centre's by more than `max_depth_jump_m` (a depth edge, not
// a surface). Needs depth, vertices_C and normals_C of the same size.
Status vertices_to_normals(ImageView<const float> depth_m,
                           ImageView<const Eigen::Vector3f> vertices_C, float max_depth_jump_m,
                           ImageView<Eigen::Vector3f> normals_C, const WorkerTeam& team);

}  // namespace octofuse
