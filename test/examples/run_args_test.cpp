// The command line and configuration files of octofuse-replay/-live: one option table for both,
// the command line over the file, errors that name the file and line, --print-config round trips.

#include <catch2/catch.hpp>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include "config_file.hpp"
#include "run_args.hpp"
#include "support/test_dir.hpp"

using namespace octofuse;
using namespace octofuse::examples;

namespace {

// argv for parse_run_args from a list of words (argv[0] is the program).
struct Argv {
  explicit Argv(std::vector<std::string> words) : storage(std::move(words)) {
    storage.insert(storage.begin(), "octofuse-replay");
    for (std::string& word : storage) pointers.push_back(&word[0]);
  }
  int argc() const { return static_cast<int>(pointers.size()); }
  char** argv() { return pointers.data(); }
  std::vector<std::string> storage;
  std::vector<char*> pointers;
};

bool parse(std::vector<std::string> words, RunOptions* options, std::string* error,
           RunArgsRequest* request = nullptr) {
  Argv args(std::move(words));
  RunArgsRequest local;
  return parse_run_args(args.argc(), args.argv(), options, request ? request : &local, error);
}

std::string print(const RunOptions& options) {
  std::string text, error;
  REQUIRE(format_run_config(options, &text, &error));
  return text;
}

std::string write_file(const std::string& name, const std::string& text) {
  const std::string dir = octofuse::test::make_test_dir("run-args");
  REQUIRE(!dir.empty());
  const std::string path = dir + "/" + name;
  std::FILE* file = std::fopen(path.c_str(), "wb");
  REQUIRE(file != nullptr);
  std::fwrite(text.data(), 1, text.size(), file);
  std::fclose(file);
  return path;
}

}  // namespace

