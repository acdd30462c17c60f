// octofuse-replay on bad input: each case ends with a clear one-line "error:" and a non-zero exit,
// or is skipped with a warning and counted; exit 0 only when the run produced what it claims.
// Recordings are written here from the noiseless sim:desk (VGA, millimetres, exact poses).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstdio>
#include <string>
#include <vector>

#include "octofuse/ports/host/png_writer.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "replay_process.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

constexpr int kFrames = 10;

struct Recording {
  std::string dir;
  PinholeCamera camera;
};

std::string matrix_text(const Eigen::Matrix4d& T) {
  std::string text;
  char line[160];
  for (int r = 0; r < 4; ++r) {
    std::snprintf(line, sizeof(line), "%.17g %.17g %.17g %.17g\n", T(r, 0), T(r, 1), T(r, 2),
                  T(r, 3));
    text += line;
  }
  return text;
}

void write_text(const std::string& path, const std::string& text) {
  std::FILE* file = std::fopen(path.c_str(), "w");
  REQUIRE(file != nullptr);
  std::fputs(text.c_str(), file);
  std::fclose(file);
}

// DIR/frame-NNNNNN.depth.png and .pose.txt, camera-intrinsics.txt: a 7-Scenes folder.
Recording write_seven_scenes(const std::string& parent, const char* name) {
  Recording recording;
  recording.dir = parent + "/" + name;
  REQUIRE(::mkdir(recording.dir.c_str(), 0755) == 0);
  sim::SimConfig config;
  config.noise.enabled = false;
  sim::SimSource source(config);
  REQUIRE(source.open().ok());
  recording.camera = source.intrinsics();
  char text[256];
  std::snprintf(text, sizeof(text), "%.9g 0 %.9g\n0 %.9g %.9g\n0 0 1\n",
                static_cast<double>(recording.camera.fx), static_cast<double>(recording.camera.cx),
                static_cast<double>(recording.camera.fy), static_cast<double>(recording.camera.cy));
  write_text(recording.dir + "/camera-intrinsics.txt", text);
  for (int i = 0; i < kFrames; ++i) {
    DepthFrame frame;
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    REQUIRE(frame.metres_per_unit == Approx(0.001f));
    char stem[64];
    std::snprintf(stem, sizeof(stem), "/frame-%06d", i);
    ErrorText error;
    REQUIRE(host::write_png_gray16((recording.dir + stem + ".depth.png").c_str(), frame.depth_raw,
                                   &error)
                .ok());
    write_text(recording.dir + stem + ".pose.txt", matrix_text(frame.T_W_C_ground_truth));
  }
  return recording;
}

