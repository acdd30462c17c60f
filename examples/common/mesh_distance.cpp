#include "mesh_distance.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace octofuse::examples {

namespace {

Eigen::Vector3f closest_point_on_segment(const Eigen::Vector3f& p, const Eigen::Vector3f& a,
                                         const Eigen::Vector3f& b) {
  const Eigen::Vector3f ab = b - a;
  const float length2 = ab.squaredNorm();
  if (!(length2 > 0.0f)) return a;
  const float t = std::clamp((p - a).dot(ab) / length2, 0.0f, 1.0f);
  return a + t * ab;
}

// Cells of the grid: coordinates offset into [0, 2^21) and packed, as the map packs blocks.
constexpr std::int64_t kCellOffset = std::int64_t{1} << 20;
constexpr std::int64_t kCellLimit = std::int64_t{1} << 21;
// A triangle spanning more cells than this is refused (the cells are at least the 99th
// percentile of the triangles' extents; a hostile file's one huge triangle would fill memory
// with cell entries).
constexpr std::int64_t kMaxCellsPerTriangle = 4096;

bool cell_of(float coordinate, float cell_m, std::int64_t* cell) {
  const double c = std::floor(static_cast<double>(coordinate) / static_cast<double>(cell_m));
  if (!(c > -static_cast<double>(kCellOffset) && c < static_cast<double>(kCellOffset - 1))) {
    return false;
  }
  *cell = static_cast<std::int64_t>(c) + kCellOffset;
  return true;
}

std::uint64_t cell_key(std::int64_t x, std::int64_t y, std::int64_t z) {
  return static_cast<std::uint64_t>(x) | (static_cast<std::uint64_t>(y) << 21) |
         (static_cast<std::uint64_t>(z) << 42);
}

}  // namespace

// The regions of the triangle's plane, as in Ericson, "Real-Time Collision Detection", 5.1.5.
Eigen::Vector3f closest_point_on_triangle(const Eigen::Vector3f& p, const Eigen::Vector3f& a,
                                          const Eigen::Vector3f& b, const Eigen::Vector3f& c) {
  const Eigen::Vector3f ab = b - a;
  const Eigen::Vector3f ac = c - a;
  if (!(ab.cross(ac).squaredNorm() > 0.0f)) {
    // No plane: the nearest of its edges.
    const Eigen::Vector3f q[3] = {closest_point_on_segment(p, a, b),
                                  closest_point_on_segment(p, b, c),
                                  closest_point_on_segment(p, c, a)};
    int best = 0;
    for (int i = 1; i < 3; ++i) {
      if ((q[i] - p).squaredNorm() < (q[best] - p).squaredNorm()) best = i;
    }
    return q[best];
  }
  const Eigen::Vector3f ap = p - a;
  const float d1 = ab.dot(ap);
  const float d2 = ac.dot(ap);
  if (d1 <= 0.0f && d2 <= 0.0f) return a;
  const Eigen::Vector3f bp = p - b;
  const float d3 = ab.dot(bp);
  const float d4 = ac.dot(bp);
  if (d3 >= 0.0f && d4 <= d3) return b;
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0f && d1 >= 0.0f && d3 <= 0.0f) return a + (d1 / (d1 - d3)) * ab;
  const Eigen::Vector3f cp = p - c;
  const float d5 = ab.dot(cp);
  const float d6 = ac.dot(cp);
  if (d6 >= 0.0f && d5 <= d6) return c;
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0f && d2 >= 0.0f && d6 <= 0.0f) return a + (d2 / (d2 - d6)) * ac;
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0.0f && (d4 - d3) >= 0.0f && (d5 - d6) >= 0.0f) {
    return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  }
  const float sum = va + vb + vc;
  if (!(sum > 0.0f)) return closest_point_on_segment(p, a, b);  // rounding at a sliver
  const float v = vb / sum;
  const float w = vc / sum;
  return a + v * ab + w * ac;
}

