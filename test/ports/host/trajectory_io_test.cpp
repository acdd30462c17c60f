#include "octofuse/ports/host/trajectory_io.hpp"

#include <catch2/catch.hpp>
#include <cstdio>
#include <fstream>
#include <random>

#include "support/test_dir.hpp"

using octofuse::ErrorText;
using octofuse::Se3d;
using octofuse::StatusCode;
using octofuse::host::TimedPose;
using octofuse::test::write_text;

namespace {

constexpr double kTolerance_m = 1e-8;
constexpr double kRotationTolerance = 1e-8;

std::vector<TimedPose> random_trajectory(int count, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  std::vector<TimedPose> poses;
  for (int i = 0; i < count; ++i) {
    TimedPose pose;
    pose.timestamp_s = 1305031102.175304 + i / 30.0;
    Eigen::Quaterniond q(uniform(rng), uniform(rng), uniform(rng), uniform(rng));
    pose.T_W_C.linear() = q.normalized().toRotationMatrix();
    pose.T_W_C.translation() = Eigen::Vector3d(uniform(rng), uniform(rng), uniform(rng)) * 3.0;
    poses.push_back(pose);
  }
  return poses;
}

}  // namespace

TEST_CASE("TUM trajectory round trip keeps poses and timestamps", "[host][trajectory]") {
  const std::string dir = octofuse::test::make_test_dir("traj");
  REQUIRE(!dir.empty());
  const std::string path = dir + "/trajectory.txt";
  const std::vector<TimedPose> written = random_trajectory(50, 7);
  ErrorText error;
  REQUIRE(octofuse::host::write_tum_trajectory(path.c_str(), written, &error).ok());
  std::vector<TimedPose> read;
  REQUIRE(octofuse::host::read_tum_trajectory(path.c_str(), &read, &error).ok());
  REQUIRE(read.size() == written.size());
  for (std::size_t i = 0; i < read.size(); ++i) {
    CHECK(read[i].timestamp_s == Approx(written[i].timestamp_s).margin(1e-6));
    CHECK((read[i].T_W_C.translation() - written[i].T_W_C.translation()).norm() < kTolerance_m);
    CHECK((read[i].T_W_C.linear() - written[i].T_W_C.linear()).norm() < kRotationTolerance);
  }
}

TEST_CASE("TUM trajectory reader reports the file and line of bad input", "[host][trajectory]") {
  const std::string dir = octofuse::test::make_test_dir("traj-bad");
  std::vector<TimedPose> poses;
  ErrorText error;

  SECTION("missing file") {
    const std::string path = dir + "/missing.txt";
    CHECK(octofuse::host::read_tum_trajectory(path.c_str(), &poses, &error) ==
          StatusCode::unavailable);
    CHECK(std::string(error.c_str()).find("missing.txt") != std::string::npos);
  }
  SECTION("too few numbers") {
    const std::string path = dir + "/short.txt";
    write_text(path, "# comment\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0\n");
    CHECK(octofuse::host::read_tum_trajectory(path.c_str(), &poses, &error) ==
          StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("short.txt:3") != std::string::npos);
  }
  SECTION("zero quaternion") {
    const std::string path = dir + "/zeroq.txt";
    write_text(path, "1.0 0 0 0 0 0 0 0\n");
    CHECK(octofuse::host::read_tum_trajectory(path.c_str(), &poses, &error) ==
          StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("quaternion") != std::string::npos);
  }
  SECTION("a line cut short or with junk after it") {
    // A cut inside the last number leaves 8 numbers but not a unit quaternion.
    for (const char* text :
         {"1.0 0 0 0 0 0 0.7071068 0.", "1.0 0 0 0 0 0 0 1 junk\n", "1.0 0 0 0 0 0 0 1 2\n"}) {
      CAPTURE(text);
      const std::string path = dir + "/cut.txt";
      write_text(path, text);
      CHECK(octofuse::host::read_tum_trajectory(path.c_str(), &poses, &error) ==
            StatusCode::data_loss);
      CHECK(std::string(error.c_str()).find("cut.txt:1") != std::string::npos);
    }
  }
  SECTION("a line too long for the reader") {
    const std::string path = dir + "/long.txt";
    const std::string text = "#" + std::string(2000, 'x') + "\n1.0 0 0 0 0 0 0 1\n";
    write_text(path, text.c_str());
    CHECK(octofuse::host::read_tum_trajectory(path.c_str(), &poses, &error) ==
          StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("long.txt:1: line longer than") != std::string::npos);
  }
  SECTION("timestamps going backwards") {
    const std::string path = dir + "/back.txt";
    write_text(path, "2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n");
    CHECK(octofuse::host::read_tum_trajectory(path.c_str(), &poses, &error) ==
          StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("backwards") != std::string::npos);
  }
}

TEST_CASE("TUM trajectory writer appends one line per pose", "[host][trajectory]") {
  const std::string dir = octofuse::test::make_test_dir("traj-stream");
  const std::string path = dir + "/t.txt";
  octofuse::host::TumTrajectoryWriter writer;
  TimedPose pose;
  CHECK(writer.append(pose) == StatusCode::failed_precondition);
  REQUIRE(writer.open(path.c_str()).ok());
  pose.timestamp_s = 0.5;
  pose.T_W_C.translation() = Eigen::Vector3d(1.0, 2.0, 3.0);
  REQUIRE(writer.append(pose).ok());
  REQUIRE(writer.close().ok());
  std::ifstream in(path);
  std::string header, line;
  std::getline(in, header);
  std::getline(in, line);
  CHECK(header[0] == '#');
  CHECK(line == "0.500000 1 2 3 0 0 0 1");
}

TEST_CASE("TUM trajectory writer: each appended line is in the file before close",
          "[host][trajectory]") {
  // What a process killed mid-run leaves: every line appended so far, each whole.
  const std::string dir = octofuse::test::make_test_dir("traj-flush");
  const std::string path = dir + "/t.txt";
  const std::vector<TimedPose> poses = random_trajectory(5, 7);
  octofuse::host::TumTrajectoryWriter writer;
  REQUIRE(writer.open(path.c_str()).ok());
  for (std::size_t i = 0; i < poses.size(); ++i) {
    REQUIRE(writer.append(poses[i]).ok());
    std::vector<TimedPose> on_disk;
    ErrorText error;
    REQUIRE(octofuse::host::read_tum_trajectory(path.c_str(), &on_disk, &error).ok());
    REQUIRE(on_disk.size() == i + 1);
    CHECK(on_disk[i].timestamp_s == Approx(poses[i].timestamp_s).margin(1e-6));
    CHECK((on_disk[i].T_W_C.translation() - poses[i].T_W_C.translation()).norm() < 1e-6);
  }
  REQUIRE(writer.close().ok());
}