bool has(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

// The one "error:" line of a failed run.
std::string error_line(const test::RunResult& run) {
  const std::vector<std::string> errors = test::lines_starting(run.output, "error: ");
  REQUIRE(errors.size() == 1);
  return errors.front();
}

std::size_t trajectory_poses(const std::string& path) {
  std::vector<host::TimedPose> poses;
  ErrorText error;
  REQUIRE(host::read_tum_trajectory(path.c_str(), &poses, &error).ok());
  return poses.size();
}

TEST_CASE("octofuse-replay: bad command lines end before any output", "[programs]") {
  const std::string dir = test::make_test_dir("replay-cli");
  const std::string log = dir + "/log.txt";
  SECTION("--out with an empty name") {
    const test::RunResult run = test::run_replay({"--out", "", "--frames", "2"}, log);
    CHECK(run.exit_status == 2);
    CHECK(error_line(run) == "error: --out needs a folder name");
    CHECK_FALSE(has(run.output, "wrote"));
  }
  SECTION("--budget-icp 0,0,0") {
    const test::RunResult run =
        test::run_replay({"--budget-icp", "0,0,0", "--out", dir + "/out"}, log);
    CHECK(run.exit_status == 2);
    CHECK(has(error_line(run), "--budget-icp 0,0,0 would track nothing"));
    CHECK_FALSE(test::file_exists(dir + "/out"));
  }
  SECTION("--budget-icp with trailing junk") {
    const test::RunResult run = test::run_replay({"--budget-icp", "4,5,10x"}, log);
    CHECK(run.exit_status == 2);
    CHECK(has(error_line(run), "--budget-icp needs three iteration counts"));
  }
  SECTION("--deadline-ms NaN") {
    const test::RunResult run =
        test::run_replay({"--deadline-ms", "nan", "--out", dir + "/out"}, log);
    CHECK(run.exit_status == 2);
    CHECK(error_line(run) == "error: --deadline-ms needs milliseconds in [0, 10000] (0: off)");
    CHECK_FALSE(test::file_exists(dir + "/out"));
  }
  SECTION("--deadline-freeze without a calibration file") {
    const test::RunResult run = test::run_replay({"--deadline-ms", "33", "--deadline-freeze"}, log);
    CHECK(run.exit_status == 2);
    CHECK(error_line(run) == "error: --deadline-freeze needs --deadline-calibration FILE");
  }
  SECTION("a corrupt deadline calibration") {
    const std::string calibration = dir + "/corrupt.cal";
    write_text(calibration, "fixed_ms = 3\nsafety = 1e400\n");
    const test::RunResult run =
        test::run_replay({"--deadline-ms", "33", "--deadline-calibration", calibration, "--out",
                          dir + "/out", "--frames", "2"},
                         log);
    CHECK(run.exit_status == 1);
    CHECK(error_line(run) ==
          "error: " + calibration + ":2: safety needs a number in [1, 16], not '1e400'");
    CHECK_FALSE(test::file_exists(dir + "/out"));
  }
}

TEST_CASE("octofuse-replay: output paths are checked before the first frame", "[programs]") {
  const std::string dir = test::make_test_dir("replay-outputs");
  const std::string log = dir + "/log.txt";
  const std::string out = dir + "/out";
  // Each case: one error line naming the option, exit 1, and nothing written, not even --out.
  auto expect_refused = [&](std::vector<std::string> args, const std::string& what) {
    for (const char* a : {"--frames", "2", "--voxel-size", "0.04", "--quiet", "--out"}) {
      args.push_back(a);
    }
    args.push_back(out);
    const test::RunResult run = test::run_replay(args, log);
    INFO(run.output);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run), what));
    CHECK_FALSE(test::file_exists(out));
  };
  SECTION("a map in a missing folder, over a folder, in /proc, over a device") {
    expect_refused({"--save-map", dir + "/missing/m.ofmap"}, "--save-map: ");
    expect_refused({"--save-map", dir}, "is a folder, not a regular file");
    expect_refused({"--save-map", "/proc/octofuse.ofmap"}, "--save-map: /proc/octofuse.ofmap");
    expect_refused({"--save-map", "/dev/full"}, "is a character device, not a regular file");
    struct stat st;
    REQUIRE(::stat("/dev/full", &st) == 0);
    CHECK(S_ISCHR(st.st_mode));
    CHECK_FALSE(test::file_exists("/dev/full.tmp"));
  }
  SECTION("a deadline calibration in a missing folder") {
    expect_refused({"--deadline-ms", "30", "--deadline-calibration", dir + "/missing/c.cal"},
                   "--deadline-calibration: ");
  }
  SECTION("a map over one of the run's own inputs or outputs") {
    const std::string odometry = dir + "/odometry.txt";
    write_text(odometry, "0 0 0 0 0 0 0 1\n");
    expect_refused({"--odometry", odometry, "--save-map", odometry}, "is the file of --odometry");
    CHECK(test::read_file(odometry) == "0 0 0 0 0 0 0 1\n");
    REQUIRE(::mkdir(out.c_str(), 0755) == 0);
    write_text(out + "/trajectory.txt", "kept\n");
    const test::RunResult run = test::run_replay(
        {"--frames", "2", "--quiet", "--out", out, "--save-map", out + "/../out/trajectory.txt"},
        log);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run), "is the file of --out's trajectory.txt"));
    CHECK(test::read_file(out + "/trajectory.txt") == "kept\n");
  }
  SECTION("a block store over one of the run's outputs, a folder or a file that is no store") {
    expect_refused({"--map-memory", "1", "--map-file", dir}, "--map-file: ");
    expect_refused({"--map-memory", "1", "--map-file", dir + "/missing/s.store"}, "--map-file: ");
    write_text(dir + "/notes.txt", "keep\n");  // shorter than a store's header
    expect_refused({"--map-memory", "1", "--map-file", dir + "/notes.txt"}, "not a block store");
    CHECK(test::read_file(dir + "/notes.txt") == "keep\n");
    REQUIRE(::mkdir(out.c_str(), 0755) == 0);
    write_text(out + "/trajectory.txt", "kept\n");
    const test::RunResult run =
        test::run_replay({"--frames", "2", "--quiet", "--map-memory", "1", "--out", out,
                          "--map-file", out + "/trajectory.txt"},
                         log);
    INFO(run.output);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run), "is the file of --out's trajectory.txt"));
    CHECK(test::read_file(out + "/trajectory.txt") == "kept\n");
  }
  SECTION("--out naming a file") {
    write_text(dir + "/plain", "x");
    const test::RunResult run =
        test::run_replay({"--frames", "2", "--quiet", "--out", dir + "/plain"}, log);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run), "not a folder"));
  }
}

