// The frame deadline in the programs: the calibration file round-trips the cost model bit for
// bit and refuses what it cannot trust, the options refuse bad values with one line, and a run
// with a frozen calibration repeats itself whatever the thread count.

#include "deadline_calibration.hpp"

#include <algorithm>
#include <catch2/catch.hpp>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "run_args.hpp"
#include "runner.hpp"
#include "support/test_dir.hpp"

using namespace octofuse;
using namespace octofuse::examples;

namespace {

CostModel odd_model() {
  CostModel m;
  m.fixed_ms = 3.2000000000000002;  // not the shortest decimal of anything simpler
  m.icp = {0.0, 23.394000000000001};
  m.integrate = {4.1234567890123456, 10.036};
  m.raycast = {6.5, 76.582};
  m.free_space = {1e-7, 456.948};
  m.safety = 1.0000000001;
  return m;
}

bool parse_args(std::vector<std::string> words, RunOptions* options, std::string* error) {
  words.insert(words.begin(), "octofuse-replay");
  std::vector<char*> argv;
  for (std::string& word : words) argv.push_back(&word[0]);
  RunArgsRequest request;
  return parse_run_args(static_cast<int>(argv.size()), argv.data(), options, &request, error);
}

}  // namespace

TEST_CASE("a calibration file gives back the model it was written from, bit for bit",
          "[examples][deadline]") {
  const CostModel model = odd_model();
  const std::string text = format_deadline_calibration(model);
  CostModel back;
  std::string error;
  REQUIRE(parse_deadline_calibration(text, "cal", &back, &error));
  CHECK(std::memcmp(&back, &model, sizeof(CostModel)) == 0);
  CHECK(text.find("raycast_ms_per_mstep = 76.582\n") != std::string::npos);

  const std::string dir = octofuse::test::make_test_dir("deadline-calibration");
  REQUIRE(!dir.empty());
  const std::string path = dir + "/board.cal";
  REQUIRE(write_deadline_calibration(path, model, &error));
  CostModel read;
  REQUIRE(read_deadline_calibration(path, &read, &error));
  CHECK(std::memcmp(&read, &model, sizeof(CostModel)) == 0);
}

TEST_CASE("a calibration file it cannot trust is refused with the file and line",
          "[examples][deadline]") {
  const std::string good = format_deadline_calibration(CostModel{});
  CostModel model;
  std::string error;
  auto refused = [&](const std::string& text) {
    return !parse_deadline_calibration(text, "b.cal", &model, &error);
  };
  CHECK(refused(good + "bogus = 1\n"));
  CHECK(error == "b.cal:12: unknown key 'bogus'");
  CHECK(refused(good + "safety = 1\n"));  // a repeated key
  CHECK(error.find("b.cal:12:") == 0);
  CHECK(refused("fixed_ms = 1\n"));
  CHECK(error == "b.cal: missing icp_fixed_ms");
  for (const char* bad : {"nan", "-1", "inf", "1e7", "", "3 ms"}) {
    CAPTURE(bad);
    std::string text = good;
    const std::size_t at = text.find("integrate_fixed_ms = ");
    const std::size_t end = text.find('\n', at);
    text.replace(at, end - at, std::string("integrate_fixed_ms = ") + bad);
    CHECK(refused(text));
    CHECK(error.find("b.cal:5: integrate_fixed_ms needs a number in [0, 1e6]") == 0);
  }
  for (const char* bad : {"0", "0.5", "17"}) {
    std::string text = good;
    const std::size_t at = text.find("safety = ");
    text.replace(at, std::string::npos, std::string("safety = ") + bad + "\n");
    CHECK(refused(text));
    CHECK(error.find("safety needs a number in [1, 16]") != std::string::npos);
  }
  std::string text = good;
  const std::size_t at = text.find("raycast_ms_per_mstep = ");
  text.replace(at, text.find('\n', at) - at, "raycast_ms_per_mstep = 0");
  CHECK(refused(text));
  CHECK(error.find("raycast_ms_per_mstep needs a number in (0, 1e6]") != std::string::npos);
  CHECK_FALSE(read_deadline_calibration("/nonexistent/octofuse.cal", &model, &error));
  CHECK(error == "cannot read deadline calibration /nonexistent/octofuse.cal");
}

