#include "octofuse/map/keys.hpp"

#include <random>

#include <catch2/catch.hpp>

namespace octofuse {
namespace {

TEST_CASE("morton encode/decode round trips at the 21-bit edges", "[map][keys]") {
  const int max = (1 << kMortonBitsPerAxis) - 1;
  const Eigen::Vector3i samples[] = {{0, 0, 0},     {1, 0, 0},   {0, 1, 0},       {0, 0, 1},
                                     {max, 0, 0},   {0, max, 0}, {0, 0, max},     {max, max, max},
                                     {12345, 6, 7}, {max, 1, 2}, {1 << 20, 3, 5}, {5, 1 << 20, 9}};
  for (const Eigen::Vector3i& v : samples) {
    CAPTURE(v.transpose());
    CHECK(morton_decode(morton_encode(v)) == v);
  }
  CHECK(morton_encode({1, 0, 0}) == 1u);
  CHECK(morton_encode({0, 1, 0}) == 2u);
  CHECK(morton_encode({0, 0, 1}) == 4u);
  CHECK(morton_encode({max, max, max}) == (std::uint64_t{1} << 63) - 1u);

  std::mt19937 rng(42);
  std::uniform_int_distribution<int> coord(0, max);
  for (int i = 0; i < 10000; ++i) {
    const Eigen::Vector3i v(coord(rng), coord(rng), coord(rng));
    REQUIRE(morton_decode(morton_encode(v)) == v);
  }
}

TEST_CASE("keys round trip at every level and at the cube's edges", "[map][keys]") {
  for (int depth : {4, 10, 16, 21}) {
    const int n = 1 << depth;
    const Eigen::Vector3i corners[] = {{0, 0, 0},     {n - 1, 0, 0},         {0, n - 1, 0},
                                       {0, 0, n - 1}, {n - 1, n - 1, n - 1}, {n / 2, n / 2 - 1, 3}};
    for (int level = 0; level <= depth; ++level) {
      const int size = octant_size_voxels(level, depth);
      for (const Eigen::Vector3i& v : corners) {
        CAPTURE(depth, level, v.transpose());
        const Key key = key_of_voxel(v, level, depth);
        REQUIRE(key.level == level);
        const Eigen::Vector3i corner = key_corner_voxel(key);
        // The corner is the voxel rounded down to the octant size; the octant contains v.
        CHECK(corner == snap_to_scale(v, depth - level));
        CHECK((v - corner).minCoeff() >= 0);
        CHECK((v - corner).maxCoeff() < size);
        CHECK(key_of_voxel(corner, level, depth) == key);
      }
    }
  }
}

TEST_CASE("parent and child keys are inverse", "[map][keys]") {
  const int depth = 12;
  const Key leaf = key_of_voxel({1000, 17, 4095}, depth, depth);
  Key k = leaf;
  for (int level = depth; level > 0; --level) {
    const Key parent = parent_key(k, depth);
    REQUIRE(parent.level == level - 1);
    const int c = child_index(k, depth);
    CHECK(child_key(parent, c, depth) == k);
    CHECK(key_contains(parent, k, depth));
    CHECK(key_contains(parent, leaf, depth));
    CHECK_FALSE(key_contains(k, parent, depth));
    CHECK(parent_key_at(leaf, level - 1, depth) == parent);
    CHECK(parent < k);  // parents sort before their children
    k = parent;
  }
  CHECK(k == Key{0, 0});
  CHECK(parent_key(k, depth) == k);

  // Children of one parent: corners offset by half the parent's size along the child bits.
  const Key parent = key_of_voxel({64, 128, 192}, 6, depth);  // size 64
  for (int c = 0; c < 8; ++c) {
    const Key child = child_key(parent, c, depth);
    const Eigen::Vector3i expected =
        key_corner_voxel(parent) + 32 * Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1);
    CHECK(key_corner_voxel(child) == expected);
    CHECK(child_index(child, depth) == c);
    CHECK(parent_key(child, depth) == parent);
  }
}

TEST_CASE("block coordinate conversions", "[map][keys]") {
  CHECK(voxel_to_block({0, 7, 8}) == Eigen::Vector3i(0, 0, 1));
  CHECK(voxel_to_block({15, 16, 1023}) == Eigen::Vector3i(1, 2, 127));
  CHECK(block_to_voxel({1, 2, 127}) == Eigen::Vector3i(8, 16, 1016));
  CHECK(snap_to_scale({7, 8, 13}, 2) == Eigen::Vector3i(4, 8, 12));
  CHECK(snap_to_scale({7, 8, 13}, 0) == Eigen::Vector3i(7, 8, 13));
}

}  // namespace
}  // namespace octofuse
