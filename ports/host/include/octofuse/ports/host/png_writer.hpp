#pragma once
// PNG output for images the host programs save (render.png, depth dumps). Built with libpng when
// CMake finds it, otherwise with a small writer that stores the pixels uncompressed (valid PNG,
// larger files); the choice is made in ports/host/CMakeLists.txt.

#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/image_view.hpp"

namespace octofuse::host {

// 8-bit RGB: `rgb` holds 3 bytes per pixel, `stride_bytes` between row starts (0: 3 * width).
// invalid_argument: empty image; unavailable: cannot create; data_loss: write error.
Status write_png_rgb8(const char* path, const std::uint8_t* rgb, int width, int height,
                      std::ptrdiff_t stride_bytes, ErrorText* error);

// 16-bit grayscale (depth images: TUM 5000 units/m, 7-Scenes millimetres).
Status write_png_gray16(const char* path, ImageView<const std::uint16_t> image, ErrorText* error);

// True when this build writes compressed PNG through libpng.
bool png_writer_compresses();

}  // namespace octofuse::host
