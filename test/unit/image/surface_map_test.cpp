#include "octofuse/image/surface_map.hpp"

#include <catch2/catch.hpp>
#include <cstdint>
#include <vector>

namespace octofuse {
namespace {

// A width x height map whose pixel (x, y) is valid where valid_at(x, y); a half-resolution one
// (stride 2) copies each cast pixel to the odd pixels beside and below it, as the ray-caster does.
struct TestMap {
  int width;
  int height;
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3f> normals;

  template <typename ValidAt>
  TestMap(int w, int h, int stride, ValidAt valid_at)
      : width(w),
        height(h),
        vertices(static_cast<std::size_t>(w * h), Eigen::Vector3f::Zero()),
        normals(static_cast<std::size_t>(w * h), Eigen::Vector3f::Zero()) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const int cx = stride == 2 ? x & ~1 : x;
        const int cy = stride == 2 ? y & ~1 : y;
        if (valid_at(cx, cy))
          normals[static_cast<std::size_t>(y * w + x)] = Eigen::Vector3f::UnitZ();
      }
    }
  }
  ConstSurfaceMap map(int stride) const {
    ConstSurfaceMap m;
    m.vertices = ImageView<const Eigen::Vector3f>(vertices.data(), width, height);
    m.normals = ImageView<const Eigen::Vector3f>(normals.data(), width, height);
    m.pixel_stride = stride;
    return m;
  }
  std::uint32_t every_valid_pixel() const {
    std::uint32_t n = 0;
    for (const Eigen::Vector3f& normal : normals) n += is_invalid_normal(normal) ? 0u : 1u;
    return n;
  }
};

TEST_CASE("a half-resolution map counts its cast pixels with their copies, as every pixel") {
  // Even and odd sizes (the last column or row without copies), a pattern with holes.
  const int sizes[][2] = {{8, 6}, {9, 6}, {8, 7}, {9, 7}, {1, 1}, {1, 4}, {5, 1}, {321, 241}};
  for (const auto& size : sizes) {
    const int w = size[0];
    const int h = size[1];
    INFO(w << " x " << h);
    const TestMap half(w, h, 2, [](int x, int y) { return (x * 7 + y * 3) % 5 != 0; });
    const std::uint32_t expected = half.every_valid_pixel();
    CHECK(valid_pixel_count(half.map(2)) == expected);
    CHECK(valid_pixel_count(half.map(1)) == expected);
    // A full-resolution map with the same cast pixels but no copies: stride 1 counts what is
    // there, so fewer pixels wherever a copy would have been valid.
    const TestMap full(w, h, 1,
                       [](int x, int y) { return (x | y) % 2 == 0 && (x * 7 + y * 3) % 5 != 0; });
    CHECK(valid_pixel_count(full.map(1)) == full.every_valid_pixel());
    if (w > 1 || h > 1) CHECK(valid_pixel_count(full.map(1)) < expected);
  }
}

TEST_CASE("an empty or all-invalid map counts no pixels") {
  const TestMap none(6, 4, 2, [](int, int) { return false; });
  CHECK(valid_pixel_count(none.map(2)) == 0u);
  CHECK(valid_pixel_count(none.map(1)) == 0u);
  CHECK(valid_pixel_count(ConstSurfaceMap()) == 0u);
}

}  // namespace
}  // namespace octofuse
