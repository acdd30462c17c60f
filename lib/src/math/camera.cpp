#include "octofuse/math/camera.hpp"

#include <cmath>

namespace octofuse {

bool PinholeCamera::valid() const {
  return std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy) &&
         fx > 0.0f && fy > 0.0f && width > 0 && height > 0;
}

PinholeCamera PinholeCamera::downsampled(int factor) const {
  // Pixel centre u_fine = factor * u_coarse + (factor - 1) / 2.
  const float f = static_cast<float>(factor);
  const float shift = 0.5f * (f - 1.0f);
  PinholeCamera c;
  c.fx = fx / f;
  c.fy = fy / f;
  c.cx = (cx - shift) / f;
  c.cy = (cy - shift) / f;
  c.width = width / factor;
  c.height = height / factor;
  return c;
}

}  // namespace octofuse
