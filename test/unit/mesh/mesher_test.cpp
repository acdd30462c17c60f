#include "octofuse/mesh/mesher.hpp"

#include <algorithm>
#include <array>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/analytic_map.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.01f;
constexpr float kMu_m = 0.05f;
constexpr float kVertexTolerance_m = 0.25f * kVoxel_m;

MapConfig test_map_config() {
  MapConfig config;
  config.voxel_size_m = kVoxel_m;
  config.voxel_depth = 7;  // 1.28 m cube
  config.origin_W = Eigen::Vector3f(-0.64f, -0.64f, -0.64f);
  config.block_capacity = 8000;
  config.node_capacity = 4000;
  return config;
}

// A mesher and a buffer over their own memory.
template <typename VoxelT>
struct Meshing {
  test::ArenaBuffer memory;
  Mesher<VoxelT> mesher;
  MeshBuffer buffer;

  explicit Meshing(const MeshConfig& config = MeshConfig{}, std::size_t vertex_capacity = 400000,
                   std::size_t triangle_capacity = 800000)
      : memory(bytes_for(config, vertex_capacity, triangle_capacity)) {
    const std::size_t mesher_bytes = Mesher<VoxelT>::bytes_required(config);
    REQUIRE(mesher_bytes > 0);
    REQUIRE(mesher.reserve(memory.arena(), config).ok());
    REQUIRE(memory.arena().bytes_used() == mesher_bytes);
    Result<MeshBuffer> b = MeshBuffer::reserve(memory.arena(), vertex_capacity, triangle_capacity);
    REQUIRE(b.ok());
    buffer = b.value();
  }
  static std::size_t bytes_for(const MeshConfig& config, std::size_t vertex_capacity,
                               std::size_t triangle_capacity) {
    ArenaSizer sizer;
    REQUIRE(MeshBuffer::reserve(sizer, vertex_capacity, triangle_capacity).ok());
    return align_up(Mesher<VoxelT>::bytes_required(config) + sizer.bytes_used() + kArenaAlignment,
                    kArenaAlignment);
  }
};

struct EdgeReport {
  std::size_t boundary_edges = 0;    // used by exactly one triangle
  std::size_t unbalanced_edges = 0;  // a -> b not matched by as many b -> a
  float longest_boundary_edge_m = 0.0f;
};

EdgeReport check_edges(const MeshBuffer& mesh) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> directed;
  for (const MeshTriangle& t : mesh.triangles()) {
    for (int k = 0; k < 3; ++k) ++directed[{t.v[k], t.v[(k + 1) % 3]}];
  }
  EdgeReport report;
  for (const auto& [edge, count] : directed) {
    const auto reverse = directed.find({edge.second, edge.first});
    const int reverse_count = reverse == directed.end() ? 0 : reverse->second;
    if (count != reverse_count) ++report.unbalanced_edges;
    if (count + reverse_count == 1) {
      ++report.boundary_edges;
      const float length =
          (mesh.vertices()[edge.first].p_W - mesh.vertices()[edge.second].p_W).norm();
      report.longest_boundary_edge_m = std::max(report.longest_boundary_edge_m, length);
    }
  }
  return report;
}

// V - E + F over the vertices triangles use: 2 for a closed surface of genus 0.
long euler_characteristic(const MeshBuffer& mesh) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> undirected;
  std::vector<bool> used(mesh.vertices().size(), false);
  for (const MeshTriangle& t : mesh.triangles()) {
    for (int k = 0; k < 3; ++k) {
      used[t.v[k]] = true;
      undirected[{std::min(t.v[k], t.v[(k + 1) % 3]), std::max(t.v[k], t.v[(k + 1) % 3])}] = 1;
    }
  }
  long v = 0;
  for (bool u : used) v += u ? 1 : 0;
  return v - static_cast<long>(undirected.size()) + static_cast<long>(mesh.triangles().size());
}

