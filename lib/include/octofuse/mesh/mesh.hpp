#pragma once
// Indexed triangle meshes that never grow: the mesher streams vertices and triangles, a block at a
// time, into a MeshSink the caller provides (a PLY writer on the host, a radio link on a board),
// or into a MeshBuffer with fixed capacity carved from an arena.
//
// Vertex indices are global and implicit: the n-th vertex a sink receives has index n.

#include <cstddef>
#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/fixed_vector.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse {

struct MeshVertex {
  Eigen::Vector3f p_W = Eigen::Vector3f::Zero();  // metres, world frame
  std::uint8_t scale = 0;  // the coarser scale of the two voxels the vertex interpolates
};

struct MeshTriangle {
  std::uint32_t v[3] = {};  // counter-clockwise seen from free space
};

class MeshSink {
 public:
  // Called once per batch, vertices before the triangles that use them. A non-ok Status stops
  // meshing and is returned to the caller of the mesher unchanged.
  virtual Status add_vertices(const MeshVertex* vertices, std::size_t count) = 0;
  virtual Status add_triangles(const MeshTriangle* triangles, std::size_t count) = 0;

 protected:
  ~MeshSink() = default;
};

// A sink over arena storage. When a batch does not fit, nothing of it is kept and
// resource_exhausted is returned (the mesh then holds whole blocks only).
class MeshBuffer final : public MeshSink {
 public:
  template <typename Allocator>
  static Result<MeshBuffer> reserve(Allocator& arena, std::size_t vertex_capacity,
                                    std::size_t triangle_capacity) {
    auto vertices = arena.template allocate_array<MeshVertex>(vertex_capacity);
    if (!vertices.ok()) return vertices.status();
    auto triangles = arena.template allocate_array<MeshTriangle>(triangle_capacity);
    if (!triangles.ok()) return triangles.status();
    return MeshBuffer(vertices.value(), vertex_capacity, triangles.value(), triangle_capacity);
  }

  MeshBuffer() = default;
  MeshBuffer(MeshVertex* vertices, std::size_t vertex_capacity, MeshTriangle* triangles,
             std::size_t triangle_capacity)
      : vertices_(vertices, vertex_capacity), triangles_(triangles, triangle_capacity) {}

  // ok or resource_exhausted.
  Status add_vertices(const MeshVertex* vertices, std::size_t count) override;
  // ok, resource_exhausted, or invalid_argument when a triangle names a vertex not yet added.
  Status add_triangles(const MeshTriangle* triangles, std::size_t count) override;

  void clear() {
    vertices_.clear();
    triangles_.clear();
  }
  const SpanVector<MeshVertex>& vertices() const { return vertices_; }
  const SpanVector<MeshTriangle>& triangles() const { return triangles_; }

 private:
  SpanVector<MeshVertex> vertices_;
  SpanVector<MeshTriangle> triangles_;
};

}  // namespace octofuse
