#pragma once
// RVL, the lossless depth codec of compressed_depth_image_transport (A. D. Wilson, "Fast
// lossless depth image compression", ISS 2017): runs of zeros and zig-zag deltas of the
// non-zero pixels, as variable-length 3-bit nibbles packed in little-endian 32-bit words.

#include <cstddef>
#include <cstdint>

namespace octofuse::replay {

// Decodes `pixel_count` pixels from `data`; false when the stream ends early or its runs
// overrun the image. Reads only inside `data`, writes only inside `pixels`.
bool decode_rvl(const std::uint8_t* data, std::size_t size, std::uint16_t* pixels,
                std::size_t pixel_count);

}  // namespace octofuse::replay
