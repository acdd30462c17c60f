// When ICP cannot track: partial and too-small models, views that do not match, degenerate
// single planes, and recovery once the view matches again.

#include "octofuse/track/icp.hpp"

#include <catch2/catch.hpp>

#include "unit/track/icp_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("ICP tracks against a model that covers only part of the view (a full block pool)") {
  // A full pool leaves the map, and so the ray-cast, covering a fraction of what the camera sees:
  // the inliers are counted against the model's valid pixels, not the whole image.
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  // Keep the lower-left window where the three walls meet (14% of the pixels): enough geometry
  // to fix all six degrees of freedom.
  const int x0 = 0;
  const int x1 = 110;
  const int y0 = 140;
  const int y1 = model.height;
  std::uint32_t kept = 0;
  for (int y = 0; y < model.height; ++y) {
    for (int x = 0; x < model.width; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * model.width + x;
      if (x >= x0 && x < x1 && y >= y0 && y < y1) {
        kept += is_invalid_normal(model.normals_W[i]) ? 0u : 1u;
      } else {
        model.normals_W[i] = Eigen::Vector3f::Zero();
      }
    }
  }
  REQUIRE(kept < 320u * 240u * 15u / 100u);  // below the old "15% of the image" gate
  f.set_live(scene, T_W_C_true);
  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1));
  REQUIRE(report.status.ok());
  CHECK(report.model_pixels == kept);
  CHECK(report.outcome == TrackOutcome::tracked);
  CHECK(report.inlier_fraction > 0.5f);
  CHECK(translation_error_m(T_W_C, T_W_C_true) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(T_W_C, T_W_C_true) < kRotationTolerance_deg);
}

TEST_CASE("a model too small to constrain the pose is reported lost") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  // 20 x 20 valid pixels: 0.5% of the image, under lost_min_image_fraction (5%).
  for (int y = 0; y < model.height; ++y) {
    for (int x = 0; x < model.width; ++x) {
      if (x >= 150 && x < 170 && y >= 110 && y < 130) continue;
      model.normals_W[static_cast<std::size_t>(y) * model.width + x] = Eigen::Vector3f::Zero();
    }
  }
  f.set_live(scene, T_W_Cref);
  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1));
  REQUIRE(report.status.ok());
  CHECK(report.outcome == TrackOutcome::lost_inliers);
  CHECK(report.inliers < 320u * 240u * 5u / 100u);
}

TEST_CASE("a live view that does not match the model is reported lost and the pose is kept") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  // The live camera sees a wall 0.6 m in front of it that the model does not have.
  test::AnalyticScene other;
  other.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), 0.6});
  f.set_live(other, Se3d::Identity());

  const Se3d guess = offset_pose();
  Se3d T_W_C = guess;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1));
  CHECK(report.status.ok());
  CHECK_FALSE(report.tracked());
  CHECK(report.outcome == TrackOutcome::lost_inliers);
  CHECK(report.inlier_fraction < 0.15f);
  CHECK(T_W_C.matrix() == guess.matrix());
}

TEST_CASE("a single plane in view is degenerate and reported as such") {
  test::AnalyticScene wall;
  wall.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), 2.0});
  TrackFixture f;
  const Se3d T_W_Cref = Se3d::Identity();
  const test::RenderedModel model = wall.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(wall, T_W_Cref);
  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1));
  CHECK(report.status.ok());
  CHECK(report.outcome == TrackOutcome::lost_singular);
  CHECK(T_W_C.matrix() == T_W_Cref.matrix());
}

TEST_CASE("along a sequence, a foreign view is lost and the next matching view recovers") {
  // The model is the exact scene ray-cast at the last estimate, as a perfect map would give.
  const test::AnalyticScene scene = test::corner_scene();
  test::AnalyticScene foreign;
  foreign.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), 0.6});
  TrackFixture f;
  constexpr int kFrames = 6;
  constexpr int kForeignFrame = 3;
  auto true_pose = [](int k) {
    return reference_pose() * make_pose(k * Eigen::Vector3d(0.003, 0.002, -0.004),
                                        Eigen::Vector3d(0.2, 1.0, -0.3), 0.8 * k);
  };
  Se3d estimate = true_pose(0);
  for (int k = 1; k < kFrames; ++k) {
    INFO("frame " << k);
    const test::RenderedModel model = scene.render_model(f.camera_level0(), estimate);
    const bool foreign_view = k == kForeignFrame;
    if (foreign_view) {
      f.set_live(foreign, Se3d::Identity());
    } else {
      f.set_live(scene, true_pose(k));
    }
    const Se3d previous = estimate;
    const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                               previous, estimate, WorkerTeam(1));
    REQUIRE(report.status.ok());
    if (foreign_view) {
      CHECK(report.outcome == TrackOutcome::lost_inliers);
      CHECK(estimate.matrix() == previous.matrix());
    } else {
      CHECK(report.tracked());
      CHECK(translation_error_m(estimate, true_pose(k)) < kTranslationTolerance_m);
      CHECK(rotation_error_deg(estimate, true_pose(k)) < kRotationTolerance_deg);
    }
  }
}

}  // namespace
}  // namespace octofuse
