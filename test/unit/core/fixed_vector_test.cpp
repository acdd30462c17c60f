#include "octofuse/core/fixed_vector.hpp"

#include <catch2/catch.hpp>
#include <cstdint>

#include "death.hpp"

namespace octofuse {
namespace {

struct Point {
  float x = 0.0f;
  float y = 0.0f;
};

TEST_CASE("SpanVector fills to capacity, then refuses and keeps what it has") {
  Point storage[3];
  SpanVector<Point> v(storage, 3);
  REQUIRE(v.empty());
  REQUIRE(v.capacity() == 3);
  for (int i = 0; i < 3; ++i) {
    REQUIRE(v.push_back(Point{static_cast<float>(i), 1.0f}).ok());
  }
  REQUIRE(v.full());
  REQUIRE(v.push_back(Point{99.0f, 99.0f}).code() == StatusCode::resource_exhausted);
  REQUIRE(v.size() == 3);
  for (std::size_t i = 0; i < 3; ++i) REQUIRE(v[i].x == static_cast<float>(i));
  REQUIRE(v.back().x == 2.0f);
  REQUIRE(v.data() == storage);  // the storage is the caller's, never reallocated

  float sum = 0.0f;
  for (const Point& p : v) sum += p.x;
  REQUIRE(sum == 3.0f);

  v.pop_back();
  REQUIRE(v.size() == 2);
  REQUIRE(v.push_back(Point{7.0f, 0.0f}).ok());
  REQUIRE(v.back().x == 7.0f);
  v.clear();
  REQUIRE(v.empty());
  REQUIRE(v.capacity() == 3);
}

TEST_CASE("SpanVector resize grows with value-initialised elements and never past capacity") {
  int storage[4] = {5, 5, 5, 5};
  SpanVector<int> v(storage, 4);
  REQUIRE(v.push_back(1).ok());
  REQUIRE(v.resize(3).ok());
  REQUIRE(v.size() == 3);
  REQUIRE(v[0] == 1);
  REQUIRE(v[1] == 0);
  REQUIRE(v[2] == 0);
  REQUIRE(v.resize(5).code() == StatusCode::resource_exhausted);
  REQUIRE(v.size() == 3);
  REQUIRE(v.resize(1).ok());
  REQUIRE(v.size() == 1);
  REQUIRE(v[0] == 1);
  REQUIRE(v.resize(4).ok());
  REQUIRE(v.full());
}

TEST_CASE("A zero-capacity SpanVector is empty and full") {
  SpanVector<int> none;
  REQUIRE(none.empty());
  REQUIRE(none.full());
  REQUIRE(none.push_back(1).code() == StatusCode::resource_exhausted);
  REQUIRE(none.resize(0).ok());
  REQUIRE(none.begin() == none.end());
}

TEST_CASE("FixedVector stores N inline and refuses the N+1th") {
  FixedVector<std::uint16_t, 4> v;
  STATIC_REQUIRE(FixedVector<std::uint16_t, 4>::capacity() == 4);
  for (std::uint16_t i = 0; i < 4; ++i)
    REQUIRE(v.push_back(static_cast<std::uint16_t>(10 + i)).ok());
  REQUIRE(v.full());
  REQUIRE(v.push_back(1).code() == StatusCode::resource_exhausted);
  REQUIRE(v.size() == 4);
  REQUIRE(v[0] == 10);
  REQUIRE(v[3] == 13);

  FixedVector<std::uint16_t, 4> copy = v;
  v.clear();
  REQUIRE(v.empty());
  REQUIRE(copy.size() == 4);
  REQUIRE(copy.back() == 13);

  v = copy;
  v.pop_back();
  REQUIRE(v.size() == 3);
  REQUIRE(v.resize(5).code() == StatusCode::resource_exhausted);
  REQUIRE(v.resize(4).ok());
  REQUIRE(v[3] == 0);  // regrown element is value-initialised, not the old 13
  int sum = 0;
  for (std::uint16_t e : v) sum += e;
  REQUIRE(sum == 10 + 11 + 12);
}

TEST_CASE("Out-of-range access and popping an empty vector trip the check") {
  SECTION("SpanVector index == size") {
    const auto end = test::run_in_child([](int) {
      int storage[2];
      SpanVector<int> v(storage, 2);
      v.push_back(1).ignore();
      volatile int x = v[1];
      (void)x;
    });
    REQUIRE(end.aborted);
    REQUIRE(end.check_text.find("i < size_") != std::string::npos);
  }
  SECTION("SpanVector pop_back on empty") {
    const auto end = test::run_in_child([](int) {
      SpanVector<int> v;
      v.pop_back();
    });
    REQUIRE(end.aborted);
    REQUIRE(end.check_text.find("size_ > 0") != std::string::npos);
  }
  SECTION("FixedVector index past size") {
    const auto end = test::run_in_child([](int) {
      FixedVector<int, 4> v;
      volatile int x = v[0];
      (void)x;
    });
    REQUIRE(end.aborted);
  }
  SECTION("FixedVector pop_back on empty") {
    const auto end = test::run_in_child([](int) {
      FixedVector<int, 1> v;
      v.pop_back();
    });
    REQUIRE(end.aborted);
  }
}

}  // namespace
}  // namespace octofuse
