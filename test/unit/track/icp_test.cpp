#include "octofuse/track/icp.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

constexpr double kTranslationTolerance_m = 1e-3;
constexpr double kRotationTolerance_deg = 0.1;
// Already aligned: only float rounding of the rendered data remains.
constexpr double kIdentityTranslationTolerance_m = 5e-5;
constexpr double kIdentityRotationTolerance_deg = 5e-3;
constexpr double kPi = 3.14159265358979323846;

Se3d make_pose(const Eigen::Vector3d& translation_m, const Eigen::Vector3d& axis,
               double angle_deg) {
  Se3d T = Se3d::Identity();
  T.linear() = Eigen::AngleAxisd(angle_deg * kPi / 180.0, axis.normalized()).toRotationMatrix();
  T.translation() = translation_m;
  return T;
}

// A reference pose looking into the corner scene and a live pose a few mm and 1.5 degrees off.
Se3d reference_pose() {
  return make_pose(Eigen::Vector3d(0.05, -0.1, 0.1), Eigen::Vector3d(0.2, -1.0, 0.1), 5.0);
}
Se3d offset_pose() {
  return reference_pose() *
         make_pose(Eigen::Vector3d(0.004, -0.003, 0.005), Eigen::Vector3d(0.3, 1.0, 0.2), 1.5);
}

double translation_error_m(const Se3d& a, const Se3d& b) {
  return (a.translation() - b.translation()).norm();
}
double rotation_error_deg(const Se3d& a, const Se3d& b) {
  const Eigen::AngleAxisd aa(Eigen::Matrix3d(a.linear().transpose() * b.linear()));
  return std::abs(aa.angle()) * 180.0 / kPi;
}

// Pre-processor and tracker reserved for VGA input at QVGA working resolution.
struct TrackFixture {
  explicit TrackFixture(const TrackConfig& track_config = TrackConfig{},
                        const PreprocessConfig& pre_config = PreprocessConfig{})
      : buffer(bytes_for(track_config, pre_config)) {
    REQUIRE(pre.reserve(buffer.arena(), pre_config, 640, 480).ok());
    REQUIRE(tracker.reserve(buffer.arena(), track_config, 320, 240).ok());
    REQUIRE(buffer.arena().bytes_used() == buffer.arena().capacity());
  }
  static std::size_t bytes_for(const TrackConfig& track_config,
                               const PreprocessConfig& pre_config) {
    ArenaSizer sizer;
    DepthPreprocessor p;
    IcpTracker t;
    REQUIRE(p.reserve(sizer, pre_config, 640, 480).ok());
    REQUIRE(t.reserve(sizer, track_config, 320, 240).ok());
    return sizer.bytes_used();
  }
  // Renders the live depth at T_W_C_live (VGA) and pre-processes it.
  void set_live(const test::AnalyticScene& scene, const Se3d& T_W_C_live, int workers = 1,
                float noise_m = 0.0f) {
    live_depth = scene.render(test::vga_camera(), T_W_C_live);
    if (noise_m > 0.0f) {
      std::mt19937 rng(7);
      std::uniform_real_distribution<float> noise(-noise_m, noise_m);
      for (float& d : live_depth) {
        if (d > 0.0f) d += noise(rng);
      }
    }
    const WorkerTeam team(workers);
    REQUIRE(
        pre.process(ImageView<const float>(live_depth.data(), 640, 480), test::vga_camera(), team)
            .ok());
  }
  PinholeCamera camera_level0() const { return test::vga_camera().downsampled(2); }

  test::ArenaBuffer buffer;
  DepthPreprocessor pre;
  IcpTracker tracker;
  std::vector<float> live_depth;
};

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

TEST_CASE("the finest level's checkerboard lands where every pixel does, at half the pairs") {
  const test::AnalyticScene scene = test::corner_scene();
  TrackConfig every_pixel;
  every_pixel.finest_level_checkerboard = false;
  TrackFixture full(every_pixel);
  TrackFixture half;  // the default: checkerboard
  const Se3d T_W_Cref = reference_pose();
  const Se3d T_W_C_true = offset_pose();
  const test::RenderedModel model = scene.render_model(full.camera_level0(), T_W_Cref);
  full.set_live(scene, T_W_C_true, 1, 0.002f);
  half.set_live(scene, T_W_C_true, 1, 0.002f);
  const WorkerTeam team(1);
  Se3d pose_full = T_W_Cref;
  Se3d pose_half = T_W_Cref;
  const TrackReport a = full.tracker.track(full.pre.pyramid(), model.map(), full.camera_level0(),
                                           T_W_Cref, pose_full, team);
  const TrackReport b = half.tracker.track(half.pre.pyramid(), model.map(), half.camera_level0(),
                                           T_W_Cref, pose_half, team);
  REQUIRE(a.tracked());
  REQUIRE(b.tracked());
  CHECK(translation_error_m(pose_half, T_W_C_true) < kTranslationTolerance_m);
  CHECK(rotation_error_deg(pose_half, T_W_C_true) < kRotationTolerance_deg);
  CHECK(translation_error_m(pose_half, pose_full) < 2e-4);
  CHECK(rotation_error_deg(pose_half, pose_full) < 0.02);
  // The half's count, doubled, stands for the whole image; the RMS is the half's own.
  CHECK(b.inliers % 2 == 0u);
  CHECK(std::abs(static_cast<double>(b.inliers) - static_cast<double>(a.inliers)) <
        0.02 * static_cast<double>(a.inliers));
  CHECK(std::abs(b.rms_residual_m - a.rms_residual_m) < 0.1f * a.rms_residual_m);
}

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
