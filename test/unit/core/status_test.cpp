#include "octofuse/core/status.hpp"

#include <catch2/catch.hpp>
#include <cstring>
#include <type_traits>

#include "octofuse/core/result.hpp"

namespace octofuse {
namespace {

TEST_CASE("Status is one byte and defaults to ok") {
  STATIC_REQUIRE(sizeof(Status) == 1);
  STATIC_REQUIRE(std::is_trivially_copyable_v<Status>);
  STATIC_REQUIRE(std::is_trivially_destructible_v<Status>);
  const Status s;
  REQUIRE(s.ok());
  REQUIRE(s == ok_status());
  REQUIRE(s.code() == StatusCode::ok);
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

TEST_CASE("the code list is fixed: kStatusCodeCount names, then unknown") {
  // Names are part of the output format (stats.json, error lines): keep them stable.
  const char* const expected[] = {
      "ok",        "invalid_argument", "out_of_range",      "resource_exhausted",  "unavailable",
      "data_loss", "end_of_stream",    "deadline_exceeded", "failed_precondition", "internal"};
  STATIC_REQUIRE(sizeof(expected) / sizeof(expected[0]) == kStatusCodeCount);
  for (int i = 0; i < kStatusCodeCount; ++i) {
    CAPTURE(i);
    REQUIRE(std::strcmp(status_code_name(static_cast<StatusCode>(i)), expected[i]) == 0);
  }
  REQUIRE(std::strcmp(status_code_name(static_cast<StatusCode>(kStatusCodeCount)), "unknown") == 0);
  REQUIRE(std::strcmp(status_code_name(static_cast<StatusCode>(255)), "unknown") == 0);
}

TEST_CASE("Status compares by code and converts from a code") {
  const Status a = StatusCode::data_loss;
  const Status b(StatusCode::data_loss);
  const Status c(StatusCode::internal);
  REQUIRE(a == b);
  REQUIRE(a != c);
  REQUIRE_FALSE(a.ok());
  REQUIRE(a != ok_status());
  STATIC_REQUIRE(Status(StatusCode::unavailable).code() == StatusCode::unavailable);
  STATIC_REQUIRE(!Status(StatusCode::unavailable).ok());
}

int g_steps_after_try = 0;

Status first_fails(Status first) {
  OCTOFUSE_TRY(first);
  ++g_steps_after_try;
  OCTOFUSE_TRY(Status(StatusCode::ok));
  ++g_steps_after_try;
  return ok_status();
}

TEST_CASE("OCTOFUSE_TRY returns the first non-ok Status and runs nothing after it") {
  g_steps_after_try = 0;
  REQUIRE(first_fails(StatusCode::end_of_stream) == Status(StatusCode::end_of_stream));
  REQUIRE(g_steps_after_try == 0);
  REQUIRE(first_fails(ok_status()).ok());
  REQUIRE(g_steps_after_try == 2);
}

TEST_CASE("Status::ignore drops a status explicitly") {
  Status(StatusCode::internal).ignore();
  SUCCEED("compiles without a nodiscard warning under -Werror");
}

}  // namespace
}  // namespace octofuse
