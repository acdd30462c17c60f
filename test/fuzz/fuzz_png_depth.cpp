// The PNG frame path: arbitrary bytes into the depth PNG decoder must give ok or a Status,
// never a crash, a hang or a write past the frame buffer.
#include <cstddef>
#include <cstdint>

#include "octofuse/ports/replay/png_depth.hpp"

namespace {

constexpr int kMaxSide = 256;
alignas(64) std::uint8_t g_scratch[octofuse::replay::PngDepthDecoder::kScratchBytes];
std::uint16_t g_pixels[kMaxSide * kMaxSide];

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static octofuse::replay::PngDepthDecoder* decoder = [] {
    static octofuse::replay::PngDepthDecoder instance;
    octofuse::LinearArena arena(g_scratch, sizeof(g_scratch));
    instance.reserve(arena).ignore();
    return &instance;
  }();
  octofuse::ErrorText error;
  int width = 0, height = 0;
  const octofuse::Status status = decoder->decode(data, size, g_pixels, kMaxSide, kMaxSide, &width,
                                                  &height, "fuzz.png", &error);
  if (status.ok() && (width <= 0 || height <= 0 || width > kMaxSide || height > kMaxSide)) {
    __builtin_trap();  // a success must describe an image that fits
  }
  if (!status.ok() && error.empty()) __builtin_trap();  // every failure explains itself
  return 0;
}
