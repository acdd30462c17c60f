// The bag fuzz targets' shared run: arbitrary bytes written as a bag file, then its odometry
// poses and its frames read through BagSource with small rings, so that every ring fills and
// wraps. Every failure must explain itself; a pose is always a number; a frame always has the
// camera's size.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>

#include "octofuse/ports/replay/bag_source.hpp"

namespace octofuse::fuzz {

// `config`: the container's format and record limits; the rest is set here. `name` and
// `extension` name the per-process file in /tmp.
inline int fuzz_bag_bytes(const std::uint8_t* data, std::size_t size,
                          octofuse::replay::BagConfig config, const char* name,
                          const char* extension) {
  static char path[64];
  if (path[0] == '\0') {
    std::snprintf(path, sizeof(path), "/tmp/%s-%d.%s", name, ::getpid(), extension);
  }
  std::FILE* file = std::fopen(path, "wb");
  if (file == nullptr) return 0;
  const bool written = std::fwrite(data, 1, size, file) == size;
  std::fclose(file);
  if (!written) return 0;

  std::memcpy(config.path, path, std::strlen(path) + 1);
  config.max_width = 64;
  config.max_height = 64;
  // A small reorder window, so that it fills, wraps and gives messages out late.
  config.limits.reorder_bytes = 16 << 10;
  config.limits.reorder_messages = 32;
  // Few transforms per TF edge and few held images, so that their rings fill and wrap too.
  config.tf_history = 4;
  config.hold_frames = 2;
  {
    // The odometry's poses (a pose topic, or TF at each depth image's stamp).
    octofuse::ErrorText error, warning;
    const octofuse::Status read = octofuse::replay::read_bag_poses(
        config,
        [](void*, std::int64_t, const octofuse::Se3d& T) {
          if (!T.matrix().allFinite()) __builtin_trap();  // a pose is always a number
        },
        nullptr, &error, &warning);
    if (!read.ok() && error.c_str()[0] == '\0') __builtin_trap();
  }
  octofuse::replay::BagSource bag(config);
  const octofuse::Status opened = bag.open();
  if (!opened.ok()) {
    if (bag.last_error()[0] == '\0') __builtin_trap();  // every failure explains itself
    return 0;
  }
  octofuse::DepthFrame frame;
  for (int i = 0; i < 10000; ++i) {
    const octofuse::NextFrame next = bag.next(frame);
    if (next.outcome == octofuse::FrameOutcome::frame) {
      const octofuse::PinholeCamera camera = bag.intrinsics();
      if (frame.depth_raw.width != camera.width || frame.depth_raw.height != camera.height) {
        __builtin_trap();  // a frame always has the camera's size
      }
      if (frame.has_ground_truth && !frame.T_W_C_ground_truth.allFinite()) __builtin_trap();
      volatile std::uint32_t sum = 0;
      for (int y = 0; y < frame.depth_raw.height; ++y) {
        for (int x = 0; x < frame.depth_raw.width; ++x) sum = sum + frame.depth_raw(x, y);
      }
      continue;
    }
    if (next.outcome == octofuse::FrameOutcome::skip) {
      if (bag.last_error()[0] == '\0') __builtin_trap();
      continue;
    }
    if (next.outcome == octofuse::FrameOutcome::end_of_stream &&
        next.status.code() != octofuse::StatusCode::end_of_stream && bag.last_error()[0] == '\0') {
      __builtin_trap();  // a cut bag says where it ended
    }
    break;
  }
  return 0;
}

}  // namespace octofuse::fuzz
