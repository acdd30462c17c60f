#pragma once
// A Kinect-like depth noise model (structured light, after Khoshelham & Elberink 2012 and Nguyen
// et al. 2012): axial noise growing with z^2, disparity quantisation, lateral jitter of the
// sampled ray, and dropouts at grazing angles and behind depth edges. Deterministic: every random
// draw is a hash of (seed, frame, pixel, stream).

#include <cstdint>

#include "octofuse/image/image_view.hpp"

namespace octofuse::sim {

struct KinectNoiseModel {
  bool enabled = true;  // off: exact depth, only rounded to the output units

  // Total axial standard deviation sigma(z) = base + quadratic * (z - reference)^2.
  bool axial = true;
  double sigma_base_m = 0.0012;
  double sigma_quadratic_per_m = 0.0019;
  double sigma_reference_m = 0.4;

  // Depth comes from a disparity measured in steps of disparity_step_px: z = fx * b / d. The
  // gaussian part is reduced so that gaussian + quantisation together still have sigma(z).
  bool disparity_quantisation = true;
  double baseline_m = 0.075;
  double disparity_step_px = 0.125;

  float lateral_sigma_px = 0.5f;  // jitter of the ray through each pixel

  // Dropout probability ramps from 0 at grazing_start_deg to 1 at grazing_full_deg (angle between
  // ray and surface normal).
  double grazing_start_deg = 72.0;
  double grazing_full_deg = 86.0;
  // A pixel more than edge_jump_fraction * z behind a 4-neighbour is dropped with this probability
  // (the projector's shadow beside foreground edges).
  double edge_jump_fraction = 0.04;
  double edge_dropout_probability = 0.5;

  double axial_sigma_m(double z_m) const {
    const double dz = z_m - sigma_reference_m;
    return sigma_base_m + sigma_quadratic_per_m * dz * dz;
  }
  // Depth difference of one disparity step at z (0 when quantisation is off).
  double disparity_depth_step_m(double z_m, double fx_px) const {
    if (!disparity_quantisation) return 0.0;
    return z_m * z_m * disparity_step_px / (fx_px * baseline_m);
  }
  // Standard deviation of the gaussian part at z.
  double gaussian_sigma_m(double z_m, double fx_px) const;
};

// Turns noiseless depth (metres along z, 0 = nothing) and |cos| incidence into raw units of
// metres_per_unit with noise for (seed, frame). Depth outside [min_range_m, max_range_m] or not
// representable in 16 bits becomes 0. All views the same size (unchecked; the caller owns them).
void apply_kinect_noise(const KinectNoiseModel& model, float fx_px, ImageView<const float> depth_m,
                        ImageView<const float> cos_incidence, float metres_per_unit,
                        float min_range_m, float max_range_m, std::uint64_t seed,
                        std::uint64_t frame, ImageView<std::uint16_t> raw);

}  // namespace octofuse::sim
