// PNG writing through libpng (chosen by ports/host/CMakeLists.txt when libpng is found).
#include <png.h>

#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>

#include "octofuse/ports/host/atomic_file.hpp"
#include "octofuse/ports/host/png_writer.hpp"

namespace octofuse::host {
namespace {

struct WriteJob {
  const char* path;
  const std::uint8_t* pixels;  // first row
  std::ptrdiff_t stride_bytes;
  int width;
  int height;
  int bit_depth;
  int color_type;
  bool swap16;  // 16-bit samples are stored big-endian in PNG
};

void on_png_error(png_structp png, png_const_charp /*message*/) {
  std::longjmp(png_jmpbuf(png), 1);
}
void on_png_warning(png_structp /*png*/, png_const_charp /*message*/) {}

// Plain C-style body: nothing with a destructor lives across the setjmp.
bool write_with_libpng(std::FILE* file, const WriteJob& job) {
  png_structp png =
      png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, on_png_error, on_png_warning);
  if (png == nullptr) return false;
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_write_struct(&png, nullptr);
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  png_init_io(png, file);
  png_set_IHDR(png, info, static_cast<png_uint_32>(job.width), static_cast<png_uint_32>(job.height),
               job.bit_depth, job.color_type, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  if (job.swap16) png_set_swap(png);
  for (int y = 0; y < job.height; ++y) {
    png_write_row(png, const_cast<png_bytep>(job.pixels + y * job.stride_bytes));
  }
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return true;
}

bool little_endian_host() {
  const std::uint16_t probe = 1;
  std::uint8_t first;
  std::memcpy(&first, &probe, 1);
  return first == 1;
}

Status write_job(const WriteJob& job, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  if (job.pixels == nullptr || job.width <= 0 || job.height <= 0) {
    err.set("%s: empty image", job.path);
    return StatusCode::invalid_argument;
  }
  // Through a temporary renamed into place: a crash leaves the previous image or this one, whole.
  AtomicFile out;
  const Status opened = out.open(job.path);
  if (!opened.ok()) {
    err.set("%s", out.last_error());
    return opened;
  }
  if (!write_with_libpng(out.file(), job)) {
    err.set("%s: PNG write failed", job.path);
    return StatusCode::data_loss;  // `out` removes the temporary
  }
  const Status committed = out.commit();
  if (!committed.ok()) err.set("%s", out.last_error());
  return committed;
}

}  // namespace

Status write_png_rgb8(const char* path, const std::uint8_t* rgb, int width, int height,
                      std::ptrdiff_t stride_bytes, ErrorText* error) {
  const WriteJob job{
      path, rgb, stride_bytes != 0 ? stride_bytes : 3 * width, width, height, 8, PNG_COLOR_TYPE_RGB,
      false};
  return write_job(job, error);
}

Status write_png_gray16(const char* path, ImageView<const std::uint16_t> image, ErrorText* error) {
  const WriteJob job{path,
                     reinterpret_cast<const std::uint8_t*>(image.data),
                     image.stride * 2,
                     image.width,
                     image.height,
                     16,
                     PNG_COLOR_TYPE_GRAY,
                     little_endian_host()};
  return write_job(job, error);
}

bool png_writer_compresses() {
  return true;
}

}  // namespace octofuse::host
