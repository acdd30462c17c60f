// Free space and map queries on an analytic scene: a wall at z = 2 m in front of a camera at the
// origin looking along +z, fused with exact depth. Every expected answer follows from that
// geometry.
#include "octofuse/query/map_query.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/fusion/integrator.hpp"
#include "octofuse/query/free_space.hpp"
#include "support/aligned_buffer.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

using test::AnalyticScene;

constexpr float kVoxel_m = 0.02f;
constexpr float kMu_m = 0.1f;
constexpr double kWall_m = 2.0;
// Interpolated signed distance next to a plane fused head-on: within half a voxel.
constexpr float kDistanceTolerance_m = 0.5f * kVoxel_m;

PinholeCamera small_camera() {
  return test::centred_camera(160, 120, 120.0f);
}

AnalyticScene wall_at(double z_m) {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), z_m});
  return scene;
}

// A multires map, an integrator and the free space over one arena; each fuse() integrates and
// carves one frame, as the pipeline does.
struct Mapper {
  explicit Mapper(FreeSpaceConfig free_config = FreeSpaceConfig())
      : camera(small_camera()),
        map_config(
            MapConfig::centred(Eigen::Vector3f(0.0f, 0.0f, 1.5f), kVoxel_m, 8, 20000, 20000)),
        fusion([] {
          FusionConfig c;
          c.mu_m = kMu_m;
          c.far_m = 6.0f;
          c.max_blocks_per_frame = 1u << 15;
          return c;
        }()),
        buffer(Octree<MultiresVoxel>::bytes_required(map_config) +
               Integrator<MultiresVoxel>::bytes_required(fusion, camera.width, camera.height) +
               FreeSpace::bytes_required(with_defaults(free_config), map_config, camera.width,
                                         camera.height)) {
    REQUIRE(map.reserve(buffer.arena(), map_config).ok());
    REQUIRE(integrator.reserve(buffer.arena(), fusion, camera.width, camera.height).ok());
    REQUIRE(free_space
                .reserve(buffer.arena(), with_defaults(free_config), map_config, camera.width,
                         camera.height)
                .ok());
    REQUIRE(buffer.arena().bytes_used() == buffer.bytes());
  }
  static FreeSpaceConfig with_defaults(FreeSpaceConfig c) {
    c.clearance_m = 0.5f * kMu_m;
    c.occlusion_clear_m = 4.0f * kMu_m;
    return c;
  }

  FreeSpaceReport fuse(const AnalyticScene& scene, const Se3d& T_W_C = Se3d::Identity(),
                       int workers = 1) {
    scene.render(camera, T_W_C, depth);
    ImageView<const float> view(depth.data(), camera.width, camera.height);
    WorkerTeam team(workers);
    const IntegrationReport fused =
        integrator.integrate(map, view, camera, T_W_C, frame, FusionBudget(), team);
    REQUIRE(fused.status.ok());
    return free_space.carve(view, camera, T_W_C, frame++);
  }
  MapQuery<MultiresVoxel> query() const { return MapQuery<MultiresVoxel>(map, &free_space, kMu_m); }

  PinholeCamera camera;
  MapConfig map_config;
  FusionConfig fusion;
  test::ArenaBuffer buffer;
  Octree<MultiresVoxel> map;
  Integrator<MultiresVoxel> integrator;
  FreeSpace free_space;
  std::vector<float> depth;
  std::uint32_t frame = 0;
};

PointAnswer ask(const Mapper& m, float x, float y, float z) {
  const Result<PointAnswer> a = m.query().point(Eigen::Vector3f(x, y, z));
  REQUIRE(a.ok());
  return a.value();
}

RegionState box_state(const Mapper& m, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  const Result<RegionAnswer> a = m.query().box(lo, hi);
  REQUIRE(a.ok());
  REQUIRE(!a.value().budget_hit);
  return a.value().state;
}

