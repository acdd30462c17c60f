#include "octofuse/mesh/mesh.hpp"

#include <catch2/catch.hpp>

#include "octofuse/core/arena.hpp"

namespace octofuse {
namespace {

TEST_CASE("MeshBuffer keeps whole batches and rejects what does not fit") {
  MeshVertex vertex_storage[4];
  MeshTriangle triangle_storage[2];
  MeshBuffer buffer(vertex_storage, 4, triangle_storage, 2);
  MeshVertex v[3];
  v[1].p_W = Eigen::Vector3f(1.0f, 0.0f, 0.0f);
  v[2].p_W = Eigen::Vector3f(0.0f, 1.0f, 0.0f);
  REQUIRE(buffer.add_vertices(v, 3).ok());
  REQUIRE(buffer.add_vertices(v, 2) == StatusCode::resource_exhausted);
  REQUIRE(buffer.vertices().size() == 3u);
  MeshTriangle t;
  t.v[0] = 0;
  t.v[1] = 1;
  t.v[2] = 2;
  REQUIRE(buffer.add_triangles(&t, 1).ok());
  MeshTriangle dangling;
  dangling.v[2] = 3;  // not added yet
  REQUIRE(buffer.add_triangles(&dangling, 1) == StatusCode::invalid_argument);
  MeshTriangle two[2] = {t, t};
  REQUIRE(buffer.add_triangles(two, 2) == StatusCode::resource_exhausted);
  REQUIRE(buffer.triangles().size() == 1u);
  REQUIRE(buffer.vertices()[1].p_W.x() == 1.0f);
  buffer.clear();
  REQUIRE(buffer.vertices().empty());
  REQUIRE(buffer.triangles().empty());
}

alignas(kArenaAlignment) unsigned char memory[4096];

TEST_CASE("MeshBuffer::reserve sizes exactly with the arena sizer") {
  ArenaSizer sizer;
  REQUIRE(MeshBuffer::reserve(sizer, 10, 20).ok());
  LinearArena arena(memory, sizeof(memory));
  Result<MeshBuffer> buffer = MeshBuffer::reserve(arena, 10, 20);
  REQUIRE(buffer.ok());
  REQUIRE(arena.bytes_used() == sizer.bytes_used());
  REQUIRE(buffer->vertices().capacity() == 10u);
  REQUIRE(buffer->triangles().capacity() == 20u);
  LinearArena tiny(memory, 64);
  REQUIRE(MeshBuffer::reserve(tiny, 10, 20).status() == StatusCode::resource_exhausted);
}

}  // namespace
}  // namespace octofuse
