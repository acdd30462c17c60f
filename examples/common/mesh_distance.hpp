#pragma once
// Distances from points to a triangle mesh's surface, to compare two meshes of one scene (a capped
// run's map against an uncapped one's, a build against the one before): each vertex of one mesh
// against the surface of the other, both ways. Exact within the search radius (the closest point
// on every triangle whose box comes that near), "beyond" past it.

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace octofuse::examples {

// The point of triangle (a, b, c) closest to p; a degenerate triangle (collinear or coincident
// corners) counts as its edges.
Eigen::Vector3f closest_point_on_triangle(const Eigen::Vector3f& p, const Eigen::Vector3f& a,
                                          const Eigen::Vector3f& b, const Eigen::Vector3f& c);

class TriangleGrid {
 public:
  // Indexes the triangles (three indices each, all below vertex_count) in cells of `search_m`
  // or, when larger, the 99th percentile of the triangles' extents; false for an index out of
  // range, a non-finite vertex of an indexed triangle, a triangle spanning more than 4096 cells
  // (a hundredfold outlier), or a search radius not in (0, 1e3]. The mesh must outlive the grid.
  bool build(const Eigen::Vector3f* vertices, std::size_t vertex_count,
             const std::uint32_t* indices, std::size_t triangle_count, float search_m);
  // Distance from p to the nearest triangle, when one lies within the search radius; otherwise
  // (or for a non-finite p) a value above it.
  float distance(const Eigen::Vector3f& p) const;
  float search_m() const { return search_m_; }

 private:
  const Eigen::Vector3f* vertices_ = nullptr;
  const std::uint32_t* indices_ = nullptr;
  float search_m_ = 0.0f;
  float cell_m_ = 0.0f;  // the search radius, or the triangles' p99 extent when larger
  // (cell key, triangle) for every cell a triangle's box overlaps, sorted by key.
  std::vector<std::uint64_t> cell_keys_;
  std::vector<std::uint32_t> cell_triangles_;
};

struct SurfaceDistances {
  std::size_t points = 0;
  std::size_t within = 0;        // at most within_m from the surface
  std::size_t within_twice = 0;  // at most 2 within_m
  std::size_t beyond = 0;        // farther than the search radius (or no finite position)
  double median_m = 0.0, p90_m = 0.0, p99_m = 0.0;  // beyond counts as the search radius
};

// Each of `count` points against the grid's surface.
SurfaceDistances distances_to_surface(const Eigen::Vector3f* points, std::size_t count,
                                      const TriangleGrid& surface, float within_m);

// A mesh in someone else's buffers: vertices and three indices per triangle.
struct MeshRef {
  const Eigen::Vector3f* vertices = nullptr;
  std::size_t vertex_count = 0;
  const std::uint32_t* indices = nullptr;
  std::size_t triangle_count = 0;
};

// Both ways, searching to kCompareSearchWithins times `within_m`: a's vertices against b's
// surface, then b's against a's. -1 when both could be compared, else the mesh (0: a, 1: b)
// that has no triangle or that TriangleGrid::build() refuses.
inline constexpr float kCompareSearchWithins = 4.0f;
int compare_meshes(const MeshRef& a, const MeshRef& b, float within_m, SurfaceDistances* a_to_b,
                   SurfaceDistances* b_to_a);

}  // namespace octofuse::examples