TEST_CASE("free space: air between the camera and a wall is free at a coarse octant") {
  Mapper m;
  const FreeSpaceReport report = m.fuse(wall_at(kWall_m));
  REQUIRE(report.marked_free > 0);
  REQUIRE(!report.budget_hit);

  const Eigen::Vector3f p_W(0.0f, 0.0f, 1.0f);
  const FreeOctant octant = m.free_space.find(m.map.point_to_voxel(p_W));
  REQUIRE(octant.free);
  // Coarser than a block: a 16 cm block is level 5 here, the octant at least 32 cm.
  REQUIRE(octant.level < m.free_space.leaf_level());
  REQUIRE(octant.size_voxels >= 16);

  const PointAnswer a = ask(m, 0.0f, 0.0f, 1.0f);
  REQUIRE(a.state == PointState::free);
  // A lower bound: positive, and not beyond the true 1 m to the wall.
  REQUIRE(a.distance_m > 0.0f);
  REQUIRE(a.distance_m <= 1.0f);
  // Nothing within a voxel of the wall reads free.
  for (float z = 0.3f; z < 2.5f; z += 0.01f) {
    const PointAnswer b = ask(m, 0.05f, -0.03f, z);
    if (b.state == PointState::free) REQUIRE(z < kWall_m - kVoxel_m);
  }
}

TEST_CASE("points near the wall are near with the signed distance, behind it never free") {
  Mapper m;
  for (int i = 0; i < 3; ++i) m.fuse(wall_at(kWall_m));
  for (float d : {0.06f, 0.03f, 0.01f, -0.02f, -0.05f}) {
    const PointAnswer a = ask(m, 0.01f, 0.02f, static_cast<float>(kWall_m) - d);
    REQUIRE(a.state == PointState::near);
    REQUIRE(a.distance_m == Approx(d).margin(kDistanceTolerance_m));
    REQUIRE(a.has_gradient);
    // The distance grows towards the camera (-z).
    REQUIRE(a.gradient.z() < -0.8f);
  }
  for (float z : {2.2f, 2.6f, 3.5f}) {
    const PointAnswer a = ask(m, 0.0f, 0.0f, z);
    REQUIRE((a.state == PointState::inside || a.state == PointState::unknown));
  }
  REQUIRE(ask(m, 0.0f, 0.0f, 10.0f).state == PointState::outside);
  REQUIRE(ask(m, 0.0f, 0.0f, -5.0f).state == PointState::outside);
  // Beside the view: never seen.
  REQUIRE(ask(m, 2.0f, 0.0f, 1.0f).state == PointState::unknown);
}

TEST_CASE("boxes, spheres and swept spheres: free only when every part is seen free") {
  Mapper m;
  for (int i = 0; i < 3; ++i) m.fuse(wall_at(kWall_m));
  // In the air in front of the wall.
  REQUIRE(box_state(m, Eigen::Vector3f(-0.2f, -0.2f, 0.9f), Eigen::Vector3f(0.2f, 0.2f, 1.4f)) ==
          RegionState::free);
  // Straddling the wall.
  REQUIRE(box_state(m, Eigen::Vector3f(-0.1f, -0.1f, 1.9f), Eigen::Vector3f(0.1f, 0.1f, 2.1f)) ==
          RegionState::blocked);
  // Touching the wall's near side only through its last centimetre.
  REQUIRE(box_state(m, Eigen::Vector3f(-0.1f, -0.1f, 1.5f), Eigen::Vector3f(0.1f, 0.1f, 1.995f)) ==
          RegionState::blocked);
  // Sticking out of the view at the side.
  REQUIRE(box_state(m, Eigen::Vector3f(0.3f, -0.1f, 0.9f), Eigen::Vector3f(1.5f, 0.1f, 1.1f)) ==
          RegionState::unknown);
  // Partly outside the cube.
  REQUIRE(box_state(m, Eigen::Vector3f(-0.1f, -0.1f, 1.0f), Eigen::Vector3f(0.1f, 0.1f, 9.0f)) !=
          RegionState::free);

  const MapQuery<MultiresVoxel> q = m.query();
  REQUIRE(q.sphere(Eigen::Vector3f(0.0f, 0.0f, 1.2f), 0.2f).value().state == RegionState::free);
  REQUIRE(q.sphere(Eigen::Vector3f(0.0f, 0.0f, 1.85f), 0.2f).value().state == RegionState::blocked);
  // A path step towards the wall ending 5 cm short of it, with a 10 cm radius: blocked.
  REQUIRE(
      q.swept_sphere(Eigen::Vector3f(0.0f, 0.0f, 1.0f), Eigen::Vector3f(0.0f, 0.0f, 1.95f), 0.1f)
          .value()
          .state == RegionState::blocked);
  REQUIRE(q.swept_sphere(Eigen::Vector3f(0.0f, 0.0f, 0.8f), Eigen::Vector3f(0.1f, 0.0f, 1.3f), 0.1f)
              .value()
              .state == RegionState::free);
  // Through unseen space beside the view.
  REQUIRE(q.swept_sphere(Eigen::Vector3f(0.0f, 0.0f, 1.0f), Eigen::Vector3f(2.0f, 0.0f, 1.0f), 0.1f)
              .value()
              .state == RegionState::unknown);
  // A visit limit that binds answers unknown and says so.
  QueryLimits tiny;
  tiny.max_visits = 3;
  const RegionAnswer capped =
      q.box(Eigen::Vector3f(-0.1f, -0.1f, 1.9f), Eigen::Vector3f(0.1f, 0.1f, 2.1f), tiny).value();
  REQUIRE(capped.budget_hit);
  REQUIRE(capped.state == RegionState::unknown);
  REQUIRE(capped.visits == 3);
}

