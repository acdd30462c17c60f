// interpolate_pose(): odometry at a frame's time, by lerp of the position and slerp of the
// rotation, with hand-computed values; no extrapolation past the ends' tolerance.

#include <catch2/catch.hpp>
#include <cmath>
#include <vector>

#include "octofuse/ports/host/trajectory_io.hpp"

using octofuse::Se3d;
using octofuse::host::interpolate_pose;
using octofuse::host::TimedPose;

namespace {

TimedPose pose_at(double t_s, double x_m, double yaw_rad) {
  TimedPose p;
  p.timestamp_s = t_s;
  p.T_W_C.linear() = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  p.T_W_C.translation() = Eigen::Vector3d(x_m, 2.0 * x_m, 0.5);
  return p;
}

double yaw_of(const Se3d& T) {
  return std::atan2(T.linear()(1, 0), T.linear()(0, 0));
}

}  // namespace

TEST_CASE("interpolation: a quarter of the way between two poses", "[host][trajectory]") {
  // 10.0 s: x = 1 m, yaw 0; 10.4 s: x = 3 m, yaw 90 deg. At 10.1 s: x = 1.5 m, y = 3 m, yaw 22.5
  // deg (slerp about a fixed axis is linear in the angle).
  const std::vector<TimedPose> poses = {pose_at(10.0, 1.0, 0.0), pose_at(10.4, 3.0, M_PI / 2)};
  Se3d T = Se3d::Identity();
  REQUIRE(interpolate_pose(poses, 10.1, 0.0, &T));
  REQUIRE(T.translation().x() == Approx(1.5).margin(1e-12));
  REQUIRE(T.translation().y() == Approx(3.0).margin(1e-12));
  REQUIRE(T.translation().z() == Approx(0.5).margin(1e-12));
  REQUIRE(yaw_of(T) == Approx(M_PI / 8).margin(1e-12));
  REQUIRE((T.linear().transpose() * T.linear() - Eigen::Matrix3d::Identity()).norm() < 1e-12);
}

TEST_CASE("interpolation: exact timestamps give the stored poses", "[host][trajectory]") {
  const std::vector<TimedPose> poses = {pose_at(1.0, 0.0, 0.1), pose_at(2.0, 1.0, 0.2),
                                        pose_at(3.0, 4.0, -0.3)};
  for (const TimedPose& p : poses) {
    Se3d T = Se3d::Identity();
    REQUIRE(interpolate_pose(poses, p.timestamp_s, 0.0, &T));
    REQUIRE((T.matrix() - p.T_W_C.matrix()).cwiseAbs().maxCoeff() < 1e-12);
  }
  // Between the second and third: half way, x = 2.5, yaw -0.05.
  Se3d T = Se3d::Identity();
  REQUIRE(interpolate_pose(poses, 2.5, 0.0, &T));
  REQUIRE(T.translation().x() == Approx(2.5).margin(1e-12));
  REQUIRE(yaw_of(T) == Approx(-0.05).margin(1e-12));
}

TEST_CASE("interpolation: no extrapolation beyond the tolerance at either end",
          "[host][trajectory]") {
  const std::vector<TimedPose> poses = {pose_at(1.0, 0.0, 0.0), pose_at(2.0, 1.0, 0.0)};
  Se3d T = Se3d::Identity();
  REQUIRE(interpolate_pose(poses, 0.99, 0.02, &T));  // within: the end pose
  REQUIRE(T.translation().x() == 0.0);
  REQUIRE(interpolate_pose(poses, 2.015, 0.02, &T));
  REQUIRE(T.translation().x() == 1.0);
  REQUIRE_FALSE(interpolate_pose(poses, 0.97, 0.02, &T));
  REQUIRE_FALSE(interpolate_pose(poses, 2.03, 0.02, &T));
  REQUIRE_FALSE(interpolate_pose(poses, std::nan(""), 0.02, &T));
  REQUIRE_FALSE(interpolate_pose({}, 1.0, 0.02, &T));
}

TEST_CASE("interpolation: repeated timestamps take the later pose", "[host][trajectory]") {
  const std::vector<TimedPose> poses = {pose_at(1.0, 0.0, 0.0), pose_at(2.0, 1.0, 0.0),
                                        pose_at(2.0, 5.0, 0.0), pose_at(3.0, 6.0, 0.0)};
  Se3d T = Se3d::Identity();
  REQUIRE(interpolate_pose(poses, 2.0, 0.0, &T));
  REQUIRE(T.translation().x() == 5.0);
  REQUIRE(interpolate_pose(poses, 2.5, 0.0, &T));
  REQUIRE(T.translation().x() == Approx(5.5).margin(1e-12));
}
