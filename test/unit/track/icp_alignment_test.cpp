// ICP alignment on synthetic pairs: known offsets recovered, the identity kept, noise and depth
// weighting within their bounds.

#include "octofuse/track/icp.hpp"

#include <catch2/catch.hpp>

#include "unit/track/icp_support.hpp"

namespace octofuse {
namespace {

// Already aligned: only float rounding of the rendered data remains.
constexpr double kIdentityTranslationTolerance_m = 5e-5;
constexpr double kIdentityRotationTolerance_deg = 5e-3;

TEST_CASE("ICP recovers a known small offset on a synthetic pair") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  REQUIRE(translation_error_m(T_W_Cref, T_W_C_true) > 4e-3);
  REQUIRE(rotation_error_deg(T_W_Cref, T_W_C_true) > 1.4);
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(scene, T_W_C_true);

  Se3d T_W_C = T_W_Cref;  // the guess: the previous pose
  const WorkerTeam team(1);
  const TrackReport report =
      f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, T_W_C, team);
  REQUIRE(report.status.ok());
  CHECK(report.outcome == TrackOutcome::tracked);
  CHECK(translation_error_m(T_W_C, T_W_C_true) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(T_W_C, T_W_C_true) < kRotationTolerance_deg);
  CHECK(report.iterations[2] >= 1);
  CHECK(report.iterations[0] >= 1);
  CHECK(report.inlier_fraction > 0.8f);
  CHECK(report.rms_residual_m < 1e-3f);
  CHECK(report.model_pixels > 0u);
  CHECK(report.inliers ==
        static_cast<std::uint32_t>(report.inlier_fraction * report.model_pixels + 0.5f));
}

// The corner scene tracked from the reference pose by two configs, `full` and `half`.
struct TwoTracks {
  TrackReport full_report;
  TrackReport half_report;
  Se3d pose_full = reference_pose();
  Se3d pose_half = reference_pose();
};

TwoTracks track_with(const TrackConfig& full_config, const TrackConfig& half_config) {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture full(full_config);
  TrackFixture half(half_config);
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  const test::RenderedModel model = scene.render_model(full.camera_level0(), T_W_Cref);
  full.set_live(scene, T_W_C_true, 1, 0.002f);
  half.set_live(scene, T_W_C_true, 1, 0.002f);
  const WorkerTeam team(1);
  TwoTracks t;
  t.full_report = full.tracker.track(full.pre.pyramid(), model.map(), full.camera_level0(),
                                     T_W_Cref, t.pose_full, team);
  t.half_report = half.tracker.track(half.pre.pyramid(), model.map(), half.camera_level0(),
                                     T_W_Cref, t.pose_half, team);
  return t;
}

TEST_CASE("the finest level's checkerboard lands where every pixel does, at half the pairs") {
  TrackConfig every_pixel;
  every_pixel.finest_level_checkerboard = false;
  const TwoTracks t = track_with(every_pixel, TrackConfig{});  // the default: checkerboard
  const TrackReport& a = t.full_report;
  const TrackReport& b = t.half_report;
  REQUIRE(a.tracked());
  REQUIRE(b.tracked());
  CHECK(translation_error_m(t.pose_half, offset_pose()) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(t.pose_half, offset_pose()) < kRotationTolerance_deg);
  CHECK(translation_error_m(t.pose_half, t.pose_full) < 2e-4);
  CHECK(rotation_error_deg(t.pose_half, t.pose_full) < 0.02);
  // The half's count, doubled, stands for the whole image; the RMS is the half's own.
  CHECK(b.inliers % 2 == 0u);
  CHECK(std::abs(static_cast<double>(b.inliers) - static_cast<double>(a.inliers)) <
        0.02 * static_cast<double>(a.inliers));
  CHECK(std::abs(b.rms_residual_m - a.rms_residual_m) < 0.1f * a.rms_residual_m);
}

TEST_CASE("the middle level's checkerboard lands where every middle pixel does") {
  TrackConfig full_middle;
  full_middle.middle_level_checkerboard = false;
  REQUIRE(TrackConfig{}.middle_level_checkerboard);
  // By default at a 320 x 240 working resolution (the fixture's) both finer levels take every
  // other pixel; at 160 x 120 the middle level keeps all of its 80 x 60.
  REQUIRE(TrackConfig{}.middle_level_halved(320, 240));
  REQUIRE_FALSE(TrackConfig{}.middle_level_halved(160, 120));
  const TwoTracks t = track_with(full_middle, TrackConfig{});
  REQUIRE(t.full_report.tracked());
  REQUIRE(t.half_report.tracked());
  CHECK(t.half_report.iterations[1] >= 1);
  CHECK(translation_error_m(t.pose_half, offset_pose()) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(t.pose_half, offset_pose()) < kRotationTolerance_deg);
  CHECK(translation_error_m(t.pose_half, t.pose_full) < 2e-4);
  CHECK(rotation_error_deg(t.pose_half, t.pose_full) < 0.02);
  // The middle passes did take other pairs: the estimates are not the same bits.
  CHECK_FALSE(t.pose_half.matrix() == t.pose_full.matrix());
}

