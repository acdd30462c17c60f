// octofuse-replay killed at random moments: whatever files it leaves are complete. SIGKILL (no
// chance to clean up) at seeded random moments of a short sim:desk run, then every file present
// must parse: trajectory.txt a prefix of the uninterrupted run's (byte for byte: the run is
// deterministic), mesh.ply the whole mesh, stats.json whole JSON, render.png ending in its IEND
// chunk, stage_times.svg closed. Temporaries ("*.tmp") are what a kill mid-write leaves; they
// are never read as outputs. SIGTERM finishes the frame and writes everything.
#include <algorithm>
#include <catch2/catch.hpp>
#include <chrono>
#include <cstdio>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "octofuse/ports/host/block_store_file.hpp"
#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/ply.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"
#include "replay_process.hpp"
#include "support/aligned_buffer.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

#ifdef OCTOFUSE_TEST_SANITIZED
constexpr int kKills = 3;
#else
constexpr int kKills = 6;
#endif
constexpr unsigned kSeed = 17;

std::vector<std::string> replay_args(const std::string& out) {
  // The desk path in 20 frames at 2 cm: a few seconds, and every output has content.
  return {"--source", "sim:desk", "--frames", "20",     "--voxel-size",
          "0.02",     "--out",    out,        "--quiet"};
}

bool ends_with(const std::string& text, const std::string& tail) {
  return text.size() >= tail.size() &&
         text.compare(text.size() - tail.size(), tail.size(), tail) == 0;
}

struct Seen {
  bool trajectory = false, mesh = false, stats = false, render = false, plot = false;
};

// Checks every output present in `out` against the uninterrupted run in `reference`.
void check_outputs(const std::string& out, const std::string& reference, Seen* seen) {
  const std::string trajectory = out + "/trajectory.txt";
  if (test::file_exists(trajectory)) {
    seen->trajectory = true;
    const std::string text = test::read_file(trajectory);
    const std::string whole = test::read_file(reference + "/trajectory.txt");
    // Every line whole: a prefix of the full file that ends at a line end (or is empty).
    CHECK(whole.compare(0, text.size(), text) == 0);
    CHECK((text.empty() || text.back() == '\n'));
    std::vector<host::TimedPose> poses;
    ErrorText error;
    CHECK(host::read_tum_trajectory(trajectory.c_str(), &poses, &error).ok());
  }
  const std::string mesh = out + "/mesh.ply";
  if (test::file_exists(mesh)) {
    seen->mesh = true;
    CHECK(test::read_file(mesh) == test::read_file(reference + "/mesh.ply"));
    host::Mesh read;
    ErrorText error;
    CHECK(host::read_ply(mesh.c_str(), &read, &error).ok());
  }
  const std::string stats = out + "/stats.json";
  if (test::file_exists(stats)) {
    seen->stats = true;
    const std::string text = test::read_file(stats);
    CHECK(test::JsonChecker(text).valid());
  }
  const std::string render = out + "/render.png";
  if (test::file_exists(render)) {
    seen->render = true;
    const std::string png = test::read_file(render);
    CHECK(png.compare(0, 8, "\x89PNG\r\n\x1a\n") == 0);
    CHECK(ends_with(png, std::string("IEND\xae\x42\x60\x82", 8)));
  }
  const std::string plot = out + "/stage_times.svg";
  if (test::file_exists(plot)) {
    seen->plot = true;
    CHECK(ends_with(test::read_file(plot), "</svg>\n"));
  }
}

