#include "octofuse/ports/replay/rvl.hpp"

namespace octofuse::replay {
namespace {

struct NibbleReader {
  const std::uint8_t* data;
  std::size_t size;
  std::size_t pos = 0;
  std::uint32_t word = 0;
  int nibbles_left = 0;
  bool ok = true;

  // One variable-length value: 3 bits a nibble, most significant nibble of a word first, the
  // nibble's top bit saying another follows. At most 11 nibbles make 32 bits.
  std::uint32_t value() {
    std::uint32_t v = 0;
    for (int shift = 0; shift < 33; shift += 3) {
      if (nibbles_left == 0) {
        if (size - pos < 4) {
          ok = false;
          return 0;
        }
        word = std::uint32_t{data[pos]} | (std::uint32_t{data[pos + 1]} << 8) |
               (std::uint32_t{data[pos + 2]} << 16) | (std::uint32_t{data[pos + 3]} << 24);
        pos += 4;
        nibbles_left = 8;
      }
      const std::uint32_t nibble = word >> 28;
      word <<= 4;
      --nibbles_left;
      v |= (nibble & 7u) << shift;
      if ((nibble & 8u) == 0) return v;
    }
    ok = false;  // longer than any 32-bit value
    return 0;
  }
};

}  // namespace

bool decode_rvl(const std::uint8_t* data, std::size_t size, std::uint16_t* pixels,
                std::size_t pixel_count) {
  NibbleReader in{data, size};
  std::size_t out = 0;
  std::uint16_t previous = 0;
  while (out < pixel_count) {
    const std::uint32_t zeros = in.value();
    if (!in.ok || zeros > pixel_count - out) return false;
    for (std::uint32_t i = 0; i < zeros; ++i) pixels[out++] = 0;
    if (out == pixel_count) break;
    const std::uint32_t nonzeros = in.value();
    if (!in.ok || nonzeros > pixel_count - out) return false;
    for (std::uint32_t i = 0; i < nonzeros; ++i) {
      const std::uint32_t positive = in.value();
      if (!in.ok) return false;
      // Zig-zag: even values are non-negative deltas, odd ones negative.
      // Unsigned arithmetic: 16-bit wrap-around, as the encoder's, and no signed overflow on
      // hostile deltas.
      const std::uint32_t delta = (positive >> 1) ^ (0u - (positive & 1u));
      previous = static_cast<std::uint16_t>(previous + delta);
      pixels[out++] = previous;
    }
    if (zeros == 0 && nonzeros == 0) return false;  // no progress: a corrupt stream
  }
  return true;
}

}  // namespace octofuse::replay