TEST_CASE("Every option set on the command line comes back from its printed config",
          "[examples][config]") {
  RunOptions options;
  std::string error;
  REQUIRE(parse({"--source",
                 "tum:my data/fr1 # desk",
                 "--out",
                 "run 1",
                 "--record",
                 "run 1.mcap",
                 "--map",
                 "single",
                 "--voxel-size",
                 "0.013",
                 "--mu",
                 "0.07",
                 "--band-behind",
                 "0.375",
                 "--allocation-step",
                 "3",
                 "--allocation-group-px",
                 "12.5",
                 "--map-size",
                 "5.5",
                 "--map-memory",
                 "333.3",
                 "--max-blocks",
                 "1234",
                 "--frames",
                 "77",
                 "--threads",
                 "3",
                 "--intrinsics",
                 "525,525.5,319.5,239.25",
                 "--depth-scale",
                 "5000",
                 "--seed",
                 "42",
                 "--budget-new-blocks",
                 "100",
                 "--budget-blocks",
                 "0",
                 "--budget-raycast-steps",
                 "123456789",
                 "--raycast-full",
                 "--icp-quarter",
                 "--icp-full-middle",
                 "--budget-icp",
                 "1,2,3",
                 "--evict",
                 "85,70",
                 "--budget-evict",
                 "50",
                 "--finest-turn",
                 "12",
                 "--gt-poses",
                 "--icp-depth-knee",
                 "0.1",
                 "--bilateral",
                 "--no-noise",
                 "--real-time",
                 "--write-frames",
                 "--no-mesh",
                 "--mesh-scale",
                 "finest",
                 "--quiet",
                 "--serve",
                 "0.0.0.0:8080",
                 "--initial-pose",
                 "1,2,3,0,0,0.6,0.8",
                 "--save-map",
                 "out.ofmap",
                 "--save-every",
                 "9",
                 "--load-map",
                 "in.ofmap",
                 "--map-file",
                 "blocks.store",
                 "--map-file-finest",
                 "off",
                 "--no-free-space",
                 "--esdf-follow",
                 "0.25",
                 "--query-points",
                 "points.txt",
                 "--deadline-ms",
                 "33.5",
                 "--deadline-calibration",
                 "board.cal",
                 "--deadline-freeze"},
                &options, &error));
  const std::string printed = print(options);
  // Nothing left at a default but the odometry options, which exclude --gt-poses (the next test
  // case spells them): every other option is spelled.
  std::string comments;
  std::istringstream lines(printed);
  for (std::string line; std::getline(lines, line);) {
    if (!line.empty() && line[0] == '#') comments += line + "\n";
  }
  CHECK(comments ==
        "# odometry = (default)\n# odometry-mode = (default)\n# odometry-weight = (default)\n"
        "# odometry-noise = (default)\n");
  CHECK(printed.find("voxel-size = 0.013\n") != std::string::npos);
  CHECK(printed.find("band-behind = 0.375\n") != std::string::npos);
  CHECK(printed.find("allocation-step = 3\n") != std::string::npos);
  CHECK(options.allocation_step == 3);
  CHECK(printed.find("allocation-group-px = 12.5\n") != std::string::npos);
  CHECK(options.allocation_group_block_px == 12.5f);
  CHECK(printed.find("intrinsics = 525,525.5,319.5,239.25\n") != std::string::npos);
  CHECK(printed.find("gt-poses = true\n") != std::string::npos);

  RunOptions reread;
  REQUIRE(apply_run_config(printed, "printed", &reread, &error));
  CHECK(print(reread) == printed);
  CHECK(reread.source_spec == "tum:my data/fr1 # desk");
  CHECK(reread.out_dir == "run 1");
  CHECK(reread.map_kind == MapKind::single_res);
  CHECK(reread.voxel_size_m == options.voxel_size_m);
  CHECK(reread.mu_m == options.mu_m);
  CHECK(reread.map_memory_mb == options.map_memory_mb);
  CHECK(reread.max_blocks == 1234u);
  CHECK(reread.max_frames == 77);
  CHECK(reread.source.frames == 77);
  CHECK(reread.threads == 3);
  CHECK(reread.source.have_intrinsics);
  CHECK(reread.source.intrinsics[3] == 239.25);
  CHECK(reread.source.depth_scale == 5000.0);
  CHECK(reread.source.seed == 42u);
  CHECK(reread.budget.max_new_blocks == 100u);
  CHECK(reread.budget.max_integrated_blocks == 0u);
  CHECK(reread.budget.raycast_steps == 123456789u);
  CHECK_FALSE(reread.budget.raycast_half);  // --raycast-full against the default half
  CHECK(reread.icp_quarter);
  CHECK(reread.icp_full_middle);
  CHECK(reread.budget.icp_iterations[2] == 3);
  CHECK(reread.eviction.enabled);
  CHECK(reread.eviction.high_water == 0.85f);
  CHECK(reread.eviction.low_water == 0.7f);
  CHECK(reread.budget.max_evictions == 50u);
  CHECK(reread.eviction.finest_turn_frames == 12u);
  CHECK(reread.pose_source == PoseSource::ground_truth);
  CHECK(reread.icp_depth_knee_m == options.icp_depth_knee_m);
  CHECK(reread.bilateral);
  CHECK_FALSE(reread.source.sim_noise);
  CHECK(reread.source.real_time);
  CHECK(reread.write_frames);
  CHECK_FALSE(reread.write_mesh);
  CHECK(reread.mesh_read_scale == MeshReadScale::finest_fused);
  CHECK_FALSE(reread.progress);
  CHECK(reread.serve == "0.0.0.0:8080");
  CHECK(reread.have_initial_pose);
  CHECK(reread.initial_T_W_C.translation().isApprox(Eigen::Vector3d(1, 2, 3)));
  CHECK(reread.initial_T_W_C.linear().isApprox(options.initial_T_W_C.linear()));
  CHECK(reread.save_map_path == "out.ofmap");
  CHECK(reread.save_every == 9);
  CHECK(reread.load_map_path == "in.ofmap");
  CHECK_FALSE(reread.free_space);
  CHECK(reread.esdf);  // --esdf-follow implies --esdf
  CHECK(reread.esdf_follow_m == 0.25f);
  CHECK(reread.query_points_path == "points.txt");
}

