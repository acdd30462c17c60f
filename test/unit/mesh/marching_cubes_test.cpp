#include "octofuse/mesh/marching_cubes.hpp"

#include <catch2/catch.hpp>
#include <map>
#include <random>
#include <utility>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace octofuse {
namespace {

Eigen::Vector3i corner_offset(int c) {
  return {c & 1, (c >> 1) & 1, (c >> 2) & 1};
}

TEST_CASE("empty and full cubes have no triangles; a lone corner gets one") {
  REQUIRE(marching_cubes_case(0).triangle_count == 0);
  REQUIRE(marching_cubes_case(255).triangle_count == 0);
  for (int c = 0; c < 8; ++c) {
    REQUIRE(marching_cubes_case(1 << c).triangle_count == 1);
    REQUIRE(marching_cubes_case(255 ^ (1 << c)).triangle_count == 1);
  }
}

TEST_CASE("edges join corners that differ along one axis") {
  for (int e = 0; e < 12; ++e) {
    const int a = kMcEdgeCorners[e][0];
    const int b = kMcEdgeCorners[e][1];
    REQUIRE((a ^ b) == (1 << (e / 4)));
    REQUIRE(a < b);
  }
}

TEST_CASE("triangles face away from the inside corners") {
  for (int mask = 1; mask < 255; ++mask) {
    const McCase& mc = marching_cubes_case(mask);
    REQUIRE(mc.triangle_count > 0);
    REQUIRE(mc.triangle_count <= kMcMaxTriangles);
    // Sum of triangle normals (edge midpoints) must point from inside corners to outside ones.
    Eigen::Vector3f normal_sum = Eigen::Vector3f::Zero();
    for (int t = 0; t < mc.triangle_count; ++t) {
      Eigen::Vector3f p[3];
      for (int k = 0; k < 3; ++k) {
        const int e = mc.edges[t * 3 + k];
        p[k] = 0.5f * (corner_offset(kMcEdgeCorners[e][0]) + corner_offset(kMcEdgeCorners[e][1]))
                          .cast<float>();
      }
      normal_sum += (p[1] - p[0]).cross(p[2] - p[0]);
    }
    // From the centroid of the inside corners to the centroid of the outside ones.
    Eigen::Vector3f inside_sum = Eigen::Vector3f::Zero();
    Eigen::Vector3f outside_sum = Eigen::Vector3f::Zero();
    int inside_count = 0;
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3f o = corner_offset(c).cast<float>();
      if ((mask >> c) & 1) {
        inside_sum += o;
        ++inside_count;
      } else {
        outside_sum += o;
      }
    }
    const Eigen::Vector3f outward = outside_sum / static_cast<float>(8 - inside_count) -
                                    inside_sum / static_cast<float>(inside_count);
    if (outward.squaredNorm() > 1e-6f) {
      INFO("mask " << mask);
      REQUIRE(normal_sum.dot(outward) > 0.0f);
    }
  }
}

// Random signs on a grid: every interior mesh edge is shared by exactly two triangles that use
// it in opposite directions (closed and consistently oriented), for every case in context.
TEST_CASE("random sign fields give a closed, consistently oriented surface") {
  constexpr int kN = 7;  // grid points per side
  std::mt19937 rng(1234);
  for (int trial = 0; trial < 20; ++trial) {
    bool inside[kN][kN][kN];
    for (auto& plane : inside) {
      for (auto& row : plane) {
        for (bool& v : row) v = (rng() & 1u) != 0u;
      }
    }
    // Only the interior points may be inside, so the surface never reaches the grid border.
    for (int x = 0; x < kN; ++x) {
      for (int y = 0; y < kN; ++y) {
        for (int z = 0; z < kN; ++z) {
          if (x == 0 || y == 0 || z == 0 || x == kN - 1 || y == kN - 1 || z == kN - 1) {
            inside[x][y][z] = false;
          }
        }
      }
    }
    // Vertex id: the grid edge it lies on (lower point index * 3 + axis).
    auto point_id = [](const Eigen::Vector3i& p) { return (p.z() * kN + p.y()) * kN + p.x(); };
    std::map<std::pair<int, int>, int> directed;
    for (int x = 0; x + 1 < kN; ++x) {
      for (int y = 0; y + 1 < kN; ++y) {
        for (int z = 0; z + 1 < kN; ++z) {
          int mask = 0;
          for (int c = 0; c < 8; ++c) {
            const Eigen::Vector3i p = Eigen::Vector3i(x, y, z) + corner_offset(c);
            if (inside[p.x()][p.y()][p.z()]) mask |= 1 << c;
          }
          const McCase& mc = marching_cubes_case(mask);
          for (int t = 0; t < mc.triangle_count; ++t) {
            int ids[3];
            for (int k = 0; k < 3; ++k) {
              const int e = mc.edges[t * 3 + k];
              const Eigen::Vector3i p =
                  Eigen::Vector3i(x, y, z) + corner_offset(kMcEdgeCorners[e][0]);
              ids[k] = point_id(p) * 3 + e / 4;
            }
            for (int k = 0; k < 3; ++k) ++directed[{ids[k], ids[(k + 1) % 3]}];
          }
        }
      }
    }
    REQUIRE(!directed.empty());
    for (const auto& [edge, count] : directed) {
      INFO("trial " << trial);
      REQUIRE(count == 1);
      const auto reverse = directed.find({edge.second, edge.first});
      REQUIRE(reverse != directed.end());
      REQUIRE(reverse->second == 1);
    }
  }
}

}  // namespace
}  // namespace octofuse
