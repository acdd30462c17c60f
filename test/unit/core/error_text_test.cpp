#include "octofuse/core/error_text.hpp"

#include <catch2/catch.hpp>
#include <cstring>
#include <string>

#include "support/alloc_counter.hpp"

namespace octofuse {
namespace {

TEST_CASE("ErrorText starts empty and formats like printf") {
  ErrorText error;
  REQUIRE(error.empty());
  REQUIRE(std::strcmp(error.c_str(), "") == 0);

  error.set("%s: truncated after %d bytes", "depth/0001.png", 1024);
  REQUIRE_FALSE(error.empty());
  REQUIRE(std::strcmp(error.c_str(), "depth/0001.png: truncated after 1024 bytes") == 0);

  error.set("frame %u", 7u);
  REQUIRE(std::strcmp(error.c_str(), "frame 7") == 0);  // set replaces, never appends

  error.clear();
  REQUIRE(error.empty());
}

TEST_CASE("ErrorText truncates at capacity - 1 and stays terminated") {
  ErrorText error;
  const std::string long_text(1000, 'x');
  error.set("%s", long_text.c_str());
  REQUIRE(std::strlen(error.c_str()) == ErrorText::kCapacity - 1);
  REQUIRE(error.c_str()[ErrorText::kCapacity - 2] == 'x');

  const std::string exact(ErrorText::kCapacity - 1, 'y');
  error.set("%s", exact.c_str());
  REQUIRE(std::string(error.c_str()) == exact);
}

TEST_CASE("ErrorText does not allocate") {
  ErrorText error;
  const test::AllocationScope scope;
  error.set("%s:%d: %f", "file", 42, 1.5);
  error.clear();
  REQUIRE(scope.allocations() == 0);
}

}  // namespace
}  // namespace octofuse
