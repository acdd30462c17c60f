#include "octofuse/fusion/fusion_config.hpp"

#include <cmath>

#include "octofuse/map/map_config.hpp"

namespace octofuse {

Status validate(const FusionConfig& c) {
  if (!std::isfinite(c.mu_m) || !(c.mu_m > 0.0f)) return StatusCode::invalid_argument;
  if (!std::isfinite(c.near_m) || !std::isfinite(c.far_m) || !(c.near_m > 0.0f) ||
      !(c.near_m < c.far_m)) {
    return StatusCode::invalid_argument;
  }
  if (!(c.y_max >= 1.0f) || !std::isfinite(c.y_max)) return StatusCode::invalid_argument;
  if (!(c.behind_mu > 0.0f && c.behind_mu <= 1.0f)) return StatusCode::invalid_argument;
  if (c.allocation_pixel_step < 1 || c.max_blocks_per_frame == 0) {
    return StatusCode::invalid_argument;
  }
  if (!(c.allocation_group_block_px >= 0.0f && c.allocation_group_block_px <= 1e6f)) {
    return StatusCode::invalid_argument;
  }
  if (!(c.scale_hysteresis >= 0.0f && c.scale_hysteresis < 1.0f)) {
    return StatusCode::invalid_argument;
  }
  if (c.fixed_scale > 3 || c.task_count < 1) return StatusCode::invalid_argument;
  return ok_status();
}

int scale_for_ratio(float r) {
  if (r < kScale0MaxRatio) return 0;
  if (r < 3.0f) return 1;
  if (r < 6.0f) return 2;
  return 3;
}

int select_scale(float r, int current_scale, float hysteresis) {
  const int raw = scale_for_ratio(r);
  if (current_scale < 0) return raw;
  if (raw > current_scale) {
    // Coarsen only when r is past the threshold by the margin; several steps at once are fine
    // (the coarse levels are kept up to date by up-propagation).
    const int s = scale_for_ratio(r / (1.0f + hysteresis));
    return s > current_scale ? s : current_scale;
  }
  if (raw < current_scale) {
    const int s = scale_for_ratio(r * (1.0f + hysteresis));
    if (s >= current_scale) return current_scale;
    // Refine one step per frame: each step down-propagates from the level above.
    return current_scale - 1;
  }
  return current_scale;
}

int scale_for_any_current(float r, float hysteresis) {
  // The tests of select_scale, bit for bit. Coarser current scales than raw coarsen to `up`;
  // finer ones refine to raw only from raw + 1, and only when `down` keeps them from staying.
  const int raw = scale_for_ratio(r);
  if (raw < kMaxBlockScale - 1) return -1;
  if (scale_for_ratio(r / (1.0f + hysteresis)) != raw) return -1;
  if (raw == kMaxBlockScale) return raw;
  return scale_for_ratio(r * (1.0f + hysteresis)) == raw ? raw : -1;
}

}  // namespace octofuse
