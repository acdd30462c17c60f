#pragma once
// Exact ray casting of planes and spheres, for tests that need depth images and surface maps with
// known geometry: the live side renders z-depth, the model side world-frame vertices and unit
// normals facing the camera (what a TSDF ray-cast delivers).

#include <cmath>
#include <vector>

#include <Eigen/Core>

#include "octofuse/image/surface_map.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse::test {

struct Plane {
  Eigen::Vector3d normal;  // unit
  double offset_m;         // points p with normal . p = offset_m
};

struct Sphere {
  Eigen::Vector3d centre_W;
  double radius_m;
};

struct AnalyticScene {
  std::vector<Plane> planes;
  std::vector<Sphere> spheres;

  // Nearest hit along origin + t * direction (t > 0); false when nothing is hit. Plain double
  // arithmetic: the tests render whole VGA images in Debug builds.
  bool intersect(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double& t_hit,
                 Eigen::Vector3d& normal) const {
    const double o[3] = {origin.x(), origin.y(), origin.z()};
    const double d[3] = {direction.x(), direction.y(), direction.z()};
    auto dot = [](const double* a, const double* b) {
      return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    };
    double n[3] = {0.0, 0.0, 0.0};
    bool hit = false;
    t_hit = 1e30;
    for (const Plane& plane : planes) {
      const double pn[3] = {plane.normal.x(), plane.normal.y(), plane.normal.z()};
      const double denom = dot(pn, d);
      if (std::abs(denom) < 1e-12) continue;
      const double t = (plane.offset_m - dot(pn, o)) / denom;
      if (t > 0.0 && t < t_hit) {
        t_hit = t;
        n[0] = pn[0];
        n[1] = pn[1];
        n[2] = pn[2];
        hit = true;
      }
    }
    for (const Sphere& sphere : spheres) {
      const double c[3] = {sphere.centre_W.x(), sphere.centre_W.y(), sphere.centre_W.z()};
      const double oc[3] = {o[0] - c[0], o[1] - c[1], o[2] - c[2]};
      const double a = dot(d, d);
      const double b = dot(oc, d);
      const double cc = dot(oc, oc) - sphere.radius_m * sphere.radius_m;
      const double disc = b * b - a * cc;
      if (disc < 0.0) continue;
      const double t = (-b - std::sqrt(disc)) / a;
      if (t > 0.0 && t < t_hit) {
        t_hit = t;
        for (int i = 0; i < 3; ++i) n[i] = (oc[i] + t * d[i]) / sphere.radius_m;
        hit = true;
      }
    }
    if (hit && dot(n, d) > 0.0) {  // face the camera
      for (double& v : n) v = -v;
    }
    normal = Eigen::Vector3d(n[0], n[1], n[2]);
    return hit;
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

// Camera ray through pixel (x, y) with unit z component (so t is the z-depth).
inline Eigen::Vector3d pixel_ray_C(const PinholeCamera& camera, int x, int y) {
  return Eigen::Vector3d((x - static_cast<double>(camera.cx)) / camera.fx,
                         (y - static_cast<double>(camera.cy)) / camera.fy, 1.0);
}

// z-depth image in metres (0 where nothing is hit), row-major.
inline std::vector<float> render_depth(const AnalyticScene& scene, const PinholeCamera& camera,
                                       const Se3d& T_W_C) {
  std::vector<float> depth(static_cast<std::size_t>(camera.width) * camera.height, 0.0f);
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      double t = 0.0;
      Eigen::Vector3d n;
      if (scene.intersect(T_W_C.translation(), T_W_C.linear() * pixel_ray_C(camera, x, y), t, n)) {
        depth[y * camera.width + x] = static_cast<float>(t);
      }
    }
  }
  return depth;
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

inline RenderedModel render_model(const AnalyticScene& scene, const PinholeCamera& camera,
                                  const Se3d& T_W_C) {
  RenderedModel model;
  model.width = camera.width;
  model.height = camera.height;
  const std::size_t n = static_cast<std::size_t>(camera.width) * camera.height;
  model.vertices_W.assign(n, Eigen::Vector3f::Zero());
  model.normals_W.assign(n, Eigen::Vector3f::Zero());
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const Eigen::Vector3d ray_W = T_W_C.linear() * pixel_ray_C(camera, x, y);
      double t = 0.0;
      Eigen::Vector3d normal_W;
      if (scene.intersect(T_W_C.translation(), ray_W, t, normal_W)) {
        model.vertices_W[y * camera.width + x] = (T_W_C.translation() + t * ray_W).cast<float>();
        model.normals_W[y * camera.width + x] = normal_W.cast<float>();
      }
    }
  }
  return model;
}

}  // namespace octofuse::test