// Volume enclosed by a closed, outward-oriented mesh (divergence theorem).
double signed_volume(const MeshBuffer& mesh) {
  double volume = 0.0;
  for (const MeshTriangle& t : mesh.triangles()) {
    const Eigen::Vector3d a = mesh.vertices()[t.v[0]].p_W.cast<double>();
    const Eigen::Vector3d b = mesh.vertices()[t.v[1]].p_W.cast<double>();
    const Eigen::Vector3d c = mesh.vertices()[t.v[2]].p_W.cast<double>();
    volume += a.dot(b.cross(c)) / 6.0;
  }
  return volume;
}

const Eigen::Vector3f kCentre_W(0.013f, -0.021f, 0.007f);
constexpr float kRadius_m = 0.3f;
float sphere_sdf(const Eigen::Vector3f& p_W) {
  return (p_W - kCentre_W).norm() - kRadius_m;
}

TEMPLATE_TEST_CASE("a sphere meshes to a closed surface on the true sphere", "", TsdfVoxel,
                   MultiresVoxel) {
  test::OwnedMap<TestType> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sphere_sdf, [](const Eigen::Vector3i&) { return 0; });
  Meshing<TestType> meshing;
  Result<MeshStats> stats = meshing.mesher.extract(owned.map, meshing.buffer);
  REQUIRE(stats.ok());
  REQUIRE(stats->vertices == meshing.buffer.vertices().size());
  REQUIRE(stats->triangles == meshing.buffer.triangles().size());
  REQUIRE(stats->triangles > 1000u);
  const EdgeReport edges = check_edges(meshing.buffer);
  REQUIRE(edges.boundary_edges == 0u);
  REQUIRE(edges.unbalanced_edges == 0u);
  REQUIRE(euler_characteristic(meshing.buffer) == 2);
  float worst_m = 0.0f;
  for (const MeshVertex& v : meshing.buffer.vertices()) {
    worst_m = std::max(worst_m, std::fabs(sphere_sdf(v.p_W)));
    REQUIRE(v.scale == 0);
  }
  REQUIRE(worst_m < kVertexTolerance_m);
  const double expected = 4.0 / 3.0 * M_PI * std::pow(kRadius_m, 3);
  REQUIRE(signed_volume(meshing.buffer) == Approx(expected).epsilon(0.01));
}

TEST_CASE("a box meshes to a closed surface near its faces") {
  const Eigen::Vector3f half(0.203f, 0.157f, 0.251f);
  const Eigen::Vector3f centre(0.0031f, 0.0047f, -0.0023f);
  auto box_sdf = [&](const Eigen::Vector3f& p_W) {
    const Eigen::Vector3f q = (p_W - centre).cwiseAbs() - half;
    const float outside = q.cwiseMax(0.0f).norm();
    const float inside = std::min(0.0f, q.maxCoeff());
    return outside + inside;
  };
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, box_sdf, [](const Eigen::Vector3i&) { return 0; });
  Meshing<MultiresVoxel> meshing;
  REQUIRE(meshing.mesher.extract(owned.map, meshing.buffer).ok());
  const EdgeReport edges = check_edges(meshing.buffer);
  REQUIRE(edges.boundary_edges == 0u);
  REQUIRE(edges.unbalanced_edges == 0u);
  REQUIRE(euler_characteristic(meshing.buffer) == 2);
  float worst_m = 0.0f;
  for (const MeshVertex& v : meshing.buffer.vertices()) {
    worst_m = std::max(worst_m, std::fabs(box_sdf(v.p_W)));
  }
  REQUIRE(worst_m < kVertexTolerance_m);
  const double expected = 8.0 * half.x() * half.y() * half.z();
  REQUIRE(signed_volume(meshing.buffer) == Approx(expected).epsilon(0.01));
}

