#include "octofuse/core/check.hpp"

#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstring>
#include <string>

#include "death.hpp"

namespace octofuse {
namespace {

int g_handler_calls = 0;
int g_handler_line = 0;
const char* g_handler_expression = nullptr;

void recording_handler(const char*, int line, const char* expression) {
  ++g_handler_calls;
  g_handler_line = line;
  g_handler_expression = expression;
}

TEST_CASE("A passing check does nothing and evaluates its condition once") {
  int evaluations = 0;
  OCTOFUSE_CHECK(++evaluations == 1);
  REQUIRE(evaluations == 1);
}

TEST_CASE(
    "A failing check calls the installed handler with file, line and expression, then aborts") {
  const int expected_line = __LINE__ + 3;
  const auto end = test::run_in_child([](int) {
    const int depth_mm = -1;
    OCTOFUSE_CHECK(depth_mm >= 0);
  });
  REQUIRE(end.aborted);
  const std::string expected =
      "check_test.cpp:" + std::to_string(expected_line) + ": depth_mm >= 0";
  REQUIRE(end.check_text.find(expected) != std::string::npos);
}

TEST_CASE("A handler that returns does not resume the failed code path") {
  const auto end = test::run_in_child([](int fd) {
    set_check_handler(&recording_handler);
    OCTOFUSE_CHECK(1 + 1 == 3);
    (void)!write(fd, "resumed", 7);  // must never run
  });
  REQUIRE(end.aborted);
  REQUIRE(end.check_text.empty());
}

TEST_CASE("The default handler prints the failure to stderr") {
  const auto end = test::run_in_child(
      [](int fd) {
        dup2(fd, STDERR_FILENO);
        OCTOFUSE_CHECK(sizeof(int) == 0);
      },
      /*install_reporting_handler=*/false);
  REQUIRE(end.aborted);
  REQUIRE(end.check_text.find("octofuse: check failed at ") != std::string::npos);
  REQUIRE(end.check_text.find("sizeof(int) == 0") != std::string::npos);
}

TEST_CASE("set_check_handler returns the previous handler; null restores the default") {
  const CheckHandler original = set_check_handler(&recording_handler);
  REQUIRE(original != nullptr);
  REQUIRE(set_check_handler(nullptr) == &recording_handler);
  // After null, the default is back: it is what the first call returned.
  REQUIRE(set_check_handler(original) == original);
}

TEST_CASE("The handler is called exactly once per failure, in the failing process") {
  g_handler_calls = 0;
  const auto end = test::run_in_child([](int fd) {
    set_check_handler(&recording_handler);
    struct Reporter {
      static void handler(const char* file, int line, const char* expression) {
        recording_handler(file, line, expression);
        char text[64];
        const int n = std::snprintf(text, sizeof(text), "calls=%d line=%d expr=%s", g_handler_calls,
                                    g_handler_line, g_handler_expression);
        (void)!write(test::death_detail::g_report_fd, text, static_cast<std::size_t>(n));
      }
    };
    test::death_detail::g_report_fd = fd;
    set_check_handler(&Reporter::handler);
    OCTOFUSE_CHECK(false);
  });
  REQUIRE(end.aborted);
  REQUIRE(end.check_text.find("calls=1 ") != std::string::npos);
  REQUIRE(end.check_text.find("expr=false") != std::string::npos);
  REQUIRE(g_handler_calls == 0);  // the parent's counter is untouched
}

TEST_CASE("Soft checks count failures and keep running") {
  const std::uint64_t before = soft_check_failures();
  REQUIRE(OCTOFUSE_SOFT_CHECK(2 > 1));
  REQUIRE(soft_check_failures() == before);
  REQUIRE_FALSE(OCTOFUSE_SOFT_CHECK(2 < 1));
  REQUIRE_FALSE(OCTOFUSE_SOFT_CHECK(false));
  REQUIRE(soft_check_failures() == before + 2);
}

}  // namespace
}  // namespace octofuse
