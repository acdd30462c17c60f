// Poses at each depth image's own stamp. The independent writers (make_bag.py, make_rosbag.py
// --motion) publish an analytic trajectory (constant velocity, constant turn rate) on /tf at
// another rate and offset than the depth images, so that every image falls between two
// transforms; each frame's pose is checked against the trajectory at its stamp.

#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "bag_fixtures.hpp"
#include "octofuse/ports/replay/bag_source.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/small_sim.hpp"

using octofuse::FrameOutcome;
using octofuse::NextFrame;
using octofuse::StatusCode;
using octofuse::replay::BagConfig;
using octofuse::replay::BagSource;
using namespace octofuse::test;

namespace {

constexpr int kFrames = 8;                           // 30 Hz
constexpr std::int64_t kStartUs = 1700000000000000;  // an epoch stamp, as robots record
constexpr std::int64_t kStartNs = kStartUs * 1000;

KeptFrames motion_frames() {
  octofuse::sim::SimConfig config = small_sim(kFrames, false);
  config.start_timestamp_us = kStartUs;
  octofuse::sim::SimSource sim(config);
  REQUIRE(sim.open().ok());
  return keep_frames(sim, kFrames);
}

Eigen::Matrix4d rot_z(double a, const Eigen::Vector3d& p) {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.topRightCorner<3, 1>() = p;
  return T;
}

Eigen::Matrix4d rot_x(double a, const Eigen::Vector3d& p) {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()).toRotationMatrix();
  T.topRightCorner<3, 1>() = p;
  return T;
}

// make_bag.py's motion_edges and BODY_CAMERA: t in seconds after the first image.
Eigen::Matrix4d world_odom(double t) {
  return rot_z(0.7 * t, {0.3 * t, 0.0, 0.0});
}
Eigen::Matrix4d odom_body(double t) {
  return rot_x(-1.1 * t, {0.6 * t, 0.4 * t, -0.1 * t});
}
Eigen::Matrix4d world_body_single(double t) {
  return rot_z(1.5 * t, {0.8 * t, -0.5 * t, 0.2 * t});
}
Eigen::Matrix4d body_camera() {
  Eigen::Matrix4d T;
  T << 0, -1, 0, 0.1, 1, 0, 0, 0, 0, 0, 1, 0.05, 0, 0, 0, 1;
  return T;
}

Eigen::Matrix4d T_W_C_at(bool chain, std::int64_t stamp_ns) {
  const double t = static_cast<double>(stamp_ns - kStartNs) * 1e-9;
  return (chain ? Eigen::Matrix4d(world_odom(t) * odom_body(t)) : world_body_single(t)) *
         body_camera();
}

// The newest stamp of a transform published every `period_ns` from `offset_ns` after the first
// image that is at or before `stamp_ns`.
std::int64_t tf_stamp_before(std::int64_t stamp_ns, std::int64_t offset_ns,
                             std::int64_t period_ns) {
  const std::int64_t since = stamp_ns - kStartNs - offset_ns;
  const std::int64_t k = since >= 0 ? since / period_ns : -((-since + period_ns - 1) / period_ns);
  return kStartNs + offset_ns + k * period_ns;
}

// Translation (m) and rotation (rad) between two poses.
std::pair<double, double> pose_error(const Eigen::Matrix4d& a, const Eigen::Matrix4d& b) {
  const double metres = (a.topRightCorner<3, 1>() - b.topRightCorner<3, 1>()).norm();
  const Eigen::Matrix3d R = a.topLeftCorner<3, 3>().transpose() * b.topLeftCorner<3, 3>();
  const double radians = Eigen::AngleAxisd(R).angle();
  return {metres, radians};
}

std::unique_ptr<BagSource> open_spec(const std::string& spec) {
  BagConfig config;
  octofuse::ErrorText error;
  INFO(spec);
  REQUIRE(octofuse::replay::parse_bag_spec(spec.c_str(), &config, &error).ok());
  auto bag = std::make_unique<BagSource>(config);
  REQUIRE(bag->open().ok());
  return bag;
}

struct Replayed {
  std::vector<std::int64_t> stamps_ns;
  std::vector<Eigen::Matrix4d> poses;
  NextFrame end;
  std::string end_text;
};

bool same_pixels(const octofuse::ImageView<const std::uint16_t>& image, const KeptFrame& kept) {
  for (int y = 0; y < kept.height; ++y) {
    for (int x = 0; x < kept.width; ++x) {
      if (image(x, y) != kept.depth[static_cast<std::size_t>(y) * kept.width + x]) return false;
    }
  }
  return true;
}

