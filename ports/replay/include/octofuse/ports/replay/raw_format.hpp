#pragma once
// SLAMBench .raw recordings: frames back to back, each
//   uint32 width, uint32 height, width*height uint16 depth (millimetres),
//   uint32 width, uint32 height, width*height*3 uint8 RGB,
// all little-endian. No timestamps (frames are taken at 30 Hz) and no intrinsics in the file.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse::replay {

// Larger RGB images than this are taken as corruption, not as a camera.
inline constexpr std::uint32_t kRawMaxRgbSide = 8192;

struct RawFrameLayout {
  std::uint32_t depth_width = 0;
  std::uint32_t depth_height = 0;
  std::uint32_t rgb_width = 0;
  std::uint32_t rgb_height = 0;
  std::uint64_t depth_offset = 0;  // file offset of the first depth pixel
  std::uint64_t next_offset = 0;   // file offset of the following frame
};

// Decodes a little-endian uint32.
inline std::uint32_t load_le32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

// Works out the layout of the frame starting at `offset` from its two 8-byte headers
// (`depth_header` at offset, `rgb_header` at the offset after the depth pixels, which the caller
// reads after a first call with rgb_header null returns ok). Checks: sizes non-zero, depth at
// most max_width x max_height (resource_exhausted otherwise), RGB at most kRawMaxRgbSide a side
// (data_loss), and the frame fits in `file_size` (data_loss "short frame"). `label` names the
// file in messages.
Status parse_raw_frame_header(const std::uint8_t depth_header[8], const std::uint8_t* rgb_header,
                              std::uint64_t offset, std::uint64_t file_size, int max_width,
                              int max_height, RawFrameLayout* layout, const char* label,
                              ErrorText* error);

// Converts `count` little-endian uint16 in place to host order.
void little_endian_to_host(std::uint16_t* pixels, std::size_t count);

}  // namespace octofuse::replay
