#pragma once
// Marching cubes case table over a topological cube. Corner i sits at offset
// (i & 1, (i >> 1) & 1, (i >> 2) & 1); edge e joins corners kMcEdgeCorners[e][0..1]. A corner is
// "inside" when its TSDF is negative (behind the surface).
//
// The table is generated (at compile time, see marching_cubes.cpp) instead of copied: on every
// face the crossing edges are paired by the face's four signs alone, and an ambiguous face (two
// diagonal inside corners) always separates the inside corners. Two cells sharing a face therefore
// cut it the same way, which is what keeps the mesh closed, also over the deformed cells of the
// multi-resolution dual grid. Triangles wind counter-clockwise seen from outside (free space).

#include <cstdint>

namespace octofuse {

inline constexpr int kMcMaxTriangles = 12;

struct McCase {
  std::uint8_t triangle_count = 0;
  std::uint8_t edges[kMcMaxTriangles * 3] = {};  // edge indices, three per triangle
};

// The two corners of each of the 12 cube edges (edges 0-3 run along x, 4-7 along y, 8-11 along z).
extern const std::uint8_t kMcEdgeCorners[12][2];

// Case for `inside_mask` (bit i set when corner i is inside); mask 0 and 255 have no triangles.
const McCase& marching_cubes_case(int inside_mask);

}  // namespace octofuse
