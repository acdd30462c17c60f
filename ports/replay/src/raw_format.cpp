#include "octofuse/ports/replay/raw_format.hpp"

#include <cstring>

namespace octofuse::replay {

Status parse_raw_frame_header(const std::uint8_t depth_header[8], const std::uint8_t* rgb_header,
                              std::uint64_t offset, std::uint64_t file_size, int max_width,
                              int max_height, RawFrameLayout* layout, const char* label,
                              ErrorText* error) {
  const std::uint32_t w = load_le32(depth_header);
  const std::uint32_t h = load_le32(depth_header + 4);
  if (w == 0 || h == 0) {
    error->set("%s: frame at byte %llu has an empty depth image (%ux%u)", label,
               static_cast<unsigned long long>(offset), w, h);
    return StatusCode::data_loss;
  }
  if (w > static_cast<std::uint32_t>(max_width) || h > static_cast<std::uint32_t>(max_height)) {
    error->set("%s: frame at byte %llu has depth %ux%u, more than the maximum %dx%d", label,
               static_cast<unsigned long long>(offset), w, h, max_width, max_height);
    return StatusCode::resource_exhausted;
  }
  layout->depth_width = w;
  layout->depth_height = h;
  layout->depth_offset = offset + 8;
  const std::uint64_t rgb_header_offset = layout->depth_offset + 2ull * w * h;
  if (rgb_header_offset + 8 > file_size) {
    error->set("%s: short frame at byte %llu: depth %ux%u needs %llu bytes, the file ends at %llu",
               label, static_cast<unsigned long long>(offset), w, h,
               static_cast<unsigned long long>(rgb_header_offset + 8 - offset),
               static_cast<unsigned long long>(file_size));
    return StatusCode::data_loss;
  }
  if (rgb_header == nullptr) return ok_status();
  const std::uint32_t rgb_w = load_le32(rgb_header);
  const std::uint32_t rgb_h = load_le32(rgb_header + 4);
  if (rgb_w > kRawMaxRgbSide || rgb_h > kRawMaxRgbSide) {
    error->set("%s: frame at byte %llu has an absurd RGB size %ux%u", label,
               static_cast<unsigned long long>(offset), rgb_w, rgb_h);
    return StatusCode::data_loss;
  }
  layout->rgb_width = rgb_w;
  layout->rgb_height = rgb_h;
  layout->next_offset = rgb_header_offset + 8 + 3ull * rgb_w * rgb_h;
  if (layout->next_offset > file_size) {
    error->set("%s: short frame at byte %llu: RGB %ux%u runs past the end of the file (%llu bytes)",
               label, static_cast<unsigned long long>(offset), rgb_w, rgb_h,
               static_cast<unsigned long long>(file_size));
    return StatusCode::data_loss;
  }
  return ok_status();
}

void little_endian_to_host(std::uint16_t* pixels, std::size_t count) {
  const std::uint16_t probe = 1;
  std::uint8_t first;
  std::memcpy(&first, &probe, 1);
  if (first == 1) return;  // already host order
  for (std::size_t i = 0; i < count; ++i) {
    std::uint8_t bytes[2];
    std::memcpy(bytes, &pixels[i], 2);
    pixels[i] = static_cast<std::uint16_t>(bytes[0] | (bytes[1] << 8));
  }
}

}  // namespace octofuse::replay