TEST_CASE("The odometry options come back from their printed config", "[examples][config]") {
  RunOptions options;
  std::string error;
  REQUIRE(parse({"--odometry", "vio.txt", "--odometry-mode", "only", "--odometry-weight", "4,0.5",
                 "--odometry-noise", "0.002,0.003"},
                &options, &error));
  const std::string printed = print(options);
  CHECK(printed.find("odometry = vio.txt\n") != std::string::npos);
  CHECK(printed.find("odometry-mode = only\n") != std::string::npos);
  CHECK(printed.find("odometry-weight = 4,0.5\n") != std::string::npos);
  CHECK(printed.find("odometry-noise = 0.002,0.003\n") != std::string::npos);
  RunOptions reread;
  REQUIRE(apply_run_config(printed, "printed", &reread, &error));
  CHECK(print(reread) == printed);
  CHECK(reread.odometry_only);
  CHECK(reread.odometry_information[1] == 0.5);
  CHECK(reread.odometry_noise[0] == 0.002);
  CHECK(reread.odometry_noise[1] == 0.003);
  // Noise values a pipeline cannot use are refused with the option's name.
  for (const char* bad : {"0,0.001", "0.001", "nan,0.001", "0.001,inf", "0.001,-1", "2e3,0.001",
                          "0.001,0.001,0.001", "0.001,0.001x"}) {
    RunOptions refused;
    CAPTURE(bad);
    CHECK_FALSE(parse({"--odometry", "sim", "--odometry-noise", bad}, &refused, &error));
    CHECK(error.find("--odometry-noise") != std::string::npos);
  }
  // Options that need one another are checked wherever they came from.
  RunOptions lonely;
  CHECK_FALSE(parse({"--odometry-mode", "only"}, &lonely, &error));
  CHECK(error == "--odometry-mode needs --odometry");
  RunOptions both;
  CHECK_FALSE(parse({"--odometry", "vio.txt", "--gt-poses"}, &both, &error));
  CHECK(error == "--odometry and --gt-poses exclude each other");
}

TEST_CASE("The defaults print as a config that reads back to the defaults", "[examples][config]") {
  RunOptions defaults;
  const std::string printed = print(defaults);
  CHECK(printed.find("# mu = (default)\n") != std::string::npos);
  CHECK(printed.find("voxel-size = 0.01\n") != std::string::npos);
  CHECK(printed.find("bilateral = false\n") != std::string::npos);
  RunOptions reread;
  reread.source_spec = "openni2";  // what the file says must win over the program's default
  reread.budget.raycast_half = false;
  std::string error;
  const bool applied = apply_run_config(printed, "defaults", &reread, &error);
  INFO(error);
  REQUIRE(applied);
  CHECK(print(reread) == printed);
  CHECK(reread.source_spec == "sim:desk");
  CHECK(reread.mu_m == 0.0f);
  CHECK(reread.budget.raycast_steps == 0u);
  CHECK(reread.budget.raycast_half);  // the default, half resolution
}

TEST_CASE("The command line overrides the config file wherever --config stands",
          "[examples][config]") {
  const std::string path = write_file("deploy.cfg",
                                      "# kitchen board\n\nvoxel-size = 0.02\n   threads = 2\n"
                                      "bilateral = true\nquiet = false\n");
  for (const bool config_first : {true, false}) {
    std::vector<std::string> words = {"--voxel-size", "0.03", "--quiet"};
    words.insert(config_first ? words.begin() : words.end(), {"--config", path});
    RunOptions options;
    std::string error;
    REQUIRE(parse(words, &options, &error));
    CHECK(options.voxel_size_m == 0.03f);  // command line
    CHECK(options.threads == 2);           // file
    CHECK(options.bilateral);              // file flag
    CHECK_FALSE(options.progress);         // command-line flag, the file left it alone
  }
}

