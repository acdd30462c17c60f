#include "octofuse/ports/sim/odometry.hpp"

#include <cmath>
#include <cstdlib>
#include <cstring>

#include "octofuse/ports/sim/random.hpp"

namespace octofuse::sim {
namespace {

bool non_negative(double v) {
  return std::isfinite(v) && v >= 0.0;
}

// Streams of draws, so drift and noise never share a hash.
enum Stream : std::uint64_t { kDriftStream = 1, kNoiseStream = 2 };

}  // namespace

Status validate(const OdometryDriftConfig& c) {
  if (!non_negative(c.drift_per_m) || !non_negative(c.drift_rad_per_m) ||
      !non_negative(c.noise_m) || !non_negative(c.noise_rad)) {
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

DriftingOdometry::DriftingOdometry(const OdometryDriftConfig& config) : config_(config) {
  // A fixed direction for each part of the drift, from the seed.
  Eigen::Vector3d t, r;
  for (int i = 0; i < 3; ++i) {
    t[i] = gaussian_from_bits(hash_key(config.seed, kDriftStream, 0, static_cast<unsigned>(i)));
    r[i] = gaussian_from_bits(hash_key(config.seed, kDriftStream, 1, static_cast<unsigned>(i)));
  }
  if (t.norm() > 0.0) t *= config.drift_per_m / t.norm();
  if (r.norm() > 0.0) r *= config.drift_rad_per_m / r.norm();
  drift_twist_per_m_ << t, r;
}

void DriftingOdometry::restart() {
  drift_ = Se3d::Identity();
  previous_true_ = Se3d::Identity();
  step_ = 0;
  distance_m_ = 0.0;
}

Se3d DriftingOdometry::next(const Se3d& T_W_C_true) {
  if (step_ > 0) {
    const double step_m = (T_W_C_true.translation() - previous_true_.translation()).norm();
    distance_m_ += step_m;
    drift_ = se3_exp(drift_twist_per_m_ * step_m) * drift_;
    drift_.linear() = orthonormalize(drift_.linear());
  }
  Vector6d noise;
  for (int i = 0; i < 6; ++i) {
    const double sigma = i < 3 ? config_.noise_m : config_.noise_rad;
    noise[i] = sigma * gaussian_from_bits(
                           hash_key(config_.seed, kNoiseStream, step_, static_cast<unsigned>(i)));
  }
  previous_true_ = T_W_C_true;
  ++step_;
  Se3d out = drift_ * T_W_C_true * se3_exp(noise);
  out.linear() = orthonormalize(out.linear());
  return out;
}

Status odometry_config_from_spec(const char* spec, OdometryDriftConfig* config, ErrorText* error) {
  OdometryDriftConfig c = *config;
  const char* p = spec;
  while (p != nullptr && *p != '\0') {
    const char* end = std::strchr(p, ',');
    const std::size_t length = end != nullptr ? static_cast<std::size_t>(end - p) : std::strlen(p);
    char item[64];
    if (length == 0 || length >= sizeof(item)) {
      if (error != nullptr) error->set("odometry option %d characters long", int(length));
      return StatusCode::invalid_argument;
    }
    std::memcpy(item, p, length);
    item[length] = '\0';
    char* equals = std::strchr(item, '=');
    char* value_end = nullptr;
    const char* value = equals != nullptr ? equals + 1 : "";
    if (equals != nullptr) *equals = '\0';
    bool ok = equals != nullptr && *value != '\0';
    if (ok && std::strcmp(item, "seed") == 0) {
      const unsigned long long seed = std::strtoull(value, &value_end, 10);
      ok = *value != '-' && *value_end == '\0';
      c.seed = seed;
    } else if (ok) {
      const double v = std::strtod(value, &value_end);
      ok = *value_end == '\0' && non_negative(v);
      if (std::strcmp(item, "drift") == 0) {
        c.drift_per_m = v;
      } else if (std::strcmp(item, "drift_rad") == 0) {
        c.drift_rad_per_m = v;
      } else if (std::strcmp(item, "noise") == 0) {
        c.noise_m = v;
      } else if (std::strcmp(item, "noise_rad") == 0) {
        c.noise_rad = v;
      } else {
        ok = false;
      }
    }
    if (!ok) {
      if (error != nullptr) {
        error->set(
            "bad odometry option '%.*s' (drift=, drift_rad=, noise=, noise_rad= take a "
            "number >= 0, seed= an integer)",
            int(length), p);
      }
      return StatusCode::invalid_argument;
    }
    p = end != nullptr ? end + 1 : nullptr;
  }
  *config = c;
  return ok_status();
}

}  // namespace octofuse::sim