TEST_CASE("a wall that moves away heals: its old place reads free, the new wall near") {
  Mapper m;
  for (int i = 0; i < 3; ++i) m.fuse(wall_at(kWall_m));
  REQUIRE(ask(m, 0.0f, 0.0f, 2.0f).state == PointState::near);
  for (int i = 0; i < 2; ++i) m.fuse(wall_at(3.0));
  REQUIRE(ask(m, 0.0f, 0.0f, 2.0f).state == PointState::free);
  REQUIRE(box_state(m, Eigen::Vector3f(-0.1f, -0.1f, 1.9f), Eigen::Vector3f(0.1f, 0.1f, 2.1f)) ==
          RegionState::free);
  const PointAnswer a = ask(m, 0.0f, 0.0f, 2.97f);
  REQUIRE(a.state == PointState::near);
  REQUIRE(a.distance_m == Approx(0.03f).margin(kDistanceTolerance_m));
}

TEST_CASE("a wall that appears in free space overrides it") {
  Mapper m;
  for (int i = 0; i < 2; ++i) m.fuse(wall_at(3.0));
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.6f).state == PointState::free);
  const FreeSpaceReport report = m.fuse(wall_at(1.5));
  REQUIRE(report.cleared > 0);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::near);
  // Just behind the new wall, within the cleared depth: no longer free.
  REQUIRE(ask(m, 0.0f, 0.0f, 1.65f).state != PointState::free);
  REQUIRE(box_state(m, Eigen::Vector3f(-0.1f, -0.1f, 1.4f), Eigen::Vector3f(0.1f, 0.1f, 1.6f)) ==
          RegionState::blocked);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.0f).state == PointState::free);
}

TEST_CASE("carving is bit-identical for 1 and 2 workers and stays within its budgets") {
  Mapper one;
  Mapper two;
  AnalyticScene scene = wall_at(kWall_m);
  scene.spheres.push_back({Eigen::Vector3d(0.2, 0.1, 1.4), 0.15});
  for (int i = 0; i < 4; ++i) {
    Se3d T_W_C = Se3d::Identity();
    T_W_C.translation() = Eigen::Vector3d(0.05 * i, -0.02 * i, 0.1 * i);
    one.fuse(scene, T_W_C, 1);
    two.fuse(scene, T_W_C, 2);
  }
  REQUIRE(one.free_space.node_count() == two.free_space.node_count());
  REQUIRE(one.free_space.node_count() > 1);
  for (std::uint32_t i = 0; i < one.free_space.node_count(); ++i) {
    REQUIRE(std::memcmp(&one.free_space.node(i), &two.free_space.node(i), sizeof(FreeNode)) == 0);
  }

  FreeSpaceConfig tight;
  tight.max_node_visits = 50;
  tight.max_new_nodes = 10;
  Mapper capped(tight);
  const FreeSpaceReport report = capped.fuse(scene);
  REQUIRE(report.budget_hit);
  REQUIRE(report.node_visits <= 50);
  REQUIRE(report.new_nodes <= 10);
  REQUIRE(capped.free_space.node_count() <= 11);
}