// The frames' poses; their pixels checked against `kept`, and each frame still intact when the
// next has been given out (the ring holds 2 valid frames beside the waiting ones).
Replayed replay(BagSource& bag, const KeptFrames& kept) {
  Replayed out;
  octofuse::DepthFrame frame;
  octofuse::ImageView<const std::uint16_t> previous;
  for (std::size_t i = 0;; ++i) {
    const NextFrame next = bag.next(frame);
    if (next.outcome != FrameOutcome::frame) {
      out.end = next;
      out.end_text = bag.last_error();
      return out;
    }
    REQUIRE(i < kept.frames.size());
    CHECK(same_pixels(frame.depth_raw, kept.frames[i]));
    if (i > 0) CHECK(same_pixels(previous, kept.frames[i - 1]));
    previous = frame.depth_raw;
    REQUIRE(frame.has_ground_truth);
    out.stamps_ns.push_back(frame.timestamp_us * 1000);
    out.poses.push_back(frame.T_W_C_ground_truth);
  }
}

// Every frame replayed, each pose the trajectory's (chained or not) at the frame's own stamp.
void check_poses_at_stamps(const Replayed& got, bool chain) {
  REQUIRE(got.poses.size() == static_cast<std::size_t>(kFrames));
  for (int i = 0; i < kFrames; ++i) {
    INFO("frame " << i);
    const auto error = pose_error(got.poses[i], T_W_C_at(chain, got.stamps_ns[i]));
    CHECK(error.first < 1e-6);
    CHECK(error.second < 1e-6);
  }
}

// The bags of both containers for `options` (a ROS 1 one only with python3-rosbag).
std::vector<std::string> motion_bags(Fixture& fixture, const std::string& name,
                                     const std::string& options) {
  std::vector<std::string> specs;
  const std::string mcap = fixture.bag(name + ".mcap", options);
  if (!mcap.empty()) specs.push_back("mcap:" + mcap);
  const std::string ros1 = fixture.rosbag(name + ".bag", options);
  if (!ros1.empty()) specs.push_back("rosbag:" + ros1);
  return specs;
}

}  // namespace

TEST_CASE("bag: each depth image gets the pose at its own stamp (TF at another rate)",
          "[replay][bag][rosbag]") {
  Fixture fixture(motion_frames());
  // /tf at 100 Hz, 3 ms after the image stamps' grid (30 Hz): every image lies between two.
  for (const std::string& spec : motion_bags(fixture, "single", "--motion single")) {
    INFO(spec);
    {
      std::unique_ptr<BagSource> bag = open_spec(spec);
      const Replayed got = replay(*bag, fixture.kept);
      REQUIRE(got.poses.size() == static_cast<std::size_t>(kFrames));
      for (int i = 0; i < kFrames; ++i) {
        INFO("frame " << i);
        CHECK(got.stamps_ns[i] == fixture.kept.frames[i].timestamp_us * 1000);
        const auto error = pose_error(got.poses[i], T_W_C_at(false, got.stamps_ns[i]));
        CHECK(error.first < 1e-6);
        CHECK(error.second < 1e-6);
      }
      CHECK(got.end.status.code() == StatusCode::end_of_stream);
      CHECK(bag->frames_pose_past_end() + bag->frames_pose_not_waited() +
                bag->frames_pose_history_short() ==
            0);
    }
    {  // hold=0: the transforms read so far, as before (each image a TF period stale at most)
      std::unique_ptr<BagSource> bag = open_spec(spec + "?hold=0");
      const Replayed got = replay(*bag, fixture.kept);
      REQUIRE(got.poses.size() == static_cast<std::size_t>(kFrames));
      for (int i = 0; i < kFrames; ++i) {
        INFO("frame " << i);
        const std::int64_t tf_ns = tf_stamp_before(got.stamps_ns[i], 3000000, 10000000);
        CHECK(got.stamps_ns[i] - tf_ns > 0);
        CHECK(got.stamps_ns[i] - tf_ns < 10000000);
        const auto stale = pose_error(got.poses[i], T_W_C_at(false, tf_ns));
        CHECK(stale.first < 1e-6);
        CHECK(stale.second < 1e-6);
        const auto error = pose_error(got.poses[i], T_W_C_at(false, got.stamps_ns[i]));
        CHECK(error.first > 1e-4);  // about 1 m/s times the lag
      }
      CHECK(bag->frames_pose_not_waited() == static_cast<std::uint64_t>(kFrames));
      CHECK(got.end.status.code() == StatusCode::out_of_range);
      CHECK(got.end_text.find("8 frames took the transforms read so far (more than hold=N "
                              "waited)") != std::string::npos);
    }
  }
  // Images logged 25 ms after their stamps (a camera driver's latency): the transforms after
  // the stamp are read before the image, and the table still holds the ones around it.
  for (const std::string& spec :
       motion_bags(fixture, "latency", "--motion single --depth-latency-ms 25")) {
    for (const char* query : {"", "?hold=0"}) {
      INFO(spec << query);
      std::unique_ptr<BagSource> bag = open_spec(spec + query);
      const Replayed got = replay(*bag, fixture.kept);
      check_poses_at_stamps(got, false);
      CHECK(got.end.status.code() == StatusCode::end_of_stream);
    }
  }
}

