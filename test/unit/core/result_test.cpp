#include "octofuse/core/result.hpp"

#include <catch2/catch.hpp>
#include <utility>

#include "death.hpp"

namespace octofuse {
namespace {

// Counts live instances so the tests can see Result construct and destroy its value exactly once.
struct Tracked {
  static int live;
  static int constructed;
  int value = 0;
  explicit Tracked(int v) : value(v) {
    ++live;
    ++constructed;
  }
  Tracked(const Tracked& other) : value(other.value) {
    ++live;
    ++constructed;
  }
  Tracked(Tracked&& other) noexcept : value(other.value) {
    other.value = -1;
    ++live;
    ++constructed;
  }
  Tracked& operator=(const Tracked&) = default;
  ~Tracked() { --live; }
};
int Tracked::live = 0;
int Tracked::constructed = 0;

TEST_CASE("Result holds a value or a non-ok status") {
  const Result<int> good = 7;
  REQUIRE(good.ok());
  REQUIRE(good.status().ok());
  REQUIRE(good.value() == 7);
  REQUIRE(*good == 7);
  REQUIRE(good.value_or(3) == 7);

  const Result<int> bad = StatusCode::out_of_range;
  REQUIRE_FALSE(bad.ok());
  REQUIRE(bad.status() == Status(StatusCode::out_of_range));
  REQUIRE(bad.value_or(3) == 3);

  const Result<int> from_status = Status(StatusCode::unavailable);
  REQUIRE(from_status.status().code() == StatusCode::unavailable);
}

TEST_CASE("Result constructs and destroys its value exactly once") {
  Tracked::live = 0;
  Tracked::constructed = 0;
  {
    Result<Tracked> a = Tracked(5);
    REQUIRE(Tracked::live == 1);
    REQUIRE(a->value == 5);

    Result<Tracked> copy = a;
    REQUIRE(Tracked::live == 2);
    REQUIRE(copy.value().value == 5);

    Result<Tracked> moved = std::move(a);
    REQUIRE(moved->value == 5);
    REQUIRE(Tracked::live == 3);

    // Assigning an error destroys the held value; assigning a value back constructs one.
    copy = Result<Tracked>(StatusCode::internal);
    REQUIRE(Tracked::live == 2);
    REQUIRE_FALSE(copy.ok());
    copy = moved;
    REQUIRE(Tracked::live == 3);
    REQUIRE(copy->value == 5);

    const Result<Tracked> failed = StatusCode::data_loss;
    REQUIRE(Tracked::live == 3);  // a failed Result holds no object
  }
  REQUIRE(Tracked::live == 0);
}

TEST_CASE("Result of a move-out value") {
  Result<Tracked> r = Tracked(9);
  Tracked taken = std::move(r).value();
  REQUIRE(taken.value == 9);
}

Result<int> half_of_even(int v) {
  if (v % 2 != 0) return StatusCode::invalid_argument;
  return v / 2;
}

int g_after_assign = 0;

Status quarter(int v, int* out) {
  OCTOFUSE_TRY_ASSIGN(const int half, half_of_even(v));
  ++g_after_assign;
  OCTOFUSE_TRY_ASSIGN(*out, half_of_even(half));
  return ok_status();
}

TEST_CASE("OCTOFUSE_TRY_ASSIGN assigns the value or returns the status") {
  g_after_assign = 0;
  int out = 0;
  REQUIRE(quarter(12, &out).ok());
  REQUIRE(out == 3);
  REQUIRE(g_after_assign == 1);

  out = -1;
  REQUIRE(quarter(6, &out) == Status(StatusCode::invalid_argument));  // 6 -> 3 -> odd
  REQUIRE(out == -1);
  REQUIRE(g_after_assign == 2);

  REQUIRE(quarter(5, &out) == Status(StatusCode::invalid_argument));
  REQUIRE(g_after_assign == 2);
}

Status try_result(int v) {
  OCTOFUSE_TRY(half_of_even(v));
  return StatusCode::ok;
}

TEST_CASE("OCTOFUSE_TRY accepts a Result") {
  REQUIRE(try_result(4).ok());
  REQUIRE(try_result(3) == Status(StatusCode::invalid_argument));
}

TEST_CASE("Result misuse trips the check") {
  SECTION("value() of a failed Result") {
    const auto end = test::run_in_child([](int) {
      const Result<int> bad = StatusCode::internal;
      volatile int v = bad.value();
      (void)v;
    });
    REQUIRE(end.aborted);
    REQUIRE(end.check_text.find("ok()") != std::string::npos);
  }
  SECTION("a Result built from an ok Status") {
    const auto end = test::run_in_child([](int) {
      const Result<int> nonsense = ok_status();
      (void)nonsense;
    });
    REQUIRE(end.aborted);
    REQUIRE(end.check_text.find("!status.ok()") != std::string::npos);
  }
}

}  // namespace
}  // namespace octofuse