TEST_CASE("across a scale boundary the sphere stays closed") {
  const int coarse = GENERATE(1, 2);
  const float coarse_voxel_m = kVoxel_m * static_cast<float>(1 << coarse);
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  // Blocks with x below the centre at scale 0, the others coarser.
  constexpr int kSplit = 8;  // block x coordinate of the cube's middle
  test::fill_band(owned.map, kMu_m, sphere_sdf,
                  [coarse](const Eigen::Vector3i& b) { return b.x() < kSplit ? 0 : coarse; });
  Meshing<MultiresVoxel> meshing;
  REQUIRE(meshing.mesher.extract(owned.map, meshing.buffer).ok());
  const EdgeReport edges = check_edges(meshing.buffer);
  REQUIRE(edges.boundary_edges == 0u);
  REQUIRE(edges.unbalanced_edges == 0u);
  REQUIRE(euler_characteristic(meshing.buffer) == 2);
  REQUIRE(edges.longest_boundary_edge_m < coarse_voxel_m);
  int fine = 0;
  int coarse_vertices = 0;
  float worst_m = 0.0f;
  for (const MeshVertex& v : meshing.buffer.vertices()) {
    worst_m = std::max(worst_m, std::fabs(sphere_sdf(v.p_W)));
    if (v.scale == 0) ++fine;
    if (v.scale == coarse) ++coarse_vertices;
  }
  REQUIRE(fine > 100);
  REQUIRE(coarse_vertices > 100);
  REQUIRE(worst_m < 0.25f * coarse_voxel_m);
  const double expected = 4.0 / 3.0 * M_PI * std::pow(kRadius_m, 3);
  REQUIRE(signed_volume(meshing.buffer) == Approx(expected).epsilon(0.02));
}

TEST_CASE("finest_fused meshes a block at the finest scale it was fused at, current at its last") {
  // Fused up close at scale 0, then seen from afar: every block last integrated at scale 2 (its
  // scale-2 level holds the mean of the fine one, as up-propagation leaves it).
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sphere_sdf, [](const Eigen::Vector3i&) { return 0; });
  for (std::uint32_t b = 0; b < owned.map.block_count(); ++b) {
    owned.map.block(b).current_scale = 2;
    owned.map.block(b).mip_scale = 2;
  }
  auto mesh_at = [&](MeshReadScale read_scale, int* worst_scale, float* worst_m) {
    MeshConfig config;
    config.read_scale = read_scale;
    Meshing<MultiresVoxel> meshing(config);
    REQUIRE(meshing.mesher.extract(owned.map, meshing.buffer).ok());
    const EdgeReport edges = check_edges(meshing.buffer);
    REQUIRE(edges.boundary_edges == 0u);
    REQUIRE(euler_characteristic(meshing.buffer) == 2);
    *worst_scale = 0;
    *worst_m = 0.0f;
    for (const MeshVertex& v : meshing.buffer.vertices()) {
      *worst_scale = std::max<int>(*worst_scale, v.scale);
      *worst_m = std::max(*worst_m, std::fabs(sphere_sdf(v.p_W)));
    }
    return meshing.buffer.vertices().size();
  };
  int current_scale = -1;
  float current_m = 0.0f;
  const std::size_t current_vertices = mesh_at(MeshReadScale::current, &current_scale, &current_m);
  int finest_scale = -1;
  float finest_m = 0.0f;
  const std::size_t finest_vertices =
      mesh_at(MeshReadScale::finest_fused, &finest_scale, &finest_m);
  CHECK(current_scale == 2);
  CHECK(finest_scale == 0);  // every vertex from scale-0 voxels
  CHECK(finest_m < kVertexTolerance_m);
  CHECK(finest_vertices > 8 * current_vertices);  // 4x finer grid: ~16x the vertices
  CHECK(current_m < 0.25f * 4.0f * kVoxel_m);
}

TEST_CASE("an unknown mesh read scale is invalid_argument") {
  MeshConfig config;
  config.read_scale = static_cast<MeshReadScale>(7);
  CHECK(validate(config).code() == StatusCode::invalid_argument);
  CHECK(Mesher<MultiresVoxel>::bytes_required(config) == 0u);
}

TEST_CASE("an empty map gives an empty mesh") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  Meshing<MultiresVoxel> meshing;
  Result<MeshStats> stats = meshing.mesher.extract(owned.map, meshing.buffer);
  REQUIRE(stats.ok());
  REQUIRE(stats->vertices == 0u);
  REQUIRE(stats->triangles == 0u);
  REQUIRE(meshing.buffer.vertices().empty());
  REQUIRE(meshing.buffer.triangles().empty());
}

