// PNG writing without libpng (chosen by ports/host/CMakeLists.txt when libpng is absent): the
// zlib stream uses stored (uncompressed) deflate blocks, which every PNG reader accepts.
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>

#include "octofuse/ports/host/atomic_file.hpp"
#include "octofuse/ports/host/host_buffer.hpp"
#include "octofuse/ports/host/png_writer.hpp"

namespace octofuse::host {
namespace {

std::uint32_t crc32_update(std::uint32_t crc, const std::uint8_t* data, std::size_t size) {
  static std::uint32_t table[256];
  static bool table_ready = false;
  if (!table_ready) {
    for (std::uint32_t n = 0; n < 256; ++n) {
      std::uint32_t c = n;
      for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      table[n] = c;
    }
    table_ready = true;
  }
  for (std::size_t i = 0; i < size; ++i) crc = table[(crc ^ data[i]) & 0xFFu] ^ (crc >> 8);
  return crc;
}

using Bytes = HostBuffer<std::uint8_t>;

void append(Bytes* out, const std::uint8_t* data, std::size_t size) {
  for (std::size_t i = 0; i < size; ++i) out->push_back(data[i]);
}

void put_be32(HostBuffer<std::uint8_t>* out, std::uint32_t v) {
  out->push_back(static_cast<std::uint8_t>(v >> 24));
  out->push_back(static_cast<std::uint8_t>(v >> 16));
  out->push_back(static_cast<std::uint8_t>(v >> 8));
  out->push_back(static_cast<std::uint8_t>(v));
}

void put_chunk(Bytes* out, const char type[4], const Bytes& data) {
  put_be32(out, static_cast<std::uint32_t>(data.size()));
  const std::size_t type_at = out->size();
  append(out, reinterpret_cast<const std::uint8_t*>(type), 4);
  append(out, data.data(), data.size());
  const std::uint32_t crc =
      crc32_update(0xFFFFFFFFu, out->data() + type_at, 4 + data.size()) ^ 0xFFFFFFFFu;
  put_be32(out, crc);
}

// `row_bytes` per row, each row already prefixed by its filter byte (0).
Status write_stored_png(const char* path, int width, int height, int bit_depth, int color_type,
                        const HostBuffer<std::uint8_t>& raw, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  static constexpr std::uint8_t kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  Bytes file_bytes;
  append(&file_bytes, kSignature, 8);
  Bytes ihdr;
  put_be32(&ihdr, static_cast<std::uint32_t>(width));
  put_be32(&ihdr, static_cast<std::uint32_t>(height));
  ihdr.push_back(static_cast<std::uint8_t>(bit_depth));
  ihdr.push_back(static_cast<std::uint8_t>(color_type));
  ihdr.push_back(0);
  ihdr.push_back(0);
  ihdr.push_back(0);
  put_chunk(&file_bytes, "IHDR", ihdr);

  Bytes zlib;
  zlib.push_back(0x78);
  zlib.push_back(0x01);
  std::uint32_t adler_a = 1, adler_b = 0;
  for (std::uint8_t byte : raw) {
    adler_a = (adler_a + byte) % 65521u;
    adler_b = (adler_b + adler_a) % 65521u;
  }
  std::size_t offset = 0;
  do {
    const std::size_t block = std::min<std::size_t>(65535, raw.size() - offset);
    const bool last = offset + block == raw.size();
    zlib.push_back(last ? 1 : 0);
    zlib.push_back(static_cast<std::uint8_t>(block));
    zlib.push_back(static_cast<std::uint8_t>(block >> 8));
    zlib.push_back(static_cast<std::uint8_t>(~block));
    zlib.push_back(static_cast<std::uint8_t>(~block >> 8));
    append(&zlib, raw.data() + offset, block);
    offset += block;
  } while (offset < raw.size());
  put_be32(&zlib, (adler_b << 16) | adler_a);
  put_chunk(&file_bytes, "IDAT", zlib);
  put_chunk(&file_bytes, "IEND", Bytes());

  // Through a temporary renamed into place: a crash leaves the previous image or this one, whole.
  AtomicFile out;
  Status status = out.open(path);
  if (status.ok()) status = out.write(file_bytes.data(), file_bytes.size());
  if (status.ok()) status = out.commit();
  if (!status.ok()) err.set("%s", out.last_error());
  return status;
}

}  // namespace

Status write_png_rgb8(const char* path, const std::uint8_t* rgb, int width, int height,
                      std::ptrdiff_t stride_bytes, ErrorText* error) {
  if (rgb == nullptr || width <= 0 || height <= 0) {
    if (error != nullptr) error->set("%s: empty image", path);
    return StatusCode::invalid_argument;
  }
  if (stride_bytes == 0) stride_bytes = 3 * width;
  HostBuffer<std::uint8_t> raw;
  raw.reserve(static_cast<std::size_t>(height) * (3 * static_cast<std::size_t>(width) + 1));
  for (int y = 0; y < height; ++y) {
    raw.push_back(0);
    const std::uint8_t* row = rgb + y * stride_bytes;
    append(&raw, row, 3 * static_cast<std::size_t>(width));
  }
  return write_stored_png(path, width, height, 8, 2, raw, error);
}

Status write_png_gray16(const char* path, ImageView<const std::uint16_t> image, ErrorText* error) {
  if (image.empty()) {
    if (error != nullptr) error->set("%s: empty image", path);
    return StatusCode::invalid_argument;
  }
  HostBuffer<std::uint8_t> raw;
  raw.reserve(static_cast<std::size_t>(image.height) *
              (2 * static_cast<std::size_t>(image.width) + 1));
  for (int y = 0; y < image.height; ++y) {
    raw.push_back(0);
    for (int x = 0; x < image.width; ++x) {
      const std::uint16_t v = image(x, y);
      raw.push_back(static_cast<std::uint8_t>(v >> 8));
      raw.push_back(static_cast<std::uint8_t>(v));
    }
  }
  return write_stored_png(path, image.width, image.height, 16, 0, raw, error);
}

bool png_writer_compresses() {
  return false;
}

}  // namespace octofuse::host