TEST_CASE("octants down to 2 voxels carve closer to the view's edges, and no closer to the wall") {
  FreeSpaceConfig fine_config;
  fine_config.finest_octant_voxels = 2;
  Mapper fine(fine_config);
  Mapper coarse;
  fine.fuse(wall_at(kWall_m));
  coarse.fuse(wall_at(kWall_m));
  REQUIRE(fine.free_space.leaf_level() == coarse.free_space.leaf_level() + 2);
  int fine_free = 0;
  int coarse_free = 0;
  for (float z = 0.5f; z < 2.3f; z += 0.02f) {
    for (float y = -0.6f; y <= 0.6f; y += 0.05f) {
      const PointAnswer f = ask(fine, 0.03f, y, z);
      const PointAnswer c = ask(coarse, 0.03f, y, z);
      if (f.state == PointState::free) {
        ++fine_free;
        REQUIRE(z < kWall_m - kVoxel_m);
      }
      if (c.state == PointState::free) ++coarse_free;
      // Whatever the coarse octants call free, the fine ones do too.
      if (c.state == PointState::free) REQUIRE(f.state == PointState::free);
    }
  }
  REQUIRE(fine_free > coarse_free);
  REQUIRE(box_state(fine, Eigen::Vector3f(-0.1f, -0.1f, 1.9f), Eigen::Vector3f(0.1f, 0.1f, 2.1f)) ==
          RegionState::blocked);
  REQUIRE(box_state(fine, Eigen::Vector3f(-0.2f, -0.2f, 0.9f), Eigen::Vector3f(0.2f, 0.2f, 1.4f)) ==
          RegionState::free);
  FreeSpaceConfig bad;
  bad.finest_octant_voxels = 3;
  REQUIRE(validate(bad).code() == StatusCode::invalid_argument);
}

TEST_CASE("octants of several blocks (the automatic choice for fine voxels) stay safe") {
  // kVoxel_m is 2 cm, so the automatic choice is a block (8 voxels, 16 cm); 16 voxels are the
  // coarser leaves fine voxels get.
  FreeSpaceConfig coarse_config;
  coarse_config.finest_octant_voxels = 16;
  Mapper coarse(coarse_config);
  Mapper block;
  REQUIRE(block.free_space.config().finest_octant_voxels == 8);
  coarse.fuse(wall_at(kWall_m));
  block.fuse(wall_at(kWall_m));
  REQUIRE(coarse.free_space.leaf_level() == block.free_space.leaf_level() - 1);
  int coarse_free = 0;
  for (float z = 0.5f; z < 2.3f; z += 0.02f) {
    for (float y = -0.6f; y <= 0.6f; y += 0.05f) {
      const PointAnswer c = ask(coarse, 0.03f, y, z);
      const PointAnswer b = ask(block, 0.03f, y, z);
      if (c.state == PointState::free) {
        ++coarse_free;
        REQUIRE(z < kWall_m - kVoxel_m);
        REQUIRE(c.distance_m <= kWall_m - z);  // a lower bound on the distance to the wall
        REQUIRE(b.state == PointState::free);  // what the coarse octants call free, blocks do too
      }
    }
  }
  REQUIRE(coarse_free > 100);
  REQUIRE(box_state(coarse, Eigen::Vector3f(-0.1f, -0.1f, 1.9f),
                    Eigen::Vector3f(0.1f, 0.1f, 2.1f)) == RegionState::blocked);
  REQUIRE(box_state(coarse, Eigen::Vector3f(-0.2f, -0.2f, 0.9f),
                    Eigen::Vector3f(0.2f, 0.2f, 1.4f)) == RegionState::free);
  // The automatic choice from the voxel size, and octant sides refused.
  MapConfig map;
  map.voxel_size_m = 0.01f;
  CHECK(resolve_finest_octant_voxels(0, map) == 8);
  map.voxel_size_m = 0.002f;
  CHECK(resolve_finest_octant_voxels(0, map) == 32);
  map.voxel_size_m = 0.005f;
  CHECK(resolve_finest_octant_voxels(0, map) == 16);
  CHECK(resolve_finest_octant_voxels(4, map) == 4);
  CHECK(free_leaf_level(10, 8) == 10);
  CHECK(free_leaf_level(10, 2) == 12);
  CHECK(free_leaf_level(10, 64) == 7);
  FreeSpaceConfig bad;
  for (int side : {1, 3, 12, 128, -8}) {
    bad.finest_octant_voxels = side;
    CHECK(validate(bad).code() == StatusCode::invalid_argument);
  }
}

