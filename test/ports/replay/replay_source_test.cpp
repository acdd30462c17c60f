#include "octofuse/ports/replay/replay_source.hpp"

#include <catch2/catch.hpp>
#include <string>

#include "fixtures.hpp"
#include "support/alloc_counter.hpp"
#include "support/text.hpp"

using octofuse::DepthFrame;
using octofuse::FrameOutcome;
using octofuse::NextFrame;
using octofuse::StatusCode;
using octofuse::replay::DatasetFormat;
using octofuse::replay::Pacing;
using octofuse::replay::ReplayConfig;
using octofuse::replay::ReplaySource;
using octofuse::test::contains;
namespace fx = octofuse::test;

namespace {

constexpr double kPoseTolerance = 1e-9;

ReplayConfig config_for(const std::string& spec) {
  ReplayConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_replay_spec(spec.c_str(), &config, &error).ok());
  return config;
}

void require_pixels(const DepthFrame& frame, const std::vector<std::uint16_t>& expected, int width,
                    int height) {
  REQUIRE(frame.depth_raw.width == width);
  REQUIRE(frame.depth_raw.height == height);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      REQUIRE(frame.depth_raw(x, y) == expected[static_cast<std::size_t>(y) * width + x]);
    }
  }
}

struct FakeClock {
  std::int64_t now_us = 5000000;
  int sleeps = 0;
  static std::int64_t now(void* self) { return static_cast<FakeClock*>(self)->now_us; }
  static void sleep_until(void* self, std::int64_t t_us) {
    FakeClock* clock = static_cast<FakeClock*>(self);
    ++clock->sleeps;
    if (t_us > clock->now_us) clock->now_us = t_us;
  }
};

}  // namespace

TEST_CASE("replay spec parsing", "[replay]") {
  ReplayConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_replay_spec("7scenes:/data/kitchen/", &config, &error).ok());
  CHECK(config.format == DatasetFormat::seven_scenes);
  CHECK(std::string(config.path) == "/data/kitchen");
  REQUIRE(octofuse::replay::parse_replay_spec("raw:a.raw", &config, &error).ok());
  CHECK(config.format == DatasetFormat::slambench_raw);
  REQUIRE(octofuse::replay::parse_replay_spec("icl:x", &config, &error).ok());
  CHECK(config.format == DatasetFormat::icl_nuim);
  REQUIRE(octofuse::replay::parse_replay_spec("tum:y", &config, &error).ok());
  CHECK(config.format == DatasetFormat::tum);
  CHECK(octofuse::replay::parse_replay_spec("kinect:x", &config, &error) ==
        StatusCode::invalid_argument);
  CHECK(contains(error.c_str(), "kinect:x"));
  CHECK(octofuse::replay::parse_replay_spec("tum:", &config, &error) ==
        StatusCode::invalid_argument);
  const std::string long_spec = "tum:" + std::string(600, 'a');
  CHECK(octofuse::replay::parse_replay_spec(long_spec.c_str(), &config, &error) ==
        StatusCode::invalid_argument);
}

TEST_CASE("TUM folder reads back exactly, with ground truth by nearest timestamp", "[replay]") {
  const std::string parent = fx::make_test_dir("tum");
  const fx::TumFixture tum = fx::write_tum(parent, "rgbd_dataset_freiburg2_fixture");
  ReplaySource source(config_for("tum:" + tum.dir));
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK(source.frame_count() == 3);
  CHECK(source.capabilities().has_ground_truth);
  CHECK_FALSE(source.capabilities().live);
  const octofuse::PinholeCamera camera = source.intrinsics();
  CHECK(camera.fx == 520.9f);  // freiburg2 by name
  CHECK(camera.cy == 249.7f);
  CHECK(camera.width == 8);
  CHECK(camera.height == 6);
  for (int i = 0; i < 3; ++i) {
    DepthFrame frame;
    const NextFrame got = source.next(frame);
    REQUIRE(got.outcome == FrameOutcome::frame);
    require_pixels(frame, fx::pattern_depth(8, 6, i), 8, 6);
    CHECK(frame.metres_per_unit == Approx(1.0 / 5000.0));
    CHECK(frame.timestamp_us == std::llround(tum.timestamps[i] * 1e6));
    CHECK(frame.sequence == static_cast<std::uint64_t>(i));
    REQUIRE(frame.has_ground_truth);
    CHECK((frame.T_W_C_ground_truth - fx::pose_for_frame(i).matrix()).norm() < kPoseTolerance);
  }
  DepthFrame frame;
  CHECK(source.next(frame).outcome == FrameOutcome::end_of_stream);
  CHECK(source.next(frame).outcome == FrameOutcome::end_of_stream);
}