TEST_CASE("bag: images wait for a slow /tf several at a time (hold=N)", "[replay][bag][rosbag]") {
  Fixture fixture(motion_frames());
  // /tf at 8 Hz: up to 4 images (125 ms at 30 Hz) wait for the transform after their stamps.
  for (const std::string& spec :
       motion_bags(fixture, "slow", "--motion single --tf-hz 8 --tf-offset-ms 3")) {
    INFO(spec);
    {
      std::unique_ptr<BagSource> bag = open_spec(spec);
      const Replayed got = replay(*bag, fixture.kept);  // pixels intact while others wait
      check_poses_at_stamps(got, false);
      CHECK(got.end.status.code() == StatusCode::end_of_stream);
    }
    {  // hold=1: an image that finds another waiting gives the older one the transforms so far
      std::unique_ptr<BagSource> bag = open_spec(spec + "?hold=1");
      const Replayed got = replay(*bag, fixture.kept);
      REQUIRE(got.poses.size() == static_cast<std::size_t>(kFrames));
      std::uint64_t exact = 0;
      for (int i = 0; i < kFrames; ++i) {
        const auto error = pose_error(got.poses[i], T_W_C_at(false, got.stamps_ns[i]));
        exact += error.first < 1e-6 && error.second < 1e-6;
      }
      CHECK(bag->frames_pose_not_waited() > 0);
      CHECK(exact + bag->frames_pose_not_waited() == static_cast<std::uint64_t>(kFrames));
      CHECK(got.end.status.code() == StatusCode::out_of_range);
    }
  }
}

TEST_CASE("bag: images logged long after their stamps need tf_history=N transforms an edge",
          "[replay][bag][rosbag]") {
  Fixture fixture(motion_frames());
  // Images logged 90 ms late against /tf at 1 kHz: 90 transforms of the edge are read after
  // each image's stamp before the image, more than the default 64 an edge keeps.
  for (const std::string& spec :
       motion_bags(fixture, "late", "--motion single --tf-hz 1000 --depth-latency-ms 90")) {
    INFO(spec);
    {
      std::unique_ptr<BagSource> bag = open_spec(spec);
      const Replayed got = replay(*bag, fixture.kept);
      REQUIRE(got.poses.size() == static_cast<std::size_t>(kFrames));
      CHECK(bag->frames_pose_history_short() == static_cast<std::uint64_t>(kFrames));
      // Each took the oldest transform kept, which is after its stamp: not its pose.
      for (int i = 0; i < kFrames; ++i) {
        const auto error = pose_error(got.poses[i], T_W_C_at(false, got.stamps_ns[i]));
        CHECK(error.first > 1e-4);
      }
      CHECK(got.end_text.find("frames older than the transforms kept took the oldest "
                              "(?tf_history=N keeps more)") != std::string::npos);
    }
    {
      std::unique_ptr<BagSource> bag = open_spec(spec + "?tf_history=128");
      const Replayed got = replay(*bag, fixture.kept);
      check_poses_at_stamps(got, false);
      CHECK(bag->frames_pose_history_short() == 0);
      CHECK(got.end.status.code() == StatusCode::end_of_stream);
    }
  }
  // Out of range or not a number: one clear error naming the option.
  for (const char* query :
       {"?tf_history=1", "?tf_history=4097", "?tf_history=", "?tf_history=6x"}) {
    INFO(query);
    BagConfig config;
    octofuse::ErrorText error;
    CHECK(octofuse::replay::parse_bag_spec((std::string("mcap:x.mcap") + query).c_str(), &config,
                                           &error)
              .code() == StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()) == "mcap: tf_history=N needs 2 to 4096 transforms");
  }
  BagConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_bag_spec("rosbag:x.bag?hold=2&tf_history=4096", &config, &error)
              .ok());
  CHECK(config.tf_history == 4096);
  CHECK(config.hold_frames == 2);
}

