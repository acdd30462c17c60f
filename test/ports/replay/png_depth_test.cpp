#include "octofuse/ports/replay/png_depth.hpp"

#include <catch2/catch.hpp>
#include <random>

#include "fixtures.hpp"
#include "octofuse/ports/host/png_writer.hpp"
#include "support/alloc_counter.hpp"

using octofuse::StatusCode;
using octofuse::replay::PngDepthDecoder;
namespace fx = octofuse::test;

namespace {

struct Decoder {
  alignas(64) static inline std::uint8_t memory[PngDepthDecoder::kScratchBytes + 64];
  PngDepthDecoder png;
  Decoder() {
    octofuse::LinearArena arena(memory, sizeof(memory));
    REQUIRE(png.reserve(arena).ok());
  }
};

std::string encode_gray16(const std::vector<std::uint16_t>& depth, int width, int height) {
  const std::string dir = fx::make_test_dir("png-enc");
  const std::string path = dir + "/d.png";
  REQUIRE(fx::write_depth_png(path, depth, width, height));
  return fx::read_bytes(path);
}

const std::uint8_t* bytes_of(const std::string& s) {
  return reinterpret_cast<const std::uint8_t*>(s.data());
}

}  // namespace

TEST_CASE("16-bit PNG decodes to the exact pixels written", "[replay][png]") {
  Decoder decoder;
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> value(0, 65535);
  std::vector<std::uint16_t> depth(33 * 17);
  for (auto& v : depth) v = static_cast<std::uint16_t>(value(rng));
  const std::string png = encode_gray16(depth, 33, 17);
  std::vector<std::uint16_t> out(64 * 64, 0);
  int width = 0, height = 0;
  octofuse::ErrorText error;
  REQUIRE(decoder.png.read_size(bytes_of(png), png.size(), &width, &height, "d.png", &error).ok());
  CHECK(width == 33);
  CHECK(height == 17);
  octofuse::test::AllocationScope scope;
  REQUIRE(
      decoder.png
          .decode(bytes_of(png), png.size(), out.data(), 64, 64, &width, &height, "d.png", &error)
          .ok());
  CHECK(scope.allocations() == 0);
  CHECK(std::equal(depth.begin(), depth.end(), out.begin()));
}

TEST_CASE("PNG decoder refuses what is not a 16-bit grayscale depth image", "[replay][png]") {
  Decoder decoder;
  std::vector<std::uint16_t> out(64 * 64);
  int width = 0, height = 0;
  octofuse::ErrorText error;
  const std::string good = encode_gray16(fx::pattern_depth(20, 10, 0), 20, 10);

  SECTION("RGB image") {
    const std::string dir = fx::make_test_dir("png-rgb");
    std::vector<std::uint8_t> rgb(4 * 4 * 3, 7);
    REQUIRE(
        octofuse::host::write_png_rgb8((dir + "/c.png").c_str(), rgb.data(), 4, 4, 0, &error).ok());
    const std::string png = fx::read_bytes(dir + "/c.png");
    CHECK(decoder.png.decode(bytes_of(png), png.size(), out.data(), 64, 64, &width, &height,
                             "c.png", &error) == StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()) ==
          "c.png: expected a 16-bit grayscale PNG, got bit depth 8 colour type 2");
  }
  SECTION("too large for the buffer") {
    CHECK(decoder.png.decode(bytes_of(good), good.size(), out.data(), 16, 64, &width, &height,
                             "d.png", &error) == StatusCode::resource_exhausted);
  }
  SECTION("every truncation is an error, never a crash") {
    for (std::size_t size = 0; size < good.size(); ++size) {
      const octofuse::Status status = decoder.png.decode(bytes_of(good), size, out.data(), 64, 64,
                                                         &width, &height, "d.png", &error);
      INFO(size);
      CHECK(status == StatusCode::data_loss);
    }
  }
  SECTION("empty input") {
    CHECK(decoder.png.decode(nullptr, 0, out.data(), 64, 64, &width, &height, "e.png", &error) ==
          StatusCode::data_loss);
    CHECK(std::string(error.c_str()) == "e.png: not a PNG file (0 bytes, no PNG signature)");
  }
}