TEST_CASE("a map of unobserved blocks gives an empty mesh") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  REQUIRE(owned.map.allocate_block(Eigen::Vector3i(3, 4, 5)).ok());
  Meshing<MultiresVoxel> meshing;
  Result<MeshStats> stats = meshing.mesher.extract(owned.map, meshing.buffer);
  REQUIRE(stats.ok());
  REQUIRE(stats->triangles == 0u);
}

TEST_CASE("meshing is deterministic and allocates nothing") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sphere_sdf,
                  [](const Eigen::Vector3i& b) { return (b.y() + b.z()) % 3; });
  Meshing<MultiresVoxel> meshing;
  REQUIRE(meshing.mesher.extract(owned.map, meshing.buffer).ok());
  std::vector<MeshVertex> first(meshing.buffer.vertices().begin(), meshing.buffer.vertices().end());
  meshing.buffer.clear();
  test::AllocationScope scope;
  Result<MeshStats> stats = meshing.mesher.extract(owned.map, meshing.buffer);
  REQUIRE(scope.allocations() == 0u);
  REQUIRE(stats.ok());
  REQUIRE(meshing.buffer.vertices().size() == first.size());
  for (std::size_t i = 0; i < first.size(); ++i) {
    REQUIRE(meshing.buffer.vertices()[i].p_W == first[i].p_W);
  }
  const EdgeReport edges = check_edges(meshing.buffer);
  REQUIRE(edges.boundary_edges == 0u);
}

TEST_CASE("bounded memory: full tables and full buffers are resource_exhausted") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sphere_sdf, [](const Eigen::Vector3i&) { return 0; });
  SECTION("vertex table") {
    MeshConfig config;
    config.vertex_capacity = 1000;
    Meshing<MultiresVoxel> meshing(config);
    REQUIRE(meshing.mesher.extract(owned.map, meshing.buffer).status() ==
            StatusCode::resource_exhausted);
    // What was streamed is a valid indexed mesh.
    REQUIRE(meshing.buffer.vertices().size() <= 1000u);
  }
  SECTION("sink capacity") {
    Meshing<MultiresVoxel> meshing(MeshConfig{}, 500, 1000);
    REQUIRE(meshing.mesher.extract(owned.map, meshing.buffer).status() ==
            StatusCode::resource_exhausted);
    REQUIRE(meshing.buffer.vertices().size() <= 500u);
    REQUIRE(meshing.buffer.triangles().size() <= 1000u);
  }
  SECTION("config") {
    MeshConfig bad;
    bad.vertex_capacity = 0;
    REQUIRE(validate(bad) == StatusCode::invalid_argument);
    Mesher<MultiresVoxel> unreserved;
    MeshBuffer none;
    REQUIRE(unreserved.extract(owned.map, none).status() == StatusCode::failed_precondition);
  }
}

// A sink that counts what it receives, to check streaming.
class CountingSink final : public MeshSink {
 public:
  Status add_vertices(const MeshVertex*, std::size_t count) override {
    vertices += count;
    ++calls;
    return ok_status();
  }
  Status add_triangles(const MeshTriangle* batch, std::size_t count) override {
    for (std::size_t i = 0; i < count; ++i) {
      for (int k = 0; k < 3; ++k) {
        if (batch[i].v[k] >= vertices) ++dangling;
      }
    }
    this->triangles += count;
    ++calls;
    return ok_status();
  }
  std::size_t vertices = 0;
  std::size_t triangles = 0;
  std::size_t calls = 0;
  std::size_t dangling = 0;
};

