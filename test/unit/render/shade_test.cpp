#include "octofuse/render/shade.hpp"

#include <catch2/catch.hpp>
#include <cstdint>

namespace octofuse {
namespace {

TEST_CASE("shading tints by scale, lights by the normal and blacks out invalid pixels") {
  constexpr int kW = 4;
  constexpr int kH = 1;
  Eigen::Vector3f vertices[kW * kH];
  Eigen::Vector3f normals[kW * kH];
  std::uint8_t scales[kW * kH] = {0, 1, 2, kNoScale};
  Rgb8 rgb[kW * kH];
  for (int i = 0; i < kW; ++i) {
    vertices[i] = Eigen::Vector3f(static_cast<float>(i), 0.0f, 1.0f);
    normals[i] = Eigen::Vector3f(0.0f, 0.0f, -1.0f);
  }
  normals[3] = Eigen::Vector3f::Zero();  // invalid
  // Pixel 2 faces sideways: only ambient light.
  normals[2] = Eigen::Vector3f(1.0f, 0.0f, 0.0f);
  SurfaceMap surface{ImageView<Eigen::Vector3f>(vertices, kW, kH),
                     ImageView<Eigen::Vector3f>(normals, kW, kH)};
  // Light straight in front of pixel 0 and 1 along -z... place it far so l ~ (0, 0, -1).
  const Eigen::Vector3f light_W(0.5f, 0.0f, -1.0e6f);
  REQUIRE(shade_by_scale(surface, ImageView<const std::uint8_t>(scales, kW, kH), light_W,
                         ImageView<Rgb8>(rgb, kW, kH))
              .ok());
  const Rgb8 red = scale_colour(0);
  const Rgb8 green = scale_colour(1);
  REQUIRE(rgb[0].r == red.r);  // fully lit
  REQUIRE(rgb[0].g == red.g);
  REQUIRE(rgb[1].g == green.g);
  REQUIRE(rgb[1].r == green.r);
  REQUIRE(rgb[2].b < scale_colour(2).b / 4 + 1);  // ambient only (0.2)
  REQUIRE(rgb[2].b > 0);
  REQUIRE(rgb[3].r == 0);
  REQUIRE(rgb[3].g == 0);
  REQUIRE(rgb[3].b == 0);
}

TEST_CASE("scale colours are distinct") {
  for (int a = 0; a < 4; ++a) {
    for (int b = a + 1; b < 4; ++b) {
      const Rgb8 ca = scale_colour(static_cast<std::uint8_t>(a));
      const Rgb8 cb = scale_colour(static_cast<std::uint8_t>(b));
      REQUIRE((ca.r != cb.r || ca.g != cb.g || ca.b != cb.b));
    }
  }
}

TEST_CASE("mismatched image sizes are invalid_argument") {
  Eigen::Vector3f v[4];
  Eigen::Vector3f n[4];
  std::uint8_t s[2] = {};
  Rgb8 rgb[4];
  SurfaceMap surface{ImageView<Eigen::Vector3f>(v, 2, 2), ImageView<Eigen::Vector3f>(n, 2, 2)};
  REQUIRE(shade_by_scale(surface, ImageView<const std::uint8_t>(s, 2, 1), Eigen::Vector3f::Zero(),
                         ImageView<Rgb8>(rgb, 2, 2)) == StatusCode::invalid_argument);
}

}  // namespace
}  // namespace octofuse