// Exact distance to the wall and the spheres of `scene` (planes z = offset, as wall_at makes).
double exact_distance(const AnalyticScene& scene, const Eigen::Vector3d& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const AnalyticScene::Plane& plane : scene.planes) {
    best = std::min(best, std::abs(plane.normal.dot(p) - plane.offset_m));
  }
  for (const AnalyticScene::Sphere& sphere : scene.spheres) {
    best = std::min(best, (p - sphere.centre_W).norm() - sphere.radius_m);
  }
  return best;
}

TEST_CASE("pixels without depth neither carve nor clear; the rest of the view still carves") {
  Mapper m;
  const AnalyticScene scene = wall_at(kWall_m);
  for (int i = 0; i < 2; ++i) m.fuse(scene);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.8f).state == PointState::free);
  // A frame with a hole in the middle (no depth there, as on a black or shiny patch).
  scene.render(m.camera, Se3d::Identity(), m.depth);
  for (int v = 50; v < 70; ++v) {
    for (int u = 70; u < 90; ++u) m.depth[static_cast<std::size_t>(v * m.camera.width + u)] = 0.0f;
  }
  ImageView<const float> holed(m.depth.data(), m.camera.width, m.camera.height);
  const FreeSpaceReport report = m.free_space.carve(holed, m.camera, Se3d::Identity(), m.frame++);
  REQUIRE(!report.budget_hit);
  // What was seen free in front of the hole stays free.
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.8f).state == PointState::free);

  // A map that only ever saw the holed frame: free around the hole, never in front of it.
  Mapper fresh;
  fresh.free_space.carve(holed, fresh.camera, Se3d::Identity(), fresh.frame++);
  REQUIRE(ask(fresh, 0.0f, 0.0f, 1.5f).state == PointState::unknown);
  // 30 pixels off the hole's edge at 1.5 m (about 0.35 m beside the axis).
  REQUIRE(ask(fresh, 0.55f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(fresh, 0.0f, 0.45f, 1.5f).state == PointState::free);
}