TEST_CASE("meshing streams in small batches to a caller's sink") {
  test::OwnedMap<MultiresVoxel> owned(test_map_config());
  test::fill_band(owned.map, kMu_m, sphere_sdf, [](const Eigen::Vector3i&) { return 1; });
  MeshConfig config;
  config.batch_capacity = 64;
  Meshing<MultiresVoxel> meshing(config);
  CountingSink sink;
  Result<MeshStats> stats = meshing.mesher.extract(owned.map, sink);
  REQUIRE(stats.ok());
  REQUIRE(sink.vertices == stats->vertices);
  REQUIRE(sink.triangles == stats->triangles);
  REQUIRE(sink.dangling == 0u);
  REQUIRE(sink.calls > 2 * stats->triangles / 64);
}

// Triangles as sorted position triples (pool order, and so vertex numbering, differs between
// maps holding the same blocks).
std::vector<std::array<float, 9>> triangle_set(const MeshBuffer& mesh) {
  std::vector<std::array<float, 9>> out;
  for (const MeshTriangle& t : mesh.triangles()) {
    std::array<float, 9> tri;
    for (int k = 0; k < 3; ++k) {
      for (int a = 0; a < 3; ++a) tri[3 * k + a] = mesh.vertices()[t.v[k]].p_W[a];
    }
    out.push_back(tri);
  }
  std::sort(out.begin(), out.end());
  return out;
}

TEST_CASE("after evicting one of two spheres the mesh is that of the other alone") {
  // Sphere A at x < 0 (finest scale), sphere B at x > 0.3 m (scale 1): their bands share no
  // block, so the blocks kept after evicting x > 0 are exactly those of a map of A alone.
  const Eigen::Vector3f centre_a(-0.33f, 0.01f, -0.02f);
  const Eigen::Vector3f centre_b(0.35f, -0.03f, 0.02f);
  constexpr float kRadiusA_m = 0.2f;
  constexpr float kRadiusB_m = 0.15f;
  auto sdf_a = [&](const Eigen::Vector3f& p_W) { return (p_W - centre_a).norm() - kRadiusA_m; };
  auto sdf_both = [&](const Eigen::Vector3f& p_W) {
    return std::min(sdf_a(p_W), (p_W - centre_b).norm() - kRadiusB_m);
  };
  auto scale_of = [](const Eigen::Vector3i& c) { return c.x() < 8 ? 0 : 1; };
  test::OwnedMap<MultiresVoxel> both(test_map_config());
  test::fill_band(both.map, kMu_m, sdf_both, scale_of);
  std::vector<std::uint32_t> evict;
  for (std::uint32_t i = 0; i < both.map.block_count(); ++i) {
    if (both.map.block_centre_W(both.map.block(i).coords).x() > 0.0f) evict.push_back(i);
  }
  both.map.evict_blocks(evict.data(), evict.size());
  // A alone, its blocks allocated in the evicted map's pool order: the mesher then meets them in
  // the same order (a vertex on a block face is computed by the first block that reaches it).
  test::OwnedMap<MultiresVoxel> alone(test_map_config());
  for (std::uint32_t i = 0; i < both.map.block_count(); ++i) {
    const Eigen::Vector3i c = both.map.block(i).coords;
    Result<std::uint32_t> index = alone.map.allocate_block(c);
    REQUIRE(index.ok());
    REQUIRE(index.value() == i);
    test::fill_block(alone.map, alone.map.block(i), scale_of(c), kMu_m, sdf_a);
  }
  // Every block of A's band is there, and no other.
  test::OwnedMap<MultiresVoxel> banded(test_map_config());
  REQUIRE(static_cast<int>(alone.map.block_count()) ==
          test::fill_band(banded.map, kMu_m, sdf_a, scale_of));

  Meshing<MultiresVoxel> after;
  Meshing<MultiresVoxel> expected;
  REQUIRE(after.mesher.extract(both.map, after.buffer).ok());
  REQUIRE(expected.mesher.extract(alone.map, expected.buffer).ok());
  REQUIRE(expected.buffer.triangles().size() > 1000u);
  REQUIRE(triangle_set(after.buffer) == triangle_set(expected.buffer));
  REQUIRE(after.buffer.vertices().size() == expected.buffer.vertices().size());
  REQUIRE(check_edges(after.buffer).boundary_edges == 0u);
}

}  // namespace
}  // namespace octofuse
