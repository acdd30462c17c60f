// Pixel layouts of 16-bit and packed mono raw streams, and the checks on LibcameraOptions. No
// libcamera here, so this part is testable without a camera.

#include <cmath>
#include <cstring>

#include "octofuse/ports/libcamera/libcamera_source.hpp"

namespace octofuse::ports {

const char* libcamera_layout_name(LibcameraPixelLayout layout) {
  switch (layout) {
    case LibcameraPixelLayout::r16:
      return "R16";
    case LibcameraPixelLayout::r12:
      return "R12";
    case LibcameraPixelLayout::r10:
      return "R10";
    case LibcameraPixelLayout::r12_csi2p:
      return "R12_CSI2P";
    case LibcameraPixelLayout::r10_csi2p:
      return "R10_CSI2P";
  }
  return "unknown";
}

std::size_t libcamera_row_bytes(LibcameraPixelLayout layout, int width) {
  if (width <= 0) return 0;
  const auto w = static_cast<std::size_t>(width);
  switch (layout) {
    case LibcameraPixelLayout::r16:
    case LibcameraPixelLayout::r12:
    case LibcameraPixelLayout::r10:
      return 2 * w;
    case LibcameraPixelLayout::r12_csi2p:
      return (w * 3 + 1) / 2;  // 2 pixels in 3 bytes
    case LibcameraPixelLayout::r10_csi2p:
      return (w * 5 + 3) / 4;  // 4 pixels in 5 bytes
  }
  return 0;
}

Status convert_libcamera_pixels(LibcameraPixelLayout layout, const std::uint8_t* src,
                                std::size_t stride, std::size_t src_bytes, int width, int height,
                                std::uint16_t* dst) {
  const std::size_t row_bytes = libcamera_row_bytes(layout, width);
  if (width <= 0 || height <= 0 || src == nullptr || dst == nullptr || stride < row_bytes) {
    return StatusCode::invalid_argument;
  }
  // The last row needs no padding after its pixels.
  if (src_bytes < stride * static_cast<std::size_t>(height - 1) + row_bytes) {
    return StatusCode::data_loss;
  }
  const auto w = static_cast<std::size_t>(width);
  for (int y = 0; y < height; ++y) {
    const std::uint8_t* in = src + static_cast<std::size_t>(y) * stride;
    std::uint16_t* out = dst + static_cast<std::size_t>(y) * w;
    switch (layout) {
      case LibcameraPixelLayout::r16:
      case LibcameraPixelLayout::r12:
      case LibcameraPixelLayout::r10: {
        const std::uint16_t mask = layout == LibcameraPixelLayout::r16   ? 0xffffu
                                   : layout == LibcameraPixelLayout::r12 ? 0x0fffu
                                                                         : 0x03ffu;
        // Byte by byte: little-endian on any host, and no unaligned 16-bit loads.
        for (std::size_t x = 0; x < w; ++x) {
          const auto value = static_cast<std::uint16_t>(in[2 * x] | (in[2 * x + 1] << 8));
          out[x] = static_cast<std::uint16_t>(value & mask);
        }
        break;
      }
      case LibcameraPixelLayout::r12_csi2p: {
        // Bytes 0, 1: bits 11..4 of pixels 0, 1; byte 2: their bits 3..0 (pixel 0 low nibble).
        for (std::size_t x = 0; x < w; ++x) {
          const std::uint8_t* group = in + (x / 2) * 3;
          const unsigned low = (group[2] >> ((x % 2) * 4)) & 0x0fu;
          out[x] = static_cast<std::uint16_t>((group[x % 2] << 4) | low);
        }
        break;
      }
      case LibcameraPixelLayout::r10_csi2p: {
        // Bytes 0..3: bits 9..2 of pixels 0..3; byte 4: their bits 1..0, pixel 0 lowest.
        for (std::size_t x = 0; x < w; ++x) {
          const std::uint8_t* group = in + (x / 4) * 5;
          const unsigned low = (group[4] >> ((x % 4) * 2)) & 0x03u;
          out[x] = static_cast<std::uint16_t>((group[x % 4] << 2) | low);
        }
        break;
      }
    }
  }
  return ok_status();
}

Status validate_libcamera_options(const LibcameraOptions& o, ErrorText& why) {
  if (o.camera_id != nullptr && std::strlen(o.camera_id) > LibcameraSource::kMaxIdLength) {
    why.set("libcamera: camera id longer than %zu characters", LibcameraSource::kMaxIdLength);
    return StatusCode::invalid_argument;
  }
  if (o.width < 0 || o.height < 0 || (o.width == 0) != (o.height == 0) || o.width > 16384 ||
      o.height > 16384) {
    why.set("libcamera: size %dx%d: give both width and height (up to 16384) or neither", o.width,
            o.height);
    return StatusCode::invalid_argument;
  }
  if (!(o.metres_per_unit > 0.0f) || !std::isfinite(o.metres_per_unit)) {
    why.set("libcamera: metres_per_unit must be a positive number");
    return StatusCode::invalid_argument;
  }
  if (o.buffer_count < 2 || o.buffer_count > LibcameraSource::kMaxBuffers || o.ring_size < 1 ||
      o.ring_size > LibcameraSource::kMaxRing || o.frame_timeout_ms <= 0) {
    why.set("libcamera: buffer_count 2..%d, ring_size 1..%d and a positive timeout are needed",
            LibcameraSource::kMaxBuffers, LibcameraSource::kMaxRing);
    return StatusCode::invalid_argument;
  }
  if (o.intrinsics.valid()) {
    if (o.width > 0 && (o.intrinsics.width != o.width || o.intrinsics.height != o.height)) {
      why.set("libcamera: intrinsics are for %dx%d, the stream is %dx%d", o.intrinsics.width,
              o.intrinsics.height, o.width, o.height);
      return StatusCode::invalid_argument;
    }
  } else if (!(o.horizontal_fov_deg > 0.0f && o.horizontal_fov_deg < 180.0f)) {
    why.set("libcamera: horizontal_fov_deg must be in (0, 180) without explicit intrinsics");
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

}  // namespace octofuse::ports
