#pragma once
// What the ICP tests share: a pre-processor and tracker reserved for VGA input at QVGA working
// resolution, the poses the synthetic pairs are rendered from, and pose errors.

#include "octofuse/track/icp.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

constexpr double kTranslationTolerance_m = 1e-3;
constexpr double kRotationTolerance_deg = 0.1;

constexpr double kPi = 3.14159265358979323846;

inline Se3d make_pose(const Eigen::Vector3d& translation_m, const Eigen::Vector3d& axis,
                      double angle_deg) {
  Se3d T = Se3d::Identity();
  T.linear() = Eigen::AngleAxisd(angle_deg * kPi / 180.0, axis.normalized()).toRotationMatrix();
  T.translation() = translation_m;
  return T;
}

// A reference pose looking into the corner scene and a live pose a few mm and 1.5 degrees off.
inline Se3d reference_pose() {
  return make_pose(Eigen::Vector3d(0.05, -0.1, 0.1), Eigen::Vector3d(0.2, -1.0, 0.1), 5.0);
}
inline Se3d offset_pose() {
  return reference_pose() *
         make_pose(Eigen::Vector3d(0.004, -0.003, 0.005), Eigen::Vector3d(0.3, 1.0, 0.2), 1.5);
}

inline double translation_error_m(const Se3d& a, const Se3d& b) {
  return (a.translation() - b.translation()).norm();
}
inline double rotation_error_deg(const Se3d& a, const Se3d& b) {
  const Eigen::AngleAxisd aa(Eigen::Matrix3d(a.linear().transpose() * b.linear()));
  return std::abs(aa.angle()) * 180.0 / kPi;
}

// Pre-processor and tracker reserved for VGA input at QVGA working resolution.
struct TrackFixture {
  explicit TrackFixture(const TrackConfig& track_config = TrackConfig{},
                        const PreprocessConfig& pre_config = PreprocessConfig{})
      : buffer(bytes_for(track_config, pre_config)) {
    REQUIRE(pre.reserve(buffer.arena(), pre_config, 640, 480).ok());
    REQUIRE(tracker.reserve(buffer.arena(), track_config, 320, 240).ok());
    REQUIRE(buffer.arena().bytes_used() == buffer.arena().capacity());
  }
  static std::size_t bytes_for(const TrackConfig& track_config,
                               const PreprocessConfig& pre_config) {
    ArenaSizer sizer;
    DepthPreprocessor p;
    IcpTracker t;
    REQUIRE(p.reserve(sizer, pre_config, 640, 480).ok());
    REQUIRE(t.reserve(sizer, track_config, 320, 240).ok());
    return sizer.bytes_used();
  }
  // Renders the live depth at T_W_C_live (VGA) and pre-processes it.
  void set_live(const test::AnalyticScene& scene, const Se3d& T_W_C_live, int workers = 1,
                float noise_m = 0.0f) {
    live_depth = scene.render(test::vga_camera(), T_W_C_live);
    if (noise_m > 0.0f) {
      std::mt19937 rng(7);
      std::uniform_real_distribution<float> noise(-noise_m, noise_m);
      for (float& d : live_depth) {
        if (d > 0.0f) d += noise(rng);
      }
    }
    const WorkerTeam team(workers);
    REQUIRE(
        pre.process(ImageView<const float>(live_depth.data(), 640, 480), test::vga_camera(), team)
            .ok());
  }
  PinholeCamera camera_level0() const { return test::vga_camera().downsampled(2); }

  test::ArenaBuffer buffer;
  DepthPreprocessor pre;
  IcpTracker tracker;
  std::vector<float> live_depth;
};

}  // namespace
}  // namespace octofuse
