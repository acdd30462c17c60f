// Carving free space on the wall scene: coarse free octants, walls that move or appear, the
// same tree for any worker count within its budgets, octant sizes, leaves carved by halves,
// pruning.

#include "octofuse/query/free_space.hpp"

#include <catch2/catch.hpp>

#include "unit/query/query_support.hpp"

namespace octofuse {
namespace {

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

TEST_CASE("skipping leaves and sub-cell looks that can change nothing gives the full walk's tree") {
  // A wall, a sphere in front of it (a silhouette with air behind), a box and a tilted plane,
  // seen from poses that turn so that part of the view misses everything (pixels without depth):
  // the shortcuts must leave every node as classifying everything does.
  AnalyticScene scene = wall_at(kWall_m);
  scene.spheres.push_back({Eigen::Vector3d(0.2, 0.1, 1.3), 0.15});
  scene.boxes.push_back({Eigen::Vector3d(-0.3, 0.2, 1.6), Eigen::Vector3d(0.1, 0.2, 0.1),
                         Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitY()).toRotationMatrix()});
  scene.planes.push_back({Eigen::Vector3d(0.0, -0.8, 0.6).normalized(), -0.1});
  for (const int octant_voxels : {8, 4, 2}) {
    for (const bool exact : {false, true}) {
      FreeSpaceConfig config;
      config.finest_octant_voxels = octant_voxels;
      config.exact_silhouettes = exact;
      Mapper full(config);
      Mapper fast(config);
      full.free_space.set_exhaustive(true);
      std::uint64_t skipped = 0;
      for (int i = 0; i < 6; ++i) {
        Se3d T_W_C = Se3d::Identity();
        T_W_C.linear() = (Eigen::AngleAxisd(0.12 * i, Eigen::Vector3d::UnitY()) *
                          Eigen::AngleAxisd(-0.05 * i, Eigen::Vector3d::UnitX()))
                             .toRotationMatrix();
        T_W_C.translation() = Eigen::Vector3d(-0.04 * i, 0.02 * i, 0.08 * i);
        const FreeSpaceReport a = full.fuse(scene, T_W_C);
        const FreeSpaceReport b = fast.fuse(scene, T_W_C);
        REQUIRE(a.looks_skipped == 0);
        REQUIRE(a.node_visits == b.node_visits);
        REQUIRE(a.marked_free == b.marked_free);
        REQUIRE(a.cleared == b.cleared);
        skipped += b.looks_skipped;
      }
      CAPTURE(octant_voxels, exact);
      REQUIRE(skipped > 0);
      REQUIRE(full.free_space.node_count() == fast.free_space.node_count());
      int free_halves = 0;
      for (std::uint32_t i = 0; i < full.free_space.node_count(); ++i) {
        REQUIRE(std::memcmp(&full.free_space.node(i), &fast.free_space.node(i), sizeof(FreeNode)) ==
                0);
        if (full.free_space.node(i).sub_free != 0) ++free_halves;
      }
      // Leaves carved by halves: the sub-cell looks were taken and mattered.
      REQUIRE(free_halves > 0);
    }
  }
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

TEST_CASE("find() outside free space names an octant around the voxel that holds no free voxel") {
  AnalyticScene scene = wall_at(kWall_m);
  scene.spheres.push_back({Eigen::Vector3d(0.1, 0.05, 1.3), 0.12});
  Mapper m;
  m.fuse(scene, Se3d::Identity());
  const int sub = m.free_space.sub_cell_voxels();
  const int leaf_voxels = sub * 2;
  bool seen_sub = false;
  bool seen_leaf = false;
  bool seen_larger = false;
  int not_free = 0;
  for (float z = -0.2f; z < 2.4f; z += 0.01f) {
    for (float x = -0.6f; x <= 0.6f; x += 0.01f) {
      const Eigen::Vector3i v = m.map.point_to_voxel(Eigen::Vector3f(x, 0.05f, z));
      const FreeOctant o = m.free_space.find(v);
      if (o.free) continue;
      ++not_free;
      REQUIRE(o.size_voxels > 0);
      // A power of two, aligned to it, holding the voxel.
      REQUIRE((o.size_voxels & (o.size_voxels - 1)) == 0);
      for (int a = 0; a < 3; ++a) REQUIRE(o.min_voxel[a] % o.size_voxels == 0);
      REQUIRE(((v - o.min_voxel).array() >= 0).all());
      REQUIRE(((v - o.min_voxel).array() < o.size_voxels).all());
      seen_sub = seen_sub || o.size_voxels == sub;
      seen_leaf = seen_leaf || o.size_voxels == leaf_voxels;
      seen_larger = seen_larger || o.size_voxels > leaf_voxels;
      // No voxel of it is free: a lattice of 5^3 points over it, its corners included.
      const int last = o.size_voxels - 1;
      for (int k = 0; k < 125; ++k) {
        const Eigen::Vector3i at(last * (k % 5) / 4, last * (k / 5 % 5) / 4, last * (k / 25) / 4);
        const FreeOctant inside = m.free_space.find(o.min_voxel + at);
        REQUIRE(!inside.free);
        // The same octant: every voxel of it ends the tree's walk where this one did.
        REQUIRE(inside.size_voxels == o.size_voxels);
        REQUIRE(inside.min_voxel == o.min_voxel);
      }
    }
  }
  REQUIRE(not_free > 1000);
  REQUIRE(seen_sub);
  REQUIRE(seen_leaf);
  REQUIRE(seen_larger);
  // Outside the cube: nothing.
  const FreeOctant outside = m.free_space.find(Eigen::Vector3i(-1, 0, 0));
  REQUIRE(!outside.free);
  REQUIRE(outside.size_voxels == 0);
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

TEST_CASE("a pool smaller than a frame's carving keeps the nearest air and refuses nothing") {
  AnalyticScene scene = wall_at(kWall_m);
  scene.spheres.push_back({Eigen::Vector3d(0.1, 0.05, 1.3), 0.12});
  scene.spheres.push_back({Eigen::Vector3d(-0.3, -0.1, 0.9), 0.08});
  Mapper whole;
  const FreeSpaceReport all = whole.fuse(scene);
  REQUIRE(all.pool_refused == 0);
  REQUIRE(all.far_dropped == 0);
  FreeSpaceConfig small_config;
  small_config.node_capacity = all.new_nodes / 3;
  Mapper small(small_config);
  const FreeSpaceReport part = small.fuse(scene);
  INFO("whole frame " << all.new_nodes << " nodes; in a pool of " << small_config.node_capacity
                      << ": " << part.new_nodes << " made, " << part.far_dropped
                      << " beyond the distance that fits");
  REQUIRE(part.pool_refused == 0);
  REQUIRE(part.refused == 0);
  REQUIRE(part.far_dropped > 0);
  REQUIRE(small.free_space.node_count() <= small_config.node_capacity);
  REQUIRE(part.new_nodes > small_config.node_capacity / 2);  // the pool is used, not left idle
  // Safe: every point the small pool holds free, the whole carving holds free. Complete near the
  // camera: every free point within the distance that fitted is free there too; beyond it, less.
  int near_free = 0, near_kept = 0, far_free = 0, far_kept = 0;
  std::vector<Eigen::Vector3f> near_points;
  for (float z = 0.3f; z < 2.0f; z += 0.02f) {
    for (float x = -0.5f; x <= 0.5f; x += 0.04f) {
      for (float y = -0.3f; y <= 0.3f; y += 0.1f) {
        const bool in_whole = ask(whole, x, y, z).state == PointState::free;
        const bool in_small = ask(small, x, y, z).state == PointState::free;
        if (in_small) REQUIRE(in_whole);
        if (!in_whole) continue;
        const bool near = Eigen::Vector3f(x, y, z).norm() < 0.6f;
        if (near) near_points.emplace_back(x, y, z);
        (near ? near_free : far_free) += 1;
        (near ? near_kept : far_kept) += in_small ? 1 : 0;
      }
    }
  }
  INFO("free near " << near_kept << " of " << near_free << ", far " << far_kept << " of "
                    << far_free);
  REQUIRE(near_free > 0);
  REQUIRE(near_kept == near_free);
  REQUIRE(far_kept < far_free);
  // The next frame from the same pose carves on within the pool, again without refusals.
  const FreeSpaceReport again = small.fuse(scene);
  REQUIRE(again.pool_refused == 0);
  REQUIRE(small.free_space.node_count() <= small_config.node_capacity);
  for (const Eigen::Vector3f& p : near_points) {
    REQUIRE(ask(small, p.x(), p.y(), p.z()).state == PointState::free);
  }
}

}  // namespace
}  // namespace octofuse
