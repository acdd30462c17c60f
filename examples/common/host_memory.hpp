#pragma once
// Host-side memory the example programs share: the one aligned buffer a pipeline, map or mesher
// is carved from, and a mesh sink that collects the streamed mesh into vectors for the PLY writer
// (the host side may allocate; the library does not).

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "octofuse/core/arena.hpp"
#include "octofuse/mesh/mesher.hpp"

namespace octofuse::examples {

struct AlignedBuffer {
  void* data = nullptr;
  // Plain pages on purpose: with transparent huge pages advised, each first touch of 2 MiB waits
  // for the kernel to compact memory, which made 1 cm integration 40% slower (6.9-7.1 ms vs
  // 10.3-11.5 ms per frame, 2 threads); at 2 mm the TLB gain did not show in integration.
  explicit AlignedBuffer(std::size_t bytes) {
    data = std::aligned_alloc(kArenaAlignment,
                              align_up(std::max<std::size_t>(bytes, 1), kArenaAlignment));
  }
  ~AlignedBuffer() { std::free(data); }
  AlignedBuffer(const AlignedBuffer&) = delete;
  AlignedBuffer& operator=(const AlignedBuffer&) = delete;
};

class VectorMeshSink final : public MeshSink {
 public:
  Status add_vertices(const MeshVertex* vertices, std::size_t count) override {
    for (std::size_t i = 0; i < count; ++i) {
      positions.push_back(vertices[i].p_W);
      scales.push_back(vertices[i].scale);
    }
    return ok_status();
  }
  Status add_triangles(const MeshTriangle* triangles, std::size_t count) override {
    for (std::size_t i = 0; i < count; ++i) {
      for (int k = 0; k < 3; ++k) indices.push_back(triangles[i].v[k]);
    }
    return ok_status();
  }
  std::vector<Eigen::Vector3f> positions;
  std::vector<std::uint8_t> scales;
  std::vector<std::uint32_t> indices;
};

}  // namespace octofuse::examples
