#include "octofuse/ports/host/atomic_file.hpp"

#include <catch2/catch.hpp>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

#include "support/test_dir.hpp"

using octofuse::StatusCode;
using octofuse::host::AtomicFile;

namespace {

std::string read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

bool exists(const std::string& path) {
  return std::ifstream(path).good();
}

void write_whole(const std::string& path, const std::string& text) {
  AtomicFile out;
  REQUIRE(out.open(path.c_str()).ok());
  REQUIRE(out.write(text.data(), text.size()).ok());
  REQUIRE(out.commit().ok());
}

}  // namespace

TEST_CASE("AtomicFile: the destination holds the old or the new content, never a mix",
          "[host][atomic_file]") {
  const std::string dir = octofuse::test::make_test_dir("atomic");
  const std::string path = dir + "/out.txt";
  write_whole(path, "first version\n");
  CHECK(read_all(path) == "first version\n");
  CHECK_FALSE(exists(path + ".tmp"));

  {
    AtomicFile out;
    REQUIRE(out.open(path.c_str()).ok());
    std::fprintf(out.file(), "second %s\n", "version, longer than the first");
    // Not committed yet: the old content is still what the destination holds.
    CHECK(read_all(path) == "first version\n");
    REQUIRE(out.commit().ok());
  }
  CHECK(read_all(path) == "second version, longer than the first\n");

  {
    AtomicFile out;
    REQUIRE(out.open(path.c_str()).ok());
    REQUIRE(out.write("abandoned", 9).ok());
    CHECK(exists(path + ".tmp"));
  }  // going out of scope abandons it
  CHECK(read_all(path) == "second version, longer than the first\n");
  CHECK_FALSE(exists(path + ".tmp"));
}

TEST_CASE("AtomicFile: bad paths and calls in the wrong state get a Status",
          "[host][atomic_file]") {
  const std::string dir = octofuse::test::make_test_dir("atomic_bad");
  AtomicFile out;
  CHECK(out.open("").code() == StatusCode::invalid_argument);
  CHECK(out.open((dir + "/no/such/folder/x").c_str()).code() == StatusCode::unavailable);
  CHECK(std::string(out.last_error()).find("cannot create") != std::string::npos);
  CHECK(out.write("x", 1).code() == StatusCode::failed_precondition);
  CHECK(out.commit().code() == StatusCode::failed_precondition);

  REQUIRE(out.open((dir + "/a").c_str()).ok());
  CHECK(out.open((dir + "/b").c_str()).code() == StatusCode::failed_precondition);
  REQUIRE(out.commit().ok());
  CHECK(read_all(dir + "/a").empty());
  CHECK(exists(dir + "/a"));
}

TEST_CASE("AtomicFile: a destination that cannot be replaced keeps its content",
          "[host][atomic_file]") {
  const std::string dir = octofuse::test::make_test_dir("atomic_dir");
  // A non-empty folder in the way: rename() cannot replace it.
  const std::string path = dir + "/taken";
  REQUIRE(std::system(("mkdir -p " + path + "/inside").c_str()) == 0);
  AtomicFile out;
  REQUIRE(out.open(path.c_str()).ok());
  REQUIRE(out.write("data", 4).ok());
  CHECK(out.commit().code() == StatusCode::data_loss);
  CHECK_FALSE(exists(path + ".tmp"));
  CHECK(exists(path + "/inside"));
}
