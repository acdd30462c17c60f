#include "octofuse/image/depth_pyramid.hpp"

#include <cmath>

namespace octofuse {

bool PreprocessConfig::valid() const {
  const bool factor_ok = downsample_factor == 1 || downsample_factor == 2 || downsample_factor == 4;
  const bool finite = std::isfinite(downsample_band_m) && std::isfinite(pyramid_band_m) &&
                      std::isfinite(normal_max_depth_jump_m);
  const bool sigmas_ok =
      !bilateral ||
      (std::isfinite(bilateral_sigma_space_px) && std::isfinite(bilateral_sigma_range_m) &&
       bilateral_sigma_space_px > 0.0f && bilateral_sigma_range_m > 0.0f);
  return factor_ok && finite && sigmas_ok && downsample_band_m >= 0.0f && pyramid_band_m >= 0.0f &&
         normal_max_depth_jump_m >= 0.0f;
}

Status DepthPreprocessor::process(ImageView<const float> depth_m, const PinholeCamera& input_camera,
                                  const WorkerTeam& team) {
  if (!reserved_) return StatusCode::failed_precondition;
  if (depth_m.empty() || depth_m.width != input_width_ || depth_m.height != input_height_ ||
      !input_camera.valid() || input_camera.width != input_width_ ||
      input_camera.height != input_height_) {
    return StatusCode::invalid_argument;
  }

  PinholeCamera camera = input_camera.downsampled(config_.downsample_factor);
  for (int level = 0; level < kPyramidLevels; ++level) {
    pyramid_.camera[level] = camera;
    camera = camera.downsampled(2);
  }

  // Level 0: robust down-sampling, then the optional bilateral filter.
  if (config_.bilateral) {
    OCTOFUSE_TRY(downsample_depth(depth_m, unfiltered_, config_.downsample_factor,
                                  config_.downsample_band_m, team));
    OCTOFUSE_TRY(bilateral_filter(unfiltered_, pyramid_.depth_m[0],
                                  config_.bilateral_sigma_space_px, config_.bilateral_sigma_range_m,
                                  team));
  } else {
    OCTOFUSE_TRY(downsample_depth(depth_m, pyramid_.depth_m[0], config_.downsample_factor,
                                  config_.downsample_band_m, team));
  }
  for (int level = 1; level < kPyramidLevels; ++level) {
    OCTOFUSE_TRY(downsample_depth(pyramid_.depth_m[level - 1], pyramid_.depth_m[level], 2,
                                  config_.pyramid_band_m, team));
  }
  for (int level = 0; level < kPyramidLevels; ++level) {
    OCTOFUSE_TRY(depth_to_vertices(pyramid_.depth_m[level], pyramid_.camera[level],
                                   pyramid_.vertices_C[level], team));
    const float jump_m = config_.normal_max_depth_jump_m * static_cast<float>(1 << level);
    OCTOFUSE_TRY(vertices_to_normals(pyramid_.depth_m[level], pyramid_.vertices_C[level], jump_m,
                                     pyramid_.normals_C[level], team));
  }
  return ok_status();
}

}  // namespace octofuse