TEST_CASE("the depth range of any pixel rectangle is the brute-force one") {
  // Random depths, holes and beyond-range pixels; every rectangle's range from the range table
  // equals the one computed pixel by pixel.
  Mapper m;
  const int w = m.camera.width;
  const int h = m.camera.height;
  const float range_end_m = 3.5f;
  std::vector<float> depth(static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
  std::vector<std::uint8_t> beyond(depth.size(), 0);
  std::uint32_t state = 12345u;
  auto next = [&state]() {
    state = state * 1664525u + 1013904223u;
    return state >> 8;
  };
  for (std::size_t i = 0; i < depth.size(); ++i) {
    const std::uint32_t r = next() % 100u;
    depth[i] = r < 10 ? 0.0f : 0.3f + static_cast<float>(next() % 3000u) * 0.001f;
    beyond[i] = r < 5 ? 1 : 0;
  }
  const ImageView<const float> depth_view(depth.data(), w, h);
  const ImageView<const std::uint8_t> beyond_view(beyond.data(), w, h);
  m.free_space.carve(depth_view, m.camera, Se3d::Identity(), m.frame++, beyond_view, range_end_m);
  for (int trial = 0; trial < 3000; ++trial) {
    int u0 = static_cast<int>(next() % static_cast<std::uint32_t>(w));
    int v0 = static_cast<int>(next() % static_cast<std::uint32_t>(h));
    // Mostly small rectangles, some up to the whole image.
    const std::uint32_t max_side = trial % 4 == 0 ? 200u : 24u;
    int u1 = u0 + static_cast<int>(next() % max_side);
    int v1 = v0 + static_cast<int>(next() % max_side);
    const FreeSpace::PixelRange got = m.free_space.pixel_range(u0, v0, u1, v1);
    u1 = std::min(u1, w - 1);
    v1 = std::min(v1, h - 1);
    float lo = FreeSpace::kNoDepth;
    float hi = 0.0f;
    bool invalid = false;
    for (int v = v0; v <= v1; ++v) {
      for (int u = u0; u <= u1; ++u) {
        const std::size_t i =
            static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
        if (depth[i] > 0.0f) {
          lo = std::min(lo, depth[i]);
          hi = std::max(hi, depth[i]);
        } else if (beyond[i] != 0) {
          lo = std::min(lo, range_end_m);
        } else {
          invalid = true;
        }
      }
    }
    REQUIRE(got.lo_m == lo);
    REQUIRE(got.hi_m == hi);
    REQUIRE(got.any_invalid == invalid);
  }
  // Clipped to the image; wholly outside it nothing is measured.
  const FreeSpace::PixelRange all = m.free_space.pixel_range(-5, -5, w + 5, h + 5);
  REQUIRE(all.any_invalid);
  REQUIRE(all.hi_m > 0.0f);
  const FreeSpace::PixelRange outside = m.free_space.pixel_range(w, 0, w + 3, 4);
  REQUIRE(outside.lo_m == FreeSpace::kNoDepth);
  REQUIRE(outside.hi_m == 0.0f);
}

TEST_CASE("pixels measured beyond the range carve in front of its end and clear nothing behind") {
  // Every pixel saw a surface beyond the range (depth 0, marked beyond): free out to the range's
  // end less the clearance, unknown past it.
  const float range_end_m = 1.2f;
  std::vector<float> no_depth;
  std::vector<std::uint8_t> all_beyond;
  {
    Mapper m;
    no_depth.assign(
        static_cast<std::size_t>(m.camera.width) * static_cast<std::size_t>(m.camera.height), 0.0f);
    all_beyond.assign(no_depth.size(), 1);
    const ImageView<const float> depth(no_depth.data(), m.camera.width, m.camera.height);
    const ImageView<const std::uint8_t> beyond(all_beyond.data(), m.camera.width, m.camera.height);
    // Without the mask the frame shows nothing.
    m.free_space.carve(depth, m.camera, Se3d::Identity(), m.frame++);
    REQUIRE(ask(m, 0.0f, 0.0f, 0.8f).state == PointState::unknown);
    const FreeSpaceReport report =
        m.free_space.carve(depth, m.camera, Se3d::Identity(), m.frame++, beyond, range_end_m);
    REQUIRE(!report.budget_hit);
    REQUIRE(report.marked_free > 0);
    REQUIRE(ask(m, 0.0f, 0.0f, 0.8f).state == PointState::free);
    REQUIRE(ask(m, 0.1f, -0.1f, 1.0f).state == PointState::free);
    // Nothing free at or past the range's end less the clearance.
    for (float z = 1.2f - 0.5f * kMu_m; z < 3.0f; z += 0.01f) {
      REQUIRE(ask(m, 0.0f, 0.0f, z).state == PointState::unknown);
    }
    // A mask whose size is not the image's is ignored.
    Mapper other;
    const ImageView<const std::uint8_t> wrong(all_beyond.data(), m.camera.width - 1,
                                              m.camera.height);
    other.free_space.carve(depth, other.camera, Se3d::Identity(), other.frame++, wrong,
                           range_end_m);
    REQUIRE(ask(other, 0.0f, 0.0f, 0.8f).state == PointState::unknown);
  }
  // Free space seen earlier behind the range's end: a surface measured there would clear it (it
  // lies within the occlusion depth behind), a ray that went beyond the range does not.
  Mapper m;
  const AnalyticScene scene = wall_at(kWall_m);
  for (int i = 0; i < 2; ++i) m.fuse(scene);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  const ImageView<const float> depth(no_depth.data(), m.camera.width, m.camera.height);
  const ImageView<const std::uint8_t> beyond(all_beyond.data(), m.camera.width, m.camera.height);
  const float end_m = 1.4f;
  m.free_space.carve(depth, m.camera, Se3d::Identity(), m.frame++, beyond, end_m);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.8f).state == PointState::free);
  std::vector<float> flat(no_depth.size(), end_m);
  const ImageView<const float> surface(flat.data(), m.camera.width, m.camera.height);
  m.free_space.carve(surface, m.camera, Se3d::Identity(), m.frame++);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::unknown);
}