// What the ray-caster leaves at half resolution (RaycastConfig::pixel_stride 2): pixels with even
// x and y cast, each odd one a copy of its even neighbour above and to the left.
test::RenderedModel half_resolution_copy(const test::RenderedModel& full) {
  test::RenderedModel half = full;
  for (int y = 0; y < full.height; ++y) {
    for (int x = 0; x < full.width; ++x) {
      const std::size_t from = static_cast<std::size_t>((y & ~1) * full.width + (x & ~1));
      const std::size_t to = static_cast<std::size_t>(y * full.width + x);
      half.vertices_W[to] = full.vertices_W[from];
      half.normals_W[to] = full.normals_W[from];
    }
  }
  return half;
}

TEST_CASE("a model cast at half resolution is paired at its cast pixels only") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  const test::RenderedModel half =
      half_resolution_copy(scene.render_model(f.camera_level0(), T_W_Cref));
  // The same cast pixels, every copy moved 2 cm off the surface along its normal: pairs read
  // through the copies would pull the pose towards it.
  test::RenderedModel moved = half;
  for (int y = 0; y < half.height; ++y) {
    for (int x = 0; x < half.width; ++x) {
      if (((x | y) & 1) == 0) continue;
      const std::size_t i = static_cast<std::size_t>(y * half.width + x);
      moved.vertices_W[i] += 0.02f * moved.normals_W[i];
    }
  }
  f.set_live(scene, T_W_C_true);
  const WorkerTeam team(1);
  ConstSurfaceMap half_map = half.map();
  ConstSurfaceMap moved_map = moved.map();
  half_map.pixel_stride = 2;
  moved_map.pixel_stride = 2;
  Se3d pose_half = T_W_Cref;
  Se3d pose_moved = T_W_Cref;
  const TrackReport a =
      f.tracker.track(f.pre.pyramid(), half_map, f.camera_level0(), T_W_Cref, pose_half, team);
  const TrackReport b =
      f.tracker.track(f.pre.pyramid(), moved_map, f.camera_level0(), T_W_Cref, pose_moved, team);
  REQUIRE(a.tracked());
  REQUIRE(b.tracked());
  CHECK(translation_error_m(pose_half, T_W_C_true) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(pose_half, T_W_C_true) < kRotationTolerance_deg);
  // The copies are never read: the same pose and pairs, bit for bit.
  CHECK(pose_half.matrix() == pose_moved.matrix());
  CHECK(a.inliers == b.inliers);
  CHECK(a.rms_residual_m == b.rms_residual_m);
  // Not vacuous: read as if every pixel were cast, the moved copies do pull the pose.
  ConstSurfaceMap moved_as_full = moved.map();
  Se3d pose_full_read = T_W_Cref;
  const TrackReport c = f.tracker.track(f.pre.pyramid(), moved_as_full, f.camera_level0(), T_W_Cref,
                                        pose_full_read, team);
  REQUIRE(c.status.ok());
  CHECK(translation_error_m(pose_full_read, pose_half) > 1e-3);
}

TEST_CASE("against a half-resolution model the finest level takes one pixel of each 2 x 2") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture halves;  // the default: the checkerboard
  TrackConfig quarter_config;
  quarter_config.finest_level_quarter_on_half_model = true;
  TrackFixture quarters(quarter_config);
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  const test::RenderedModel full = scene.render_model(quarters.camera_level0(), T_W_Cref);
  const test::RenderedModel half = half_resolution_copy(full);
  ConstSurfaceMap half_map = half.map();
  half_map.pixel_stride = 2;
  halves.set_live(scene, T_W_C_true, 1, 0.002f);
  quarters.set_live(scene, T_W_C_true, 1, 0.002f);
  const WorkerTeam team(1);
  Se3d pose_halves = T_W_Cref;
  Se3d pose_quarters = T_W_Cref;
  const TrackReport a = halves.tracker.track(halves.pre.pyramid(), half_map, halves.camera_level0(),
                                             T_W_Cref, pose_halves, team);
  const TrackReport b = quarters.tracker.track(
      quarters.pre.pyramid(), half_map, quarters.camera_level0(), T_W_Cref, pose_quarters, team);
  REQUIRE(a.tracked());
  REQUIRE(b.tracked());
  CHECK(translation_error_m(pose_quarters, T_W_C_true) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(pose_quarters, T_W_C_true) < kRotationTolerance_deg);
  CHECK(translation_error_m(pose_quarters, pose_halves) < 2e-4);
  CHECK(rotation_error_deg(pose_quarters, pose_halves) < 0.02);
  // The quarter's count, times four, stands for the whole image.
  CHECK(b.inliers % 4 == 0u);
  CHECK(std::abs(static_cast<double>(b.inliers) - static_cast<double>(a.inliers)) <
        0.03 * static_cast<double>(a.inliers));
  CHECK(pose_quarters.matrix() != pose_halves.matrix());  // not the same passes
  // Against a model cast at every pixel the setting changes nothing, bit for bit.
  Se3d pose_full_halves = T_W_Cref;
  Se3d pose_full_quarters = T_W_Cref;
  const TrackReport c = halves.tracker.track(
      halves.pre.pyramid(), full.map(), halves.camera_level0(), T_W_Cref, pose_full_halves, team);
  const TrackReport d =
      quarters.tracker.track(quarters.pre.pyramid(), full.map(), quarters.camera_level0(), T_W_Cref,
                             pose_full_quarters, team);
  REQUIRE(c.tracked());
  CHECK(pose_full_halves.matrix() == pose_full_quarters.matrix());
  CHECK(c.inliers == d.inliers);
}

