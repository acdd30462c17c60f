// All 1000 frames of the real 7-Scenes "redkitchen" recording (../shared/data, found through
// OCTOFUSE_TEST_DATA_DIR): counts, the 65535 invalid marker, and ground-truth poses.
#include <catch2/catch.hpp>
#include <string>

#include "octofuse/ports/replay/replay_source.hpp"
#include "support/test_data.hpp"

using octofuse::DepthFrame;
using octofuse::FrameOutcome;
using octofuse::replay::ReplayConfig;
using octofuse::replay::ReplaySource;

namespace {
constexpr int kExpectedFrames = 1000;
constexpr int kFramesWithInvalidMarker = 59;  // from the dataset's README
constexpr std::uint16_t kInvalidMarker = 65535;
constexpr double kRigidTolerance = 1e-3;
// Kinect v1 range: anything beyond 10 m (other than the marker) would be a decoding error.
constexpr std::uint16_t kMaxPlausibleDepth_mm = 10000;
}  // namespace

TEST_CASE("7-Scenes redkitchen: all frames, invalid pixels and poses", "[replay][data]") {
  std::string why;
  const std::string recording = octofuse::test::recording_dir("7scenes-redkitchen", &why);
  if (recording.empty()) {
    WARN(why << ": skipping the 7scenes-redkitchen test");
    return;
  }
  const std::string spec = "7scenes:" + recording;
  ReplayConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_replay_spec(spec.c_str(), &config, &error).ok());
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK(source.frame_count() == kExpectedFrames);
  const octofuse::PinholeCamera camera = source.intrinsics();
  CHECK(camera.fx == 585.0f);
  CHECK(camera.fy == 585.0f);
  CHECK(camera.cx == 320.0f);
  CHECK(camera.cy == 240.0f);
  CHECK(camera.width == 640);
  CHECK(camera.height == 480);
  CHECK(source.capabilities().has_ground_truth);

  int frames = 0, frames_with_marker = 0, implausible = 0, poses_rigid = 0;
  std::int64_t previous_us = -1;
  for (;;) {
    DepthFrame frame;
    const octofuse::NextFrame got = source.next(frame);
    if (got.outcome == FrameOutcome::end_of_stream) break;
    INFO(source.last_error());
    REQUIRE(got.outcome == FrameOutcome::frame);
    REQUIRE(frame.depth_raw.width == 640);
    REQUIRE(frame.depth_raw.height == 480);
    CHECK(frame.sequence == static_cast<std::uint64_t>(frames));
    CHECK(frame.timestamp_us > previous_us);
    previous_us = frame.timestamp_us;
    bool marker = false;
    for (int y = 0; y < 480; ++y) {
      for (int x = 0; x < 640; ++x) {
        const std::uint16_t d = frame.depth_raw(x, y);
        if (d == kInvalidMarker) {
          marker = true;
        } else if (d > kMaxPlausibleDepth_mm) {
          ++implausible;
        }
      }
    }
    frames_with_marker += marker ? 1 : 0;
    REQUIRE(frame.has_ground_truth);
    if (octofuse::is_rigid(frame.T_W_C_ground_truth, kRigidTolerance)) ++poses_rigid;
    ++frames;
  }
  CHECK(frames == kExpectedFrames);
  CHECK(frames_with_marker == kFramesWithInvalidMarker);
  CHECK(implausible == 0);
  CHECK(poses_rigid == kExpectedFrames);
  CHECK(previous_us == (kExpectedFrames - 1) * 1000000LL / 30);
}
