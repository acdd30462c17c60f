#include "octofuse/ports/host/atomic_file.hpp"

#include <catch2/catch.hpp>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

#include "support/test_dir.hpp"

using octofuse::StatusCode;
using octofuse::host::AtomicFile;
using octofuse::test::file_exists;
using octofuse::test::read_bytes;

namespace {

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
  CHECK(read_bytes(path) == "first version\n");
  CHECK_FALSE(file_exists(path + ".tmp"));

  {
    AtomicFile out;
    REQUIRE(out.open(path.c_str()).ok());
    std::fprintf(out.file(), "second %s\n", "version, longer than the first");
    // Not committed yet: the old content is still what the destination holds.
    CHECK(read_bytes(path) == "first version\n");
    REQUIRE(out.commit().ok());
  }
  CHECK(read_bytes(path) == "second version, longer than the first\n");

  {
    AtomicFile out;
    REQUIRE(out.open(path.c_str()).ok());
    REQUIRE(out.write("abandoned", 9).ok());
    CHECK(file_exists(path + ".tmp"));
  }  // going out of scope abandons it
  CHECK(read_bytes(path) == "second version, longer than the first\n");
  CHECK_FALSE(file_exists(path + ".tmp"));
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
  CHECK(read_bytes(dir + "/a").empty());
  CHECK(file_exists(dir + "/a"));
}

TEST_CASE("AtomicFile: a destination that is not a regular file is never replaced",
          "[host][atomic_file]") {
  const std::string dir = octofuse::test::make_test_dir("atomic_dir");
  // A folder, a FIFO and a device: refused at open, before anything is written, and left as
  // they were (rename() would have turned the FIFO or the device into a regular file).
  const std::string folder = dir + "/taken";
  const std::string fifo = dir + "/fifo";
  REQUIRE(std::system(("mkdir -p " + folder + "/inside").c_str()) == 0);
  REQUIRE(std::system(("mkfifo " + fifo).c_str()) == 0);
  for (const std::string& path : {folder, fifo, std::string("/dev/null")}) {
    INFO(path);
    AtomicFile out;
    CHECK(out.open(path.c_str()).code() == StatusCode::invalid_argument);
    CHECK(std::string(out.last_error()).find("not a regular file") != std::string::npos);
    CHECK(octofuse::host::check_writable(path.c_str(), nullptr).code() ==
          StatusCode::invalid_argument);
    CHECK_FALSE(file_exists(path + ".tmp"));
  }
  CHECK(file_exists(folder + "/inside"));
  CHECK(std::system(("test -p " + fifo).c_str()) == 0);
  CHECK(std::system("test -c /dev/null") == 0);

  // A temporary's name taken by a FIFO: refused too (opening it would block).
  const std::string blocked = dir + "/blocked";
  REQUIRE(std::system(("mkfifo " + blocked + ".tmp").c_str()) == 0);
  AtomicFile out;
  CHECK(out.open(blocked.c_str()).code() == StatusCode::invalid_argument);
  CHECK_FALSE(file_exists(blocked));
}

TEST_CASE("AtomicFile: a link is followed, the file it names replaced", "[host][atomic_file]") {
  const std::string dir = octofuse::test::make_test_dir("atomic_link");
  write_whole(dir + "/target", "old");
  REQUIRE(std::system(("ln -s target " + dir + "/link").c_str()) == 0);
  write_whole(dir + "/link", "new");
  CHECK(read_bytes(dir + "/target") == "new");
  CHECK(std::system(("test -L " + dir + "/link").c_str()) == 0);
  // A link to nothing names no file to replace.
  REQUIRE(std::system(("ln -s missing " + dir + "/dangling").c_str()) == 0);
  AtomicFile out;
  CHECK(out.open((dir + "/dangling").c_str()).code() == StatusCode::invalid_argument);
}

TEST_CASE("check_writable: folders that do not exist or cannot hold files", "[host][atomic_file]") {
  using octofuse::host::check_writable;
  const std::string dir = octofuse::test::make_test_dir("atomic_check");
  CHECK(check_writable((dir + "/new.bin").c_str(), nullptr).ok());
  CHECK_FALSE(file_exists(dir + "/new.bin"));
  CHECK_FALSE(file_exists(dir + "/new.bin.tmp"));
  octofuse::ErrorText error;
  CHECK(check_writable((dir + "/missing/new.bin").c_str(), &error).code() ==
        StatusCode::unavailable);
  CHECK(std::string(error.c_str()).find("missing/new.bin.tmp: cannot create") != std::string::npos);
  CHECK(check_writable("/proc/octofuse-map.bin", nullptr).code() == StatusCode::unavailable);
  CHECK(check_writable("", nullptr).code() == StatusCode::invalid_argument);
  // An existing file is left as it was.
  write_whole(dir + "/old.bin", "kept");
  CHECK(check_writable((dir + "/old.bin").c_str(), nullptr).ok());
  CHECK(read_bytes(dir + "/old.bin") == "kept");
}
