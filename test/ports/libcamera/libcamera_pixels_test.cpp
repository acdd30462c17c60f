#include <catch2/catch.hpp>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "octofuse/ports/libcamera/libcamera_source.hpp"

namespace octofuse {
namespace {

using ports::convert_libcamera_pixels;
using ports::libcamera_row_bytes;
using ports::LibcameraOptions;
using ports::LibcameraPixelLayout;
using ports::validate_libcamera_options;

// A 12-bit (or 10-bit) test value for pixel (x, y) that exercises every bit over a frame.
std::uint16_t pattern(int x, int y, int bits) {
  return static_cast<std::uint16_t>((x * 37 + y * 101 + 5) & ((1 << bits) - 1));
}

// Packs `width` x `height` values the way the MIPI CSI-2 RAW10/RAW12 formats do, rows padded to
// `stride` bytes with 0xAA (padding must never leak into pixels).
std::vector<std::uint8_t> pack_csi2(int bits, int width, int height, std::size_t stride) {
  std::vector<std::uint8_t> out(stride * static_cast<std::size_t>(height), 0xAA);
  for (int y = 0; y < height; ++y) {
    std::uint8_t* row = out.data() + static_cast<std::size_t>(y) * stride;
    if (bits == 12) {
      for (int x = 0; x < width; x += 2) {
        std::uint8_t* g = row + (x / 2) * 3;
        const std::uint16_t p0 = pattern(x, y, 12);
        const std::uint16_t p1 = x + 1 < width ? pattern(x + 1, y, 12) : 0;
        g[0] = static_cast<std::uint8_t>(p0 >> 4);
        g[1] = static_cast<std::uint8_t>(p1 >> 4);
        g[2] = static_cast<std::uint8_t>((p0 & 0x0f) | ((p1 & 0x0f) << 4));
      }
    } else {
      for (int x = 0; x < width; x += 4) {
        std::uint8_t* g = row + (x / 4) * 5;
        g[4] = 0;
        for (int i = 0; i < 4; ++i) {
          const std::uint16_t p = x + i < width ? pattern(x + i, y, 10) : 0;
          g[i] = static_cast<std::uint8_t>(p >> 2);
          g[4] = static_cast<std::uint8_t>(g[4] | ((p & 0x03) << (2 * i)));
        }
      }
    }
  }
  return out;
}

TEST_CASE("libcamera pixels: row sizes of each layout") {
  CHECK(libcamera_row_bytes(LibcameraPixelLayout::r16, 640) == 1280);
  CHECK(libcamera_row_bytes(LibcameraPixelLayout::r12, 7) == 14);
  CHECK(libcamera_row_bytes(LibcameraPixelLayout::r12_csi2p, 640) == 960);
  CHECK(libcamera_row_bytes(LibcameraPixelLayout::r12_csi2p, 5) == 8);  // 3 groups, last half
  CHECK(libcamera_row_bytes(LibcameraPixelLayout::r10_csi2p, 640) == 800);
  CHECK(libcamera_row_bytes(LibcameraPixelLayout::r10_csi2p, 6) == 8);
  CHECK(libcamera_row_bytes(LibcameraPixelLayout::r10_csi2p, 0) == 0);
}

TEST_CASE("libcamera pixels: 16-bit little-endian words, masked for R12 and R10") {
  constexpr int kWidth = 5;
  constexpr int kHeight = 3;
  constexpr std::size_t kStride = 16;  // 10 bytes of pixels + 6 of padding
  std::vector<std::uint8_t> src(kStride * kHeight, 0xEE);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      // High bits set beyond 12 to prove the masks: 0xF000 | value.
      const std::uint16_t value = static_cast<std::uint16_t>(0xF000 | pattern(x, y, 12));
      src[y * kStride + 2 * x] = static_cast<std::uint8_t>(value & 0xff);
      src[y * kStride + 2 * x + 1] = static_cast<std::uint8_t>(value >> 8);
    }
  }
  std::uint16_t out[kWidth * kHeight] = {};
  REQUIRE(convert_libcamera_pixels(LibcameraPixelLayout::r16, src.data(), kStride, src.size(),
                                   kWidth, kHeight, out)
              .ok());
  CHECK(out[0] == (0xF000 | pattern(0, 0, 12)));
  CHECK(out[2 * kWidth + 4] == (0xF000 | pattern(4, 2, 12)));

  REQUIRE(convert_libcamera_pixels(LibcameraPixelLayout::r12, src.data(), kStride, src.size(),
                                   kWidth, kHeight, out)
              .ok());
  bool all = true;
  for (int y = 0; y < kHeight; ++y)
    for (int x = 0; x < kWidth; ++x) all = all && out[y * kWidth + x] == pattern(x, y, 12);
  CHECK(all);

