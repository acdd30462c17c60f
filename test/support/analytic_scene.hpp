#pragma once
// Exact images of simple scenes: planes, spheres, capped cylinders and oriented boxes, ray-cast
// analytically. The live side renders z-depth (depth = z in the camera frame of the first hit);
// the model side world-frame vertices and unit normals facing the camera (what a TSDF ray-cast
// delivers). The committed map fixture (test/unit/map/data) was written from render(): keep its
// arithmetic as it is.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <vector>

#include <Eigen/Core>

#include "octofuse/image/image_view.hpp"
#include "octofuse/image/surface_map.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse::test {

// Camera ray through pixel (u, v) with unit z component (so a hit's t is its z-depth). The
// pixel's offset is computed in float, as the camera holds it.
inline Eigen::Vector3d pixel_ray_C(const PinholeCamera& camera, int u, int v) {
  return Eigen::Vector3d((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
}

// World-frame vertices and normals as a ray-cast model would hold them.
struct RenderedModel {
  std::vector<Eigen::Vector3f> vertices_W;
  std::vector<Eigen::Vector3f> normals_W;
  int width = 0;
  int height = 0;

  ConstSurfaceMap map() const {
    ConstSurfaceMap m;
    m.vertices = ImageView<const Eigen::Vector3f>(vertices_W.data(), width, height);
    m.normals = ImageView<const Eigen::Vector3f>(normals_W.data(), width, height);
    return m;
  }
};

struct AnalyticScene {
  struct Plane {
    Eigen::Vector3d normal;  // unit
    double offset_m;         // points p with normal . p = offset_m
  };
  struct Sphere {
    Eigen::Vector3d centre_W;
    double radius_m;
  };
  // Axis-aligned along world y, from y_min_m to y_max_m.
  struct CylinderY {
    Eigen::Vector3d centre_W;  // y ignored
    double radius_m;
    double y_min_m;
    double y_max_m;
  };
  // Points centre_W + R_W_B q with |q_i| <= half_m_i.
  struct Box {
    Eigen::Vector3d centre_W;
    Eigen::Vector3d half_m;
    Eigen::Matrix3d R_W_B;  // box axes in world coordinates (columns)
  };
  std::vector<Plane> planes;
  std::vector<Sphere> spheres;
  std::vector<CylinderY> cylinders;
  std::vector<Box> boxes;

  // Smallest t > 0 with o + t d on a primitive, or +inf. When normal_W is given and something is
  // hit, it receives the unit surface normal there, turned to face the ray's origin.
  double intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                   Eigen::Vector3d* normal_W = nullptr) const {
    double best = std::numeric_limits<double>::infinity();
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    for (const Plane& p : planes) {
      const double den = p.normal.dot(d);
      if (std::abs(den) < 1e-12) continue;
      const double t = (p.offset_m - p.normal.dot(o)) / den;
      if (t > 0.0 && t < best) {
        best = t;
        n = p.normal;
      }
    }
    for (const Sphere& s : spheres) {
      const Eigen::Vector3d oc = o - s.centre_W;
      const double a = d.squaredNorm();
      const double b = oc.dot(d);
      const double c = oc.squaredNorm() - s.radius_m * s.radius_m;
      const double disc = b * b - a * c;
      if (disc < 0.0) continue;
      const double t = (-b - std::sqrt(disc)) / a;
      if (t > 0.0 && t < best) {
        best = t;
        for (int i = 0; i < 3; ++i) n[i] = (oc[i] + t * d[i]) / s.radius_m;
      }
    }
    for (const CylinderY& cy : cylinders) {
      const double ox = o.x() - cy.centre_W.x();
      const double oz = o.z() - cy.centre_W.z();
      const double a = d.x() * d.x() + d.z() * d.z();
      if (a < 1e-15) continue;
      const double b = ox * d.x() + oz * d.z();
      const double c = ox * ox + oz * oz - cy.radius_m * cy.radius_m;
      const double disc = b * b - a * c;
      if (disc < 0.0) continue;
      const double t = (-b - std::sqrt(disc)) / a;
      const double y = o.y() + t * d.y();
      if (t > 0.0 && t < best && y >= cy.y_min_m && y <= cy.y_max_m) {
        best = t;
        n = Eigen::Vector3d((ox + t * d.x()) / cy.radius_m, 0.0, (oz + t * d.z()) / cy.radius_m);
      }
    }
    for (const Box& box : boxes) {
      // Slabs in the box frame.
      const Eigen::Vector3d ob = box.R_W_B.transpose() * (o - box.centre_W);
      const Eigen::Vector3d db = box.R_W_B.transpose() * d;
      double t_in = -std::numeric_limits<double>::infinity();
      double t_out = std::numeric_limits<double>::infinity();
      int axis_in = 0;
      for (int a = 0; a < 3; ++a) {
        if (std::abs(db[a]) < 1e-15) {
          if (std::abs(ob[a]) > box.half_m[a]) t_out = -1.0;
          continue;
        }
        const double t0 = (-box.half_m[a] - ob[a]) / db[a];
        const double t1 = (box.half_m[a] - ob[a]) / db[a];
        if (std::min(t0, t1) > t_in) axis_in = a;
        t_in = std::max(t_in, std::min(t0, t1));
        t_out = std::min(t_out, std::max(t0, t1));
      }
      if (t_in <= t_out && t_in > 0.0 && t_in < best) {
        best = t_in;
        n = box.R_W_B.col(axis_in);
      }
    }
    if (normal_W != nullptr && std::isfinite(best)) {
      *normal_W = n.dot(d) > 0.0 ? Eigen::Vector3d(-n) : n;
    }
    return best;
  }

  // Depth (z in the camera frame, metres) for every pixel, row-major; 0 where nothing is hit.
  void render(const PinholeCamera& camera, const Se3d& T_W_C, std::vector<float>& depth_m) const {
    depth_m.assign(static_cast<std::size_t>(camera.width) * camera.height, 0.0f);
    const Eigen::Vector3d o = T_W_C.translation();
    for (int v = 0; v < camera.height; ++v) {
      for (int u = 0; u < camera.width; ++u) {
        const double t = intersect(o, T_W_C.linear() * pixel_ray_C(camera, u, v));
        if (std::isfinite(t))
          depth_m[static_cast<std::size_t>(v) * camera.width + u] = static_cast<float>(t);
      }
    }
  }
  std::vector<float> render(const PinholeCamera& camera, const Se3d& T_W_C) const {
    std::vector<float> depth_m;
    render(camera, T_W_C, depth_m);
    return depth_m;
  }

  // World-frame vertices and normals of every pixel's hit (zero where nothing is hit).
  RenderedModel render_model(const PinholeCamera& camera, const Se3d& T_W_C) const {
    RenderedModel model;
    model.width = camera.width;
    model.height = camera.height;
    const std::size_t count = static_cast<std::size_t>(camera.width) * camera.height;
    model.vertices_W.assign(count, Eigen::Vector3f::Zero());
    model.normals_W.assign(count, Eigen::Vector3f::Zero());
    for (int v = 0; v < camera.height; ++v) {
      for (int u = 0; u < camera.width; ++u) {
        const Eigen::Vector3d ray_W = T_W_C.linear() * pixel_ray_C(camera, u, v);
        Eigen::Vector3d normal_W;
        const double t = intersect(T_W_C.translation(), ray_W, &normal_W);
        if (!std::isfinite(t)) continue;
        const std::size_t i = static_cast<std::size_t>(v) * camera.width + u;
        model.vertices_W[i] = (T_W_C.translation() + t * ray_W).cast<float>();
        model.normals_W[i] = normal_W.cast<float>();
      }
    }
    return model;
  }
};

// Three orthogonal walls around a sphere, seen from near the origin looking down +z.
inline AnalyticScene corner_scene() {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(1.0, 0.0, 0.0), -1.0});  // left wall x = -1
  scene.planes.push_back({Eigen::Vector3d(0.0, 1.0, 0.0), 0.9});   // floor y = 0.9 (y down)
  scene.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), 3.0});   // back wall z = 3
  scene.spheres.push_back({Eigen::Vector3d(0.25, 0.1, 2.2), 0.35});
  return scene;
}

}  // namespace octofuse::test