TEST_CASE("octofuse-replay: a FIFO where a file is read is refused at once", "[programs]") {
  // Opening a FIFO with no writer blocks; every file the program reads is opened without waiting
  // and must be a regular file.
  const std::string dir = test::make_test_dir("replay-fifo");
  const std::string fifo = dir + "/fifo";
  REQUIRE(::mkfifo(fifo.c_str(), 0644) == 0);
  const std::string log = dir + "/log.txt";
  const std::vector<std::vector<std::string>> cases = {
      {"--source", "mcap:" + fifo},
      {"--source", "rosbag:" + fifo},
      {"--source", "raw:" + fifo},
      {"--odometry", fifo},
      {"--load-map", fifo},
      {"--query-points", fifo},
      {"--config", fifo},
      {"--deadline-ms", "30", "--deadline-calibration", fifo, "--deadline-freeze"},
  };
  for (std::vector<std::string> args : cases) {
    CAPTURE(args[0], args[1]);
    for (const char* a : {"--frames", "2", "--voxel-size", "0.04", "--quiet", "--out"}) {
      args.push_back(a);
    }
    args.push_back(dir + "/out");
    const test::RunResult run = test::run_replay(args, log);
    INFO(run.output);
    CHECK(run.exit_status != 0);
    CHECK(run.exit_status < 128);  // an error, not a signal
    CHECK(has(error_line(run), "error: "));
  }
  struct stat st;
  REQUIRE(::stat(fifo.c_str(), &st) == 0);
  CHECK(S_ISFIFO(st.st_mode));
}

TEST_CASE("octofuse-replay: a run that fails before its first frame leaves no output",
          "[programs]") {
  const std::string dir = test::make_test_dir("replay-early");
  const std::string log = dir + "/log.txt";
  const std::string out = dir + "/out";
  SECTION("a malformed --serve address is a bad command line") {
    for (const char* spec : {"abc", "[::1]80", "127.0.0.1:99999", "host.example:80"}) {
      const test::RunResult run =
          test::run_replay({"--serve", spec, "--frames", "2", "--out", out}, log);
      INFO(spec << ": " << run.output);
      CHECK(run.exit_status == 2);
      CHECK(has(error_line(run), "--serve needs"));
      CHECK_FALSE(test::file_exists(out));
    }
  }
  SECTION("a port in use") {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    REQUIRE(fd >= 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof(address)) == 0);
    REQUIRE(::listen(fd, 1) == 0);
    socklen_t length = sizeof(address);
    REQUIRE(::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) == 0);
    const std::string port = std::to_string(ntohs(address.sin_port));
    const test::RunResult run = test::run_replay(
        {"--serve", "127.0.0.1:" + port, "--frames", "2", "--quiet", "--out", out}, log);
    ::close(fd);
    INFO(run.output);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run), "--serve"));
    CHECK_FALSE(test::file_exists(out));
  }
  SECTION("an odometry that starts after the first frame") {
    const std::string odometry = dir + "/late.txt";
    write_text(odometry, "100 0 0 0 0 0 0 1\n101 0 0 0 0 0 0 1\n");
    const test::RunResult run =
        test::run_replay({"--odometry", odometry, "--frames", "2", "--quiet", "--out", out}, log);
    INFO(run.output);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run), "does not cover the first frame"));
    CHECK_FALSE(test::file_exists(out));
  }
}

TEST_CASE("octofuse-replay: maps saved at fine voxel sizes load back", "[programs]") {
  // 5 mm picks 16-voxel free-space octants, which the loader once refused.
  const std::string dir = test::make_test_dir("replay-fine-map");
  const std::string log = dir + "/log.txt";
  const std::string map = dir + "/fine.ofmap";
  const test::RunResult saved =
      test::run_replay({"--frames", "2", "--gt-poses", "--voxel-size", "0.005", "--quiet",
                        "--no-mesh", "--save-map", map, "--out", dir + "/saved"},
                       log);
  INFO(saved.output);
  REQUIRE(saved.exit_status == 0);
  const test::RunResult loaded = test::run_replay(
      {"--frames", "1", "--quiet", "--no-mesh", "--load-map", map, "--out", dir + "/out"}, log);
  INFO(loaded.output);
  CHECK(loaded.exit_status == 0);
  CHECK(test::lines_starting(loaded.output, "error: ").empty());
}