TEST_CASE("--print-config after --config prints what the run would use", "[examples][config]") {
  const std::string path = write_file("a.cfg", "map = single\nframes = 10\n");
  RunOptions options;
  RunArgsRequest request;
  std::string error;
  REQUIRE(
      parse({"--print-config", "--config", path, "--frames", "20"}, &options, &error, &request));
  CHECK(request.print_config);
  const std::string printed = print(options);
  CHECK(printed.find("map = single\n") != std::string::npos);
  CHECK(printed.find("frames = 20\n") != std::string::npos);
  // Fed back alone, the printed config gives the same options.
  const std::string again = write_file("b.cfg", printed);
  RunOptions reread;
  REQUIRE(parse({"--config", again}, &reread, &error));
  CHECK(print(reread) == printed);
}

TEST_CASE("Config errors name the file and the line", "[examples][config]") {
  struct Case {
    const char* text;
    const char* error;
  };
  const Case cases[] = {
      {"# comment\n\nfoo = 1\n", "f.cfg:3: unknown key 'foo'"},
      {"voxel-size = 0.01\nvoxel-size = 0.02\n", "f.cfg:2: 'voxel-size' already set on line 1"},
      {"\n\n\nvoxel-size = 2\n", "f.cfg:4: voxel-size needs metres in [0.0001, 1]"},
      {"voxel-size = 0.01cm\n", "f.cfg:1: voxel-size needs metres in [0.0001, 1]"},
      {"voxel-size =\n", "f.cfg:1: voxel-size needs metres in [0.0001, 1]"},
      {"map = octree\n", "f.cfg:1: map must be multires, single or multires16, not 'octree'"},
      {"band-behind = 0\n", "f.cfg:1: band-behind needs a share of mu in [0.01, 1]"},
      {"allocation-step = 0\n", "f.cfg:1: allocation-step needs a count in [1, 16]"},
      {"allocation-step = 17\n", "f.cfg:1: allocation-step needs a count in [1, 16]"},
      {"allocation-group-px = -1\n", "f.cfg:1: allocation-group-px needs pixels in [0, 1000]"},
      {"allocation-group-px = nan\n", "f.cfg:1: allocation-group-px needs pixels in [0, 1000]"},
      {"threads 2\n", "f.cfg:1: expected 'key = value', got 'threads 2'"},
      {"= 2\n", "f.cfg:1: missing key before '='"},
      {"bilateral = yes\n", "f.cfg:1: bilateral takes true or false, not 'yes'"},
      {"--threads = 2\n", "f.cfg:1: unknown key '--threads'"},
      {"config = other.cfg\n", "f.cfg:1: 'config' can only be given on the command line"},
      {"budget-icp = 1,2,3,4\n",
       "f.cfg:1: budget-icp needs three iteration counts A,B,C in [0, 100]"},
  };
  for (const Case& c : cases) {
    RunOptions options;
    std::string error;
    const std::string text = c.text;
    INFO(text);
    CHECK_FALSE(apply_run_config(text, "f.cfg", &options, &error));
    CHECK(error == c.error);
  }
  std::string long_line(5000, 'x');
  RunOptions options;
  std::string error;
  CHECK_FALSE(apply_run_config("out = " + long_line + "\n", "f.cfg", &options, &error));
  CHECK(error == "f.cfg:1: line longer than 4096 bytes");
}

TEST_CASE("A NUL inside a config line is an error, not a cut value", "[examples][config]") {
  std::vector<ConfigEntry> entries;
  std::string error;
  CHECK_FALSE(parse_config_text(std::string("out = a\0b\n", 10), "n.cfg", &entries, &error));
  CHECK(error == "n.cfg:1: NUL byte in line");
}

