#include "esdf_slice.hpp"

#include <algorithm>
#include <cmath>

namespace octofuse::examples {

void esdf_slice_colour(float distance_m, float max_m, std::uint8_t rgb[3]) {
  const float t = max_m > 0.0f ? std::min(std::max(distance_m / max_m, 0.0f), 1.0f) : 0.0f;
  const float b = std::floor(t * 255.0f + 0.5f);
  rgb[0] = static_cast<std::uint8_t>(255.0f - b);
  rgb[1] =
      static_cast<std::uint8_t>(std::floor(255.0f * (1.0f - std::abs(2.0f * t - 1.0f)) + 0.5f));
  rgb[2] = static_cast<std::uint8_t>(b);
}

}  // namespace octofuse::examples
