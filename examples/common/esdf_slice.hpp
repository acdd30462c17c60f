#pragma once
// A horizontal slice of the distance field (query/esdf.hpp) as an image, for the live view: one
// pixel per field cell of the window, x to the right and y up, at the height z_W (the camera's).
// Distance by colour: blue = distance / max_m (0 to 255, saturating), red its complement, green
// a tent peaking at max_m / 2; points the map has not observed are grey, whatever the field says
// there (with unknown space as obstacle the field reads them near zero).

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "octofuse/query/esdf.hpp"

namespace octofuse::examples {

struct EsdfSliceImage {
  int width = 0;
  int height = 0;
  float z_W = 0.0f;
  std::vector<std::uint8_t> rgb;  // rows top first (largest y first)
};

constexpr std::uint8_t kSliceUnknownGrey = 128;

// The colour of a distance (clamped to [0, max_m]).
void esdf_slice_colour(float distance_m, float max_m, std::uint8_t rgb[3]);

// Fills `out` from the published field. `observed(p_W)` says whether the map observed p_W (free,
// near or inside); pixels where it is false, or where the field has no distance, are grey. False
// (and `out` empty) when the field is not reserved or z_W lies outside its window.
template <typename Observed>
bool esdf_slice(const EsdfField& field, float z_W, float max_m, const Observed& observed,
                EsdfSliceImage* out) {
  out->width = 0;
  out->height = 0;
  out->rgb.clear();
  if (!field.reserved()) return false;
  const int n = field.cells_per_side();
  const float cell = field.cell_m();
  const Eigen::Vector3f lo = field.window_min_W();
  if (!(z_W >= lo.z() && z_W < lo.z() + cell * static_cast<float>(n))) return false;
  out->width = n;
  out->height = n;
  out->z_W = z_W;
  out->rgb.assign(static_cast<std::size_t>(n) * static_cast<std::size_t>(n) * 3, kSliceUnknownGrey);
  std::vector<Eigen::Vector3f> points(static_cast<std::size_t>(n));
  std::vector<EsdfAnswer> answers(static_cast<std::size_t>(n));
  for (int row = 0; row < n; ++row) {
    const int y = n - 1 - row;
    for (int x = 0; x < n; ++x) {
      points[static_cast<std::size_t>(x)] =
          lo + Eigen::Vector3f((static_cast<float>(x) + 0.5f) * cell,
                               (static_cast<float>(y) + 0.5f) * cell, z_W - lo.z());
    }
    if (!field.distances(points.data(), points.size(), answers.data()).ok()) continue;
    for (int x = 0; x < n; ++x) {
      const EsdfAnswer& a = answers[static_cast<std::size_t>(x)];
      if (!a.has_distance || !observed(points[static_cast<std::size_t>(x)])) continue;
      esdf_slice_colour(a.distance_m, max_m,
                        &out->rgb[(static_cast<std::size_t>(row) * n + x) * 3]);
    }
  }
  return true;
}

}  // namespace octofuse::examples
