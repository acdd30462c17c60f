#include "octofuse/ports/sim/sim_source.hpp"

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Eigenvalues>

#include "octofuse/sensor/frame_validator.hpp"
#include "support/alloc_counter.hpp"

namespace octofuse::sim {
namespace {

using V3 = Eigen::Vector3d;
constexpr double kRigidTolerance = 1e-9;

std::unique_ptr<SimSource> open_source(const char* spec, int downsample = 1) {
  SimConfig config;
  ErrorText error;
  INFO(spec);
  REQUIRE(sim_config_from_spec(spec, &config, &error).ok());
  // Heavy checks run at a lower resolution: same path and scene, fewer pixels.
  if (downsample > 1) config.camera = kinect_camera().downsampled(downsample);
  auto source = std::make_unique<SimSource>(config);
  REQUIRE(source->open().ok());
  return source;
}

TEST_CASE("the factory knows desk and room and their options") {
  ErrorText error;
  SimConfig config;
  REQUIRE(sim_config_from_spec("desk", &config, &error).ok());
  REQUIRE(config.scene == SceneId::desk);
  REQUIRE(sim_config_from_spec("sim:room", &config, &error).ok());
  REQUIRE(config.scene == SceneId::room);
  REQUIRE(config.noise.enabled);
  REQUIRE(
      sim_config_from_spec("sim:desk,frames=12,seed=99,noise=off,ring=2", &config, &error).ok());
  REQUIRE(config.frame_count == 12);
  REQUIRE(config.seed == 99);
  REQUIRE(!config.noise.enabled);
  REQUIRE(config.ring_size == 2);

  for (const char* bad : {"", "sim:", "kitchen", "sim:desk,frames=0", "desk,frames=-3",
                          "desk,frames", "desk,colour=red", "desk,noise=maybe", "desks"}) {
    INFO(bad);
    REQUIRE(sim_config_from_spec(bad, &config, &error).code() == StatusCode::invalid_argument);
    REQUIRE(!error.empty());
    REQUIRE(make_sim_source(bad, &error) == nullptr);
  }
  sim_config_from_spec("kitchen", &config, &error).ignore();
  REQUIRE(std::strstr(error.c_str(), "kitchen") != nullptr);
}

TEST_CASE("defaults: Kinect intrinsics, 30 Hz, millimetres, ground truth, 300 desk frames") {
  auto source = open_source("desk");
  const PinholeCamera cam = source->intrinsics();
  REQUIRE(cam.width == 640);
  REQUIRE(cam.height == 480);
  REQUIRE(cam.fx == 525.0f);
  REQUIRE(cam.fy == 525.0f);
  REQUIRE(cam.cx == 319.5f);
  REQUIRE(cam.cy == 239.5f);
  REQUIRE(source->frame_count() == 300);
  const SourceCapabilities caps = source->capabilities();
  REQUIRE(caps.has_ground_truth);
  REQUIRE(!caps.live);
  REQUIRE(caps.ring_size == 4);
  REQUIRE(caps.nominal_rate_hz == 30.0f);
  REQUIRE(open_source("room")->frame_count() == 360);
}

TEST_CASE("next before open fails, and open rejects bad configs") {
  SimSource source(SimConfig{});
  DepthFrame frame;
  const NextFrame r = source.next(frame);
  REQUIRE(r.outcome == FrameOutcome::error);
  REQUIRE(r.status.code() == StatusCode::failed_precondition);

  SimConfig bad;
  bad.ring_size = 0;
  REQUIRE(SimSource(bad).open().code() == StatusCode::invalid_argument);
  bad = SimConfig{};
  bad.camera.fx = -1.0f;
  REQUIRE(SimSource(bad).open().code() == StatusCode::invalid_argument);
  bad = SimConfig{};
  bad.metres_per_unit = 0.0f;
  REQUIRE(SimSource(bad).open().code() == StatusCode::invalid_argument);
  bad = SimConfig{};
  bad.min_range_m = 5.0f;
  bad.max_range_m = 1.0f;
  REQUIRE(SimSource(bad).open().code() == StatusCode::invalid_argument);
  REQUIRE(SimSource::bytes_required(bad) == 0);
}

TEST_CASE("frames: monotonic time, counted sequence, rigid ground truth, then end_of_stream") {
  auto source = open_source("desk,frames=6,ring=3", 4);
  DepthFrame frame;
  std::int64_t previous_us = -1;
  const std::uint16_t* slots[6] = {};
  for (int i = 0; i < 6; ++i) {
    REQUIRE(source->next(frame).outcome == FrameOutcome::frame);
    REQUIRE(frame.sequence == static_cast<std::uint64_t>(i));
    REQUIRE(frame.timestamp_us > previous_us);
    REQUIRE(frame.timestamp_us == std::llround(i * 1e6 / 30.0));
    previous_us = frame.timestamp_us;
    REQUIRE(frame.metres_per_unit == 0.001f);
    REQUIRE(frame.depth_raw.width == 160);
    REQUIRE(frame.depth_raw.height == 120);
    REQUIRE(frame.has_ground_truth);
    REQUIRE(is_rigid(frame.T_W_C_ground_truth, kRigidTolerance));
    REQUIRE(frame.T_W_C_ground_truth.isApprox(source->ground_truth_T_W_C(i).matrix()));
    slots[i] = frame.depth_raw.data;
  }
  // A ring of three buffers, reused in order.
  REQUIRE(slots[0] != slots[1]);
  REQUIRE(slots[1] != slots[2]);
  REQUIRE(slots[3] == slots[0]);
  for (int i = 0; i < 3; ++i) {
    const NextFrame end = source->next(frame);
    REQUIRE(end.outcome == FrameOutcome::end_of_stream);
    REQUIRE(end.status.code() == StatusCode::end_of_stream);
  }
  // open() again restarts the stream.
  REQUIRE(source->open().ok());
  REQUIRE(source->next(frame).outcome == FrameOutcome::frame);
  REQUIRE(frame.sequence == 0);
}

TEST_CASE("ground truth poses are rigid along the whole path and move smoothly") {
  for (const char* spec : {"desk", "room"}) {
    auto source = open_source(spec);
    constexpr double kMaxStep_m = 0.05;    // per frame at 30 Hz
    constexpr double kMaxTurn_rad = 0.05;  // about 3 degrees per frame
    for (int i = 0; i < source->frame_count(); ++i) {
      const Se3d T = source->ground_truth_T_W_C(i);
      REQUIRE(is_rigid(T.matrix(), kRigidTolerance));
      if (i > 0) {
        const Se3d step = source->ground_truth_T_W_C(i - 1).inverse() * T;
        REQUIRE(step.translation().norm() < kMaxStep_m);
        REQUIRE(Eigen::AngleAxisd(step.linear()).angle() < kMaxTurn_rad);
      }
    }
  }
}

TEST_CASE("same seed gives identical frames, another seed other noise, noise off is exact") {
  auto a = open_source("desk,frames=3,seed=5", 4);
  auto b = open_source("desk,frames=3,seed=5", 4);
  auto c = open_source("desk,frames=3,seed=6", 4);
  auto exact = open_source("desk,frames=3,noise=off", 4);
  DepthFrame fa, fb, fc, fe;
  for (int i = 0; i < 3; ++i) {
    REQUIRE(a->next(fa).outcome == FrameOutcome::frame);
    REQUIRE(b->next(fb).outcome == FrameOutcome::frame);
    REQUIRE(c->next(fc).outcome == FrameOutcome::frame);
    REQUIRE(exact->next(fe).outcome == FrameOutcome::frame);
    const std::size_t n = fa.depth_raw.pixel_count();
    REQUIRE(std::equal(fa.depth_raw.data, fa.depth_raw.data + n, fb.depth_raw.data));
    REQUIRE(!std::equal(fa.depth_raw.data, fa.depth_raw.data + n, fc.depth_raw.data));
    REQUIRE(fa.T_W_C_ground_truth == fc.T_W_C_ground_truth);
    // Noise off: the raw value is the exact depth rounded to millimetres.
    const ImageView<const float> z = exact->last_exact_depth_m();
    std::size_t mismatches = 0;
    for (std::size_t p = 0; p < n; ++p) {
      const float zm = z.data[p];
      const double units = std::round(zm / static_cast<double>(0.001f));
      const int expected = (zm >= 0.2f && zm <= 6.0f) ? static_cast<int>(units) : 0;
      mismatches += fe.depth_raw.data[p] != expected;
    }
    REQUIRE(mismatches == 0);
  }
}

TEST_CASE("next() allocates nothing") {
  auto source = open_source("room,frames=5", 4);
  DepthFrame frame;
  int frames = 0;
  test::AllocationScope scope;
  while (source->next(frame).outcome == FrameOutcome::frame) ++frames;
  const std::uint64_t allocations = scope.allocations();
  REQUIRE(frames == 5);
  REQUIRE(allocations == 0);
}

// The point-to-plane ICP information matrix of a frame, from ground-truth normals. Its smallest
// eigenvalue (relative to the largest) says whether every motion direction is observable.
double icp_conditioning(const SimSource& source, const Se3d& T_W_C, const DepthFrame& frame) {
  const PinholeCamera cam = source.intrinsics();
  Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
  constexpr double kGradientStep_m = 1e-5;
  for (int v = 0; v < cam.height; v += 4) {
    for (int u = 0; u < cam.width; u += 4) {
      const std::uint16_t raw = frame.depth_raw(u, v);
      if (raw == 0) continue;
      const double z = raw * 0.001;
      const V3 p_C((u - cam.cx) * z / cam.fx, (v - cam.cy) * z / cam.fy, z);
      const V3 p_W = T_W_C * p_C;
      V3 n_W;
      for (int k = 0; k < 3; ++k) {
        V3 e = V3::Zero();
        e[k] = kGradientStep_m;
        n_W[k] = source.scene().distance_m(p_W + e) - source.scene().distance_m(p_W - e);
      }
      const V3 n_C = T_W_C.linear().transpose() * n_W.normalized();
      Eigen::Matrix<double, 6, 1> J;
      J << n_C, p_C.cross(n_C);
      A += J * J.transpose();
    }
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> solver(A);
  return solver.eigenvalues()(0) / solver.eigenvalues()(5);
}

TEST_CASE("desk: close, then far, enough geometry for ICP at every frame, frames validate") {
  // 20 frames span the same path as 300, every fifteenth pose.
  auto source = open_source("desk,frames=20", 4);
  FrameValidatorConfig vconfig;
  vconfig.near_m = 0.2f;
  vconfig.far_m = 6.0f;
  FrameValidator validator;
  REQUIRE(validator.init(source->intrinsics(), vconfig).ok());
  const PinholeCamera cam = source->intrinsics();
  std::vector<float> metres(cam.width * cam.height);
  DepthFrame frame;
  double worst_conditioning = 1.0;
  std::vector<float> medians;
  for (int i = 0; i < 20; ++i) {
    REQUIRE(source->next(frame).outcome == FrameOutcome::frame);
    FrameReport report;
    REQUIRE(validator.validate(frame, {metres.data(), cam.width, cam.height}, &report).ok());
    INFO("frame " << i << " valid fraction " << report.valid_fraction());
    REQUIRE(report.valid_fraction() > 0.5f);
    std::vector<float> valid;
    for (float m : metres) {
      if (m > 0.0f) valid.push_back(m);
    }
    std::nth_element(valid.begin(), valid.begin() + valid.size() / 2, valid.end());
    medians.push_back(valid[valid.size() / 2]);
    worst_conditioning = std::min(worst_conditioning,
                                  icp_conditioning(*source, source->ground_truth_T_W_C(i), frame));
  }
  // The first fifth is close range (0.3-0.6 m), the last third far (2-3 m).
  for (int i = 0; i < 4; ++i) {
    REQUIRE(medians[i] > 0.3f);
    REQUIRE(medians[i] < 0.6f);
  }
  // Far: the camera is 2-3 m from the desk; the image median also sees the wall behind it.
  const V3 desk_centre_W(0.0, 0.0, 0.75);
  for (int i = 14; i < 20; ++i) {
    const double range_m = (source->ground_truth_T_W_C(i).translation() - desk_centre_W).norm();
    REQUIRE(range_m > 2.0);
    REQUIRE(range_m < 3.0);
    REQUIRE(medians[i] > 2.0f);
    REQUIRE(medians[i] < 3.2f);
  }
  REQUIRE(validator.frames_dropped() == 0);
  constexpr double kMinConditioning = 1e-4;  // a single plane gives ~1e-17
  INFO("worst ICP conditioning " << worst_conditioning);
  REQUIRE(worst_conditioning > kMinConditioning);
}

TEST_CASE("the thin structures are in view and measurable") {
  auto source = open_source("desk,frames=60,noise=off", 2);
  const Scene& scene = source->scene();
  int handle = 0;
  int cable = 0;
  int bar = 0;
  for (const Primitive& p : scene) {
    handle += p.part == Part::mug_handle;
    cable += p.part == Part::cable;
    bar += p.part == Part::chair_bar;
    if (p.part == Part::mug_handle) REQUIRE(p.radius_m == Approx(0.0025));  // 5 mm thick
  }
  REQUIRE(handle >= 3);
  REQUIRE(cable >= 10);
  REQUIRE(bar >= 8);

  // Pixels on the handle at close range: exact depth back-projected onto a handle primitive.
  DepthFrame frame;
  int best_handle_pixels = 0;
  for (int i = 0; i < 12; ++i) {
    REQUIRE(source->next(frame).outcome == FrameOutcome::frame);
    if (i % 3 != 0) continue;
    const Se3d T_W_C = source->ground_truth_T_W_C(i);
    const ImageView<const float> z = source->last_exact_depth_m();
    const PinholeCamera cam = source->intrinsics();
    int on_handle = 0;
    for (int v = 0; v < cam.height; ++v) {
      for (int u = 0; u < cam.width; ++u) {
        const double d = z(u, v);
        if (d <= 0.0) continue;
        const V3 p_W = T_W_C * V3((u - cam.cx) * d / cam.fx, (v - cam.cy) * d / cam.fy, d);
        for (const Primitive& p : scene) {
          if (p.part == Part::mug_handle && std::abs(p.distance_m(p_W)) < 1e-4) {
            ++on_handle;
            break;
          }
        }
      }
    }
    best_handle_pixels = std::max(best_handle_pixels, on_handle);
  }
  REQUIRE(best_handle_pixels > 25);  // at QVGA

  std::vector<V3> samples(5000);
  const std::size_t n = scene.sample_surface(kThinParts, 1, samples.data(), samples.size());
  REQUIRE(n > 4000);
  for (std::size_t i = 0; i < n; ++i) REQUIRE(std::abs(scene.distance_m(samples[i])) < 1e-9);
}

TEST_CASE("bytes_required covers the ring, the render buffers and the tiles") {
  SimConfig config;
  config.ring_size = 5;
  const std::size_t pixels = 640 * 480;
  const std::size_t bytes = SimSource::bytes_required(config);
  REQUIRE(bytes >= 5 * pixels * sizeof(std::uint16_t) + 2 * pixels * sizeof(float));
  REQUIRE(bytes < 5 * pixels * sizeof(std::uint16_t) + 2 * pixels * sizeof(float) + (1u << 20));
}

}  // namespace
}  // namespace octofuse::sim
