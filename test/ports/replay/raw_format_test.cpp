#include "octofuse/ports/replay/raw_format.hpp"

#include <catch2/catch.hpp>
#include <cstring>
#include <string>

#include "fixtures.hpp"

using octofuse::StatusCode;
namespace rp = octofuse::replay;

TEST_CASE(".raw frame layout from the two headers", "[replay][raw]") {
  const std::string frame = octofuse::test::raw_frame_bytes(5, 4, 0);
  const auto* bytes = reinterpret_cast<const std::uint8_t*>(frame.data());
  octofuse::ErrorText error;
  rp::RawFrameLayout layout;
  REQUIRE(rp::parse_raw_frame_header(bytes, nullptr, 100, 100 + frame.size(), 640, 480, &layout,
                                     "f.raw", &error)
              .ok());
  CHECK(layout.depth_width == 5);
  CHECK(layout.depth_offset == 108);
  REQUIRE(rp::parse_raw_frame_header(bytes, bytes + 8 + 40, 100, 100 + frame.size(), 640, 480,
                                     &layout, "f.raw", &error)
              .ok());
  CHECK(layout.rgb_width == 5);
  CHECK(layout.rgb_height == 4);
  CHECK(layout.next_offset == 100 + frame.size());
  CHECK(rp::parse_raw_frame_header(bytes, bytes + 48, 100, 99 + frame.size(), 640, 480, &layout,
                                   "f.raw", &error) == StatusCode::data_loss);
  CHECK(std::string(error.c_str()).find("f.raw: short frame at byte 100") == 0);
  CHECK(rp::parse_raw_frame_header(bytes, nullptr, 0, frame.size(), 4, 480, &layout, "f.raw",
                                   &error) == StatusCode::resource_exhausted);
}

TEST_CASE("little-endian depth converts to host order", "[replay][raw]") {
  std::uint16_t pixels[2];
  const std::uint8_t le[4] = {0x34, 0x12, 0xff, 0x00};
  std::memcpy(pixels, le, 4);
  rp::little_endian_to_host(pixels, 2);
  CHECK(pixels[0] == 0x1234);
  CHECK(pixels[1] == 0x00ff);
}
