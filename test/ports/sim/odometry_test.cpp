// DriftingOdometry: drift in proportion to the distance travelled, seeded noise, determinism.

#include "octofuse/ports/sim/odometry.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>

namespace octofuse::sim {
namespace {

Se3d at_x(double x_m) {
  Se3d T = Se3d::Identity();
  T.translation() = Eigen::Vector3d(x_m, 0.0, 0.0);
  return T;
}

TEST_CASE("translation drift is 1 % of the distance travelled, without noise") {
  OdometryDriftConfig config;
  config.drift_per_m = 0.01;
  config.drift_rad_per_m = 0.0;
  config.noise_m = 0.0;
  config.noise_rad = 0.0;
  DriftingOdometry odometry(config);
  // There and back along x: 2 m travelled, the drift grows with distance, not displacement.
  for (int i = 0; i <= 100; ++i)
    REQUIRE((odometry.next(at_x(i * 0.01)).translation() - at_x(i * 0.01).translation()).norm() ==
            Approx(0.01 * i * 0.01).margin(1e-12));
  Se3d last = Se3d::Identity();
  for (int i = 99; i >= 0; --i) last = odometry.next(at_x(i * 0.01));
  REQUIRE(odometry.distance_m() == Approx(2.0).margin(1e-12));
  REQUIRE(last.translation().norm() == Approx(0.02).margin(1e-12));
  REQUIRE((last.linear() - Eigen::Matrix3d::Identity()).norm() < 1e-12);
}

TEST_CASE("rotation drift grows with distance; noise is bounded and does not accumulate") {
  OdometryDriftConfig config;
  config.drift_per_m = 0.0;
  config.drift_rad_per_m = 0.01;
  config.noise_m = 0.0;
  config.noise_rad = 0.0;
  DriftingOdometry odometry(config);
  Se3d out = Se3d::Identity();
  for (int i = 0; i <= 100; ++i) out = odometry.next(at_x(i * 0.01));
  REQUIRE(Eigen::AngleAxisd(out.linear()).angle() == Approx(0.01).margin(1e-12));

  OdometryDriftConfig noisy;
  noisy.drift_per_m = 0.0;
  noisy.drift_rad_per_m = 0.0;
  noisy.noise_m = 0.001;
  noisy.noise_rad = 0.0;
  DriftingOdometry jitter(noisy);
  for (int i = 0; i < 1000; ++i) {
    const Se3d T = jitter.next(at_x(i * 0.01));
    // Irwin-Hall draws are bounded at sqrt(12) sigma per axis.
    REQUIRE((T.translation() - at_x(i * 0.01).translation()).norm() <=
            std::sqrt(3.0) * std::sqrt(12.0) * 0.001 + 1e-12);
  }
}

TEST_CASE("the same seed gives the same odometry, another seed another one; restart repeats") {
  OdometryDriftConfig config;
  DriftingOdometry a(config), b(config);
  config.seed = 2;
  DriftingOdometry c(config);
  Se3d first[50];
  bool differs = false;
  for (int i = 0; i < 50; ++i) {
    const Se3d truth = at_x(i * 0.02);
    first[i] = a.next(truth);
    const Se3d same = b.next(truth);
    REQUIRE(std::memcmp(first[i].matrix().data(), same.matrix().data(), 16 * sizeof(double)) == 0);
    differs = differs || !(c.next(truth).matrix() == first[i].matrix());
  }
  REQUIRE(differs);
  a.restart();
  for (int i = 0; i < 50; ++i) {
    const Se3d again = a.next(at_x(i * 0.02));
    REQUIRE(std::memcmp(first[i].matrix().data(), again.matrix().data(), 16 * sizeof(double)) == 0);
  }
}

TEST_CASE("odometry options parse, and bad ones say which") {
  OdometryDriftConfig config;
  ErrorText error;
  REQUIRE(odometry_config_from_spec("drift=0.02,seed=7,noise=0", &config, &error).ok());
  REQUIRE(config.drift_per_m == 0.02);
  REQUIRE(config.seed == 7);
  REQUIRE(config.noise_m == 0.0);
  REQUIRE(config.drift_rad_per_m == OdometryDriftConfig{}.drift_rad_per_m);
  REQUIRE(odometry_config_from_spec("", &config, &error).ok());
  for (const char* bad : {"drift=-1", "drift=x", "speed=2", "seed=-3", "noise=", "drift=nan",
                          "drift=0.01,,seed=1", "drift"}) {
    CAPTURE(bad);
    const OdometryDriftConfig before = config;
    REQUIRE(odometry_config_from_spec(bad, &config, &error).code() == StatusCode::invalid_argument);
    REQUIRE(config.drift_per_m == before.drift_per_m);
    REQUIRE(std::strlen(error.c_str()) > 0);
  }
  REQUIRE_FALSE(odometry_config_from_spec("seed=1,speed=2", &config, &error).ok());
  REQUIRE(std::strstr(error.c_str(), "'speed=2'") != nullptr);
}

}  // namespace
}  // namespace octofuse::sim