  REQUIRE(convert_libcamera_pixels(LibcameraPixelLayout::r10, src.data(), kStride, src.size(),
                                   kWidth, kHeight, out)
              .ok());
  CHECK(out[kWidth + 3] == (pattern(3, 1, 12) & 0x3ff));
}

TEST_CASE("libcamera pixels: CSI-2 packed RAW12 and RAW10, odd widths and padded rows") {
  for (int width : {1, 2, 5, 8, 13}) {
    constexpr int kHeight = 4;
    const std::size_t stride12 = libcamera_row_bytes(LibcameraPixelLayout::r12_csi2p, width) + 3;
    const std::vector<std::uint8_t> raw12 = pack_csi2(12, width, kHeight, stride12);
    std::vector<std::uint16_t> out(static_cast<std::size_t>(width) * kHeight, 0xFFFF);
    REQUIRE(convert_libcamera_pixels(LibcameraPixelLayout::r12_csi2p, raw12.data(), stride12,
                                     raw12.size(), width, kHeight, out.data())
                .ok());
    bool exact12 = true;
    for (int y = 0; y < kHeight; ++y)
      for (int x = 0; x < width; ++x) exact12 = exact12 && out[y * width + x] == pattern(x, y, 12);
    CHECK(exact12);

    const std::size_t stride10 = libcamera_row_bytes(LibcameraPixelLayout::r10_csi2p, width) + 7;
    const std::vector<std::uint8_t> raw10 = pack_csi2(10, width, kHeight, stride10);
    REQUIRE(convert_libcamera_pixels(LibcameraPixelLayout::r10_csi2p, raw10.data(), stride10,
                                     raw10.size(), width, kHeight, out.data())
                .ok());
    bool exact10 = true;
    for (int y = 0; y < kHeight; ++y)
      for (int x = 0; x < width; ++x) exact10 = exact10 && out[y * width + x] == pattern(x, y, 10);
    CHECK(exact10);
  }
}

TEST_CASE("libcamera pixels: short buffers and bad arguments are refused") {
  std::uint8_t src[64] = {};
  std::uint16_t out[64] = {};
  // 4x4 R16 with stride 10 needs 3 * 10 + 8 = 38 bytes: the last row has no padding.
  CHECK(convert_libcamera_pixels(LibcameraPixelLayout::r16, src, 10, 38, 4, 4, out).ok());
  CHECK(convert_libcamera_pixels(LibcameraPixelLayout::r16, src, 10, 37, 4, 4, out).code() ==
        StatusCode::data_loss);
  CHECK(convert_libcamera_pixels(LibcameraPixelLayout::r16, src, 7, 64, 4, 4, out).code() ==
        StatusCode::invalid_argument);  // stride below one row
  CHECK(convert_libcamera_pixels(LibcameraPixelLayout::r16, src, 8, 64, 0, 4, out).code() ==
        StatusCode::invalid_argument);
  CHECK(convert_libcamera_pixels(LibcameraPixelLayout::r16, nullptr, 8, 64, 4, 4, out).code() ==
        StatusCode::invalid_argument);
}

TEST_CASE("libcamera options: validation names the problem") {
  ErrorText why;
  CHECK(validate_libcamera_options(LibcameraOptions{}, why).ok());

  LibcameraOptions options;
  options.width = 640;
  CHECK(validate_libcamera_options(options, why).code() == StatusCode::invalid_argument);
  CHECK(std::strstr(why.c_str(), "640x0") != nullptr);

  options = LibcameraOptions{};
  options.metres_per_unit = 0.0f;
  CHECK(validate_libcamera_options(options, why).code() == StatusCode::invalid_argument);
  options = LibcameraOptions{};
  options.buffer_count = 1;
  CHECK(validate_libcamera_options(options, why).code() == StatusCode::invalid_argument);
  options = LibcameraOptions{};
  options.ring_size = 9;
  CHECK(validate_libcamera_options(options, why).code() == StatusCode::invalid_argument);
  options = LibcameraOptions{};
  options.horizontal_fov_deg = 180.0f;
  CHECK(validate_libcamera_options(options, why).code() == StatusCode::invalid_argument);

  options = LibcameraOptions{};
  options.width = 240;
  options.height = 180;
  options.intrinsics = PinholeCamera{200.0f, 200.0f, 119.5f, 89.5f, 240, 180};
  CHECK(validate_libcamera_options(options, why).ok());
  options.intrinsics.width = 320;
  CHECK(validate_libcamera_options(options, why).code() == StatusCode::invalid_argument);
  CHECK(std::strstr(why.c_str(), "320x180") != nullptr);

  const std::string long_id(300, 'x');
  options = LibcameraOptions{};
  options.camera_id = long_id.c_str();
  CHECK(validate_libcamera_options(options, why).code() == StatusCode::invalid_argument);
}

}  // namespace
}  // namespace octofuse
