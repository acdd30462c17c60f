#pragma once
// Turns a ray-cast into a picture people can read: Lambertian shading from a point light (usually
// the camera centre), tinted by the scale the surface was interpolated at, as in the paper's
// Fig. 6. Scale 0 red, 1 green, 2 blue, 3 yellow; invalid pixels black.

#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/status.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/image/surface_map.hpp"

namespace octofuse {

struct Rgb8 {
  std::uint8_t r = 0;
  std::uint8_t g = 0;
  std::uint8_t b = 0;
};

// Value of a scale-image pixel that saw no surface.
inline constexpr std::uint8_t kNoScale = 0xFF;

// Tint of scale 0..3 at full brightness; other values get grey.
Rgb8 scale_colour(std::uint8_t scale);

// Writes `rgb` (same size as the surface map) from surface_W (world frame) and its scale image.
// Brightness = kAmbient + (1 - kAmbient) * max(0, n . l), l the unit vector from the vertex to
// light_W. Returns ok, or invalid_argument when the images are empty or their sizes differ.
Status shade_by_scale(const ConstSurfaceMap& surface_W, ImageView<const std::uint8_t> scale,
                      const Eigen::Vector3f& light_W, ImageView<Rgb8> rgb);

}  // namespace octofuse