TEST_CASE("TUM overrides: intrinsics and depth scale", "[replay]") {
  const std::string parent = fx::make_test_dir("tum-override");
  const fx::TumFixture tum = fx::write_tum(parent, "plain", 2, false);
  ReplayConfig config = config_for("tum:" + tum.dir);
  config.has_intrinsics = true;
  config.intrinsics = octofuse::PinholeCamera{100.0f, 101.0f, 3.5f, 2.5f, 0, 0};
  config.depth_units_per_m = 1000.0f;
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK_FALSE(source.capabilities().has_ground_truth);
  CHECK(source.intrinsics().fx == 100.0f);
  CHECK(source.intrinsics().width == 8);
  DepthFrame frame;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK(frame.metres_per_unit == Approx(0.001));
  CHECK_FALSE(frame.has_ground_truth);
}

TEST_CASE("ground truth outside the association window is left out", "[replay]") {
  const std::string parent = fx::make_test_dir("tum-window");
  const fx::TumFixture tum = fx::write_tum(parent, "w", 2);
  ReplayConfig config = config_for("tum:" + tum.dir);
  config.ground_truth_max_dt_s = 0.001;  // the nearest pose is 3 ms away
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  DepthFrame frame;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK_FALSE(frame.has_ground_truth);
}

TEST_CASE("7-Scenes folder reads back exactly, 65535 kept for the validator", "[replay]") {
  const std::string parent = fx::make_test_dir("seven");
  const std::string dir = fx::write_seven_scenes(parent);
  ReplaySource source(config_for("7scenes:" + dir));
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK(source.frame_count() == 3);
  CHECK(source.intrinsics().fx == 585.0f);
  CHECK(source.intrinsics().cx == 320.0f);
  CHECK(source.intrinsics().width == 10);
  CHECK(source.intrinsics().height == 4);
  CHECK(source.capabilities().has_ground_truth);
  for (int i = 0; i < 3; ++i) {
    DepthFrame frame;
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    require_pixels(frame, fx::pattern_depth(10, 4, i, true), 10, 4);
    CHECK(frame.depth_raw(2, 2) == 65535);
    CHECK(frame.metres_per_unit == Approx(0.001));
    CHECK(frame.timestamp_us == i * 1000000 / 30);
    REQUIRE(frame.has_ground_truth);
    CHECK((frame.T_W_C_ground_truth - fx::pose_for_frame(i).matrix()).norm() < kPoseTolerance);
  }
  DepthFrame frame;
  CHECK(source.next(frame).outcome == FrameOutcome::end_of_stream);
}

