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
// unavailable: missing file; data_loss: bad header, truncated body, non-triangle face, index out
// of range. The message names the file and the problem.
Status read_ply(const char* path, Mesh* mesh, ErrorText* error);

}  // namespace octofuse::host
