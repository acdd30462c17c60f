#pragma once
// The small simulated camera the system tests run on: the desk at 160 x 120 pixels (VGA's
// intrinsics scaled by a quarter), so a run of tens of frames takes seconds.

#include "octofuse/ports/sim/sim_source.hpp"

namespace octofuse::test {

inline constexpr int kSmallSimWidth = 160;
inline constexpr int kSmallSimHeight = 120;

inline sim::SimConfig small_sim(int frames, bool noise = true) {
  sim::SimConfig config;
  config.scene = sim::SceneId::desk;
  config.frame_count = frames;
  config.camera.width = kSmallSimWidth;
  config.camera.height = kSmallSimHeight;
  config.camera.fx = config.camera.fy = 525.0f / 4.0f;
  config.camera.cx = (kSmallSimWidth - 1) * 0.5f;
  config.camera.cy = (kSmallSimHeight - 1) * 0.5f;
  config.noise.enabled = noise;
  return config;
}

}  // namespace octofuse::test