bool TriangleGrid::build(const Eigen::Vector3f* vertices, std::size_t vertex_count,
                         const std::uint32_t* indices, std::size_t triangle_count, float search_m) {
  vertices_ = vertices;
  indices_ = indices;
  search_m_ = search_m;
  cell_m_ = search_m;
  cell_keys_.clear();
  cell_triangles_.clear();
  if (!(search_m > 0.0f && search_m <= 1e3f)) return false;
  // Cells at least the search radius (a query looks one cell around its own) and at least the
  // 99th percentile of the triangles' extents (so a small radius does not cut each triangle into
  // many cells).
  std::vector<Eigen::Vector3f> box_lo(triangle_count), box_hi(triangle_count);
  std::vector<float> extents(triangle_count);
  for (std::size_t t = 0; t < triangle_count; ++t) {
    Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::infinity());
    Eigen::Vector3f hi = -lo;
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t i = indices[3 * t + static_cast<std::size_t>(k)];
      if (i >= vertex_count || !vertices[i].allFinite()) return false;
      lo = lo.cwiseMin(vertices[i]);
      hi = hi.cwiseMax(vertices[i]);
    }
    box_lo[t] = lo;
    box_hi[t] = hi;
    extents[t] = (hi - lo).maxCoeff();
  }
  if (triangle_count > 0) {
    const std::size_t rank = std::min(triangle_count - 1, triangle_count * 99 / 100);
    std::nth_element(extents.begin(), extents.begin() + static_cast<std::ptrdiff_t>(rank),
                     extents.end());
    cell_m_ = std::max(search_m, extents[rank]);
  }
  std::vector<std::pair<std::uint64_t, std::uint32_t>> entries;
  entries.reserve(triangle_count * 2);
  for (std::size_t t = 0; t < triangle_count; ++t) {
    const Eigen::Vector3f& lo = box_lo[t];
    const Eigen::Vector3f& hi = box_hi[t];
    std::int64_t l[3], h[3];
    std::int64_t cells = 1;
    for (int d = 0; d < 3; ++d) {
      if (!cell_of(lo[d], cell_m_, &l[d]) || !cell_of(hi[d], cell_m_, &h[d])) return false;
      cells *= h[d] - l[d] + 1;
    }
    if (cells > kMaxCellsPerTriangle) return false;
    for (std::int64_t z = l[2]; z <= h[2]; ++z) {
      for (std::int64_t y = l[1]; y <= h[1]; ++y) {
        for (std::int64_t x = l[0]; x <= h[0]; ++x) {
          entries.emplace_back(cell_key(x, y, z), static_cast<std::uint32_t>(t));
        }
      }
    }
  }
  std::sort(entries.begin(), entries.end());
  cell_keys_.resize(entries.size());
  cell_triangles_.resize(entries.size());
  for (std::size_t i = 0; i < entries.size(); ++i) {
    cell_keys_[i] = entries[i].first;
    cell_triangles_[i] = entries[i].second;
  }
  return true;
}

float TriangleGrid::distance(const Eigen::Vector3f& p) const {
  const float none = 2.0f * search_m_;
  if (!p.allFinite() || cell_keys_.empty()) return none;
  // A triangle within the radius overlaps a cell within one cell of p's.
  std::int64_t c[3];
  for (int d = 0; d < 3; ++d) {
    if (!cell_of(p[d], cell_m_, &c[d])) return none;
  }
  float best2 = search_m_ * search_m_;
  bool found = false;
  for (std::int64_t z = c[2] - 1; z <= c[2] + 1; ++z) {
    for (std::int64_t y = c[1] - 1; y <= c[1] + 1; ++y) {
      for (std::int64_t x = c[0] - 1; x <= c[0] + 1; ++x) {
        if (x < 0 || y < 0 || z < 0 || x >= kCellLimit || y >= kCellLimit || z >= kCellLimit) {
          continue;
        }
        const std::uint64_t key = cell_key(x, y, z);
        auto it = std::lower_bound(cell_keys_.begin(), cell_keys_.end(), key);
        for (; it != cell_keys_.end() && *it == key; ++it) {
          const std::size_t t = cell_triangles_[static_cast<std::size_t>(it - cell_keys_.begin())];
          const Eigen::Vector3f q = closest_point_on_triangle(p, vertices_[indices_[3 * t]],
                                                              vertices_[indices_[3 * t + 1]],
                                                              vertices_[indices_[3 * t + 2]]);
          const float d2 = (q - p).squaredNorm();
          if (d2 <= best2) {
            best2 = d2;
            found = true;
          }
        }
      }
    }
  }
  return found ? std::sqrt(best2) : none;
}

SurfaceDistances distances_to_surface(const Eigen::Vector3f* points, std::size_t count,
                                      const TriangleGrid& surface, float within_m) {
  SurfaceDistances s;
  s.points = count;
  if (count == 0) return s;
  const float search_m = surface.search_m();
  std::vector<float> d(count);
  for (std::size_t i = 0; i < count; ++i) {
    float distance_m = surface.distance(points[i]);
    if (distance_m > search_m) {
      ++s.beyond;
      distance_m = search_m;
    }
    if (distance_m <= within_m) ++s.within;
    if (distance_m <= 2.0f * within_m) ++s.within_twice;
    d[i] = distance_m;
  }
  std::sort(d.begin(), d.end());
  auto at = [&](double share) {
    const std::size_t rank =
        static_cast<std::size_t>(std::ceil(share * static_cast<double>(count)));
    return static_cast<double>(d[std::min(count, std::max<std::size_t>(rank, 1)) - 1]);
  };
  s.median_m = at(0.5);
  s.p90_m = at(0.9);
  s.p99_m = at(0.99);
  return s;
}

int compare_meshes(const MeshRef& a, const MeshRef& b, float within_m, SurfaceDistances* a_to_b,
                   SurfaceDistances* b_to_a) {
  const MeshRef* meshes[2] = {&a, &b};
  TriangleGrid grids[2];
  for (int i = 0; i < 2; ++i) {
    const MeshRef& m = *meshes[i];
    if (m.triangle_count == 0 ||
        !grids[i].build(m.vertices, m.vertex_count, m.indices, m.triangle_count,
                        kCompareSearchWithins * within_m)) {
      return i;
    }
  }
  *a_to_b = distances_to_surface(a.vertices, a.vertex_count, grids[1], within_m);
  *b_to_a = distances_to_surface(b.vertices, b.vertex_count, grids[0], within_m);
  return -1;
}

}  // namespace octofuse::examples
