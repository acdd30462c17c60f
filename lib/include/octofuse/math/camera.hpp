#pragma once
// Pinhole camera model in pixels, for the optical frame (x right, y down, z forward). Pixel
// centres are at integer coordinates: pixel (u, v) covers [u - 0.5, u + 0.5).

#include <Eigen/Core>

namespace octofuse {

struct PinholeCamera {
  float fx = 0.0f;
  float fy = 0.0f;
  float cx = 0.0f;
  float cy = 0.0f;
  int width = 0;
  int height = 0;

  bool valid() const;

  // Point in the camera frame to pixel coordinates; only meaningful for p_C.z() > 0.
  Eigen::Vector2f project(const Eigen::Vector3f& p_C) const {
    return {fx * p_C.x() / p_C.z() + cx, fy * p_C.y() / p_C.z() + cy};
  }
  // Pixel and depth along z (metres) to a point in the camera frame.
  Eigen::Vector3f back_project(float u, float v, float depth_m) const {
    return {(u - cx) * depth_m / fx, (v - cy) * depth_m / fy, depth_m};
  }
  bool in_image(const Eigen::Vector2f& px) const {
    return px.x() >= -0.5f && px.y() >= -0.5f && px.x() < static_cast<float>(width) - 0.5f &&
           px.y() < static_cast<float>(height) - 0.5f;
  }

  // The camera after averaging `factor` x `factor` pixel blocks (factor 2: VGA -> QVGA).
  PinholeCamera downsampled(int factor) const;
};

}  // namespace octofuse