TEST_CASE("exact silhouettes: a nearer object's silhouette neither clears free air nor hides it") {
  // The wall at 2 m, then a ball 0.8 m in front of the camera. The ball's shadow at 1.5 m
  // reaches about 0.19 m from the axis. Its depth lies far (more than occlusion_clear_m) in front
  // of the air there, so it is no evidence about that air either way: octants that see the
  // ball's edge and the wall behind are settled pixel by pixel.
  AnalyticScene ball = wall_at(kWall_m);
  ball.spheres.push_back({Eigen::Vector3d(0.0, 0.0, 0.8), 0.1});
  FreeSpaceConfig exact;
  exact.exact_silhouettes = true;
  Mapper fresh(exact);
  fresh.fuse(ball);
  fresh.fuse(ball);
  // Seen only with the ball: free from a leaf's width beside the shadow to short of the image's
  // border, unknown in the shadow.
  for (float x = 0.34f; x <= 0.58f; x += 0.02f) {
    INFO("x " << x);
    REQUIRE(ask(fresh, x, 0.0f, 1.5f).state == PointState::free);
    REQUIRE(ask(fresh, -x, 0.0f, 1.5f).state == PointState::free);
    REQUIRE(ask(fresh, 0.0f, x, 1.5f).state == PointState::free);
  }
  for (float z = 1.1f; z < 1.8f; z += 0.02f) {
    INFO("z " << z);
    REQUIRE(ask(fresh, 0.0f, 0.0f, z).state == PointState::unknown);
    REQUIRE(ask(fresh, 0.05f, -0.05f, z).state == PointState::unknown);
  }
  // Seen free first, then the ball passes in front: the air across its silhouette stays free.
  Mapper m(exact);
  const AnalyticScene wall = wall_at(kWall_m);
  m.fuse(wall);
  m.fuse(wall);
  for (float x = 0.0f; x <= 0.4f; x += 0.02f) {
    REQUIRE(ask(m, x, 0.0f, 1.5f).state == PointState::free);
  }
  m.fuse(ball);
  m.fuse(ball);
  for (float x = 0.0f; x <= 0.4f; x += 0.02f) {
    INFO("x " << x);
    REQUIRE(ask(m, x, 0.0f, 1.5f).state == PointState::free);
    REQUIRE(ask(m, 0.0f, -x, 1.5f).state == PointState::free);
  }
  // The ball itself and the air just around it are not free.
  REQUIRE(ask(m, 0.0f, 0.0f, 0.8f).state != PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 0.69f).state != PointState::free);
  REQUIRE(ask(m, 0.11f, 0.0f, 0.8f).state != PointState::free);
}

TEST_CASE(
    "leaves carve by halves: air beside a surface in a leaf's view is free, the surface not") {
  AnalyticScene scene = wall_at(kWall_m);
  scene.spheres.push_back({Eigen::Vector3d(0.1, 0.05, 1.3), 0.12});
  Mapper m;
  for (int i = 0; i < 3; ++i) {
    Se3d T_W_C = Se3d::Identity();
    T_W_C.translation() = Eigen::Vector3d(0.03 * i, -0.02 * i, 0.0);
    m.fuse(scene, T_W_C);
  }
  const int leaf = m.free_space.leaf_level();
  REQUIRE(m.free_space.sub_cell_voxels() == 4);
  int half_leaf_free = 0;
  int free_points = 0;
  for (float z = 0.4f; z < 2.2f; z += 0.01f) {
    for (float x = -0.4f; x <= 0.4f; x += 0.02f) {
      const Eigen::Vector3f p_W(x, 0.05f, z);
      const PointAnswer a = ask(m, p_W.x(), p_W.y(), p_W.z());
      if (a.state != PointState::free) continue;
      ++free_points;
      // Nothing within a voxel of the wall or the ball reads free.
      REQUIRE(exact_distance(scene, p_W.cast<double>()) > kVoxel_m);
      const FreeOctant o = m.free_space.find(m.map.point_to_voxel(p_W));
      if (o.free && o.level == leaf + 1) {
        ++half_leaf_free;
        REQUIRE(o.size_voxels == 4);
        // The octant holds the point.
        const Eigen::Vector3i v = m.map.point_to_voxel(p_W);
        REQUIRE(((v - o.min_voxel).array() >= 0).all());
        REQUIRE(((v - o.min_voxel).array() < 4).all());
      }
    }
  }
  REQUIRE(free_points > 1000);
  REQUIRE(half_leaf_free > 0);
  // A box over the ball's near side is blocked; one in the air beside the ball is free.
  REQUIRE(box_state(m, Eigen::Vector3f(0.05f, 0.0f, 1.1f), Eigen::Vector3f(0.15f, 0.1f, 1.2f)) ==
          RegionState::blocked);
  REQUIRE(box_state(m, Eigen::Vector3f(-0.35f, -0.05f, 0.8f), Eigen::Vector3f(-0.2f, 0.1f, 1.0f)) ==
          RegionState::free);
}

