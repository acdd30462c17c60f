// ICP with a pose prior: the directions a view leaves open follow the prior, a well-constrained
// view barely moves, out-of-range priors are refused.

#include "octofuse/track/icp.hpp"

#include <catch2/catch.hpp>

#include "unit/track/icp_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("a prior holds the directions a single plane leaves open; ICP keeps the rest") {
  test::AnalyticScene wall;
  wall.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), 2.0});
  TrackConfig config;
  config.depth_weight_knee_m = 0.0f;  // every pair weighs 1: the wall gives ~76800 per m^2
  TrackFixture f(config);
  const Se3d T_W_Cref = Se3d::Identity();
  // The camera moved 1 cm along the wall (invisible to ICP) and 4 mm towards it (visible).
  const Se3d T_W_C_true =
      make_pose(Eigen::Vector3d(0.01, 0.005, 0.004), Eigen::Vector3d::UnitZ(), 0.0);
  const test::RenderedModel model = wall.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(wall, T_W_C_true);
  // The prior knows the motion along the wall but is 2 mm off towards it.
  IcpPrior prior;
  prior.T_W_C = T_W_C_true;
  prior.T_W_C.translation().z() -= 0.002;
  prior.fixed_information = true;
  prior.information_t = 100.0;
  prior.information_r = 100.0;
  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1), &prior);
  REQUIRE(report.status.ok());
  REQUIRE(report.outcome == TrackOutcome::tracked);  // not singular: the prior fills the gap
  CHECK(std::abs(T_W_C.translation().x() - 0.01) < 1e-4);
  CHECK(std::abs(T_W_C.translation().y() - 0.005) < 1e-4);
  // Along the normal the wall's 76800 pairs outweigh the prior's 100: 2 mm * 100 / 76900.
  CHECK(std::abs(T_W_C.translation().z() - 0.004) < 1e-4);
  CHECK(rotation_error_deg(T_W_C, T_W_C_true) < 0.01);

  // A prior with a negative or NaN weight is refused.
  prior.information_t = -1.0;
  Se3d unchanged = T_W_Cref;
  CHECK(f.tracker
            .track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, unchanged,
                   WorkerTeam(1), &prior)
            .status.code() == StatusCode::invalid_argument);
  CHECK(unchanged.matrix() == T_W_Cref.matrix());
}

TEST_CASE("weighted by uncertainty, a plane-only view follows the prior along the plane") {
  // The wall z = 2 seen head-on: ICP fixes z and the tilts, the prior alone x, y and the roll.
  test::AnalyticScene wall;
  wall.planes.push_back({Eigen::Vector3d(0.0, 0.0, 1.0), 2.0});
  TrackConfig config;
  config.depth_weight_knee_m = 0.0f;  // every pair weighs 1: A_zz is the pair count
  TrackFixture f(config);
  const Se3d T_W_Cref = Se3d::Identity();
  const Se3d T_W_C_true =
      make_pose(Eigen::Vector3d(0.01, 0.005, 0.004), Eigen::Vector3d::UnitZ(), 0.0);
  const test::RenderedModel model = wall.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(wall, T_W_C_true);
  IcpPrior prior;  // uncertainty weighting (the default)
  prior.T_W_C = T_W_C_true;
  prior.T_W_C.translation().z() -= 0.002;  // 2 mm off across the wall
  // Exact depth leaves sub-millimetre residuals, so the 5 mm floor sets ICP's variance:
  // var = 0.005^2 * 16 = 4e-4 m^2 per pair. The prior's 0.1 mm gives it 4e-4 / 1e-8 = 4e4 pairs'
  // worth along each axis, a third of the wall's.
  prior.icp_noise_floor_m = 0.005;
  prior.icp_pixels_per_sample = 16.0;
  prior.sigma_t_m = 1e-4;
  prior.sigma_rad = 1e-4;
  const double information = 0.005 * 0.005 * 16.0 / (1e-4 * 1e-4);
  Se3d T_W_C = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, T_W_C, WorkerTeam(1), &prior);
  REQUIRE(report.status.ok());
  REQUIRE(report.outcome == TrackOutcome::tracked);
  REQUIRE(report.inliers > 70000u);  // the whole QVGA view but its border
  CHECK(std::abs(T_W_C.translation().x() - 0.01) < 1e-5);
  CHECK(std::abs(T_W_C.translation().y() - 0.005) < 1e-5);
  // Across the wall: (N + L) z = N z_icp + L z_prior, with N pairs of weight 1.
  const double pairs = static_cast<double>(report.inliers);
  const double expected_z = 0.004 - 0.002 * information / (pairs + information);
  CAPTURE(expected_z, T_W_C.translation().z());
  CHECK(std::abs(T_W_C.translation().z() - expected_z) < 1e-5);
  CHECK(std::abs(T_W_C.translation().z() - 0.004) > 4e-4);  // it did move: about 0.7 mm
  CHECK(rotation_error_deg(T_W_C, T_W_C_true) < 0.01);

  // A tenth of the variance on the ICP side (a 10x smaller floor here: 100 x less) and the wall
  // all but ignores the prior across it, while along it the prior still decides.
  prior.icp_noise_floor_m = 0.0005;
  Se3d sharp = T_W_Cref;
  REQUIRE(f.tracker
              .track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, sharp,
                     WorkerTeam(1), &prior)
              .tracked());
  CHECK(std::abs(sharp.translation().z() - 0.004) < 2e-5);
  CHECK(std::abs(sharp.translation().x() - 0.01) < 1e-5);

  // ICP seen (from outside) to err along the camera's z as much as the prior does: that axis is
  // shared half and half, z = (4 mm + 2 mm) / 2, whatever its normal equations claim.
  prior.icp_error_var_C[2] = prior.sigma_t_m * prior.sigma_t_m;
  Se3d shared = T_W_Cref;
  REQUIRE(f.tracker
              .track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, shared,
                     WorkerTeam(1), &prior)
              .tracked());
  CAPTURE(shared.translation().z());
  CHECK(std::abs(shared.translation().z() - 0.003) < 2e-5);
  CHECK(std::abs(shared.translation().x() - 0.01) < 1e-5);
}

