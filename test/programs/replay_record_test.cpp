// octofuse-replay --record: the bag it writes replays to the same trajectory and mesh, bit for
// bit; a recording cut short (a killed recorder) replays to its last whole frame with a warning;
// the --odometry a run was given, recorded, replays as its odometry to the same run.

#include <sys/wait.h>

#include <catch2/catch.hpp>
#include <cstdlib>
#include <string>

#include "replay_process.hpp"
#include "support/test_dir.hpp"

TEST_CASE("replay --record: the recording replays bit for bit", "[programs][bag]") {
  const std::string dir = octofuse::test::make_test_dir("record");
  const std::string bag = dir + "/desk.mcap";
  const std::string log = dir + "/log.txt";
  const octofuse::test::RunResult recorded = octofuse::test::run_replay(
      {"--source", "sim:desk", "--frames", "30", "--quiet", "--out", dir + "/a", "--record", bag},
      log);
  INFO(recorded.output);
  REQUIRE(recorded.exit_status == 0);
  CHECK(recorded.output.find("recorded 30 frames") != std::string::npos);

  const octofuse::test::RunResult replayed =
      octofuse::test::run_replay({"--source", "mcap:" + bag, "--quiet", "--out", dir + "/b"}, log);
  INFO(replayed.output);
  REQUIRE(replayed.exit_status == 0);
  const std::string trajectory = octofuse::test::read_bytes(dir + "/a/trajectory.txt");
  CHECK(trajectory.size() > 30 * 40);
  CHECK(trajectory == octofuse::test::read_bytes(dir + "/b/trajectory.txt"));
  CHECK(octofuse::test::read_bytes(dir + "/a/mesh.ply") ==
        octofuse::test::read_bytes(dir + "/b/mesh.ply"));

  {  // cut short: a warning, and the frames before the cut
    const std::string bytes = octofuse::test::read_bytes(bag);
    const std::string cut = dir + "/cut.mcap";
    octofuse::test::write_text(cut, bytes.substr(0, bytes.size() * 2 / 3));
    const octofuse::test::RunResult run = octofuse::test::run_replay(
        {"--source", "mcap:" + cut, "--quiet", "--out", dir + "/c"}, log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("warning: " + cut + ": bag cut short at byte") != std::string::npos);
    const std::string part = octofuse::test::read_bytes(dir + "/c/trajectory.txt");
    CHECK(part.size() > 10 * 40);
    CHECK(trajectory.compare(0, part.size(), part) == 0);
  }
  {  // the recording's poses as the odometry prior of a replay of it
    const octofuse::test::RunResult run = octofuse::test::run_replay(
        {"--source", "mcap:" + bag, "--odometry", "mcap:" + bag, "--quiet", "--out", dir + "/d"},
        log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("odometry: 0 frames without it") != std::string::npos);
  }
  {  // recording over the bag being replayed is refused, and the bag is left alone
    const octofuse::test::RunResult run = octofuse::test::run_replay(
        {"--source", "mcap:" + bag, "--record", bag, "--quiet", "--out", dir + "/e"}, log);
    CHECK(run.exit_status == 1);
    CHECK(run.output.find("is the file of --source; refusing to overwrite it") !=
          std::string::npos);
    CHECK(octofuse::test::read_bytes(bag).size() > 1000000);
  }
  {  // --list prints the topics
    const octofuse::test::RunResult run = octofuse::test::run_replay({"--list", bag}, log);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("/camera/depth/image_raw") != std::string::npos);
    CHECK(run.output.find("sensor_msgs/msg/CameraInfo") != std::string::npos);
    CHECK(run.output.find("time span 0.967 s") != std::string::npos);
  }
}

TEST_CASE("replay --record --odometry: the recorded odometry replays bit for bit",
          "[programs][bag]") {
  const std::string dir = octofuse::test::make_test_dir("record-odometry");
  const std::string bag = dir + "/desk.mcap";
  const std::string log = dir + "/log.txt";
  const octofuse::test::RunResult recorded =
      octofuse::test::run_replay({"--source", "sim:desk", "--frames", "30", "--odometry", "sim",
                                  "--quiet", "--out", dir + "/a", "--record", bag},
                                 log);
  INFO(recorded.output);
  REQUIRE(recorded.exit_status == 0);
  {  // the odometry is a topic of its own, beside the ground truth
    const octofuse::test::RunResult run = octofuse::test::run_replay({"--list", bag}, log);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("/odom                                    nav_msgs/msg/Odometry") !=
          std::string::npos);
    CHECK(run.output.find("/ground_truth") != std::string::npos);
  }
  const std::string trajectory = octofuse::test::read_bytes(dir + "/a/trajectory.txt");
  const std::string odometry = octofuse::test::read_bytes(dir + "/a/odometry.txt");
  REQUIRE(trajectory.size() > 30 * 40);
  REQUIRE(odometry.size() > 30 * 40);
  // The drifting odometry is not the ground truth: the prior it gives is its own.
  CHECK(odometry != trajectory);
  // The recording as source (ground truth: /ground_truth) and as odometry (/odom): the run that
  // recorded it, byte for byte; with the topic named, the same.
  for (const std::string& spec : {"mcap:" + bag, "mcap:" + bag + "?pose=/odom"}) {
    INFO(spec);
    const std::string out = dir + (spec.find('?') == std::string::npos ? "/b" : "/c");
    const octofuse::test::RunResult run = octofuse::test::run_replay(
        {"--source", "mcap:" + bag, "--odometry", spec, "--quiet", "--out", out}, log);
    INFO(run.output);
    REQUIRE(run.exit_status == 0);
    CHECK(run.output.find("odometry: 0 frames without it") != std::string::npos);
    CHECK(octofuse::test::read_bytes(out + "/trajectory.txt") == trajectory);
    CHECK(octofuse::test::read_bytes(out + "/odometry.txt") == odometry);
    CHECK(octofuse::test::read_bytes(out + "/mesh.ply") ==
          octofuse::test::read_bytes(dir + "/a/mesh.ply"));
  }
#if defined(OCTOFUSE_PYTHON) && defined(OCTOFUSE_MAKE_ROSBAG)
  {  // converted to a ROS 1 bag by ROS 1's own writer (Odometry as nav_msgs/Odometry): the same
    const std::string ros1 = dir + "/desk.bag";
    const int rc = std::system((std::string(OCTOFUSE_PYTHON) + " " + OCTOFUSE_MAKE_ROSBAG + " " +
                                bag + " " + ros1 + " --compression lz4")
                                   .c_str());
    if (rc >= 0 && WEXITSTATUS(rc) == 77) {
      WARN("python3-rosbag or python3-roslz4 missing: skipping the ROS 1 run");
    } else {
      REQUIRE(rc == 0);
      const octofuse::test::RunResult run =
          octofuse::test::run_replay({"--source", "rosbag:" + ros1, "--odometry", "rosbag:" + ros1,
                                      "--quiet", "--out", dir + "/e"},
                                     log);
      INFO(run.output);
      REQUIRE(run.exit_status == 0);
      CHECK(octofuse::test::read_bytes(dir + "/e/trajectory.txt") == trajectory);
      CHECK(octofuse::test::read_bytes(dir + "/e/odometry.txt") == odometry);
    }
  }
#endif
  {  // without the odometry the replay tracks differently: the test above sees the prior
    const octofuse::test::RunResult run = octofuse::test::run_replay(
        {"--source", "mcap:" + bag, "--quiet", "--out", dir + "/d"}, log);
    REQUIRE(run.exit_status == 0);
    CHECK(octofuse::test::read_bytes(dir + "/d/trajectory.txt") != trajectory);
  }
}
