#include "octofuse/ports/host/png_writer.hpp"

#include <catch2/catch.hpp>
#include <fstream>
#include <vector>

#include "support/test_dir.hpp"

// Pixel-exact round trips go through the replay port's decoder (test/ports/replay); here the
// container: signature and IHDR fields.
namespace {

std::vector<unsigned char> read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<unsigned char>((std::istreambuf_iterator<char>(in)),
                                    std::istreambuf_iterator<char>());
}

std::uint32_t be32(const unsigned char* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) |
         p[3];
}

}  // namespace

TEST_CASE("PNG writer produces a PNG header with the right size and format", "[host][png]") {
  const std::string dir = octofuse::test::make_test_dir("png");
  octofuse::ErrorText error;

  std::vector<std::uint16_t> depth(7 * 5, 1234);
  const std::string gray_path = dir + "/depth.png";
  REQUIRE(
      octofuse::host::write_png_gray16(
          gray_path.c_str(), octofuse::ImageView<const std::uint16_t>(depth.data(), 7, 5), &error)
          .ok());
  std::vector<unsigned char> bytes = read_bytes(gray_path);
  REQUIRE(bytes.size() > 33);
  const unsigned char signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  CHECK(std::equal(signature, signature + 8, bytes.begin()));
  CHECK(std::string(bytes.begin() + 12, bytes.begin() + 16) == "IHDR");
  CHECK(be32(&bytes[16]) == 7);
  CHECK(be32(&bytes[20]) == 5);
  CHECK(bytes[24] == 16);  // bit depth
  CHECK(bytes[25] == 0);   // grayscale

  std::vector<std::uint8_t> rgb(4 * 3 * 3, 200);
  const std::string rgb_path = dir + "/render.png";
  REQUIRE(octofuse::host::write_png_rgb8(rgb_path.c_str(), rgb.data(), 4, 3, 0, &error).ok());
  bytes = read_bytes(rgb_path);
  REQUIRE(bytes.size() > 33);
  CHECK(be32(&bytes[16]) == 4);
  CHECK(be32(&bytes[20]) == 3);
  CHECK(bytes[24] == 8);
  CHECK(bytes[25] == 2);  // truecolour
}

TEST_CASE("PNG writer reports empty images and unwritable paths", "[host][png]") {
  octofuse::ErrorText error;
  CHECK(octofuse::host::write_png_rgb8("/nonexistent-dir/x.png", nullptr, 0, 0, 0, &error) ==
        octofuse::StatusCode::invalid_argument);
  std::vector<std::uint8_t> rgb(3, 0);
  CHECK(octofuse::host::write_png_rgb8("/nonexistent-dir/x.png", rgb.data(), 1, 1, 0, &error) ==
        octofuse::StatusCode::unavailable);
  CHECK(std::string(error.c_str()).find("/nonexistent-dir/x.png") != std::string::npos);
}
