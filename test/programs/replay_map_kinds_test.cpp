// octofuse-replay with the 16-bit map (--map multires16): the whole loop, every output file, and a
// map file that says what it holds and starts the next run with that voxel type.
#include <catch2/catch.hpp>
#include <string>
#include <vector>

#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"
#include "replay_process.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

bool has(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
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

}  // namespace
}  // namespace octofuse
