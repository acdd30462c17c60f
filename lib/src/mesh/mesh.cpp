#include "octofuse/mesh/mesh.hpp"

namespace octofuse {

Status MeshBuffer::add_vertices(const MeshVertex* vertices, std::size_t count) {
  if (count > vertices_.capacity() - vertices_.size()) return StatusCode::resource_exhausted;
  for (std::size_t i = 0; i < count; ++i) vertices_.push_back(vertices[i]).ignore();
  return ok_status();
}

Status MeshBuffer::add_triangles(const MeshTriangle* triangles, std::size_t count) {
  if (count > triangles_.capacity() - triangles_.size()) return StatusCode::resource_exhausted;
  for (std::size_t i = 0; i < count; ++i) {
    for (int k = 0; k < 3; ++k) {
      if (triangles[i].v[k] >= vertices_.size()) return StatusCode::invalid_argument;
    }
  }
  for (std::size_t i = 0; i < count; ++i) triangles_.push_back(triangles[i]).ignore();
  return ok_status();
}

}  // namespace octofuse