TEST_CASE("ICL-NUIM layout: associations.txt, *.gt.freiburg, frame indices at 30 Hz", "[replay]") {
  const std::string dir = fx::make_test_dir("icl");
  ::mkdir((dir + "/depth").c_str(), 0755);
  std::string associations, gt;
  for (int i = 0; i < 3; ++i) {
    fx::write_depth_png(dir + "/depth/" + std::to_string(i) + ".png", fx::pattern_depth(6, 5, i), 6,
                        5);
    associations += std::to_string(i) + " depth/" + std::to_string(i) + ".png " +
                    std::to_string(i) + " rgb/" + std::to_string(i) + ".png\n";
    gt += fx::tum_pose_line(i, fx::pose_for_frame(i));
  }
  fx::write_text(dir + "/associations.txt", associations);
  fx::write_text(dir + "/livingRoom0.gt.freiburg", gt);
  ReplaySource source(config_for("icl:" + dir));
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK(source.intrinsics().fx == 481.2f);
  for (int i = 0; i < 3; ++i) {
    DepthFrame frame;
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    require_pixels(frame, fx::pattern_depth(6, 5, i), 6, 5);
    CHECK(frame.timestamp_us == std::llround(i / 30.0 * 1e6));
    CHECK(frame.metres_per_unit == Approx(1.0 / 5000.0));
    REQUIRE(frame.has_ground_truth);
    CHECK((frame.T_W_C_ground_truth - fx::pose_for_frame(i).matrix()).norm() < kPoseTolerance);
  }
}

TEST_CASE("SLAMBench .raw reads back exactly", "[replay]") {
  const std::string dir = fx::make_test_dir("raw");
  const std::string path = dir + "/scene.raw";
  fx::write_text(path, fx::raw_frame_bytes(7, 3, 0) + fx::raw_frame_bytes(7, 3, 1) +
                           fx::raw_frame_bytes(7, 3, 2));
  ReplayConfig config = config_for("raw:" + path);
  config.has_intrinsics = true;
  config.intrinsics = octofuse::PinholeCamera{525.0f, 525.0f, 3.0f, 1.0f, 0, 0};
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK(source.frame_count() == 3);
  CHECK(source.intrinsics().width == 7);
  CHECK_FALSE(source.capabilities().has_ground_truth);
  for (int i = 0; i < 3; ++i) {
    DepthFrame frame;
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    require_pixels(frame, fx::pattern_depth(7, 3, i), 7, 3);
    CHECK(frame.metres_per_unit == Approx(0.001));
    CHECK(frame.timestamp_us == i * 1000000 / 30);
  }
  DepthFrame frame;
  CHECK(source.next(frame).outcome == FrameOutcome::end_of_stream);
}

TEST_CASE("the ring keeps ring_size frames valid at once", "[replay]") {
  const std::string parent = fx::make_test_dir("ring");
  const fx::TumFixture tum = fx::write_tum(parent, "ring", 3, false);
  ReplayConfig config = config_for("tum:" + tum.dir);
  config.ring_size = 2;
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK(source.capabilities().ring_size == 2);
  DepthFrame a, b;
  REQUIRE(source.next(a).outcome == FrameOutcome::frame);
  REQUIRE(source.next(b).outcome == FrameOutcome::frame);
  CHECK(a.depth_raw.data != b.depth_raw.data);
  require_pixels(a, fx::pattern_depth(8, 6, 0), 8, 6);
  require_pixels(b, fx::pattern_depth(8, 6, 1), 8, 6);
}

TEST_CASE("next() after open() does not allocate", "[replay]") {
  const std::string parent = fx::make_test_dir("alloc");
  const fx::TumFixture tum = fx::write_tum(parent, "alloc", 40);
  const std::string seven = fx::write_seven_scenes(parent, 10);
  for (const std::string& spec : {"tum:" + tum.dir, "7scenes:" + seven}) {
    ReplaySource source(config_for(spec));
    {
      const octofuse::Status opened = source.open();
      INFO(source.last_error());
      REQUIRE(opened.ok());
    }
    DepthFrame frame;
    int frames = 0;
    octofuse::test::AllocationScope scope;
    for (;;) {
      const NextFrame got = source.next(frame);
      if (got.outcome != FrameOutcome::frame) break;
      ++frames;
    }
    CHECK(scope.allocations() == 0);
    CHECK(frames == static_cast<int>(source.frame_count()));
  }
}

