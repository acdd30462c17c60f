#pragma once
// Pinhole cameras and camera poses that tests build their images with.

#include <Eigen/Core>

#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse::test {

// Square pixels, principal point at the image centre.
inline PinholeCamera centred_camera(int width, int height, float f_px) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = f_px;
  c.fy = f_px;
  c.cx = 0.5f * static_cast<float>(width) - 0.5f;
  c.cy = 0.5f * static_cast<float>(height) - 0.5f;
  return c;
}

// A Kinect-like VGA depth camera.
inline PinholeCamera vga_camera() {
  return centred_camera(640, 480, 525.0f);
}

// Camera at `position_W` looking along world +z (optical axes = world axes).
inline Se3d looking_along_z(const Eigen::Vector3d& position_W) {
  Se3d T = Se3d::Identity();
  T.translation() = position_W;
  return T;
}

}  // namespace octofuse::test
