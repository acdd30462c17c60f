#pragma once
// Binary little-endian PLY for indexed triangle meshes: vertex float x, y, z (metres) and an
// optional uchar "scale" (the integration scale a vertex was extracted at), face list uchar/uint32
// vertex_indices. The reader takes exactly what the writer produces (plus either order of the
// optional scale) so meshes round-trip; it is not a general PLY reader.

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse::host {

// A mesh in someone else's buffers. `vertex_scale` may be null (no scale property written).
struct MeshView {
  const Eigen::Vector3f* vertices = nullptr;
  std::size_t vertex_count = 0;
  const std::uint32_t* indices = nullptr;  // three per triangle
  std::size_t triangle_count = 0;
  const std::uint8_t* vertex_scale = nullptr;
};

struct Mesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<std::uint32_t> indices;
  std::vector<std::uint8_t> vertex_scale;  // empty when the file had no scale property

  MeshView view() const {
    return {vertices.data(), vertices.size(), indices.data(), indices.size() / 3,
            vertex_scale.empty() ? nullptr : vertex_scale.data()};
  }
};

// invalid_argument: an index >= vertex_count; unavailable: cannot create; data_loss: write error.
Status write_ply(const char* path, const MeshView& mesh, ErrorText* error);
// Where read_ply_into puts a mesh: `allocate` is called once with the counts from the header and
// returns storage for them (`scale` is requested only when the file has the property); false
// aborts the read with resource_exhausted.
struct PlyMeshTarget {
  void* context = nullptr;
  bool (*allocate)(void* context, std::size_t vertex_count, std::size_t triangle_count,
                   bool has_scale, Eigen::Vector3f** vertices, std::uint32_t** indices,
                   std::uint8_t** scale) = nullptr;
};

// unavailable: missing file; data_loss: bad header, truncated body, non-triangle face, index out
// of range. The message names the file and the problem.
Status read_ply_into(const char* path, const PlyMeshTarget& target, ErrorText* error);

// Header-only so the std::vector growth is compiled into the (host) caller, not this library.
// On failure `mesh` is left empty.
inline Status read_ply(const char* path, Mesh* mesh, ErrorText* error) {
  *mesh = Mesh();
  PlyMeshTarget target;
  target.context = mesh;
  target.allocate = [](void* context, std::size_t vertex_count, std::size_t triangle_count,
                       bool has_scale, Eigen::Vector3f** vertices, std::uint32_t** indices,
                       std::uint8_t** scale) {
    Mesh& m = *static_cast<Mesh*>(context);
    m.vertices.resize(vertex_count);
    m.indices.resize(3 * triangle_count);
    m.vertex_scale.resize(has_scale ? vertex_count : 0);
    *vertices = m.vertices.data();
    *indices = m.indices.data();
    *scale = m.vertex_scale.data();
    return true;
  };
  const Status status = read_ply_into(path, target, error);
  if (!status.ok()) *mesh = Mesh();
  return status;
}

}  // namespace octofuse::host