TEST_CASE("octofuse-replay killed at random moments leaves only complete files", "[programs]") {
  const std::string dir = test::make_test_dir("replay-kill");
  REQUIRE(!dir.empty());
  const std::string reference = dir + "/reference";
  const auto start = std::chrono::steady_clock::now();
  const test::RunResult full = test::run_replay(replay_args(reference), dir + "/reference.log");
  const double run_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  INFO(full.output);
  REQUIRE(full.exit_status == 0);
  Seen all;
  check_outputs(reference, reference, &all);
  REQUIRE((all.trajectory && all.mesh && all.stats && all.render && all.plot));

  // Moments spread over the whole run, a little past its usual end (outputs being written).
  std::mt19937 rng(kSeed);
  std::uniform_real_distribution<double> moment(0.0, 1.1 * run_s);
  Seen seen;
  int before_end = 0;
  for (int k = 0; k < kKills; ++k) {
    const std::string out = dir + "/kill" + std::to_string(k);
    const double after_s = moment(rng);
    CAPTURE(k, after_s, run_s);
    const test::Child child = test::start_replay(replay_args(out), out + ".log");
    REQUIRE(child.pid > 0);
    std::this_thread::sleep_for(std::chrono::duration<double>(after_s));
    ::kill(child.pid, SIGKILL);
    const int status = test::wait_for(child);
    CHECK((status == 128 + SIGKILL || status == 0));
    before_end += status == 128 + SIGKILL;
    check_outputs(out, reference, &seen);
  }
  // The kills must have hit runs in progress, or the test proves nothing.
  CHECK(before_end >= kKills / 3);
  CHECK(seen.trajectory);

  // One more as the last trajectory line appears: the mesh, stats and images are being written.
  const std::string out = dir + "/kill-at-end";
  const test::Child child = test::start_replay(replay_args(out), out + ".log");
  REQUIRE(child.pid > 0);
  const std::string whole = test::read_file(reference + "/trajectory.txt");
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(300);
  while (test::read_file(out + "/trajectory.txt").size() != whole.size() &&
         std::chrono::steady_clock::now() < give_up) {
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  ::kill(child.pid, SIGKILL);
  const int status = test::wait_for(child);
  CHECK((status == 128 + SIGKILL || status == 0));
  check_outputs(out, reference, &seen);
  CHECK(test::read_file(out + "/trajectory.txt") == whole);
}

// A store left by a killed run opens (a torn tail dropped with a warning), the blocks in it merge
// into a map that saves and loads, and the free space beside it merges into a tree.
void check_store(const std::string& path, const std::string& map_path) {
  host::BlockStoreFile store;
  ErrorText error;
  ErrorText warning;
  REQUIRE(store.open(path.c_str(), nullptr, 0, &error, &warning).ok());
  host::StoreGeometry geometry;
  REQUIRE(host::decode_store_geometry(store.geometry(), store.geometry_size(), &geometry));
  REQUIRE(geometry.voxel_type == MapVoxelType::multires);
  MapConfig config;
  config.voxel_size_m = geometry.voxel_size_m;
  config.voxel_depth = geometry.voxel_depth;
  config.origin_W = geometry.origin_W;
  std::unique_ptr<host::HeapMap<MultiresVoxel>> merged;
  INFO(error.c_str());
  REQUIRE(host::merge_map_with_store<MultiresVoxel>(nullptr, config, store, path.c_str(), &merged,
                                                    &error)
              .ok());
  REQUIRE(merged->map.block_count() == store.stats().keys);
  MapSaveInfo info;
  info.frames = 1;
  info.mu_m = 0.1f;
  // save_map_file() reads the whole file back as the loader does before it claims success.
  REQUIRE(host::save_map_file(map_path.c_str(), merged->map, info, &error).ok());
  // The free space beside it: every whole region grafts into a tree.
  const std::string free_path = path + ".free";
  if (!test::file_exists(free_path)) return;
  host::BlockStoreFile free_store;
  REQUIRE(free_store.open(free_path.c_str(), nullptr, 0, &error, &warning).ok());
  std::uint8_t expected[host::kFreeStoreGeometryBytes];
  host::encode_free_store_geometry(geometry, expected);
  REQUIRE(free_store.geometry_size() == sizeof(expected));
  REQUIRE(std::equal(expected, expected + sizeof(expected), free_store.geometry()));
  FreeSpaceConfig free_config;
  free_config.node_capacity = 1;
  test::ArenaBuffer memory(FreeSpace::bytes_required(free_config, config, 1, 1));
  FreeSpace empty;
  REQUIRE(empty.reserve(memory.arena(), free_config, config, 1, 1).ok());
  std::unique_ptr<host::HeapFreeSpace> merged_free;
  REQUIRE(
      host::merge_free_space_with_store(empty, free_store, free_path.c_str(), &merged_free, &error)
          .ok());
  REQUIRE(merged_free->space.node_count() >= 1);
}

TEST_CASE("octofuse-replay --map-file killed at random moments leaves a store that loads",
          "[programs][store]") {
  const std::string dir = test::make_test_dir("replay-kill-store");
  REQUIRE(!dir.empty());
  // A map memory for a fraction of the room: blocks are evicted into the store from early on.
  auto args = [&](const std::string& name) {
    return std::vector<std::string>{"--source",
                                    "sim:room",
                                    "--frames",
                                    "40",
                                    "--voxel-size",
                                    "0.02",
                                    "--gt-poses",
                                    "--map-memory",
                                    "1",
                                    "--map-file",
                                    dir + "/" + name + ".store",
                                    "--out",
                                    dir + "/" + name,
                                    "--quiet"};
  };
  const auto start = std::chrono::steady_clock::now();
  const test::RunResult full = test::run_replay(args("reference"), dir + "/reference.log");
  const double run_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  INFO(full.output);
  REQUIRE(full.exit_status == 0);
  check_store(dir + "/reference.store", dir + "/reference.ofmap");
  // At 2 cm the free-space pool is too small for the room: its air is in the store too.
  REQUIRE(test::file_exists(dir + "/reference.store.free"));
  {
    host::BlockStoreFile free_store;
    ErrorText error;
    ErrorText warning;
    REQUIRE(free_store.open((dir + "/reference.store.free").c_str(), nullptr, 0, &error, &warning)
                .ok());
    REQUIRE(free_store.stats().keys > 0);
  }
  std::mt19937 rng(kSeed);
  std::uniform_real_distribution<double> moment(0.2 * run_s, 1.0 * run_s);
  int killed = 0;
  for (int k = 0; k < kKills; ++k) {
    const std::string name = "kill" + std::to_string(k);
    const double after_s = moment(rng);
    CAPTURE(k, after_s, run_s);
    const test::Child child = test::start_replay(args(name), dir + "/" + name + ".log");
    REQUIRE(child.pid > 0);
    std::this_thread::sleep_for(std::chrono::duration<double>(after_s));
    ::kill(child.pid, SIGKILL);
    const int status = test::wait_for(child);
    CHECK((status == 128 + SIGKILL || status == 0));
    killed += status == 128 + SIGKILL;
    if (test::file_exists(dir + "/" + name + ".store")) {
      check_store(dir + "/" + name + ".store", dir + "/" + name + ".ofmap");
    }
  }
  CHECK(killed >= kKills / 3);
}

TEST_CASE("octofuse-replay on SIGTERM finishes the frame and writes everything", "[programs]") {
  const std::string dir = test::make_test_dir("replay-term");
  REQUIRE(!dir.empty());
  const std::string out = dir + "/out";
  const test::Child child = test::start_replay(
      {"--source", "sim:desk", "--frames", "300", "--voxel-size", "0.02", "--out", out, "--quiet"},
      dir + "/log.txt");
  REQUIRE(child.pid > 0);
  // Wait until a few frames are in trajectory.txt (one line each, after the "#" header).
  for (int i = 0; i < 1200; ++i) {
    const std::string text = test::read_file(out + "/trajectory.txt");
    if (std::count(text.begin(), text.end(), '\n') >= 4) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ::kill(child.pid, SIGTERM);
  const int status = test::wait_for(child);
  const std::string log = test::read_file(dir + "/log.txt");
  INFO(log);
  CHECK(status == 128 + SIGTERM);
  CHECK(log.find("stopped by SIGTERM after ") != std::string::npos);
  std::vector<host::TimedPose> poses;
  ErrorText error;
  REQUIRE(host::read_tum_trajectory((out + "/trajectory.txt").c_str(), &poses, &error).ok());
  CHECK(poses.size() >= 3);
  CHECK(poses.size() < 300);
  // Everything written, and it agrees with the trajectory.
  host::Mesh mesh;
  CHECK(host::read_ply((out + "/mesh.ply").c_str(), &mesh, &error).ok());
  CHECK(!mesh.vertices.empty());
  const std::string stats = test::read_file(out + "/stats.json");
  CHECK(test::JsonChecker(stats).valid());
  CHECK(stats.find("\"frames\":" + std::to_string(poses.size()) + ",") != std::string::npos);
  CHECK(test::file_exists(out + "/render.png"));
  CHECK(test::file_exists(out + "/stage_times.svg"));
}

}  // namespace
}  // namespace octofuse