TEST_CASE("prune() forgets the free space far from a point and keeps the tree whole") {
  Mapper m;
  // Two views: one from the origin, one from 1.5 m to the side, each carving its own air.
  m.fuse(wall_at(kWall_m));
  Se3d side = Se3d::Identity();
  side.translation() = Eigen::Vector3d(1.5, 0.0, 0.0);
  m.fuse(wall_at(kWall_m), side);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.2f).state == PointState::free);
  REQUIRE(ask(m, 1.5f, 0.0f, 1.2f).state == PointState::free);
  const std::uint32_t before = m.free_space.node_count();

  const std::uint32_t dropped = m.free_space.prune(Eigen::Vector3f(1.5f, 0.0f, 0.0f), 1.4f);
  REQUIRE(dropped > 0);
  REQUIRE(m.free_space.node_count() == before - dropped);
  // Far from the centre: unknown again; near it: still free, and the same answers as before.
  REQUIRE(ask(m, -0.3f, 0.0f, 1.2f).state == PointState::unknown);
  REQUIRE(ask(m, 1.5f, 0.0f, 1.2f).state == PointState::free);
  // Children still come after their parents and inside the pool, each with one parent.
  const std::uint32_t count = m.free_space.node_count();
  std::vector<int> parents(count, 0);
  for (std::uint32_t i = 0; i < count; ++i) {
    for (std::uint32_t child : m.free_space.node(i).children) {
      if (child == FreeSpace::kNoNode) continue;
      REQUIRE(child > i);
      REQUIRE(child < count);
      ++parents[child];
    }
  }
  for (std::uint32_t i = 1; i < count; ++i) REQUIRE(parents[i] == 1);
  // Carving goes on in the compacted pool.
  m.fuse(wall_at(kWall_m));
  REQUIRE(ask(m, 0.0f, 0.0f, 1.2f).state == PointState::free);
  // A radius of 0 around a point outside the cube leaves the root alone.
  m.free_space.prune(Eigen::Vector3f(100.0f, 0.0f, 0.0f), 0.0f);
  REQUIRE(m.free_space.node_count() == 1);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.2f).state == PointState::unknown);
}

TEST_CASE("bad arguments get invalid_argument") {
  Mapper m;
  m.fuse(wall_at(kWall_m));
  const MapQuery<MultiresVoxel> q = m.query();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  const Eigen::Vector3f p(0.0f, 0.0f, 1.0f);
  REQUIRE(q.point(Eigen::Vector3f(nan, 0.0f, 1.0f)).status().code() ==
          StatusCode::invalid_argument);
  REQUIRE(q.box(p, Eigen::Vector3f(inf, 1.0f, 1.0f)).status().code() ==
          StatusCode::invalid_argument);
  REQUIRE(q.box(p, p - Eigen::Vector3f::Constant(0.1f)).status().code() ==
          StatusCode::invalid_argument);
  REQUIRE(q.sphere(p, -0.1f).status().code() == StatusCode::invalid_argument);
  REQUIRE(q.sphere(p, nan).status().code() == StatusCode::invalid_argument);
  REQUIRE(q.swept_sphere(p, Eigen::Vector3f(0.0f, nan, 0.0f), 0.1f).status().code() ==
          StatusCode::invalid_argument);
  QueryLimits none;
  none.max_visits = 0;
  REQUIRE(q.sphere(p, 0.1f, none).status().code() == StatusCode::invalid_argument);

  FreeSpaceConfig bad;
  bad.margin_m = -1.0f;
  REQUIRE(validate(bad).code() == StatusCode::invalid_argument);
  bad = FreeSpaceConfig();
  bad.clearance_m = nan;
  REQUIRE(validate(bad).code() == StatusCode::invalid_argument);
  bad = FreeSpaceConfig();
  bad.prune_radius_m = -1.0f;
  REQUIRE(validate(bad).code() == StatusCode::invalid_argument);
  bad = FreeSpaceConfig();
  bad.max_free_count = 0;
  REQUIRE(validate(bad).code() == StatusCode::invalid_argument);
  REQUIRE(validate(FreeSpaceConfig()).ok());
  // A zero sphere is a point: free in the air.
  REQUIRE(q.sphere(p, 0.0f).value().state == RegionState::free);
}

}  // namespace
}  // namespace octofuse