TEST_CASE("weighted by uncertainty, a well-constrained view barely moves towards a far prior") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(scene, T_W_C_true, 1, 0.004f);  // about 1.2 mm RMS residual
  Se3d alone = T_W_Cref;
  REQUIRE(
      f.tracker
          .track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, alone, WorkerTeam(1))
          .tracked());
  // The odometry at its default noise, 2.5 cm and 1 degree off the true pose (inside the gate).
  IcpPrior prior;
  prior.T_W_C = T_W_C_true * make_pose(Eigen::Vector3d(0.015, -0.01, 0.0165),
                                       Eigen::Vector3d(1.0, 0.5, 0.0), 1.0);
  REQUIRE(translation_error_m(prior.T_W_C, T_W_C_true) > 0.024);
  Se3d pulled = T_W_Cref;
  const TrackReport report = f.tracker.track(f.pre.pyramid(), model.map(), f.camera_level0(),
                                             T_W_Cref, pulled, WorkerTeam(1), &prior);
  REQUIRE(report.tracked());
  CHECK(translation_error_m(pulled, alone) < 1e-4);
  CHECK(translation_error_m(pulled, T_W_C_true) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(pulled, T_W_C_true) < kRotationTolerance_deg);
  // Two workers: the same bits.
  Se3d pulled_two = T_W_Cref;
  REQUIRE(f.tracker
              .track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, pulled_two,
                     WorkerTeam(2), &prior)
              .tracked());
  CHECK(std::memcmp(pulled.matrix().data(), pulled_two.matrix().data(), sizeof(double) * 16) == 0);
  // A fixed pull of 300 per m^2 in A's units (the old default) moves it a hundred times as far.
  IcpPrior fixed = prior;
  fixed.fixed_information = true;
  fixed.information_t = 300.0;
  fixed.information_r = 300.0;
  Se3d pulled_fixed = T_W_Cref;
  REQUIRE(f.tracker
              .track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, pulled_fixed,
                     WorkerTeam(1), &fixed)
              .tracked());
  CAPTURE(translation_error_m(pulled, alone), translation_error_m(pulled_fixed, alone));
  CHECK(translation_error_m(pulled_fixed, alone) > 50.0 * translation_error_m(pulled, alone));
}

TEST_CASE("a prior with an out-of-range noise is refused and the pose kept") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackFixture f;
  const Se3d T_W_Cref = reference_pose();
  const test::RenderedModel model = scene.render_model(f.camera_level0(), T_W_Cref);
  f.set_live(scene, offset_pose());
  struct Bad {
    const char* what;
    void (*spoil)(IcpPrior&);
  };
  const Bad cases[] = {
      {"sigma_t 0", [](IcpPrior& p) { p.sigma_t_m = 0.0; }},
      {"sigma_t NaN", [](IcpPrior& p) { p.sigma_t_m = std::numeric_limits<double>::quiet_NaN(); }},
      {"sigma_rad negative", [](IcpPrior& p) { p.sigma_rad = -1e-3; }},
      {"sigma_rad huge", [](IcpPrior& p) { p.sigma_rad = 1e4; }},
      {"floor NaN",
       [](IcpPrior& p) { p.icp_noise_floor_m = std::numeric_limits<double>::quiet_NaN(); }},
      {"floor 2 m", [](IcpPrior& p) { p.icp_noise_floor_m = 2.0; }},
      {"pixels per sample 0.5", [](IcpPrior& p) { p.icp_pixels_per_sample = 0.5; }},
      {"icp sigma negative", [](IcpPrior& p) { p.icp_sigma_m = -1e-3; }},
      {"error variance NaN",
       [](IcpPrior& p) { p.icp_error_var_C[4] = std::numeric_limits<double>::quiet_NaN(); }},
      {"error variance negative", [](IcpPrior& p) { p.icp_error_var_C[0] = -1e-6; }},
      {"pixels per sample inf",
       [](IcpPrior& p) { p.icp_pixels_per_sample = std::numeric_limits<double>::infinity(); }},
      {"information NaN",
       [](IcpPrior& p) { p.information_r = std::numeric_limits<double>::quiet_NaN(); }},
  };
  for (const Bad& bad : cases) {
    CAPTURE(bad.what);
    IcpPrior prior;
    prior.T_W_C = offset_pose();
    REQUIRE(prior.valid());
    bad.spoil(prior);
    CHECK_FALSE(prior.valid());
    Se3d T_W_C = T_W_Cref;
    CHECK(f.tracker
              .track(f.pre.pyramid(), model.map(), f.camera_level0(), T_W_Cref, T_W_C,
                     WorkerTeam(1), &prior)
              .status.code() == StatusCode::invalid_argument);
    CHECK(T_W_C.matrix() == T_W_Cref.matrix());
  }
}

}  // namespace
}  // namespace octofuse
