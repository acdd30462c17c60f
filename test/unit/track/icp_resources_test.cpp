// The tracker's contract: exact arena bytes, the same poses for any worker count, no heap after
// reserve, bad arguments and corrupt models refused without touching the pose.

#include "octofuse/track/icp.hpp"

#include <catch2/catch.hpp>

#include "unit/track/icp_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("ArenaSizer gives the exact bytes the tracker takes") {
  ArenaSizer sizer;
  IcpTracker tracker;
  REQUIRE(tracker.reserve(sizer, TrackConfig{}, 320, 240).ok());
  test::ArenaBuffer exact(sizer.bytes_used());
  REQUIRE(tracker.reserve(exact.arena(), TrackConfig{}, 320, 240).ok());
  CHECK(exact.arena().bytes_used() == sizer.bytes_used());
  test::ArenaBuffer short_buffer(sizer.bytes_used() - 1);
  CHECK(tracker.reserve(short_buffer.arena(), TrackConfig{}, 320, 240) ==
        StatusCode::resource_exhausted);
  TrackConfig bad;
  bad.min_normal_dot = 2.0f;
  CHECK(tracker.reserve(sizer, bad, 320, 240) == StatusCode::invalid_argument);
  bad = TrackConfig{};
  bad.iterations[1] = -1;
  CHECK(tracker.set_config(bad) == StatusCode::invalid_argument);
}

TEST_CASE("1 and 2 workers give bit-identical poses and reports") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(scene, offset_pose(), 1, 0.004f);

  Se3d one = T_W_Cref;
  Se3d two = T_W_Cref;
  const TrackReport r1 = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref,
                                         one, WorkerTeam(1));
  const TrackReport r2 = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref,
                                         two, WorkerTeam(2));
  REQUIRE(r1.tracked());
  CHECK(std::memcmp(one.matrix().data(), two.matrix().data(), sizeof(double) * 16) == 0);
  CHECK(r1.rms_residual_m == r2.rms_residual_m);
  CHECK(r1.inliers == r2.inliers);
  for (int level = 0; level < kPyramidLevels; ++level) {
    CHECK(r1.iterations[level] == r2.iterations[level]);
  }
}

TEST_CASE("track allocates nothing after reserve") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(scene, offset_pose());
  const WorkerTeam team1(1);
  const WorkerTeam team2(2);
  Se3d T_W_C = T_W_Cref;
  test::AllocationScope scope;
  const TrackReport r1 =
      f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, T_W_C, team1);
  T_W_C = T_W_Cref;
  const TrackReport r2 =
      f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, T_W_C, team2);
  const std::uint64_t allocations = scope.allocations();
  CHECK(allocations == 0);
  CHECK(r1.tracked());
  CHECK(r2.tracked());
}

TEST_CASE("bad arguments are refused without touching the pose") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(scene, T_W_Cref);
  const WorkerTeam team(1);

  SECTION("before reserve") {
    IcpTracker unreserved;
    Se3d T_W_C = T_W_Cref;
    const TrackReport r =
        unreserved.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, T_W_C, team);
    CHECK(r.status == StatusCode::failed_precondition);
    CHECK(r.outcome == TrackOutcome::failed);
  }
  SECTION("model of another size than the camera") {
    PinholeCamera camera = f.camera_level0();
    camera.width = 160;
    Se3d T_W_C = T_W_Cref;
    const TrackReport r =
        f.tracker.track(f.pre.pyramid(), model.map(), camera, T_W_Cref, T_W_C, team);
    CHECK(r.status == StatusCode::invalid_argument);
    CHECK(T_W_C.matrix() == T_W_Cref.matrix());
  }
  SECTION("a non-finite guess") {
    Se3d T_W_C = T_W_Cref;
    T_W_C.translation().x() = std::numeric_limits<double>::quiet_NaN();
    const TrackReport r =
        f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, T_W_C, team);
    CHECK(r.status == StatusCode::invalid_argument);
    CHECK(std::isnan(T_W_C.translation().x()));
  }
  SECTION("a pyramid of another size than reserved") {
    IcpTracker small;
    ArenaSizer sizer;
    REQUIRE(small.reserve(sizer, TrackConfig{}, 160, 120).ok());
    test::ArenaBuffer buffer(sizer.bytes_used());
    REQUIRE(small.reserve(buffer.arena(), TrackConfig{}, 160, 120).ok());
    Se3d T_W_C = T_W_Cref;
    const TrackReport r =
        small.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, T_W_C, team);
    CHECK(r.status == StatusCode::invalid_argument);
  }
  CHECK(std::string(track_outcome_name(TrackOutcome::lost_inliers)) == "lost_inliers");
}

TEST_CASE("a corrupt model (NaN vertices, non-unit normals) never crashes or poisons the pose") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (std::size_t i = 0; i < model.vertices_W.size(); i += 3) {
    model.vertices_W[i] = Eigen::Vector3f(nan, 0.0f, 1.0f);
    model.normals_W[i + 1] = Eigen::Vector3f(nan, nan, nan);
  }
  f.set_live(scene, offset_pose());
  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1));
  CHECK(report.status.ok());
  CHECK(T_W_C.matrix().allFinite());
  CHECK(std::isfinite(report.rms_residual_m));
  // A third of the pairs are gone, the rest still pin the pose down.
  CHECK(report.tracked());
  CHECK(translation_error_m(T_W_C, offset_pose()) < kTranslationTolerance_m);
}

}  // namespace
}  // namespace octofuse