TEST_CASE("the deadline options refuse bad values and missing partners", "[examples][deadline]") {
  RunOptions options;
  std::string error;
  for (const char* bad : {"-1", "nan", "abc", "1e5", ""}) {
    CAPTURE(bad);
    CHECK_FALSE(parse_args({"--deadline-ms", bad}, &options, &error));
    CHECK(error == "--deadline-ms needs milliseconds in [0, 10000] (0: off)");
  }
  CHECK_FALSE(parse_args({"--deadline-calibration", "x.cal"}, &options, &error));
  CHECK(error == "--deadline-calibration needs --deadline-ms D (D > 0)");
  options = RunOptions{};
  CHECK_FALSE(parse_args({"--deadline-ms", "33", "--deadline-freeze"}, &options, &error));
  CHECK(error == "--deadline-freeze needs --deadline-calibration FILE");
  options = RunOptions{};
  CHECK_FALSE(parse_args({"--deadline-ms", "33", "--deadline-calibration", ""}, &options, &error));
  CHECK(error == "--deadline-calibration needs a file");
  options = RunOptions{};
  REQUIRE(parse_args({"--deadline-ms", "0"}, &options, &error));
  CHECK(options.deadline_ms == 0.0);
}

TEST_CASE("a frozen calibration replays the same run with 1 and 2 threads",
          "[examples][deadline][long]") {
  const std::string dir = octofuse::test::make_test_dir("deadline-run");
  REQUIRE(!dir.empty());
  const std::string calibration = dir + "/desk.cal";
  std::remove(calibration.c_str());
  RunOptions options;
  options.source_spec = "sim:desk";
  options.voxel_size_m = 0.02f;
  options.map_memory_mb = 64.0f;
  options.max_frames = 12;
  options.source.frames = 60;  // the first 12 of a 60-frame sequence: slow enough to track
  options.write_mesh = false;
  options.progress = false;
  options.deadline_ms = 40.0;
  options.deadline_calibration = calibration;
  // A learning run writes the calibration (the file did not exist: the defaults started it).
  RunSummary learnt;
  REQUIRE(run_pipeline(options, &learnt) == 0);
  CHECK_FALSE(learnt.deadline_calibration_loaded);
  CostModel written;
  std::string error;
  REQUIRE(read_deadline_calibration(calibration, &written, &error));
  CHECK(std::memcmp(&written, &learnt.deadline_model, sizeof(CostModel)) == 0);

  // Frozen, it is read and not rewritten, and the runs agree bit for bit. The learnt model is
  // this machine's as it was while learning (beside other work it once learnt rates that, times
  // eight, cut no frame); rates at least eight times the defaults' make the budgets bind anywhere.
  written.raycast.ms_per_munit =
      8.0 * std::max(written.raycast.ms_per_munit, CostModel().raycast.ms_per_munit);
  written.integrate.ms_per_munit =
      8.0 * std::max(written.integrate.ms_per_munit, CostModel().integrate.ms_per_munit);
  REQUIRE(write_deadline_calibration(calibration, written, &error));
  options.deadline_freeze = true;
  RunSummary one, two;
  options.threads = 1;
  REQUIRE(run_pipeline(options, &one) == 0);
  options.threads = 2;
  REQUIRE(run_pipeline(options, &two) == 0);
  CHECK(one.deadline_calibration_loaded);
  CHECK(std::memcmp(&one.deadline_model, &written, sizeof(CostModel)) == 0);
  REQUIRE(one.trajectory.size() == 12);
  int cut = 0;
  REQUIRE(two.trajectory.size() == 12);
  for (std::size_t i = 0; i < one.trajectory.size(); ++i) {
    CAPTURE(i);
    REQUIRE(std::memcmp(one.trajectory[i].T_W_C.matrix().data(),
                        two.trajectory[i].T_W_C.matrix().data(), sizeof(double) * 16) == 0);
    const DeadlineReport& a = one.frames[i].deadline;
    const DeadlineReport& b = two.frames[i].deadline;
    REQUIRE(a.raycast_steps == b.raycast_steps);
    REQUIRE(a.max_voxel_updates == b.max_voxel_updates);
    if (a.deepest != DeadlineStep::none) ++cut;
  }
  CHECK(cut > 0);
  CHECK(one.frames_lost == 0);
  CostModel after;
  REQUIRE(read_deadline_calibration(calibration, &after, &error));
  CHECK(std::memcmp(&after, &written, sizeof(CostModel)) == 0);

  // A frozen run without its file stops before it starts.
  options.deadline_calibration = dir + "/missing.cal";
  RunSummary none;
  CHECK(run_pipeline(options, &none) == 1);
}
