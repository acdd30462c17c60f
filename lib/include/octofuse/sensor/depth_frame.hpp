#pragma once
// What a depth sensor delivers: a view of raw 16-bit depth in a buffer the source owns, the scale
// to metres, a monotonic timestamp and, for simulation and datasets, a ground-truth pose.

#include <cstdint>

#include "octofuse/image/image_view.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse {

struct DepthFrame {
  // Raw depth units; 0 means "no measurement". Valid until the source's next call to next() for
  // this ring slot comes round again (the ring holds SourceCapabilities::ring_size frames).
  ImageView<const std::uint16_t> depth_raw;
  float metres_per_unit = 0.001f;  // 0.001 for millimetres, 0.0002 for TUM's 5000 units/m
  std::int64_t timestamp_us = 0;   // monotonic, microseconds
  std::uint64_t sequence = 0;      // the source's frame counter, gaps mean dropped frames
  bool has_ground_truth = false;
  Eigen::Matrix4d T_W_C_ground_truth = Eigen::Matrix4d::Identity();  // camera to world
};

}  // namespace octofuse
