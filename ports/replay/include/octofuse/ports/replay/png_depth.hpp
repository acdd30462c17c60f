#pragma once
// Decoding 16-bit grayscale depth PNGs (TUM, 7-Scenes, ICL-NUIM) from memory with libpng. All of
// libpng's and zlib's memory comes from a scratch area carved at reserve() (a bump allocator
// reset per image), so decoding a frame never touches the heap. libpng reports errors through
// setjmp/longjmp inside the decoder; callers see a Status and a message.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse::replay {

class PngDepthDecoder {
 public:
  // Enough for libpng's structures, zlib's 32 KiB window and row buffers up to 8192 px wide.
  static constexpr std::size_t kScratchBytes = 256 * 1024;

  template <typename Arena>
  Status reserve(Arena& arena) {
    Result<void*> scratch = arena.allocate_bytes(kScratchBytes, 16);
    if (!scratch.ok()) return scratch.status();
    scratch_ = static_cast<std::uint8_t*>(scratch.value());
    return ok_status();
  }

  // Reads only the header: image size. data_loss for anything that is not a PNG; invalid_argument
  // for a PNG that is not 16-bit grayscale.
  Status read_size(const std::uint8_t* png, std::size_t size, int* width, int* height,
                   const char* label, ErrorText* error);

  // Decodes into `pixels` (row-major, no padding, host byte order). resource_exhausted when the
  // image has more than max_width x max_height pixels; invalid_argument when it is not 16-bit
  // grayscale; data_loss when it is truncated or corrupt. The message starts with `label`.
  Status decode(const std::uint8_t* png, std::size_t size, std::uint16_t* pixels, int max_width,
                int max_height, int* width, int* height, const char* label, ErrorText* error);

 private:
  Status run(const std::uint8_t* png, std::size_t size, std::uint16_t* pixels, int max_width,
             int max_height, int* width, int* height, const char* label, ErrorText* error);

  std::uint8_t* scratch_ = nullptr;
};

}  // namespace octofuse::replay