TEST_CASE("bag: a chain of two moving TF edges at their own rates is taken at the stamp",
          "[replay][bag][rosbag]") {
  Fixture fixture(motion_frames());
  // world -> odom at 100 Hz (+3 ms), odom -> body at 40 Hz (+7 ms), body -> camera static.
  for (const std::string& spec : motion_bags(fixture, "chain", "--motion chain")) {
    INFO(spec);
    std::unique_ptr<BagSource> bag = open_spec(spec);
    const Replayed got = replay(*bag, fixture.kept);
    check_poses_at_stamps(got, true);
    CHECK(got.end.status.code() == StatusCode::end_of_stream);

    // The odometry prior from the same TF (?tf=odom): T_odom_camera at each image's stamp.
    struct Collected {
      std::vector<std::int64_t> stamps_ns;
      std::vector<Eigen::Matrix4d> poses;
    } collected;
    BagConfig config;
    octofuse::ErrorText error, warning;
    REQUIRE(octofuse::replay::parse_bag_spec((spec + "?tf=odom").c_str(), &config, &error).ok());
    REQUIRE(octofuse::replay::read_bag_poses(
                config,
                [](void* context, std::int64_t stamp_ns, const octofuse::Se3d& T) {
                  static_cast<Collected*>(context)->stamps_ns.push_back(stamp_ns);
                  static_cast<Collected*>(context)->poses.push_back(T.matrix());
                },
                &collected, &error, &warning)
                .ok());
    CHECK(warning.c_str()[0] == '\0');
    REQUIRE(collected.poses.size() == static_cast<std::size_t>(kFrames));
    for (int i = 0; i < kFrames; ++i) {
      const std::int64_t stamp_ns = fixture.kept.frames[i].timestamp_us * 1000;
      CHECK(collected.stamps_ns[i] == stamp_ns);
      const double t = static_cast<double>(stamp_ns - kStartNs) * 1e-9;
      const auto e = pose_error(collected.poses[i], odom_body(t) * body_camera());
      CHECK(e.first < 1e-6);
      CHECK(e.second < 1e-6);
    }
  }
}

TEST_CASE("bag: the pose topic's poses are taken at each image's stamp too",
          "[replay][bag][rosbag]") {
  Fixture fixture(motion_frames());
  // nav_msgs/Odometry of the body at 50 Hz (+5 ms), the camera on the body by /tf_static.
  for (const std::string& spec :
       motion_bags(fixture, "odom", "--motion odometry --tf-hz 50 --tf-offset-ms 5")) {
    INFO(spec);
    std::unique_ptr<BagSource> bag = open_spec(spec);
    const Replayed got = replay(*bag, fixture.kept);
    check_poses_at_stamps(got, false);
    CHECK(got.end.status.code() == StatusCode::end_of_stream);
  }
}

TEST_CASE(
    "bag: a bag whose /tf ends before its last images gives them the newest transform and a "
    "warning",
    "[replay][bag][rosbag]") {
  Fixture fixture(motion_frames());
  // /tf stops 50 ms before the last image: the images after its last stamp take it.
  for (const std::string& spec : motion_bags(fixture, "tf_end", "--motion single --tf-end-ms 50")) {
    INFO(spec);
    const std::int64_t last_ns = fixture.kept.frames.back().timestamp_us * 1000;
    const std::int64_t last_tf_ns = tf_stamp_before(last_ns - 50000000, 3000000, 10000000);
    std::unique_ptr<BagSource> bag = open_spec(spec);
    const Replayed got = replay(*bag, fixture.kept);
    REQUIRE(got.poses.size() == static_cast<std::size_t>(kFrames));
    std::uint64_t past = 0;
    for (int i = 0; i < kFrames; ++i) {
      INFO("frame " << i);
      const bool after = got.stamps_ns[i] > last_tf_ns;
      past += after;
      const auto error =
          pose_error(got.poses[i], T_W_C_at(false, after ? last_tf_ns : got.stamps_ns[i]));
      CHECK(error.first < 1e-6);
      CHECK(error.second < 1e-6);
    }
    CHECK(past == 2);  // the images at 200 and 233 ms; /tf's last stamp is 183 ms
    CHECK(bag->frames_pose_past_end() == past);
    CHECK(got.end.status.code() == StatusCode::out_of_range);
    CHECK(got.end_text.find("2 frames past the last /tf took its newest transform") !=
          std::string::npos);

    // The odometry prior from it says the same.
    BagConfig config;
    octofuse::ErrorText error, warning;
    REQUIRE(octofuse::replay::parse_bag_spec((spec + "?tf=world").c_str(), &config, &error).ok());
    int poses = 0;
    REQUIRE(octofuse::replay::read_bag_poses(
                config,
                [](void* context, std::int64_t, const octofuse::Se3d&) {
                  ++*static_cast<int*>(context);
                },
                &poses, &error, &warning)
                .ok());
    CHECK(poses == kFrames);
    CHECK(std::strstr(warning.c_str(), "2 frames past the last /tf took its newest transform") !=
          nullptr);
  }
}
