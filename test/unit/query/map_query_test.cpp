// Map queries on the wall scene: points near, inside, outside and unknown with their signed
// distance; boxes, spheres and swept spheres free only when every part is seen free; bad
// arguments refused.

#include "octofuse/query/map_query.hpp"

#include <catch2/catch.hpp>

#include "unit/query/query_support.hpp"

namespace octofuse {
namespace {

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
