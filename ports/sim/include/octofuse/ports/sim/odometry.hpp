#pragma once
// A drifting, noisy odometry of a known trajectory, for testing pose priors: what a VIO or wheel
// odometry reports when it drifts in proportion to the distance travelled. Deterministic: the
// drift direction and every noise draw are hashes of the seed (and the step), so the same seed
// gives the same odometry on every machine.
//
//   T_O_C(k) = D(k) * T_W_C_true(k) * N(k)
//
// D(k) is the accumulated drift: each step multiplies it from the left by exp(s_k * twist), s_k
// the distance travelled in the step and twist a fixed seeded direction of length
// drift_per_m (translation, metres per metre) and drift_rad_per_m (rotation). N(k) is white
// noise of the pose (sigma per axis), not accumulated.

#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse::sim {

struct OdometryDriftConfig {
  double drift_per_m = 0.01;       // translation drift per metre travelled (1 %)
  double drift_rad_per_m = 0.002;  // rotation drift per metre travelled (0.11 deg)
  double noise_m = 0.001;          // white position noise per axis (sigma)
  double noise_rad = 0.001;        // white rotation noise per axis (sigma)
  std::uint64_t seed = 1;
};

// ok, or invalid_argument for a negative or non-finite value.
Status validate(const OdometryDriftConfig& config);

class DriftingOdometry {
 public:
  explicit DriftingOdometry(const OdometryDriftConfig& config = {});

  // The odometry for the next pose of the true trajectory (the first call starts it: D = I).
  Se3d next(const Se3d& T_W_C_true);
  // Starts over (the next call is step 0 again).
  void restart();
  double distance_m() const { return distance_m_; }

 private:
  OdometryDriftConfig config_;
  Vector6d drift_twist_per_m_ = Vector6d::Zero();
  Se3d drift_ = Se3d::Identity();
  Se3d previous_true_ = Se3d::Identity();
  std::uint64_t step_ = 0;
  double distance_m_ = 0.0;
};

// Parses "drift=0.01,drift_rad=0.002,noise=0.001,noise_rad=0.001,seed=N" (any subset, any
// order; empty keeps the defaults). invalid_argument names the bad item in `error`.
Status odometry_config_from_spec(const char* spec, OdometryDriftConfig* config, ErrorText* error);

}  // namespace octofuse::sim
