#include "octofuse/math/camera.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <limits>

namespace octofuse {
namespace {

constexpr float kTolerance_px = 1e-4f;
constexpr float kTolerance_m = 1e-5f;

// 7-Scenes Kinect intrinsics (VGA).
PinholeCamera kinect_vga() {
  return PinholeCamera{585.0f, 585.0f, 320.0f, 240.0f, 640, 480};
}

TEST_CASE("A point on the optical axis projects to the principal point") {
  const PinholeCamera camera = kinect_vga();
  const Eigen::Vector2f px = camera.project(Eigen::Vector3f(0.0f, 0.0f, 2.5f));
  REQUIRE(px.x() == Approx(320.0f).margin(kTolerance_px));
  REQUIRE(px.y() == Approx(240.0f).margin(kTolerance_px));
}

TEST_CASE("project and back_project are inverse") {
  const PinholeCamera camera = kinect_vga();
  for (float u : {0.0f, 100.5f, 639.0f}) {
    for (float v : {0.0f, 240.0f, 479.0f}) {
      for (float depth_m : {0.4f, 1.0f, 4.0f}) {
        const Eigen::Vector3f p_C = camera.back_project(u, v, depth_m);
        REQUIRE(p_C.z() == depth_m);
        const Eigen::Vector2f px = camera.project(p_C);
        REQUIRE(px.x() == Approx(u).margin(kTolerance_px));
        REQUIRE(px.y() == Approx(v).margin(kTolerance_px));
      }
    }
  }
  // x right, y down: pixel (320 + 585, 240) at 1 m is 1 m to the right.
  const Eigen::Vector3f p_C = camera.back_project(905.0f, 240.0f, 1.0f);
  REQUIRE((p_C - Eigen::Vector3f(1.0f, 0.0f, 1.0f)).norm() < kTolerance_m);
}

TEST_CASE("in_image covers [-0.5, size - 0.5) on both axes") {
  const PinholeCamera camera = kinect_vga();
  REQUIRE(camera.in_image({-0.5f, -0.5f}));
  REQUIRE(camera.in_image({639.49f, 479.49f}));
  REQUIRE_FALSE(camera.in_image({639.5f, 0.0f}));
  REQUIRE_FALSE(camera.in_image({0.0f, 479.5f}));
  REQUIRE_FALSE(camera.in_image({-0.51f, 10.0f}));
  REQUIRE_FALSE(camera.in_image({10.0f, -0.51f}));
}

TEST_CASE("valid rejects non-positive, non-finite focal lengths and empty images") {
  REQUIRE(kinect_vga().valid());
  PinholeCamera c = kinect_vga();
  c.fx = 0.0f;
  REQUIRE_FALSE(c.valid());
  c = kinect_vga();
  c.fy = -1.0f;
  REQUIRE_FALSE(c.valid());
  c = kinect_vga();
  c.cx = std::numeric_limits<float>::quiet_NaN();
  REQUIRE_FALSE(c.valid());
  c = kinect_vga();
  c.fx = std::numeric_limits<float>::infinity();
  REQUIRE_FALSE(c.valid());
  c = kinect_vga();
  c.width = 0;
  REQUIRE_FALSE(c.valid());
  REQUIRE_FALSE(PinholeCamera{}.valid());
}

TEST_CASE("downsampled(2) keeps rays through matching pixel centres") {
  const PinholeCamera vga = kinect_vga();
  const PinholeCamera qvga = vga.downsampled(2);
  REQUIRE(qvga.width == 320);
  REQUIRE(qvga.height == 240);
  REQUIRE(qvga.fx == Approx(292.5f));
  REQUIRE(qvga.cx == Approx(159.75f));
  REQUIRE(qvga.cy == Approx(119.75f));
  // Coarse pixel (uc, vc) averages fine pixels 2uc, 2uc+1: its centre is fine 2uc + 0.5.
  for (float uc : {0.0f, 77.0f, 319.0f}) {
    for (float vc : {0.0f, 120.0f, 239.0f}) {
      const Eigen::Vector3f coarse = qvga.back_project(uc, vc, 1.0f);
      const Eigen::Vector3f fine = vga.back_project(2.0f * uc + 0.5f, 2.0f * vc + 0.5f, 1.0f);
      REQUIRE((coarse - fine).norm() < kTolerance_m);
    }
  }
  const PinholeCamera same = vga.downsampled(1);
  REQUIRE(same.cx == vga.cx);
  REQUIRE(same.fx == vga.fx);
  REQUIRE(same.width == vga.width);
}

}  // namespace
}  // namespace octofuse