TEST_CASE("octofuse-replay: bad 7-Scenes recordings", "[programs]") {
  const std::string parent = test::make_test_dir("replay-bad-seven");
  const std::string log = parent + "/log.txt";
  const std::string out = parent + "/out";

  SECTION("a frame missing in the middle is skipped and counted") {
    const Recording rec = write_seven_scenes(parent, "gap");
    std::remove((rec.dir + "/frame-000004.depth.png").c_str());
    const test::RunResult run =
        test::run_replay({"--source", "7scenes:" + rec.dir, "--out", out, "--quiet"}, log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    CHECK(has(run.output,
              "warning: skipped a frame: " + rec.dir + "/frame-000004.depth.png: cannot open"));
    CHECK(has(run.output, "9 frames (0 lost, 0 rejected, 1 skipped by the source)"));
    CHECK(trajectory_poses(out + "/trajectory.txt") == 9);
    CHECK(has(test::read_file(out + "/stats.json"), "\"frames_skipped_by_source\":1"));
  }
  SECTION("absurd intrinsics are refused before any output") {
    const Recording rec = write_seven_scenes(parent, "intrinsics");
    write_text(rec.dir + "/camera-intrinsics.txt", "5 0 320\n0 5 240\n0 0 1\n");
    const test::RunResult run =
        test::run_replay({"--source", "7scenes:" + rec.dir, "--out", out, "--quiet"}, log);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run),
              "intrinsics fx 5 fy 5 cx 320 cy 240 for 640x480 images: a field "
              "of view of 178.2 x 177.6 degrees"));
    CHECK_FALSE(test::file_exists(out));
  }
  SECTION("a first frame smaller than the rest") {
    const Recording rec = write_seven_scenes(parent, "small");
    const std::vector<std::uint16_t> small(320 * 240, 1500);
    ErrorText error;
    REQUIRE(host::write_png_gray16((rec.dir + "/frame-000000.depth.png").c_str(),
                                   ImageView<const std::uint16_t>(small.data(), 320, 240), &error)
                .ok());
    // The intrinsics are for 640x480: refused at once.
    test::RunResult run =
        test::run_replay({"--source", "7scenes:" + rec.dir, "--out", out, "--quiet"}, log);
    CHECK(run.exit_status == 1);
    CHECK(has(error_line(run),
              "for 320x240 images: the principal point is far from the image "
              "centre (intrinsics for another size?)"));
    CHECK_FALSE(test::file_exists(out));
    // Intrinsics that fit the first frame: every later frame is rejected, and the run says so.
    run = test::run_replay({"--source", "7scenes:" + rec.dir, "--intrinsics", "262,262,160,120",
                            "--out", out, "--quiet"},
                           log);
    CHECK(run.exit_status == 1);
    CHECK(has(run.output, "warning: frame 1 rejected: frame 1: depth is 640x480"));
    CHECK(error_line(run) ==
          "error: 9 of 10 frames lost, rejected or unreadable (0 lost, 9 rejected, 0 unreadable)");
    CHECK(trajectory_poses(out + "/trajectory.txt") == 1);
  }
  SECTION("--gt-poses with poses far outside the map") {
    const Recording rec = write_seven_scenes(parent, "far");
    for (int i = 1; i < kFrames; ++i) {
      char name[64];
      std::snprintf(name, sizeof(name), "/frame-%06d.pose.txt", i);
      Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
      T(0, 3) = 500.0;
      write_text(rec.dir + name, matrix_text(T));
    }
    const test::RunResult run = test::run_replay(
        {"--source", "7scenes:" + rec.dir, "--gt-poses", "--out", out, "--quiet"}, log);
    CHECK(run.exit_status == 1);
    CHECK(has(run.output, "warning: frame 1 fused nothing (its view lies outside the map's cube)"));
    CHECK(error_line(run) == "error: nothing was fused after the first frame (10 frames)");
    // The outputs are still written, for diagnosis.
    CHECK(trajectory_poses(out + "/trajectory.txt") == 10);
    CHECK(has(test::read_file(out + "/stats.json"), "\"frames_unfused\":9"));
  }
  SECTION("a full block pool warns once and tracking goes on against what the map holds") {
    // The first frame wants 396 blocks.
    const Recording rec = write_seven_scenes(parent, "pool");
    const test::RunResult run = test::run_replay(
        {"--source", "7scenes:" + rec.dir, "--max-blocks", "100", "--out", out, "--quiet"}, log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    const std::vector<std::string> warnings = test::lines_starting(run.output, "warning: ");
    REQUIRE(warnings.size() == 1);
    CHECK(warnings.front() ==
          "warning: frame 0: the block pool is full (100 blocks): surface it has no room for "
          "is not mapped (raise --map-memory)");
    CHECK(has(run.output, "10 frames (0 lost, 0 rejected, 0 skipped by the source)"));
  }
  SECTION("a clean recording exits 0 and lists what it wrote") {
    const Recording rec = write_seven_scenes(parent, "clean");
    const test::RunResult run = test::run_replay(
        {"--source", "7scenes:" + rec.dir, "--out", out, "--quiet", "--no-mesh"}, log);
    INFO(run.output);
    CHECK(run.exit_status == 0);
    CHECK(test::lines_starting(run.output, "error: ").empty());
    CHECK(test::lines_starting(run.output, "warning: ").empty());
    CHECK(has(run.output,
              "wrote " + out + "/{trajectory.txt,render.png,stats.json,stage_times.svg}"));
    CHECK_FALSE(test::file_exists(out + "/mesh.ply"));
  }
}

}  // namespace
}  // namespace octofuse
