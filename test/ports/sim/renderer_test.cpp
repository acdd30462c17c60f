#include "octofuse/ports/sim/renderer.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <vector>

#include "octofuse/ports/sim/noise.hpp"
#include "octofuse/ports/sim/scenes.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/alloc_counter.hpp"

namespace octofuse::sim {
namespace {

using V3 = Eigen::Vector3d;
constexpr double kOnSurface_m = 1e-4;  // back-projected exact depth vs the distance query
constexpr double kDepthRelative = 1e-6;

struct Harness {
  std::vector<unsigned char> memory;
  SceneRenderer renderer;
  PinholeCamera camera;
  std::vector<float> depth;
  std::vector<float> cosine;

  explicit Harness(const PinholeCamera& cam) : camera(cam) {
    ArenaSizer sizer;
    REQUIRE(renderer.reserve(sizer, cam).ok());
    memory.resize(sizer.bytes_used() + kArenaAlignment);
    const auto base = reinterpret_cast<std::uintptr_t>(memory.data());
    LinearArena arena(memory.data() + (align_up(base, kArenaAlignment) - base), sizer.bytes_used());
    REQUIRE(renderer.reserve(arena, cam).ok());
    REQUIRE(arena.bytes_used() == sizer.bytes_used());
    depth.assign(cam.width * cam.height, -1.0f);
    cosine.assign(cam.width * cam.height, -1.0f);
  }
  ImageView<float> depth_view() { return {depth.data(), camera.width, camera.height}; }
  ImageView<float> cos_view() { return {cosine.data(), camera.width, camera.height}; }
  Status render(const Scene& scene, const Se3d& T_W_C, RenderOptions options = {}) {
    return renderer.render(scene, T_W_C, options, depth_view(), cos_view());
  }
};

PinholeCamera qvga_camera() {
  return kinect_camera().downsampled(2);
}

TEST_CASE("a frontal plane at 1.5 m renders as exactly 1.5 m, 1500 mm without noise") {
  Scene scene;
  REQUIRE(scene.add(make_plane(V3(0, 0, 1.5), V3(0, 0, -1))).ok());  // camera at origin looks +z
  Harness h(kinect_camera());
  REQUIRE(h.render(scene, Se3d::Identity()).ok());
  for (float d : h.depth) REQUIRE(d == 1.5f);
  REQUIRE(h.renderer.last_stats().hit_pixels == 640u * 480u);

  std::vector<std::uint16_t> raw(h.depth.size(), 7);
  KinectNoiseModel off;
  off.enabled = false;
  apply_kinect_noise(off, h.camera.fx, h.depth_view(), h.cos_view(), 0.001f, 0.2f, 6.0f, 1, 0,
                     ImageView<std::uint16_t>(raw.data(), 640, 480));
  for (std::uint16_t v : raw) REQUIRE(v == 1500);
}

TEST_CASE("a tilted plane renders the analytic depth of every pixel") {
  // Plane n . p_C = c in the camera frame.
  const V3 n_C = V3(0.3, -0.2, -1.0).normalized();
  const double c = 2.0 * n_C.z();  // passes through (0, 0, 2)
  Scene scene;
  // Outward normal towards the camera (at the origin).
  REQUIRE(scene.add(make_plane(V3(0, 0, 2.0), n_C)).ok());
  Harness h(kinect_camera());
  // Move the camera and the plane together: a world pose must not change the image.
  Se3d T_W_C = Se3d::Identity();
  T_W_C.rotate(Eigen::AngleAxisd(0.4, V3(0.2, 1, 0.1).normalized()));
  T_W_C.translation() = V3(1, -2, 0.5);
  Scene moved;
  REQUIRE(moved.add(make_plane(T_W_C * V3(0, 0, 2.0), T_W_C.linear() * n_C)).ok());
  REQUIRE(h.render(moved, T_W_C).ok());
  double worst_depth = 0.0;
  double worst_cos = 0.0;
  for (int v = 0; v < 480; ++v) {
    for (int u = 0; u < 640; ++u) {
      const V3 ray((u - 319.5) / 525.0, (v - 239.5) / 525.0, 1.0);
      const double expected = c / n_C.dot(ray);
      worst_depth = std::max(worst_depth, std::abs(h.depth[v * 640 + u] / expected - 1.0));
      const double cos_expected = std::abs(n_C.dot(ray.normalized()));
      worst_cos = std::max(worst_cos, std::abs(h.cosine[v * 640 + u] - cos_expected));
    }
  }
  REQUIRE(worst_depth < kDepthRelative);
  REQUIRE(worst_cos < 1e-6);
}

TEST_CASE("culled rendering equals the brute-force reference, desk and room") {
  for (const SceneId id : {SceneId::desk, SceneId::room}) {
    SimWorld world;
    REQUIRE(build_world(id, &world).ok());
    Harness h(qvga_camera());
    for (const double s : {0.0, 0.45, 1.0}) {
      const Se3d T_W_C = world.path.T_W_C(s);
      REQUIRE(h.render(world.scene, T_W_C).ok());
      REQUIRE(h.renderer.last_stats().visible_primitives <= world.scene.size());
      double worst = 0.0;
      for (int v = 0; v < h.camera.height; v += 5) {
        for (int u = 0; u < h.camera.width; u += 5) {
          const V3 d_C = V3((u - h.camera.cx) / h.camera.fx, (v - h.camera.cy) / h.camera.fy, 1.0)
                             .normalized();
          double t = 0.0;
          double cosine = 0.0;
          const int hit = world.scene.intersect(T_W_C.translation(), T_W_C.linear() * d_C,
                                                10.0 / d_C.z(), &t, &cosine);
          const double expected = hit >= 0 ? t * d_C.z() : 0.0;
          worst = std::max(worst, std::abs(h.depth[v * h.camera.width + u] - expected));
        }
      }
      INFO("scene " << scene_name(id) << " s " << s);
      REQUIRE(worst < kDepthRelative * 10.0);  // metres; float output of up to 10 m
    }
  }
}

TEST_CASE("rendered points lie on the zero set of the distance query") {
  for (const SceneId id : {SceneId::desk, SceneId::room}) {
    SimWorld world;
    REQUIRE(build_world(id, &world).ok());
    Harness h(kinect_camera());
    for (const double s : {0.0, 0.3, 0.6, 1.0}) {
      const Se3d T_W_C = world.path.T_W_C(s);
      REQUIRE(h.render(world.scene, T_W_C).ok());
      int checked = 0;
      double worst = 0.0;
      for (int v = 0; v < 480; v += 8) {
        for (int u = 0; u < 640; u += 8) {
          const float z = h.depth[v * 640 + u];
          if (z <= 0.0f) continue;
          const V3 p_C((u - 319.5) * z / 525.0, (v - 239.5) * z / 525.0, z);
          worst = std::max(worst, std::abs(world.scene.distance_m(T_W_C * p_C)));
          ++checked;
        }
      }
      INFO("scene " << scene_name(id) << " s " << s);
      REQUIRE(checked > 3000);  // most of the 4800 samples see something
      REQUIRE(worst < kOnSurface_m);
    }
  }
}

TEST_CASE("lateral jitter is deterministic per key") {
  SimWorld world;
  REQUIRE(build_world(SceneId::desk, &world).ok());
  Harness a(qvga_camera());
  Harness b(qvga_camera());
  RenderOptions options;
  options.lateral_sigma_px = 0.5f;
  options.jitter_key = 11;
  const Se3d T_W_C = world.path.T_W_C(0.1);
  REQUIRE(a.render(world.scene, T_W_C, options).ok());
  REQUIRE(b.render(world.scene, T_W_C, options).ok());
  REQUIRE(a.depth == b.depth);
  options.jitter_key = 12;
  REQUIRE(b.render(world.scene, T_W_C, options).ok());
  REQUIRE(a.depth != b.depth);
}

TEST_CASE("render checks its inputs and allocates nothing") {
  Scene scene;
  REQUIRE(scene.add(make_plane(V3(0, 0, 1.5), V3(0, 0, -1))).ok());
  SceneRenderer unready;
  std::vector<float> buffer(640 * 480);
  REQUIRE(unready.render(scene, Se3d::Identity(), {}, {buffer.data(), 640, 480}, {}).code() ==
          StatusCode::failed_precondition);

  Harness h(kinect_camera());
  REQUIRE(h.renderer.render(scene, Se3d::Identity(), {}, {buffer.data(), 320, 480}, {}).code() ==
          StatusCode::invalid_argument);
  Se3d scaled = Se3d::Identity();
  scaled.linear() *= 1.1;
  REQUIRE(h.render(scene, scaled).code() == StatusCode::invalid_argument);
  RenderOptions bad;
  bad.max_range_m = -1.0f;
  REQUIRE(h.render(scene, Se3d::Identity(), bad).code() == StatusCode::invalid_argument);

  // Without a cos view the depth is the same.
  REQUIRE(h.renderer.render(scene, Se3d::Identity(), {}, {buffer.data(), 640, 480}, {}).ok());
  REQUIRE(buffer[12345] == 1.5f);

  SimWorld world;
  REQUIRE(build_world(SceneId::room, &world).ok());
  int ok_count = 0;
  test::AllocationScope scope;
  for (int i = 0; i < 3; ++i) {
    if (h.render(world.scene, world.path.T_W_C(i / 3.0)).ok()) ++ok_count;
  }
  const std::uint64_t allocations = scope.allocations();
  REQUIRE(ok_count == 3);
  REQUIRE(allocations == 0);
}

TEST_CASE("nothing beyond max range, nothing behind the camera") {
  Scene scene;
  REQUIRE(scene.add(make_sphere(V3(0, 0, 5), 1.0)).ok());
  REQUIRE(scene.add(make_sphere(V3(0, 0, -3), 1.0)).ok());
  Harness h(qvga_camera());
  RenderOptions options;
  options.max_range_m = 3.0f;
  REQUIRE(h.render(scene, Se3d::Identity(), options).ok());
  for (float d : h.depth) REQUIRE(d == 0.0f);
  REQUIRE(h.renderer.last_stats().visible_primitives == 1);  // the one behind is culled
  options.max_range_m = 10.0f;
  REQUIRE(h.render(scene, Se3d::Identity(), options).ok());
  REQUIRE(h.depth[120 * 320 + 160] == Approx(4.0f).margin(1e-4));
}

}  // namespace
}  // namespace octofuse::sim
