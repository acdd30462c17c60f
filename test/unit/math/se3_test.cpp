#include "octofuse/math/se3.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <limits>
#include <random>

namespace octofuse {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTolerance = 1e-12;          // closed-form identities in double
constexpr double kRoundTripTolerance = 1e-9;  // exp/log round trips
constexpr double kTolerance_m = 1e-12;

Vector6d twist(double vx, double vy, double vz, double wx, double wy, double wz) {
  Vector6d t;
  t << vx, vy, vz, wx, wy, wz;
  return t;
}

TEST_CASE("se3_exp of zero is the identity; of a pure translation, that translation") {
  REQUIRE(se3_exp(Vector6d::Zero()).matrix().isApprox(Eigen::Matrix4d::Identity(), kTolerance));
  const Se3d T = se3_exp(twist(0.5, -1.0, 2.0, 0.0, 0.0, 0.0));
  REQUIRE(T.linear().isApprox(Eigen::Matrix3d::Identity(), kTolerance));
  REQUIRE((T.translation() - Eigen::Vector3d(0.5, -1.0, 2.0)).norm() < kTolerance_m);
}

TEST_CASE("se3_exp of a quarter turn about z maps x to y") {
  const Se3d T = se3_exp(twist(0.0, 0.0, 0.0, 0.0, 0.0, kPi / 2.0));
  const Eigen::Vector3d p_A = T * Eigen::Vector3d(1.0, 0.0, 0.0);
  REQUIRE((p_A - Eigen::Vector3d(0.0, 1.0, 0.0)).norm() < kTolerance_m);
  REQUIRE(is_rigid(T.matrix()));
}

TEST_CASE("se3_exp: rotation and translation couple through V (screw motion)") {
  // Rotating by pi about z while translating (0, 0, 1) along the axis is a pure screw: the
  // translation stays along the axis. With v = (1, 0, 0) and w = (0, 0, pi), the orbit of the
  // origin is a half circle of radius 1/pi: it ends at (0, 2/pi, 0).
  const Se3d screw = se3_exp(twist(0.0, 0.0, 1.0, 0.0, 0.0, kPi));
  REQUIRE((screw.translation() - Eigen::Vector3d(0.0, 0.0, 1.0)).norm() < kTolerance_m);
  const Se3d arc = se3_exp(twist(1.0, 0.0, 0.0, 0.0, 0.0, kPi));
  REQUIRE((arc.translation() - Eigen::Vector3d(0.0, 2.0 / kPi, 0.0)).norm() < 1e-12);
}

TEST_CASE("se3_log inverts se3_exp, including tiny rotations") {
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (int i = 0; i < 200; ++i) {
    // Angles from 1e-10 (series branch) up to 3 rad.
    const double scale = (i % 4 == 0) ? 1e-10 : (i % 4 == 1) ? 1e-6 : (i % 4 == 2) ? 0.3 : 1.0;
    Eigen::Vector3d w(unit(rng), unit(rng), unit(rng));
    w = w.normalized() * std::abs(unit(rng)) * 3.0 * scale;
    const Vector6d xi = twist(unit(rng), unit(rng), unit(rng), w.x(), w.y(), w.z());
    const Se3d T = se3_exp(xi);
    REQUIRE(is_rigid(T.matrix(), 1e-10));
    CAPTURE(i, w.norm());
    REQUIRE((se3_log(T) - xi).norm() < kRoundTripTolerance);
  }
}

TEST_CASE("se3_exp(xi) * se3_exp(-xi) is the identity") {
  const Vector6d xi = twist(0.3, -0.2, 0.9, 0.4, -0.7, 0.2);
  const Se3d product = se3_exp(xi) * se3_exp(-xi);
  REQUIRE(product.matrix().isApprox(Eigen::Matrix4d::Identity(), kTolerance));
}

TEST_CASE("is_rigid accepts rotations and rejects everything else") {
  Eigen::Matrix4d T = se3_exp(twist(1, 2, 3, 0.1, 0.2, 0.3)).matrix();
  REQUIRE(is_rigid(T));

  SECTION("scale") {
    T.topLeftCorner<3, 3>() *= 1.01;
    REQUIRE_FALSE(is_rigid(T));
  }
  SECTION("reflection") {
    T.col(0) = -T.col(0);
    REQUIRE_FALSE(is_rigid(T));
  }
  SECTION("NaN and infinity") {
    T(0, 3) = std::numeric_limits<double>::quiet_NaN();
    REQUIRE_FALSE(is_rigid(T));
    T(0, 3) = std::numeric_limits<double>::infinity();
    REQUIRE_FALSE(is_rigid(T));
  }
  SECTION("bad bottom row") {
    T(3, 0) = 0.5;
    REQUIRE_FALSE(is_rigid(T));
  }
  SECTION("perturbation inside and outside the tolerance") {
    T(0, 1) += 1e-6;
    REQUIRE(is_rigid(T, 1e-4));
    REQUIRE_FALSE(is_rigid(T, 1e-8));
  }
}

TEST_CASE("orthonormalize returns the nearest rotation") {
  const Eigen::Matrix3d R = se3_exp(twist(0, 0, 0, 0.5, -0.3, 1.1)).linear();
  SECTION("a rotation is unchanged") {
    REQUIRE(orthonormalize(R).isApprox(R, kTolerance));
  }
  SECTION("a drifted rotation becomes rigid again and stays close") {
    Eigen::Matrix3d drifted = R;
    drifted(0, 0) += 1e-3;
    drifted(2, 1) -= 2e-3;
    Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
    T.topLeftCorner<3, 3>() = drifted;
    REQUIRE_FALSE(is_rigid(T, 1e-6));
    T.topLeftCorner<3, 3>() = orthonormalize(drifted);
    REQUIRE(is_rigid(T, 1e-12));
    REQUIRE((orthonormalize(drifted) - R).norm() < 3e-3);
  }
  SECTION("a reflection is mapped to a proper rotation") {
    Eigen::Matrix3d reflected = R;
    reflected.col(2) = -reflected.col(2);
    REQUIRE(orthonormalize(reflected).determinant() == Approx(1.0).margin(kTolerance));
  }
}

}  // namespace
}  // namespace octofuse
