#include "octofuse/render/shade.hpp"

#include <algorithm>

namespace octofuse {
namespace {

// Keeps faces turned away from the light readable.
constexpr float kAmbient = 0.2f;

std::uint8_t to_byte(float channel, float brightness) {
  const float v = std::min(255.0f, std::max(0.0f, channel * brightness + 0.5f));
  return static_cast<std::uint8_t>(v);
}

}  // namespace

Rgb8 scale_colour(std::uint8_t scale) {
  switch (scale) {
    case 0:
      return Rgb8{230, 40, 40};
    case 1:
      return Rgb8{40, 200, 40};
    case 2:
      return Rgb8{50, 80, 230};
    case 3:
      return Rgb8{230, 210, 40};
    default:
      return Rgb8{160, 160, 160};
  }
}

Status shade_by_scale(const ConstSurfaceMap& surface_W, ImageView<const std::uint8_t> scale,
                      const Eigen::Vector3f& light_W, ImageView<Rgb8> rgb) {
  const int w = surface_W.width();
  const int h = surface_W.height();
  if (surface_W.vertices.empty() || surface_W.normals.empty() || scale.empty() || rgb.empty() ||
      surface_W.normals.width != w || surface_W.normals.height != h || scale.width != w ||
      scale.height != h || rgb.width != w || rgb.height != h) {
    return StatusCode::invalid_argument;
  }
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!surface_W.valid(x, y)) {
        rgb(x, y) = Rgb8{};
        continue;
      }
      const Eigen::Vector3f to_light = light_W - surface_W.vertices(x, y);
      const float distance = to_light.norm();
      const float lambert =
          distance > 0.0f ? std::max(0.0f, surface_W.normals(x, y).dot(to_light) / distance) : 1.0f;
      const float brightness = kAmbient + (1.0f - kAmbient) * lambert;
      const Rgb8 tint = scale_colour(scale(x, y));
      rgb(x, y) = Rgb8{to_byte(tint.r, brightness), to_byte(tint.g, brightness),
                       to_byte(tint.b, brightness)};
    }
  }
  return ok_status();
}

}  // namespace octofuse