TEST_CASE("Comments, blank lines, CRLF and blanks around '=' are accepted", "[examples][config]") {
  RunOptions options;
  std::string error;
  REQUIRE(
      apply_run_config("# top\r\n\r\n  \t\n  # indented comment\r\nout =  a # b \r\n"
                       "no-mesh=true\r\ngt-poses = false",
                       "crlf.cfg", &options, &error));
  CHECK(options.out_dir == "a # b");  // no inline comments: '#' is part of a value
  CHECK_FALSE(options.write_mesh);
  CHECK(options.pose_source == PoseSource::track);  // false leaves the default
}

TEST_CASE("Config files that cannot be read give one clear error", "[examples][config]") {
  RunOptions options;
  std::string error;
  CHECK_FALSE(parse({"--config", "/nonexistent/octofuse.cfg"}, &options, &error));
  CHECK(error == "cannot open config file '/nonexistent/octofuse.cfg'");
  CHECK_FALSE(parse({"--config"}, &options, &error));
  CHECK(error == "--config needs a file");
  const std::string path = write_file("c.cfg", "threads = 2\n");
  CHECK_FALSE(parse({"--config", path, "--config", path}, &options, &error));
  CHECK(error == "--config given twice");
  const std::string bad = write_file("bad.cfg", "threads = 2\nthreads = 3\n");
  CHECK_FALSE(parse({"--config", bad}, &options, &error));
  CHECK(error == bad + ":2: 'threads' already set on line 1");
}

TEST_CASE("The command line keeps its spellings and messages", "[examples][config]") {
  RunOptions options;
  std::string error;
  CHECK_FALSE(parse({"--voxel-size"}, &options, &error));
  CHECK(error == "--voxel-size needs metres in [0.0001, 1]");
  CHECK_FALSE(parse({"--source"}, &options, &error));
  CHECK(error == "--source needs a value");
  CHECK_FALSE(parse({"--bogus"}, &options, &error));
  CHECK(error == "unknown option '--bogus' (see --help)");
  CHECK_FALSE(parse({"voxel-size", "0.1"}, &options, &error));
  CHECK(error == "unknown option 'voxel-size' (see --help)");
  CHECK_FALSE(parse({"--budget-blocks", "-1"}, &options, &error));
  CHECK(error == "--budget-blocks needs a count");
  RunArgsRequest request;
  REQUIRE(parse({"--threads", "2", "-h"}, &options, &error, &request));
  CHECK(request.help);
  // A value that looks like an option is still the value.
  REQUIRE(parse({"--out", "--print-config"}, &options, &error, &request));
  CHECK(options.out_dir == "--print-config");
  CHECK_FALSE(request.print_config);
}

TEST_CASE("A value no config line can hold is refused by --print-config", "[examples][config]") {
  RunOptions options;
  options.out_dir = "two\nlines";
  std::string text, error;
  CHECK_FALSE(format_run_config(options, &text, &error));
  CHECK(error.find("--out value") == 0);
  options.out_dir = " padded";
  CHECK_FALSE(format_run_config(options, &text, &error));
}

TEST_CASE("--map takes multires, single and multires16, prints and rereads them",
          "[examples][config]") {
  for (const char* kind : {"multires", "single", "multires16"}) {
    CAPTURE(kind);
    RunOptions options;
    std::string error;
    REQUIRE(parse({"--map", kind}, &options, &error));
    CHECK(std::string(map_option_name(options.map_kind)) == kind);
    const std::string printed = print(options);
    CHECK(printed.find(std::string("map = ") + kind + "\n") != std::string::npos);
    RunOptions reread;
    REQUIRE(apply_run_config(printed, "printed", &reread, &error));
    CHECK(reread.map_kind == options.map_kind);
  }
  RunOptions options;
  std::string error;
  CHECK_FALSE(parse({"--map", "multires8"}, &options, &error));
  CHECK(error.find("must be multires, single or multires16, not 'multires8'") != std::string::npos);
}