TEST_CASE("ICP stays at the identity when already aligned") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(scene, T_W_Cref);
  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1));
  REQUIRE(report.tracked());
  CHECK(translation_error_m(T_W_C, T_W_Cref) < kIdentityTranslationTolerance_m);
  CHECK(rotation_error_deg(T_W_C, T_W_Cref) < kIdentityRotationTolerance_deg);
  CHECK(report.iterations[0] <= f.tracker.config().iterations[0]);
}

TEST_CASE("ICP with depth noise still lands within a millimetre, and the RMS gate works") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  constexpr float kNoise_m = 0.004f;  // uniform +- 4 mm per VGA pixel
  f.set_live(scene, T_W_C_true, 1, kNoise_m);

  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1));
  REQUIRE(report.tracked());
  CHECK(translation_error_m(T_W_C, T_W_C_true) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(T_W_C, T_W_C_true) < kRotationTolerance_deg);
  // Averaging 4 samples of +-4 mm uniform noise leaves about 1.2 mm RMS.
  CHECK(report.rms_residual_m > 0.5e-3f);
  CHECK(report.rms_residual_m < 2.5e-3f);

  // The same frame against a stricter RMS threshold: lost, pose kept bit for bit.
  TrackConfig strict;
  strict.lost_max_rms_m = 0.5e-3f;
  REQUIRE(f.tracker.set_config(strict).ok());
  Se3d kept = T_W_Cref;
  const TrackReport lost = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                           T_W_Cref, kept, WorkerTeam(1));
  CHECK(lost.status.ok());
  CHECK(lost.outcome == TrackOutcome::lost_residual);
  CHECK(kept.matrix() == T_W_Cref.matrix());
}

TEST_CASE("depth weighting lets a far surface that disagrees pull the estimate less") {
  // A large sphere 0.9-1.3 m away in front of the corner's back wall (3 m). The live back wall
  // sits 2 cm farther than the model's; the sphere and the side walls agree. Only the sphere and
  // the back wall fix the camera's z (its viewing direction here), so the estimate's z lands
  // between "no motion" (sphere) and the wall's shift. Relative to a wall pair, a sphere pair
  // weighs 1 unweighted, at least (1 + 1.5^4) / (1 + 0.65^4) = 5 with a 2 m knee and at least
  // (1 + 3^4) / (1 + 1.3^4) = 21 with a 1 m knee, so the estimate moves towards the sphere.
  test::AnalyticScene scene = test::corner_scene();
  scene.spheres[0] = {Eigen::Vector3d(0.1, 0.0, 1.3), 0.4};
  test::AnalyticScene moved = scene;
  constexpr double kWallShift_m = 0.02;
  moved.planes[2].offset_m += kWallShift_m;
  const Se3d T_W_Cref = Se3d::Identity();
  TrackFixture f;
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(moved, T_W_Cref);

  double shift_m[3] = {0.0, 0.0, 0.0};
  const float knees_m[3] = {0.0f, 2.0f, 1.0f};
  for (int i = 0; i < 3; ++i) {
    TrackConfig config;
    config.depth_weight_knee_m = knees_m[i];
    REQUIRE(f.tracker.set_config(config).ok());
    Se3d T_W_C = T_W_Cref;
    const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                               T_W_Cref, T_W_C, WorkerTeam(1));
    REQUIRE(report.tracked());
    shift_m[i] = std::abs(T_W_C.translation().z() - T_W_Cref.translation().z());
  }
  INFO("z shift unweighted, knee 2 m, knee 1 m: " << shift_m[0] << ", " << shift_m[1] << ", "
                                                  << shift_m[2]);
  CHECK(shift_m[0] > 0.1 * kWallShift_m);  // the wall matters when unweighted
  CHECK(shift_m[0] < kWallShift_m);        // a compromise, never past the wall's own shift
  CHECK(shift_m[1] < 0.5 * shift_m[0]);
  CHECK(shift_m[2] < 0.5 * shift_m[1]);
}

TEST_CASE("the depth weight knee is checked") {
  TrackConfig config;
  CHECK(config.depth_weight_knee_m == 1.0f);
  config.depth_weight_knee_m = 0.0f;  // equal weights
  CHECK(config.valid());
  config.depth_weight_knee_m = -1.0f;
  CHECK_FALSE(config.valid());
  config.depth_weight_knee_m = std::numeric_limits<float>::infinity();
  CHECK_FALSE(config.valid());
}

}  // namespace
}  // namespace octofuse
