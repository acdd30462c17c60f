#include "octofuse/mesh/marching_cubes.hpp"

namespace octofuse {
namespace {

struct Table {
  McCase cases[256] = {};
  std::uint8_t edge_corners[12][2] = {};
};

constexpr int corner_coord(int corner, int axis) {
  return (corner >> axis) & 1;
}

// Edges along axis a are 4a..4a+3; k enumerates the other two bits in increasing order.
constexpr int edge_first_corner(int axis, int k) {
  return axis == 0   ? ((k & 1) << 1) | ((k >> 1) << 2)
         : axis == 1 ? (k & 1) | ((k >> 1) << 2)
                     : (k & 1) | ((k >> 1) << 1);
}

constexpr int edge_between(const Table& t, int c0, int c1) {
  for (int e = 0; e < 12; ++e) {
    if ((t.edge_corners[e][0] == c0 && t.edge_corners[e][1] == c1) ||
        (t.edge_corners[e][0] == c1 && t.edge_corners[e][1] == c0)) {
      return e;
    }
  }
  return -1;
}

constexpr void link(int (&nbr)[12][2], int (&degree)[12], int a, int b) {
  nbr[a][degree[a]++] = b;
  nbr[b][degree[b]++] = a;
}

constexpr void build_case(Table& t, int mask) {
  auto inside = [mask](int c) { return ((mask >> c) & 1) != 0; };
  int nbr[12][2] = {};
  int degree[12] = {};
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3;
    const int v = (axis + 2) % 3;
    for (int side = 0; side < 2; ++side) {
      // Face corners in cyclic order.
      int f[4] = {};
      const int uv[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
      for (int i = 0; i < 4; ++i) f[i] = (side << axis) | (uv[i][0] << u) | (uv[i][1] << v);
      int inside_count = 0;
      for (int i = 0; i < 4; ++i) inside_count += inside(f[i]) ? 1 : 0;
      if (inside_count == 0 || inside_count == 4) continue;
      const bool diagonal = inside_count == 2 && inside(f[0]) == inside(f[2]);
      for (int i = 0; i < 4; ++i) {
        const int prev = f[(i + 3) % 4];
        const int next = f[(i + 1) % 4];
        // Cut around a corner when it is isolated on this face (or inside on an ambiguous face).
        const bool isolated = inside(prev) == inside(next) && inside(prev) != inside(f[i]);
        if (isolated && (!diagonal || inside(f[i]))) {
          link(nbr, degree, edge_between(t, prev, f[i]), edge_between(t, f[i], next));
        }
      }
      if (inside_count == 2 && !diagonal) {
        int cut[2] = {};
        int n = 0;
        for (int i = 0; i < 4; ++i) {
          const int a = f[i];
          const int b = f[(i + 1) % 4];
          if (inside(a) != inside(b)) cut[n++] = edge_between(t, a, b);
        }
        link(nbr, degree, cut[0], cut[1]);
      }
    }
  }

  McCase& out = t.cases[mask];
  bool visited[12] = {};
  for (int start = 0; start < 12; ++start) {
    if (degree[start] == 0 || visited[start]) continue;
    int loop[12] = {};
    int length = 0;
    int prev = -1;
    int cur = start;
    while (!visited[cur]) {
      visited[cur] = true;
      loop[length++] = cur;
      const int next = nbr[cur][0] != prev ? nbr[cur][0] : nbr[cur][1];
      prev = cur;
      cur = next;
    }
    // Orient: the loop's normal (Newell, on doubled edge midpoints) must point from the inside
    // corners towards the outside ones.
    long long normal[3] = {};
    long long outward[3] = {};
    for (int i = 0; i < length; ++i) {
      const int e0 = loop[i];
      const int e1 = loop[(i + 1) % length];
      long long p0[3] = {};
      long long p1[3] = {};
      for (int a = 0; a < 3; ++a) {
        p0[a] = corner_coord(t.edge_corners[e0][0], a) + corner_coord(t.edge_corners[e0][1], a);
        p1[a] = corner_coord(t.edge_corners[e1][0], a) + corner_coord(t.edge_corners[e1][1], a);
      }
      normal[0] += p0[1] * p1[2] - p0[2] * p1[1];
      normal[1] += p0[2] * p1[0] - p0[0] * p1[2];
      normal[2] += p0[0] * p1[1] - p0[1] * p1[0];
      const int ca = t.edge_corners[e0][0];
      const int cb = t.edge_corners[e0][1];
      const int in_c = inside(ca) ? ca : cb;
      const int out_c = inside(ca) ? cb : ca;
      for (int a = 0; a < 3; ++a) outward[a] += corner_coord(out_c, a) - corner_coord(in_c, a);
    }
    const long long dot = normal[0] * outward[0] + normal[1] * outward[1] + normal[2] * outward[2];
    if (dot < 0) {
      for (int i = 0; i < length / 2; ++i) {
        const int tmp = loop[i];
        loop[i] = loop[length - 1 - i];
        loop[length - 1 - i] = tmp;
      }
    }
    for (int i = 1; i + 1 < length; ++i) {
      const int tri = out.triangle_count++;
      out.edges[tri * 3 + 0] = static_cast<std::uint8_t>(loop[0]);
      out.edges[tri * 3 + 1] = static_cast<std::uint8_t>(loop[i]);
      out.edges[tri * 3 + 2] = static_cast<std::uint8_t>(loop[i + 1]);
    }
  }
}

constexpr Table make_table() {
  Table t{};
  for (int axis = 0; axis < 3; ++axis) {
    for (int k = 0; k < 4; ++k) {
      const int c0 = edge_first_corner(axis, k);
      t.edge_corners[axis * 4 + k][0] = static_cast<std::uint8_t>(c0);
      t.edge_corners[axis * 4 + k][1] = static_cast<std::uint8_t>(c0 | (1 << axis));
    }
  }
  for (int mask = 0; mask < 256; ++mask) build_case(t, mask);
  return t;
}

constexpr Table kTable = make_table();

}  // namespace

const std::uint8_t kMcEdgeCorners[12][2] = {
    {kTable.edge_corners[0][0], kTable.edge_corners[0][1]},
    {kTable.edge_corners[1][0], kTable.edge_corners[1][1]},
    {kTable.edge_corners[2][0], kTable.edge_corners[2][1]},
    {kTable.edge_corners[3][0], kTable.edge_corners[3][1]},
    {kTable.edge_corners[4][0], kTable.edge_corners[4][1]},
    {kTable.edge_corners[5][0], kTable.edge_corners[5][1]},
    {kTable.edge_corners[6][0], kTable.edge_corners[6][1]},
    {kTable.edge_corners[7][0], kTable.edge_corners[7][1]},
    {kTable.edge_corners[8][0], kTable.edge_corners[8][1]},
    {kTable.edge_corners[9][0], kTable.edge_corners[9][1]},
    {kTable.edge_corners[10][0], kTable.edge_corners[10][1]},
    {kTable.edge_corners[11][0], kTable.edge_corners[11][1]},
};

const McCase& marching_cubes_case(int inside_mask) {
  return kTable.cases[inside_mask & 255];
}

}  // namespace octofuse
