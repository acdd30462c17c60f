#include "octofuse/ports/host/trajectory_eval.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <random>

using octofuse::Se3d;
using octofuse::host::TimedPose;

namespace {

constexpr double kTolerance_m = 1e-9;
constexpr double kAngleTolerance_rad = 1e-9;

Se3d make_pose(double angle_rad, const Eigen::Vector3d& axis, const Eigen::Vector3d& t) {
  Se3d T = Se3d::Identity();
  T.linear() = Eigen::AngleAxisd(angle_rad, axis.normalized()).toRotationMatrix();
  T.translation() = t;
  return T;
}

std::vector<TimedPose> random_walk(int count, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> step(0.0, 0.05);
  std::vector<TimedPose> poses;
  Se3d T = Se3d::Identity();
  for (int i = 0; i < count; ++i) {
    T = T * make_pose(step(rng), Eigen::Vector3d(step(rng), step(rng), 1.0),
                      Eigen::Vector3d(step(rng), step(rng), step(rng)));
    poses.push_back({i / 30.0, T});
  }
  return poses;
}

}  // namespace

TEST_CASE("error_stats gives rmse, mean, median and max", "[host][eval]") {
  const octofuse::host::ErrorStats stats = octofuse::host::error_stats({3.0, 1.0, 4.0, 2.0});
  CHECK(stats.mean == Approx(2.5));
  CHECK(stats.median == Approx(2.5));
  CHECK(stats.max == 4.0);
  CHECK(stats.rmse == Approx(std::sqrt(30.0 / 4.0)));
  CHECK(octofuse::host::error_stats({}).rmse == 0.0);
}

TEST_CASE("Horn alignment recovers a known rigid transform", "[host][eval]") {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> uniform(-2.0, 2.0);
  const Se3d T_gt_est = make_pose(2.0, Eigen::Vector3d(1.0, -2.0, 0.5), Eigen::Vector3d(1, 2, 3));
  std::vector<Eigen::Vector3d> p_est, p_gt;
  for (int i = 0; i < 20; ++i) {
    p_est.emplace_back(uniform(rng), uniform(rng), uniform(rng));
    p_gt.push_back(T_gt_est * p_est.back());
  }
  const Se3d found = octofuse::host::horn_alignment(p_est, p_gt);
  CHECK((found.matrix() - T_gt_est.matrix()).norm() < 1e-9);
}

TEST_CASE("ATE of a trajectory against a rigidly moved copy of itself is zero", "[host][eval]") {
  const std::vector<TimedPose> ground_truth = random_walk(200, 3);
  const Se3d T_offset = make_pose(0.7, Eigen::Vector3d(0.2, 1.0, -0.3), Eigen::Vector3d(-4, 5, 1));
  std::vector<TimedPose> estimate = ground_truth;
  for (TimedPose& pose : estimate) pose.T_W_C = T_offset * pose.T_W_C;
  octofuse::ErrorText error;
  const auto ate = octofuse::host::compute_ate(estimate, ground_truth, 0.02, &error);
  REQUIRE(ate.ok());
  CHECK(ate->pairs == 200);
  CHECK(ate->translation_m.rmse < kTolerance_m);
  CHECK(ate->translation_m.max < kTolerance_m);
  CHECK((ate->T_gt_est * T_offset).matrix().isIdentity(1e-9));
}

TEST_CASE("ATE against a known perturbation is the perturbation size", "[host][eval]") {
  // Four ground-truth positions in a symmetric cross; the estimate moves two of them up and two
  // down by d. The best rigid alignment is then the identity, so every error is exactly d.
  constexpr double kArm_m = 1.0;
  constexpr double kOffset_m = 0.03;
  const Eigen::Vector3d positions[4] = {
      {kArm_m, 0, 0}, {-kArm_m, 0, 0}, {0, kArm_m, 0}, {0, -kArm_m, 0}};
  const double signs[4] = {1.0, 1.0, -1.0, -1.0};
  // A rigid change of the estimate's world frame must not change the answer.
  const Se3d T_offset = make_pose(1.1, Eigen::Vector3d(1, 1, 0), Eigen::Vector3d(0.5, 0, -2));
  std::vector<TimedPose> ground_truth, estimate;
  for (int i = 0; i < 4; ++i) {
    TimedPose gt{i * 0.1, Se3d::Identity()};
    gt.T_W_C.translation() = positions[i];
    TimedPose est = gt;
    est.T_W_C.translation() += Eigen::Vector3d(0, 0, signs[i] * kOffset_m);
    est.T_W_C = T_offset * est.T_W_C;
    est.timestamp_s += 0.004;  // within the association window
    ground_truth.push_back(gt);
    estimate.push_back(est);
  }
  octofuse::ErrorText error;
  const auto ate = octofuse::host::compute_ate(estimate, ground_truth, 0.02, &error);
  REQUIRE(ate.ok());
  CHECK(ate->pairs == 4);
  CHECK(ate->translation_m.rmse == Approx(kOffset_m).margin(kTolerance_m));
  CHECK(ate->translation_m.mean == Approx(kOffset_m).margin(kTolerance_m));
  CHECK(ate->translation_m.median == Approx(kOffset_m).margin(kTolerance_m));
  CHECK(ate->translation_m.max == Approx(kOffset_m).margin(kTolerance_m));
}

