// mesh_distance (examples/common/mesh_distance.hpp), behind `octofuse-map compare`: the closest
// point on a triangle in each of its regions, hand-computed; the grid's distances against a
// brute-force search over every triangle; two parallel planes a known distance apart.

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "mesh_distance.hpp"

using namespace octofuse::examples;
using Eigen::Vector3f;

namespace {

bool near(const Vector3f& a, const Vector3f& b) {
  return (a - b).norm() < 1e-6f;
}

// A square of side `side_m` at height z, split into n x n cells of two triangles each.
struct GridMesh {
  std::vector<Vector3f> vertices;
  std::vector<std::uint32_t> indices;
};
GridMesh plane(int n, float side_m, float z) {
  GridMesh m;
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      m.vertices.emplace_back(side_m * static_cast<float>(i) / static_cast<float>(n),
                              side_m * static_cast<float>(j) / static_cast<float>(n), z);
    }
  }
  const auto at = [n](int i, int j) { return static_cast<std::uint32_t>(j * (n + 1) + i); };
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      m.indices.insert(m.indices.end(), {at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      m.indices.insert(m.indices.end(), {at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  }
  return m;
}

}  // namespace

TEST_CASE("the closest point on a triangle lies in the region of the point's projection") {
  const Vector3f a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  CHECK(near(closest_point_on_triangle({0.2f, 0.2f, 0.5f}, a, b, c), {0.2f, 0.2f, 0.0f}));
  CHECK(near(closest_point_on_triangle({-1.0f, -1.0f, 3.0f}, a, b, c), a));              // vertex a
  CHECK(near(closest_point_on_triangle({2.0f, -1.0f, 0.0f}, a, b, c), b));               // vertex b
  CHECK(near(closest_point_on_triangle({-0.5f, 2.0f, 1.0f}, a, b, c), c));               // vertex c
  CHECK(near(closest_point_on_triangle({0.5f, -1.0f, 0.0f}, a, b, c), {0.5f, 0, 0}));    // ab
  CHECK(near(closest_point_on_triangle({-2.0f, 0.25f, 0.0f}, a, b, c), {0, 0.25f, 0}));  // ca
  CHECK(near(closest_point_on_triangle({1.0f, 1.0f, -2.0f}, a, b, c), {0.5f, 0.5f, 0}));  // bc
  // Degenerate: coincident corners, then collinear ones.
  CHECK(near(closest_point_on_triangle({1.0f, 2.0f, 3.0f}, a, a, a), a));
  CHECK(near(closest_point_on_triangle({1.5f, 1.0f, 0.0f}, a, b, {2, 0, 0}), {1.5f, 0, 0}));
}

TEST_CASE("the grid finds the nearest triangle within its radius as a search of all of them does") {
  const GridMesh m = plane(10, 1.0f, 0.0f);
  // A second, tilted patch above, so the nearest triangle is not always the plane's.
  const std::uint32_t base = static_cast<std::uint32_t>(m.vertices.size());
  GridMesh mesh = m;
  mesh.vertices.insert(mesh.vertices.end(),
                       {{0.3f, 0.3f, 0.02f}, {0.6f, 0.3f, 0.05f}, {0.3f, 0.6f, 0.03f}});
  mesh.indices.insert(mesh.indices.end(), {base, base + 1, base + 2});
  const std::size_t triangles = mesh.indices.size() / 3;
  const float search_m = 0.04f;
  TriangleGrid grid;
  REQUIRE(grid.build(mesh.vertices.data(), mesh.vertices.size(), mesh.indices.data(), triangles,
                     search_m));
  CHECK(grid.distance({0.37f, 0.52f, 0.004f}) == Approx(0.004f).margin(1e-6));
  CHECK(grid.distance({1.02f, 0.5f, 0.0f}) == Approx(0.02f).margin(1e-6));  // beyond the edge
  CHECK(grid.distance({0.5f, 0.5f, 0.5f}) > search_m);                      // too far
  CHECK(grid.distance({std::nanf(""), 0.5f, 0.0f}) > search_m);

  std::mt19937 rng(7);
  std::uniform_real_distribution<float> xy(-0.1f, 1.1f);
  std::uniform_real_distribution<float> z(-0.06f, 0.1f);
  int within = 0;
  for (int k = 0; k < 2000; ++k) {
    const Vector3f p(xy(rng), xy(rng), z(rng));
    float brute = std::numeric_limits<float>::infinity();
    for (std::size_t t = 0; t < triangles; ++t) {
      const Vector3f q = closest_point_on_triangle(p, mesh.vertices[mesh.indices[3 * t]],
                                                   mesh.vertices[mesh.indices[3 * t + 1]],
                                                   mesh.vertices[mesh.indices[3 * t + 2]]);
      brute = std::min(brute, (q - p).norm());
    }
    const float found = grid.distance(p);
    if (brute <= search_m) {
      ++within;
      CHECK(found == Approx(brute).margin(1e-6));
    } else {
      CHECK(found > search_m);
    }
  }
  CHECK(within > 500);  // both cases were tried
  CHECK(within < 2000);
}

TEST_CASE("two parallel planes 4 mm apart are 4 mm from each other at every vertex") {
  const GridMesh a = plane(20, 1.0f, 0.0f);
  const GridMesh b = plane(13, 1.0f, 0.004f);
  TriangleGrid grid;
  REQUIRE(grid.build(b.vertices.data(), b.vertices.size(), b.indices.data(), b.indices.size() / 3,
                     0.02f));
  const SurfaceDistances d5 =
      distances_to_surface(a.vertices.data(), a.vertices.size(), grid, 0.005f);
  CHECK(d5.points == a.vertices.size());
  CHECK(d5.within == a.vertices.size());
  CHECK(d5.beyond == 0);
  CHECK(d5.median_m == Approx(0.004).margin(1e-6));
  CHECK(d5.p99_m == Approx(0.004).margin(1e-6));
  const SurfaceDistances d3 =
      distances_to_surface(a.vertices.data(), a.vertices.size(), grid, 0.003f);
  CHECK(d3.within == 0);
  CHECK(d3.within_twice == a.vertices.size());
  // Points far from it: beyond the search radius, counted at it.
  const std::vector<Vector3f> far = {{0.5f, 0.5f, 1.0f}, {0.5f, 0.5f, 0.001f}};
  const SurfaceDistances f = distances_to_surface(far.data(), far.size(), grid, 0.005f);
  CHECK(f.beyond == 1);
  CHECK(f.within == 1);
  CHECK(f.p99_m == Approx(0.02).margin(1e-6));
  CHECK(distances_to_surface(far.data(), 0, grid, 0.005f).points == 0);
}

TEST_CASE("a mesh the grid cannot index is refused") {
  GridMesh m = plane(2, 1.0f, 0.0f);
  TriangleGrid grid;
  CHECK_FALSE(grid.build(m.vertices.data(), m.vertices.size(), m.indices.data(), 8, 0.0f));
  CHECK_FALSE(grid.build(m.vertices.data(), m.vertices.size() - 1, m.indices.data(), 8, 0.1f));
  std::vector<Vector3f> bad = m.vertices;
  bad[4].x() = std::numeric_limits<float>::infinity();
  CHECK_FALSE(grid.build(bad.data(), bad.size(), m.indices.data(), 8, 0.1f));
  // One triangle 1 km across among 20 000 of 1 cm: a hostile outlier, refused.
  GridMesh outlier = plane(100, 1.0f, 0.0f);
  const std::uint32_t base = static_cast<std::uint32_t>(outlier.vertices.size());
  outlier.vertices.insert(outlier.vertices.end(), {{0, 0, 0}, {1000, 0, 0}, {0, 1000, 0}});
  outlier.indices.insert(outlier.indices.end(), {base, base + 1, base + 2});
  CHECK_FALSE(grid.build(outlier.vertices.data(), outlier.vertices.size(), outlier.indices.data(),
                         outlier.indices.size() / 3, 0.01f));
  // Large triangles alone set the cells' size: searched as any other.
  const std::vector<Vector3f> huge = {{0, 0, 0}, {1000, 0, 0}, {0, 1000, 0}};
  const std::uint32_t one[3] = {0, 1, 2};
  REQUIRE(grid.build(huge.data(), huge.size(), one, 1, 0.01f));
  CHECK(grid.distance({10.0f, 10.0f, 0.005f}) == Approx(0.005f).margin(1e-5));
  CHECK(grid.distance({10.0f, 10.0f, 0.5f}) > 0.01f);
  CHECK(grid.build(m.vertices.data(), m.vertices.size(), m.indices.data(), 8, 0.1f));
}
