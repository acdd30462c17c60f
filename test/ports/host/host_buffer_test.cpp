#include "octofuse/ports/host/host_buffer.hpp"

#include <catch2/catch.hpp>
#include <utility>

#include "octofuse/math/se3.hpp"

using octofuse::host::HostBuffer;

TEST_CASE("HostBuffer grows, keeps its elements and moves", "[host][buffer]") {
  HostBuffer<int> numbers;
  CHECK(numbers.empty());
  for (int i = 0; i < 1000; ++i) numbers.push_back(i * 3);
  REQUIRE(numbers.size() == 1000);
  for (int i = 0; i < 1000; ++i) REQUIRE(numbers[static_cast<std::size_t>(i)] == i * 3);
  CHECK(numbers.back() == 2997);
  numbers.resize(10);
  CHECK(numbers.size() == 10);
  numbers.resize(12);
  CHECK(numbers[11] == 0);  // value-initialised
  HostBuffer<int> moved(std::move(numbers));
  CHECK(moved.size() == 12);
  CHECK(numbers.empty());  // NOLINT: moved-from is empty by contract
  numbers = std::move(moved);
  CHECK(numbers.size() == 12);
  numbers.clear();
  CHECK(numbers.empty());
}

TEST_CASE("HostBuffer keeps over-aligned Eigen types aligned", "[host][buffer]") {
  HostBuffer<octofuse::Se3d> poses;
  for (int i = 0; i < 100; ++i) {
    octofuse::Se3d T = octofuse::Se3d::Identity();
    T.translation().x() = i;
    poses.push_back(T);
  }
  CHECK(reinterpret_cast<std::uintptr_t>(poses.data()) % alignof(octofuse::Se3d) == 0);
  CHECK(poses[57].translation().x() == 57.0);
}