TEST_CASE("ATE needs three associated poses", "[host][eval]") {
  std::vector<TimedPose> a = random_walk(5, 1), b = a;
  for (TimedPose& pose : b) pose.timestamp_s += 10.0;
  octofuse::ErrorText error;
  const auto ate = octofuse::host::compute_ate(a, b, 0.02, &error);
  CHECK(ate.status() == octofuse::StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("only 0 poses") != std::string::npos);
}

TEST_CASE("association matches nearest timestamps once each", "[host][eval]") {
  std::vector<TimedPose> estimate(3), ground_truth(4);
  const double t_est[3] = {1.00, 1.03, 2.00};
  const double t_gt[4] = {0.99, 1.005, 1.031, 1.5};
  for (int i = 0; i < 3; ++i) estimate[i].timestamp_s = t_est[i];
  for (int i = 0; i < 4; ++i) ground_truth[i].timestamp_s = t_gt[i];
  const auto pairs = octofuse::host::associate_by_time(estimate, ground_truth, 0.02);
  REQUIRE(pairs.size() == 2);
  CHECK(pairs[0].estimate == 0);
  CHECK(pairs[0].ground_truth == 1);
  CHECK(pairs[1].estimate == 1);
  CHECK(pairs[1].ground_truth == 2);
}

TEST_CASE("RPE is zero under a world-frame change and known for a known drift", "[host][eval]") {
  const std::vector<TimedPose> ground_truth = random_walk(100, 5);
  octofuse::ErrorText error;

  SECTION("world-frame change") {
    const Se3d T_offset = make_pose(-0.4, Eigen::Vector3d(0, 1, 1), Eigen::Vector3d(3, 2, 1));
    std::vector<TimedPose> estimate = ground_truth;
    for (TimedPose& pose : estimate) pose.T_W_C = T_offset * pose.T_W_C;
    const auto rpe = octofuse::host::compute_rpe(estimate, ground_truth, 0.02, &error);
    REQUIRE(rpe.ok());
    CHECK(rpe->pairs == 99);
    CHECK(rpe->translation_m.max < kTolerance_m);
    CHECK(rpe->rotation_rad.max < 1e-7);  // acos near 1 loses half the digits
  }
  SECTION("per-frame drift of 1 cm and 0.02 rad") {
    // Ground truth steps 10 cm along x; the estimate steps 11 cm and turns 0.02 rad about z, so
    // E = [Rz(0.02), 1 cm along x] for every frame.
    constexpr double kStep_m = 0.10, kDrift_m = 0.01, kTurn_rad = 0.02;
    std::vector<TimedPose> gt, estimate;
    Se3d P = Se3d::Identity();
    for (int i = 0; i < 20; ++i) {
      TimedPose q{i / 30.0, Se3d::Identity()};
      q.T_W_C.translation() = Eigen::Vector3d(kStep_m * i, 0, 0);
      gt.push_back(q);
      estimate.push_back({i / 30.0, P});
      P = P *
          make_pose(kTurn_rad, Eigen::Vector3d::UnitZ(), Eigen::Vector3d(kStep_m + kDrift_m, 0, 0));
    }
    const auto rpe = octofuse::host::compute_rpe(estimate, gt, 0.02, &error);
    REQUIRE(rpe.ok());
    CHECK(rpe->pairs == 19);
    CHECK(rpe->translation_m.rmse == Approx(kDrift_m).margin(kTolerance_m));
    CHECK(rpe->translation_m.max == Approx(kDrift_m).margin(kTolerance_m));
    CHECK(rpe->rotation_rad.mean == Approx(kTurn_rad).margin(kAngleTolerance_rad));
    CHECK(rpe->rotation_rad.median == Approx(kTurn_rad).margin(kAngleTolerance_rad));
  }
}
