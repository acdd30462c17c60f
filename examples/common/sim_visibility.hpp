// Whether a sim scene's point was seen through by a depth camera at any of a set of poses: in
// front of the camera within 0.4-4 m, inside the image, nothing before it along the ray and a
// surface behind it within 4 m of depth (else that pixel had no depth). The benchmarks that check
// the map against the exact scene count only such points.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/ports/sim/scene.hpp"

namespace octofuse::examples {

inline bool seen_through(const sim::Scene& scene, const std::vector<Se3d>& T_C_W,
                         const PinholeCamera& camera, const Eigen::Vector3d& p_W) {
  for (const Se3d& T : T_C_W) {
    const Eigen::Vector3d p_C = T * p_W;
    if (p_C.z() < 0.4 || p_C.z() > 4.0) continue;
    const double u = camera.fx * p_C.x() / p_C.z() + camera.cx;
    const double v = camera.fy * p_C.y() / p_C.z() + camera.cy;
    if (u < 0.0 || v < 0.0 || u > camera.width - 1.0 || v > camera.height - 1.0) continue;
    const Eigen::Vector3d o_W = T.inverse().translation();
    const double length = (p_W - o_W).norm();
    const Eigen::Vector3d d_W = (p_W - o_W) / length;
    double t = 0.0;
    double cos_incidence = 0.0;
    if (scene.intersect(o_W, d_W, 20.0, &t, &cos_incidence) < 0 || t <= length) continue;
    if ((T * (o_W + t * d_W)).z() <= 4.0) return true;
  }
  return false;
}

}  // namespace octofuse::examples