TEST_CASE("real-time pacing drops frames that were due while the reader was busy", "[replay]") {
  const std::string parent = fx::make_test_dir("pacing");
  const std::string dir = fx::write_seven_scenes(parent, 8);  // 30 Hz: frame i at i*33333 us
  ReplayConfig config = config_for("7scenes:" + dir);
  FakeClock clock;
  config.pacing = Pacing::real_time;
  config.clock.now_us = &FakeClock::now;
  config.clock.sleep_until_us = &FakeClock::sleep_until;
  config.clock.context = &clock;
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  CHECK(source.capabilities().live);
  const std::int64_t start_us = clock.now_us;
  DepthFrame frame;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK(frame.sequence == 0);

  // Busy for 100 ms: frames 1 and 2 were overwritten, frame 3 (due at 100 ms) is delivered.
  clock.now_us = start_us + 100000;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK(frame.sequence == 3);
  CHECK(source.frames_dropped() == 2);
  CHECK(clock.sleeps == 0);

  // Reading at once: frame 4 is not due yet, so the source waits for it.
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK(frame.sequence == 4);
  CHECK(clock.sleeps == 1);
  CHECK(clock.now_us == start_us + 4 * 1000000 / 30);

  // Far behind: everything but the last frame is dropped.
  clock.now_us = start_us + 10 * 1000000;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK(frame.sequence == 7);
  CHECK(source.frames_dropped() == 4);
  CHECK(source.next(frame).outcome == FrameOutcome::end_of_stream);
}

TEST_CASE("as-fast-as-possible pacing never waits and never drops", "[replay]") {
  const std::string parent = fx::make_test_dir("fast");
  const std::string dir = fx::write_seven_scenes(parent, 5);
  ReplayConfig config = config_for("7scenes:" + dir);
  FakeClock clock;
  config.clock.now_us = &FakeClock::now;
  config.clock.sleep_until_us = &FakeClock::sleep_until;
  config.clock.context = &clock;
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  DepthFrame frame;
  std::uint64_t expected = 0;
  while (source.next(frame).outcome == FrameOutcome::frame) CHECK(frame.sequence == expected++);
  CHECK(expected == 5);
  CHECK(clock.sleeps == 0);
  CHECK(source.frames_dropped() == 0);
}

TEST_CASE("real-time pacing replays a long gap between timestamps as no gap", "[replay]") {
  // A recording paused for 11.6 days (or a corrupt timestamp): --real-time slept through it.
  const std::string parent = fx::make_test_dir("pacing-gap");
  const fx::TumFixture tum = fx::write_tum(parent, "gap", 4, false);
  std::string list;
  const double times_s[4] = {10.0, 10.05, 1000010.0, 1000010.05};
  for (int i = 0; i < 4; ++i) {
    char line[128];
    std::snprintf(line, sizeof(line), "%.6f depth/%.6f.png\n", times_s[i],
                  tum.timestamps[static_cast<std::size_t>(i)]);
    list += line;
  }
  fx::write_text(tum.dir + "/depth.txt", list);
  ReplayConfig config = config_for("tum:" + tum.dir);
  FakeClock clock;
  config.pacing = Pacing::real_time;
  config.clock.now_us = &FakeClock::now;
  config.clock.sleep_until_us = &FakeClock::sleep_until;
  config.clock.context = &clock;
  ReplaySource source(config);
  {
    const octofuse::Status opened = source.open();
    INFO(source.last_error());
    REQUIRE(opened.ok());
  }
  const std::int64_t start_us = clock.now_us;
  DepthFrame frame;
  for (std::uint64_t i = 0; i < 4; ++i) {
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    CHECK(frame.sequence == i);
  }
  // Waits of 50 ms before frames 1 and 3, none across the gap.
  CHECK(clock.sleeps == 2);
  CHECK(clock.now_us == start_us + 100000);
  CHECK(source.gaps_shortened() == 1);
  CHECK(source.frames_dropped() == 0);
}
