#include "octofuse/ports/sim/noise.hpp"

#include <algorithm>
#include <cmath>

#include "octofuse/ports/sim/random.hpp"

namespace octofuse::sim {
namespace {

constexpr double kDegToRad = 3.14159265358979323846 / 180.0;

// Random streams, one per decision, so that switching one effect off leaves the others' draws.
enum Stream : std::uint64_t { kGrazing = 3, kEdge = 4, kAxial = 5 };

}  // namespace

double KinectNoiseModel::gaussian_sigma_m(double z_m, double fx_px) const {
  if (!axial) return 0.0;
  const double sigma = axial_sigma_m(z_m);
  const double step = disparity_depth_step_m(z_m, fx_px);
  // Rounding adds step^2 / 12 of variance; take it out of the gaussian part.
  return std::sqrt(std::max(0.0, sigma * sigma - step * step / 12.0));
}

void apply_kinect_noise(const KinectNoiseModel& model, float fx_px, ImageView<const float> depth_m,
                        ImageView<const float> cos_incidence, float metres_per_unit,
                        float min_range_m, float max_range_m, std::uint64_t seed,
                        std::uint64_t frame, ImageView<std::uint16_t> raw) {
  const int width = depth_m.width;
  const int height = depth_m.height;
  const double units_per_m = 1.0 / static_cast<double>(metres_per_unit);
  const double cos_start = std::cos(model.grazing_start_deg * kDegToRad);
  const double cos_full = std::cos(model.grazing_full_deg * kDegToRad);
  const double fb = static_cast<double>(fx_px) * model.baseline_m;
  const std::uint64_t frame_key = mix64(seed) ^ frame;

  for (int y = 0; y < height; ++y) {
    const float* z_row = depth_m.row(y);
    const float* cos_row = cos_incidence.empty() ? nullptr : cos_incidence.row(y);
    std::uint16_t* out = raw.row(y);
    for (int x = 0; x < width; ++x) {
      double z = z_row[x];
      std::uint16_t value = 0;
      if (z > 0.0 && model.enabled) {
        const std::uint64_t pixel = static_cast<std::uint64_t>(y) * width + x;
        bool drop = false;
        if (cos_row != nullptr) {
          const double c = cos_row[x];
          if (c < cos_start) {
            const double p = c <= cos_full ? 1.0 : (cos_start - c) / (cos_start - cos_full);
            drop = uniform_from_bits(hash_key(frame_key, pixel, kGrazing, 0)) < p;
          }
        }
        if (!drop && model.edge_dropout_probability > 0.0) {
          const double jump = model.edge_jump_fraction * z;
          bool behind_edge = false;
          const auto check = [&](int nx, int ny) {
            if (nx < 0 || ny < 0 || nx >= width || ny >= height) return;
            const double zn = depth_m(nx, ny);
            if (zn > 0.0 && z - zn > jump) behind_edge = true;
          };
          check(x - 1, y);
          check(x + 1, y);
          check(x, y - 1);
          check(x, y + 1);
          drop = behind_edge && uniform_from_bits(hash_key(frame_key, pixel, kEdge, 0)) <
                                    model.edge_dropout_probability;
        }
        if (drop) {
          z = 0.0;
        } else {
          z += model.gaussian_sigma_m(z, fx_px) *
               gaussian_from_bits(hash_key(frame_key, pixel, kAxial, 0));
          if (model.disparity_quantisation && z > 0.0) {
            const double d_px = fb / z;
            const double d_q = std::round(d_px / model.disparity_step_px) * model.disparity_step_px;
            z = d_q > 0.0 ? fb / d_q : 0.0;
          }
        }
      }
      if (z >= min_range_m && z <= max_range_m) {
        const double units = std::round(z * units_per_m);
        if (units >= 1.0 && units <= 65534.0) value = static_cast<std::uint16_t>(units);
      }
      out[x] = value;
    }
  }
}

}  // namespace octofuse::sim
