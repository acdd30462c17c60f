// The live view's slice of the distance field against a sphere over a floor written into the
// map: every pixel's colour decodes to the exact distance within the field's error bound, and
// unobserved points are grey, rows top first (largest y), columns left first (smallest x).

#include "esdf_slice.hpp"

#include <algorithm>
#include <cmath>

#include <catch2/catch.hpp>

#include "support/aligned_buffer.hpp"
#include "support/analytic_map.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.02f;
constexpr float kMu_m = 0.08f;

struct SphereOverFloor {
  Eigen::Vector3f centre = Eigen::Vector3f(0.1f, -0.05f, 0.2f);
  float radius = 0.3f;
  float floor_z = -0.8f;
  float operator()(const Eigen::Vector3f& p) const {
    return std::min(p.z() - floor_z, (p - centre).norm() - radius);
  }
};

TEST_CASE("the distance field's slice shows the field's distances by colour, unknown grey") {
  const MapConfig map_config =
      MapConfig::centred(Eigen::Vector3f::Zero(), kVoxel_m, 7, 40000, 40000);
  test::OwnedMap<TsdfVoxel> owned(map_config);
  const SphereOverFloor scene;
  test::fill_band(owned.map, kMu_m, scene, [](const Eigen::Vector3i&) { return 0; });
  EsdfConfig config;
  config.enabled = true;
  config.cells_per_side = 64;  // the whole cube
  config.cell_voxels = 2;
  config.max_cell_steps = 0;
  test::ArenaBuffer memory(EsdfField::bytes_required(config));
  EsdfField field;
  REQUIRE(field.reserve(memory.arena(), config, map_config).ok());
  REQUIRE(field.flush(owned.map, nullptr, kMu_m, 1, 1).published);

  // The map "has not observed" x < -1 and y > 1: the left columns and the top rows.
  auto observed = [](const Eigen::Vector3f& p) { return p.x() >= -1.0f && p.y() <= 1.0f; };
  const float max_m = 0.5f;
  examples::EsdfSliceImage image;
  REQUIRE(examples::esdf_slice(field, scene.centre.z(), max_m, observed, &image));
  REQUIRE(image.width == 64);
  REQUIRE(image.height == 64);
  REQUIRE(image.rgb.size() == 64u * 64u * 3u);

  const float cell = field.cell_m();
  const Eigen::Vector3f lo = field.window_min_W();
  const float step = max_m / 255.0f;  // one colour level
  long checked = 0, grey = 0, saturated = 0, near_zero = 0;
  for (int row = 0; row < image.height; ++row) {
    for (int x = 0; x < image.width; ++x) {
      const std::uint8_t* px = &image.rgb[(static_cast<std::size_t>(row) * 64 + x) * 3];
      const Eigen::Vector3f p(lo.x() + (static_cast<float>(x) + 0.5f) * cell,
                              lo.y() + (static_cast<float>(63 - row) + 0.5f) * cell,
                              scene.centre.z());
      if (!observed(p)) {
        INFO("row " << row << " x " << x);
        REQUIRE(px[0] == examples::kSliceUnknownGrey);
        REQUIRE(px[1] == examples::kSliceUnknownGrey);
        REQUIRE(px[2] == examples::kSliceUnknownGrey);
        ++grey;
        continue;
      }
      const float exact = scene(p);
      if (exact <= 0.0f) continue;  // inside the sphere: the field answers surfaces outside
      // Blue is distance / max, red its complement.
      REQUIRE(static_cast<int>(px[0]) + static_cast<int>(px[2]) == 255);
      const float shown = static_cast<float>(px[2]) * step;
      INFO("row " << row << " x " << x << " exact " << exact << " shown " << shown);
      if (exact >= max_m + kVoxel_m) {
        CHECK(px[2] == 255);
        ++saturated;
      } else {
        // At most a finest voxel above the exact distance, at most the error bound below it.
        CHECK(shown <= std::min(exact, max_m) + kVoxel_m + step);
        CHECK(shown >= std::min(exact, max_m) - field.error_bound_m() - step);
        if (exact < kVoxel_m) ++near_zero;
      }
      ++checked;
    }
  }
  CHECK(grey == 7 * 64 + 7 * 57);  // 7 columns with x < -1, 7 rows with y > 1
  CHECK(checked > 2000);
  CHECK(saturated > 100);
  CHECK(near_zero > 10);

  // A height outside the window: no slice.
  CHECK_FALSE(examples::esdf_slice(field, lo.z() - 0.1f, max_m, observed, &image));
  CHECK(image.width == 0);
  CHECK(image.rgb.empty());
}

TEST_CASE("the slice's colour map: red at zero, blue from max on, green at half") {
  std::uint8_t rgb[3];
  examples::esdf_slice_colour(0.0f, 1.0f, rgb);
  CHECK((rgb[0] == 255 && rgb[1] == 0 && rgb[2] == 0));
  examples::esdf_slice_colour(2.0f, 1.0f, rgb);
  CHECK((rgb[0] == 0 && rgb[1] == 0 && rgb[2] == 255));
  examples::esdf_slice_colour(0.5f, 1.0f, rgb);
  CHECK((rgb[0] == 127 && rgb[1] == 255 && rgb[2] == 128));
  examples::esdf_slice_colour(-0.1f, 1.0f, rgb);
  CHECK(rgb[2] == 0);
}

}  // namespace
}  // namespace octofuse
