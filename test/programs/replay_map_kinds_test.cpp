// octofuse-replay with the 16-bit map (--map multires16): the whole loop, every output file, and a
// map file that says what it holds and starts the next run with that voxel type.
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "octofuse/map/voxel_block.hpp"
#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"
#include "replay_process.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

bool has(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

// The number after "key": in a stats.json.
double json_number(const std::string& text, const std::string& key) {
  const std::string tag = "\"" + key + "\":";
  const std::size_t at = text.find(tag);
  REQUIRE(at != std::string::npos);
  return std::strtod(text.c_str() + at + tag.size(), nullptr);
}

std::size_t trajectory_poses(const std::string& path) {
  std::vector<host::TimedPose> poses;
  ErrorText error;
  REQUIRE(host::read_tum_trajectory(path.c_str(), &poses, &error).ok());
  return poses.size();
}

TEST_CASE("octofuse-replay --map multires16 runs end to end and its map file says multires16",
          "[programs][multires16]") {
  const std::string dir = test::make_test_dir("replay-multires16");
  const std::string map_path = dir + "/desk16.ofmap";
  const test::RunResult run =
      test::run_replay({"--map", "multires16", "--frames", "20", "--voxel-size", "0.02", "--out",
                        dir + "/out", "--save-map", map_path, "--quiet"},
                       dir + "/log.txt");
  INFO(run.output);
  REQUIRE(run.exit_status == 0);
  CHECK(trajectory_poses(dir + "/out/trajectory.txt") == 20);
  const std::string stats = test::read_file(dir + "/out/stats.json");
  CHECK(has(stats, "\"map\":\"multires16\""));
  CHECK(test::read_file(dir + "/out/mesh.ply").size() > 1000);
  CHECK(test::file_exists(dir + "/out/render.png"));

  ErrorText error;
  const Result<MapFileHeader> header = host::read_map_file_header(map_path.c_str(), &error);
  REQUIRE(header.ok());
  CHECK(header.value().voxel_type == MapVoxelType::multires16);
  CHECK(header.value().frames == 20);

  // The file decides the voxel type, whatever --map says; the loaded map fuses on.
  const test::RunResult resumed =
      test::run_replay({"--map", "multires", "--load-map", map_path, "--gt-poses", "--frames", "3",
                        "--out", dir + "/resumed", "--quiet"},
                       dir + "/log2.txt");
  INFO(resumed.output);
  REQUIRE(resumed.exit_status == 0);
  CHECK(has(test::read_file(dir + "/resumed/stats.json"), "\"map\":\"multires16\""));
  CHECK(trajectory_poses(dir + "/resumed/trajectory.txt") == 3);
}

TEST_CASE(
    "under a cap a 16-bit map keeps the float map's blocks and spends what it saves on "
    "finest levels",
    "[programs][multires16]") {
  const std::string dir = test::make_test_dir("replay-multires16-cap");
  const auto pools = [&](const char* kind) {
    const std::string out = dir + "/" + kind;
    const test::RunResult run =
        test::run_replay({"--map", kind, "--frames", "2", "--gt-poses", "--voxel-size", "0.01",
                          "--map-memory", "16", "--out", out, "--no-mesh", "--quiet"},
                         dir + "/" + kind + ".log");
    INFO(run.output);
    REQUIRE(run.exit_status == 0);
    return test::read_file(out + "/stats.json");
  };
  const std::string wide = pools("multires");
  const std::string narrow = pools("multires16");
  const double blocks = json_number(wide, "pool_block_capacity");
  CHECK(json_number(narrow, "pool_block_capacity") == blocks);
  CHECK(json_number(narrow, "pool_mid_capacity") == json_number(wide, "pool_mid_capacity"));
  // The cap bounds all the octree reserves (inner nodes, hash and scratch too), and is used.
  const double cap = 16.0 * 1048576.0;
  for (const std::string* stats : {&wide, &narrow}) {
    const double reserved = json_number(*stats, "map_bytes_reserved");
    CHECK(reserved <= cap);
    CHECK(reserved >= 0.99 * cap);
  }
  // Half the bytes go to finest levels; the 16-bit map spends what its blocks and mid levels
  // save on the float's there too, in levels half as large.
  const double mids = json_number(wide, "pool_mid_capacity");
  const double wide_finest = json_number(wide, "pool_finest_capacity");
  const double narrow_finest = json_number(narrow, "pool_finest_capacity");
  using WideBlock = VoxelBlock<MultiresVoxel>;
  using NarrowBlock = VoxelBlock<Multires16Voxel>;
  const double wide_pools = blocks * sizeof(WideBlock) + mids * sizeof(MidLevel<MultiresVoxel>) +
                            wide_finest * sizeof(FinestLevel<MultiresVoxel>);
  const double narrow_pools = blocks * sizeof(NarrowBlock) +
                              mids * sizeof(MidLevel<Multires16Voxel>) +
                              narrow_finest * sizeof(FinestLevel<Multires16Voxel>);
  CHECK(wide_finest * sizeof(FinestLevel<MultiresVoxel>) == Approx(0.5 * wide_pools).epsilon(0.01));
  CHECK(narrow_pools == Approx(wide_pools).epsilon(0.01));
  CHECK(narrow_finest > 2.9 * wide_finest);
}

TEST_CASE("--map-memory bounds all the octree reserves, for every map kind and voxel size",
          "[programs][multires16]") {
  const std::string dir = test::make_test_dir("replay-map-memory-cap");
  struct Setting {
    const char* voxel;
    const char* megabytes;
  };
  int run_index = 0;
  for (const char* kind : {"multires", "multires16", "single"}) {
    for (const Setting& setting : {Setting{"0.01", "1"}, Setting{"0.004", "5"}}) {
      const std::string out = dir + "/run" + std::to_string(run_index++);
      const test::RunResult run = test::run_replay(
          {"--map", kind, "--frames", "2", "--gt-poses", "--voxel-size", setting.voxel,
           "--map-memory", setting.megabytes, "--out", out, "--no-mesh", "--quiet"},
          out + ".log");
      INFO(kind << " " << setting.voxel << " m, " << setting.megabytes << " MB: " << run.output);
      REQUIRE(run.exit_status == 0);
      const std::string stats = test::read_file(out + "/stats.json");
      const double cap = std::atof(setting.megabytes) * 1048576.0;
      const double reserved = json_number(stats, "map_bytes_reserved");
      CHECK(reserved <= cap);
      CHECK(reserved >= 0.98 * cap);
      CHECK(json_number(stats, "pool_block_capacity") >= 100.0);
    }
  }
}

}  // namespace
}  // namespace octofuse
