#include "octofuse/ports/replay/png_depth.hpp"

#include <png.h>

#include <csetjmp>
#include <cstdio>
#include <cstring>

namespace octofuse::replay {
namespace {

// Everything libpng's callbacks need, reachable from the png_struct.
struct DecodeJob {
  const std::uint8_t* png;
  std::size_t size;
  std::size_t read_offset;
  std::uint8_t* scratch;
  std::size_t scratch_used;
  bool scratch_exhausted;
  char message[128];
};

constexpr std::size_t kScratchAlignment = 16;

png_voidp bump_malloc(png_structp png, png_alloc_size_t bytes) {
  DecodeJob* job = static_cast<DecodeJob*>(png_get_mem_ptr(png));
  const std::size_t start = align_up(job->scratch_used, kScratchAlignment);
  if (start > PngDepthDecoder::kScratchBytes || bytes > PngDepthDecoder::kScratchBytes - start) {
    job->scratch_exhausted = true;
    return nullptr;
  }
  job->scratch_used = start + bytes;
  return job->scratch + start;
}

// The scratch area is reset per image; single frees are not needed.
void bump_free(png_structp /*png*/, png_voidp /*memory*/) {}

void on_error(png_structp png, png_const_charp message) {
  DecodeJob* job = static_cast<DecodeJob*>(png_get_error_ptr(png));
  std::snprintf(job->message, sizeof(job->message), "%s", message);
  std::longjmp(png_jmpbuf(png), 1);
}

void on_warning(png_structp /*png*/, png_const_charp /*message*/) {}

void read_from_memory(png_structp png, png_bytep out, png_size_t bytes) {
  DecodeJob* job = static_cast<DecodeJob*>(png_get_io_ptr(png));
  if (bytes > job->size - job->read_offset) {
    png_error(png, "file is truncated");  // does not return
  }
  std::memcpy(out, job->png + job->read_offset, bytes);
  job->read_offset += bytes;
}

bool host_is_little_endian() {
  const std::uint16_t probe = 1;
  std::uint8_t first;
  std::memcpy(&first, &probe, 1);
  return first == 1;
}

enum class Outcome { ok, not_png, bad_format, too_large, corrupt };

struct ImageInfo {
  png_uint_32 width = 0;
  png_uint_32 height = 0;
  int bit_depth = 0;
  int color_type = 0;
};

// The libpng calls. Nothing with a destructor lives in this frame, so longjmp out of libpng back
// to the setjmp here is well defined. `pixels` null: header only.
Outcome decode_with_libpng(DecodeJob* job, std::uint16_t* pixels, int max_width, int max_height,
                           ImageInfo* info_out) {
  if (job->size < 8 || png_sig_cmp(job->png, 0, 8) != 0) return Outcome::not_png;
  png_structp png = png_create_read_struct_2(PNG_LIBPNG_VER_STRING, job, on_error, on_warning, job,
                                             bump_malloc, bump_free);
  if (png == nullptr) {
    std::snprintf(job->message, sizeof(job->message), "decoder could not start");
    return Outcome::corrupt;
  }
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    std::snprintf(job->message, sizeof(job->message), "decoder could not start");
    return Outcome::corrupt;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return Outcome::corrupt;
  }
  png_set_read_fn(png, job, read_from_memory);
  // Ancillary chunks (text, ICC profiles) are not needed and only cost scratch memory.
  png_set_keep_unknown_chunks(png, PNG_HANDLE_CHUNK_NEVER, nullptr, 0);
  png_set_chunk_malloc_max(png, 64 * 1024);
  png_read_info(png, info);
  int interlace = 0;
  png_get_IHDR(png, info, &info_out->width, &info_out->height, &info_out->bit_depth,
               &info_out->color_type, &interlace, nullptr, nullptr);
  Outcome outcome = Outcome::ok;
  if (info_out->bit_depth != 16 || info_out->color_type != PNG_COLOR_TYPE_GRAY) {
    outcome = Outcome::bad_format;
  } else if (info_out->width > static_cast<png_uint_32>(max_width) ||
             info_out->height > static_cast<png_uint_32>(max_height)) {
    outcome = Outcome::too_large;
  }
  if (outcome != Outcome::ok || pixels == nullptr) {
    png_destroy_read_struct(&png, &info, nullptr);
    return outcome;
  }
  if (host_is_little_endian()) png_set_swap(png);
  const int passes = png_set_interlace_handling(png);
  png_read_update_info(png, info);
  const std::size_t width = info_out->width;
  for (int pass = 0; pass < passes; ++pass) {
    for (png_uint_32 y = 0; y < info_out->height; ++y) {
      png_read_row(png, reinterpret_cast<png_bytep>(pixels + y * width), nullptr);
    }
  }
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return Outcome::ok;
}

}  // namespace

Status PngDepthDecoder::run(const std::uint8_t* png, std::size_t size, std::uint16_t* pixels,
                            int max_width, int max_height, int* width, int* height,
                            const char* label, ErrorText* error) {
  OCTOFUSE_CHECK(scratch_ != nullptr);  // reserve() first
  DecodeJob job{png, size, 0, scratch_, 0, false, {}};
  ImageInfo info;
  const Outcome outcome = decode_with_libpng(&job, pixels, max_width, max_height, &info);
  switch (outcome) {
    case Outcome::ok:
      *width = static_cast<int>(info.width);
      *height = static_cast<int>(info.height);
      return ok_status();
    case Outcome::not_png:
      error->set("%s: not a PNG file (%zu bytes, no PNG signature)", label, size);
      return StatusCode::data_loss;
    case Outcome::bad_format:
      error->set("%s: expected a 16-bit grayscale PNG, got bit depth %d colour type %d", label,
                 info.bit_depth, info.color_type);
      return StatusCode::invalid_argument;
    case Outcome::too_large:
      error->set("%s: image is %ux%u, larger than the configured maximum %dx%d", label,
                 static_cast<unsigned>(info.width), static_cast<unsigned>(info.height), max_width,
                 max_height);
      return StatusCode::resource_exhausted;
    case Outcome::corrupt:
      break;
  }
  if (job.scratch_exhausted) {
    error->set("%s: PNG decoder needs more than %zu bytes of scratch memory", label, kScratchBytes);
    return StatusCode::resource_exhausted;
  }
  error->set("%s: corrupt or truncated PNG (%s)", label, job.message);
  return StatusCode::data_loss;
}

Status PngDepthDecoder::read_size(const std::uint8_t* png, std::size_t size, int* width,
                                  int* height, const char* label, ErrorText* error) {
  // Header only: the size limit does not apply yet.
  return run(png, size, nullptr, 1 << 30, 1 << 30, width, height, label, error);
}

Status PngDepthDecoder::decode(const std::uint8_t* png, std::size_t size, std::uint16_t* pixels,
                               int max_width, int max_height, int* width, int* height,
                               const char* label, ErrorText* error) {
  OCTOFUSE_CHECK(pixels != nullptr);
  return run(png, size, pixels, max_width, max_height, width, height, label, error);
}

}  // namespace octofuse::replay
