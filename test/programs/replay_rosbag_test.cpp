// octofuse-replay --source rosbag:FILE: a ROS 1 bag of a recording (written by python3-rosbag,
// in bz2 and lz4 chunks) replays to the recording run's trajectory and mesh, byte for byte; a
// bag cut short replays to its last whole frame with a warning; --list reads it too.

#include <sys/wait.h>

#include <catch2/catch.hpp>
#include <cstdlib>
#include <string>

#include "replay_process.hpp"
#include "support/test_dir.hpp"

TEST_CASE("replay rosbag: a ROS 1 bag of a recording replays bit for bit", "[programs][bag]") {
#if !defined(OCTOFUSE_PYTHON) || !defined(OCTOFUSE_MAKE_ROSBAG)
  WARN("no Python interpreter at configure time: skipping the ROS 1 bag run");
#else
  const std::string dir = octofuse::test::make_test_dir("rosbag");
  const std::string log = dir + "/log.txt";
  const std::string mcap = dir + "/desk.mcap";
  const octofuse::test::RunResult recorded = octofuse::test::run_replay(
      {"--source", "sim:desk", "--frames", "30", "--quiet", "--out", dir + "/a", "--record", mcap},
      log);
  INFO(recorded.output);
  REQUIRE(recorded.exit_status == 0);
  // The recording's messages, converted to ROS 1 and written by ROS 1's own writer.
  const std::string batch = dir + "/batch.txt";
  octofuse::test::write_text(batch, mcap + " " + dir + "/desk-bz2.bag --compression bz2\n" + mcap +
                                        " " + dir + "/desk-lz4.bag --compression lz4\n");
  const int rc = std::system(
      (std::string(OCTOFUSE_PYTHON) + " " + OCTOFUSE_MAKE_ROSBAG + " --batch " + batch).c_str());
  if (rc >= 0 && WEXITSTATUS(rc) == 77) {
    WARN("python3-rosbag or python3-roslz4 missing: skipping the ROS 1 bag run");
    return;
  }
  REQUIRE(rc == 0);
  const std::string trajectory = octofuse::test::read_bytes(dir + "/a/trajectory.txt");
  const std::string mesh = octofuse::test::read_bytes(dir + "/a/mesh.ply");
  REQUIRE(trajectory.size() > 30 * 40);
  for (const char* compression : {"bz2", "lz4"}) {
    INFO(compression);
    const std::string bag = dir + "/desk-" + compression + ".bag";
    const std::string out = dir + "/" + compression;
    const octofuse::test::RunResult run =
        octofuse::test::run_replay({"--source", "rosbag:" + bag, "--quiet", "--out", out}, log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("cut short") == std::string::npos);
    CHECK(octofuse::test::read_bytes(out + "/trajectory.txt") == trajectory);
    CHECK(octofuse::test::read_bytes(out + "/mesh.ply") == mesh);
  }
  {  // the bag's poses as the odometry prior
    const std::string bag = dir + "/desk-lz4.bag";
    const octofuse::test::RunResult run =
        octofuse::test::run_replay({"--source", "rosbag:" + bag, "--odometry", "rosbag:" + bag,
                                    "--quiet", "--out", dir + "/d"},
                                   log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("odometry: 0 frames without it") != std::string::npos);
  }
  {  // a bag cut part way: the lz4 chunk (about 768 kB) the cut went through is lost
    const std::string bytes = octofuse::test::read_bytes(dir + "/desk-lz4.bag");
    const std::string cut = dir + "/cut.bag";
    octofuse::test::write_text(cut, bytes.substr(0, bytes.size() * 2 / 3));
    const octofuse::test::RunResult run = octofuse::test::run_replay(
        {"--source", "rosbag:" + cut, "--quiet", "--out", dir + "/c"}, log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("warning: " + cut + ": bag cut short at byte") != std::string::npos);
    const std::string part = octofuse::test::read_bytes(dir + "/c/trajectory.txt");
    CHECK(part.size() > 4 * 40);
    CHECK(part.size() < trajectory.size());
    CHECK(trajectory.compare(0, part.size(), part) == 0);
  }
  {  // --list tells the formats apart by their magic
    const octofuse::test::RunResult run =
        octofuse::test::run_replay({"--list", dir + "/desk-bz2.bag"}, log);
    CHECK(run.exit_status == 0);
    CHECK(run.output.find("/camera/depth/image_raw") != std::string::npos);
    CHECK(run.output.find("sensor_msgs/CameraInfo") != std::string::npos);
    CHECK(run.output.find("geometry_msgs/PoseStamped") != std::string::npos);
  }
  {  // not a ROS 1 bag: one error line
    const octofuse::test::RunResult run = octofuse::test::run_replay(
        {"--source", "rosbag:" + mcap, "--quiet", "--out", dir + "/e"}, log);
    CHECK(run.exit_status != 0);
    CHECK(run.output.find("not a ROS 1 bag") != std::string::npos);
  }
#endif
}
