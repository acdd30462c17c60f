#include "octofuse/core/status.hpp"

#include <catch2/catch.hpp>
#include <cstring>

#include "octofuse/core/result.hpp"

namespace octofuse {
namespace {

TEST_CASE("Status is one byte and defaults to ok") {
  STATIC_REQUIRE(sizeof(Status) == 1);
  const Status s;
  REQUIRE(s.ok());
  REQUIRE(s == ok_status());
  REQUIRE(std::strcmp(s.name(), "ok") == 0);
}

TEST_CASE("every code has a distinct name") {
  for (int a = 0; a < kStatusCodeCount; ++a) {
    for (int b = a + 1; b < kStatusCodeCount; ++b) {
      REQUIRE(std::strcmp(status_code_name(static_cast<StatusCode>(a)),
                          status_code_name(static_cast<StatusCode>(b))) != 0);
    }
  }
  REQUIRE(std::strcmp(Status(StatusCode::resource_exhausted).name(), "resource_exhausted") == 0);
}

}  // namespace
}  // namespace octofuse
