// The RVL depth codec (compressedDepth rvl) on arbitrary bytes: a decode succeeds or says no,
// never reading past the input or writing past the image.
#include <cstddef>
#include <cstdint>

#include "octofuse/ports/replay/rvl.hpp"

namespace {
std::uint16_t g_pixels[64 * 48];
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  // The first byte picks an image size, so short streams can fill whole images.
  const std::size_t pixels = 1 + static_cast<std::size_t>(data[0]) * 12;
  (void)octofuse::replay::decode_rvl(data + 1, size - 1, g_pixels, pixels);
  return 0;
}
