#pragma once
// Exact depth images of simple scenes for fusion tests: planes, spheres, capped cylinders and
// oriented boxes, rendered by ray-primitive intersection (depth = z in the camera frame of the
// first hit).

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <vector>

#include <Eigen/Core>

#include "octofuse/image/image_view.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse::test {

struct AnalyticScene {
  struct Plane {
    Eigen::Vector3d normal;  // unit
    double offset;           // points p with normal . p = offset
  };
  struct Sphere {
    Eigen::Vector3d centre;
    double radius;
  };
  // Axis-aligned along world y, from y_min to y_max.
  struct CylinderY {
    Eigen::Vector3d centre;  // y ignored
    double radius;
    double y_min;
    double y_max;
  };
  // Points centre + R q with |q_i| <= half_i.
  struct Box {
    Eigen::Vector3d centre;
    Eigen::Vector3d half;
    Eigen::Matrix3d R;  // box axes in world coordinates (columns)
  };
  std::vector<Plane> planes;
  std::vector<Sphere> spheres;
  std::vector<CylinderY> cylinders;
  std::vector<Box> boxes;

  // Smallest t > 0 with o + t d on a primitive, or +inf.
  double intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
    double best = std::numeric_limits<double>::infinity();
    for (const Plane& p : planes) {
      const double den = p.normal.dot(d);
      if (std::abs(den) < 1e-12) continue;
      const double t = (p.offset - p.normal.dot(o)) / den;
      if (t > 0.0 && t < best) best = t;
    }
    for (const Sphere& s : spheres) {
      const Eigen::Vector3d oc = o - s.centre;
      const double a = d.squaredNorm();
      const double b = oc.dot(d);
      const double c = oc.squaredNorm() - s.radius * s.radius;
      const double disc = b * b - a * c;
      if (disc < 0.0) continue;
      const double t = (-b - std::sqrt(disc)) / a;
      if (t > 0.0 && t < best) best = t;
    }
    for (const CylinderY& cy : cylinders) {
      const double ox = o.x() - cy.centre.x();
      const double oz = o.z() - cy.centre.z();
      const double a = d.x() * d.x() + d.z() * d.z();
      if (a < 1e-15) continue;
      const double b = ox * d.x() + oz * d.z();
      const double c = ox * ox + oz * oz - cy.radius * cy.radius;
      const double disc = b * b - a * c;
      if (disc < 0.0) continue;
      const double t = (-b - std::sqrt(disc)) / a;
      const double y = o.y() + t * d.y();
      if (t > 0.0 && t < best && y >= cy.y_min && y <= cy.y_max) best = t;
    }
    for (const Box& box : boxes) {
      // Slabs in the box frame.
      const Eigen::Vector3d ob = box.R.transpose() * (o - box.centre);
      const Eigen::Vector3d db = box.R.transpose() * d;
      double t_in = -std::numeric_limits<double>::infinity();
      double t_out = std::numeric_limits<double>::infinity();
      for (int a = 0; a < 3; ++a) {
        if (std::abs(db[a]) < 1e-15) {
          if (std::abs(ob[a]) > box.half[a]) t_out = -1.0;
          continue;
        }
        const double t0 = (-box.half[a] - ob[a]) / db[a];
        const double t1 = (box.half[a] - ob[a]) / db[a];
        t_in = std::max(t_in, std::min(t0, t1));
        t_out = std::min(t_out, std::max(t0, t1));
      }
      if (t_in <= t_out && t_in > 0.0 && t_in < best) best = t_in;
    }
    return best;
  }

  // Depth (z in the camera frame, metres) for every pixel; 0 where nothing is hit.
  void render(const PinholeCamera& camera, const Se3d& T_W_C, std::vector<float>& depth_m) const {
    depth_m.assign(static_cast<std::size_t>(camera.width) * camera.height, 0.0f);
    const Eigen::Vector3d o = T_W_C.translation();
    for (int v = 0; v < camera.height; ++v) {
      for (int u = 0; u < camera.width; ++u) {
        // Ray with unit z in the camera frame: the hit's t is its depth.
        const Eigen::Vector3d ray_C((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
        const double t = intersect(o, T_W_C.linear() * ray_C);
        if (std::isfinite(t))
          depth_m[static_cast<std::size_t>(v) * camera.width + u] = static_cast<float>(t);
      }
    }
  }
};

inline PinholeCamera test_camera(int width, int height, float fx) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = fx;
  c.fy = fx;
  c.cx = 0.5f * static_cast<float>(width) - 0.5f;
  c.cy = 0.5f * static_cast<float>(height) - 0.5f;
  return c;
}

// Camera at `position_W` looking along world +z (optical axes = world axes).
inline Se3d looking_along_z(const Eigen::Vector3d& position_W) {
  Se3d T = Se3d::Identity();
  T.translation() = position_W;
  return T;
}

}  // namespace octofuse::test
