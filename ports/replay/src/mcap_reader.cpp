#include "octofuse/ports/replay/mcap_reader.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>

#include "little_endian.hpp"
#include "octofuse/core/arena.hpp"

#if defined(OCTOFUSE_REPLAY_HAVE_ZSTD)
#include <zstd.h>
#endif
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
#include <lz4frame.h>
#endif

namespace octofuse::replay {
namespace {

constexpr std::uint8_t kMagic[8] = {0x89, 'M', 'C', 'A', 'P', 0x30, '\r', '\n'};
constexpr std::uint8_t kOpFooter = 0x02;
constexpr std::uint8_t kOpSchema = 0x03;
constexpr std::uint8_t kOpChannel = 0x04;
constexpr std::uint8_t kOpMessage = 0x05;
constexpr std::uint8_t kOpChunk = 0x06;
constexpr std::uint8_t kOpDataEnd = 0x0F;

using detail::le16;
using detail::le32;
using detail::le64;

// Bounds-checked walk over a record's fields.
struct Fields {
  const std::uint8_t* p;
  std::uint64_t size;
  std::uint64_t pos = 0;
  bool ok = true;

  const std::uint8_t* take(std::uint64_t n) {
    if (!ok || n > size - pos) {
      ok = false;
      return nullptr;
    }
    const std::uint8_t* at = p + pos;
    pos += n;
    return at;
  }
  std::uint16_t u16() {
    const std::uint8_t* at = take(2);
    return at ? le16(at) : 0;
  }
  std::uint32_t u32() {
    const std::uint8_t* at = take(4);
    return at ? le32(at) : 0;
  }
  std::uint64_t u64() {
    const std::uint8_t* at = take(8);
    return at ? le64(at) : 0;
  }
  // Copies a string into `out` (capacity bytes, NUL-terminated); false when it does not fit.
  bool string(char* out, std::size_t capacity) {
    const std::uint32_t n = u32();
    const std::uint8_t* at = take(n);
    if (at == nullptr) return false;
    if (out == nullptr) return true;
    if (n >= capacity) {
      ok = false;
      return false;
    }
    std::memcpy(out, at, n);
    out[n] = '\0';
    return true;
  }
};

}  // namespace

McapReader::~McapReader() {
  close();
}

std::size_t McapReader::bytes_required(const McapLimits& limits) {
  ArenaSizer sizer;
  (void)sizer.allocate_bytes(limits.max_record_bytes, 16);
  (void)sizer.allocate_bytes(limits.max_chunk_bytes, 16);
  (void)sizer.allocate_array<McapChannel>(static_cast<std::size_t>(limits.max_channels));
  (void)sizer.allocate_array<Schema>(static_cast<std::size_t>(limits.max_schemas));
  return sizer.bytes_used();
}

Status McapReader::open(const char* path, const McapLimits& limits) {
  close();
  error_.clear();
  warning_.clear();
  if (limits.max_record_bytes < 64 || limits.max_chunk_bytes < 64 || limits.max_channels < 1 ||
      limits.max_schemas < 1 || limits.max_channels > 65536 || limits.max_schemas > 65536) {
    error_.set("mcap: invalid limits");
    return StatusCode::invalid_argument;
  }
  limits_ = limits;
  fd_ = ::open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd_ < 0) {
    error_.set("%s: cannot open: %s", path, std::strerror(errno));
    return StatusCode::unavailable;
  }
  struct stat info;
  if (::fstat(fd_, &info) != 0 || !S_ISREG(info.st_mode)) {
    error_.set("%s: not a regular file", path);
    close();
    return StatusCode::unavailable;
  }
  file_size_ = static_cast<std::uint64_t>(info.st_size);
  std::uint8_t magic[8];
  std::size_t got = 0;
  if (!read_at(0, magic, 8, &got) || std::memcmp(magic, kMagic, 8) != 0) {
    error_.set("%s: not an MCAP file (no magic at the start)", path);
    close();
    return StatusCode::data_loss;
  }
  memory_bytes_ = bytes_required(limits);
  memory_ = std::aligned_alloc(kArenaAlignment, align_up(memory_bytes_, kArenaAlignment));
  if (memory_ == nullptr) {
    error_.set("mcap: cannot reserve %zu bytes", memory_bytes_);
    close();
    return StatusCode::resource_exhausted;
  }
  LinearArena arena(memory_, memory_bytes_);
  record_ = static_cast<std::uint8_t*>(arena.allocate_bytes(limits.max_record_bytes, 16).value());
  chunk_ = static_cast<std::uint8_t*>(arena.allocate_bytes(limits.max_chunk_bytes, 16).value());
  channels_ =
      arena.allocate_array<McapChannel>(static_cast<std::size_t>(limits.max_channels)).value();
  schemas_ = arena.allocate_array<Schema>(static_cast<std::size_t>(limits.max_schemas)).value();
#if defined(OCTOFUSE_REPLAY_HAVE_ZSTD)
  zstd_ = ZSTD_createDCtx();
#endif
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
  if (LZ4F_isError(LZ4F_createDecompressionContext(&lz4_, LZ4F_VERSION))) lz4_ = nullptr;
#endif
  rewind();
  return ok_status();
}

void McapReader::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
#if defined(OCTOFUSE_REPLAY_HAVE_ZSTD)
  ZSTD_freeDCtx(zstd_);
#endif
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
  if (lz4_ != nullptr) LZ4F_freeDecompressionContext(lz4_);
#endif
  zstd_ = nullptr;
  lz4_ = nullptr;
  std::free(memory_);
  memory_ = nullptr;
  memory_bytes_ = 0;
  channel_count_ = schema_count_ = 0;
}

void McapReader::rewind() {
  offset_ = 8;
  done_ = truncated_ = false;
  chunk_records_ = nullptr;
  chunk_size_ = chunk_pos_ = 0;
  chunk_cut_ = false;
  last_log_time_ns_ = 0;
  messages_ = out_of_order_ = 0;
  warning_.clear();
}

bool McapReader::read_at(std::uint64_t offset, std::uint8_t* out, std::size_t size,
                         std::size_t* got) {
  *got = 0;
  while (*got < size) {
    const ssize_t n = ::pread(fd_, out + *got, size - *got, static_cast<off_t>(offset + *got));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    *got += static_cast<std::size_t>(n);
  }
  return true;
}

McapNext McapReader::fail(StatusCode code) {
  (void)code;
  done_ = true;
  return McapNext::error;
}

void McapReader::note_truncation(const char* what) {
  truncated_ = done_ = true;
  warning_.set(
      "bag cut short at byte %llu of %llu (%s); read up to the last whole message (%llu "
      "messages, last log time %.6f s)",
      static_cast<unsigned long long>(offset_), static_cast<unsigned long long>(file_size_), what,
      static_cast<unsigned long long>(messages_), static_cast<double>(last_log_time_ns_) * 1e-9);
}

bool McapReader::handle_record(std::uint8_t opcode, const std::uint8_t* body, std::uint64_t size,
                               McapMessage* message, bool* failed) {
  Fields f{body, size};
  if (opcode == kOpSchema) {
    const std::uint16_t id = f.u16();
    char name[McapChannel::kMaxName];
    f.string(name, sizeof(name));
    if (!f.ok) {
      error_.set("mcap: malformed schema record at byte %llu",
                 static_cast<unsigned long long>(chunk_records_ ? chunk_offset_ : offset_));
      *failed = true;
      return false;
    }
    for (int i = 0; i < schema_count_; ++i) {
      if (schemas_[i].id == id) return false;
    }
    if (schema_count_ >= limits_.max_schemas) {
      error_.set("mcap: more than %d schemas", limits_.max_schemas);
      *failed = true;
      return false;
    }
    Schema& schema = schemas_[schema_count_++];
    schema.id = id;
    std::memcpy(schema.name, name, sizeof(name));
    for (int i = 0; i < channel_count_; ++i) {
      if (channels_[i].schema_id == id) std::memcpy(channels_[i].schema_name, name, sizeof(name));
    }
    return false;
  }
  if (opcode == kOpChannel) {
    McapChannel channel;
    channel.id = f.u16();
    channel.schema_id = f.u16();
    f.string(channel.topic, sizeof(channel.topic));
    f.string(channel.message_encoding, sizeof(channel.message_encoding));
    if (!f.ok) {
      error_.set("mcap: malformed channel record (or a topic over %zu bytes)",
                 McapChannel::kMaxName - 1);
      *failed = true;
      return false;
    }
    for (int i = 0; i < channel_count_; ++i) {
      if (channels_[i].id == channel.id) return false;
    }
    if (channel_count_ >= limits_.max_channels) {
      error_.set("mcap: more than %d channels", limits_.max_channels);
      *failed = true;
      return false;
    }
    for (int i = 0; i < schema_count_; ++i) {
      if (schemas_[i].id == channel.schema_id) {
        std::memcpy(channel.schema_name, schemas_[i].name, sizeof(channel.schema_name));
      }
    }
    channels_[channel_count_++] = channel;
    return false;
  }
  if (opcode == kOpMessage) {
    const std::uint16_t channel_id = f.u16();
    message->sequence = f.u32();
    message->log_time_ns = f.u64();
    message->publish_time_ns = f.u64();
    if (!f.ok) {
      error_.set("mcap: malformed message record");
      *failed = true;
      return false;
    }
    message->channel = nullptr;
    for (int i = 0; i < channel_count_; ++i) {
      if (channels_[i].id == channel_id) message->channel = &channels_[i];
    }
    if (message->channel == nullptr) {
      error_.set("mcap: message on channel %u, which no channel record declared",
                 unsigned{channel_id});
      *failed = true;
      return false;
    }
    message->data = body + f.pos;
    message->size = static_cast<std::size_t>(size - f.pos);
    if (messages_ > 0 && message->log_time_ns < last_log_time_ns_) ++out_of_order_;
    last_log_time_ns_ = message->log_time_ns;
    ++messages_;
    return true;
  }
  return false;  // indexes, attachments, metadata, statistics: not needed to replay
}

bool McapReader::load_chunk(const std::uint8_t* body, std::size_t size, bool complete) {
  Fields f{body, size};
  (void)f.u64();  // message start time
  (void)f.u64();  // message end time
  const std::uint64_t uncompressed_size = f.u64();
  const std::uint32_t crc = f.u32();
  char compression[16];
  f.string(compression, sizeof(compression));
  const std::uint64_t records_size = f.u64();
  if (!f.ok) {
    if (!complete) {
      note_truncation("inside a chunk's header");
      return true;
    }
    error_.set("mcap: malformed chunk at byte %llu", static_cast<unsigned long long>(offset_));
    return false;
  }
  const std::uint8_t* records = body + f.pos;
  std::size_t available = static_cast<std::size_t>(size - f.pos);
  if (available > records_size) available = static_cast<std::size_t>(records_size);
  if (complete && available < records_size) {
    error_.set("mcap: chunk at byte %llu: its records run past the record's end",
               static_cast<unsigned long long>(offset_));
    return false;
  }
  chunk_offset_ = offset_;
  chunk_pos_ = 0;
  chunk_cut_ = !complete;
  if (compression[0] == '\0') {
    chunk_records_ = records;
    chunk_size_ = available;
  } else {
    if (uncompressed_size > limits_.max_chunk_bytes) {
      error_.set(
          "mcap: chunk at byte %llu holds %llu bytes, over the %zu-byte chunk buffer (raise it "
          "with ?buffer=MB)",
          static_cast<unsigned long long>(offset_),
          static_cast<unsigned long long>(uncompressed_size), limits_.max_chunk_bytes);
      return false;
    }
    std::size_t out = 0;
    bool good = false;
    if (std::strcmp(compression, "zstd") == 0) {
#if defined(OCTOFUSE_REPLAY_HAVE_ZSTD)
      if (zstd_ != nullptr) {
        ZSTD_DCtx_reset(zstd_, ZSTD_reset_session_only);
        ZSTD_inBuffer in{records, available, 0};
        ZSTD_outBuffer dst{chunk_, static_cast<std::size_t>(uncompressed_size), 0};
        good = true;
        while (in.pos < in.size && dst.pos < dst.size) {
          const std::size_t rc = ZSTD_decompressStream(zstd_, &dst, &in);
          if (ZSTD_isError(rc)) {
            good = false;
            break;
          }
          if (rc == 0) break;
        }
        out = dst.pos;
      }
#else
      error_.set("mcap: zstd chunks are not supported in this build (no libzstd)");
      return false;
#endif
    } else if (std::strcmp(compression, "lz4") == 0) {
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
      if (lz4_ != nullptr) {
        LZ4F_resetDecompressionContext(lz4_);
        std::size_t in_pos = 0;
        good = true;
        while (in_pos < available && out < uncompressed_size) {
          std::size_t dst_size = static_cast<std::size_t>(uncompressed_size) - out;
          std::size_t src_size = available - in_pos;
          const std::size_t rc =
              LZ4F_decompress(lz4_, chunk_ + out, &dst_size, records + in_pos, &src_size, nullptr);
          if (LZ4F_isError(rc)) {
            good = false;
            break;
          }
          out += dst_size;
          in_pos += src_size;
          if (rc == 0 || (dst_size == 0 && src_size == 0)) break;
        }
      }
#else
      error_.set("mcap: lz4 chunks are not supported in this build (no liblz4)");
      return false;
#endif
    } else {
      error_.set("mcap: chunk at byte %llu: unknown compression '%s'",
                 static_cast<unsigned long long>(offset_), compression);
      return false;
    }
    if (complete && (!good || out != uncompressed_size)) {
      error_.set("mcap: chunk at byte %llu: corrupt %s data",
                 static_cast<unsigned long long>(offset_), compression);
      return false;
    }
    chunk_records_ = chunk_;
    chunk_size_ = out;
  }
  if (complete && crc != 0 && chunk_size_ == uncompressed_size) {
    const uLong actual = crc32(0L, chunk_records_, static_cast<uInt>(0));
    uLong sum = actual;
    // zlib takes uInt lengths: feed big chunks in pieces.
    std::size_t done = 0;
    while (done < chunk_size_) {
      const std::size_t piece = chunk_size_ - done > (1u << 30) ? (1u << 30) : chunk_size_ - done;
      sum = crc32(sum, chunk_records_ + done, static_cast<uInt>(piece));
      done += piece;
    }
    if (sum != crc) {
      error_.set("mcap: chunk at byte %llu: CRC mismatch (stored %08x, data %08lx)",
                 static_cast<unsigned long long>(offset_), crc, static_cast<unsigned long>(sum));
      chunk_records_ = nullptr;
      return false;
    }
  }
  return true;
}

McapNext McapReader::next(McapMessage* message) {
  if (fd_ < 0) {
    error_.set("mcap: next() before a successful open()");
    return McapNext::error;
  }
  for (;;) {
    while (chunk_records_ != nullptr) {
      const std::size_t left = chunk_size_ - chunk_pos_;
      if (left == 0) {
        chunk_records_ = nullptr;
        if (chunk_cut_) {
          offset_ = chunk_offset_;
          note_truncation("inside the chunk record");
          return McapNext::truncated;
        }
        break;
      }
      const std::uint8_t* at = chunk_records_ + chunk_pos_;
      if (left < 9 || le64(at + 1) > left - 9) {
        chunk_records_ = nullptr;
        if (chunk_cut_) {
          offset_ = chunk_offset_;
          note_truncation("inside the chunk record");
          return McapNext::truncated;
        }
        error_.set("mcap: chunk at byte %llu: a record runs past the chunk's end",
                   static_cast<unsigned long long>(chunk_offset_));
        return fail(StatusCode::data_loss);
      }
      const std::uint64_t size = le64(at + 1);
      chunk_pos_ += 9 + static_cast<std::size_t>(size);
      bool failed = false;
      if (handle_record(at[0], at + 9, size, message, &failed)) return McapNext::message;
      if (failed) return fail(StatusCode::data_loss);
    }
    if (done_) return truncated_ ? McapNext::truncated : McapNext::end;

    std::uint8_t head[9];
    std::size_t got = 0;
    if (!read_at(offset_, head, 9, &got)) {
      note_truncation(got == 0 ? "no data end or footer record" : "inside a record header");
      return McapNext::truncated;
    }
    const std::uint8_t opcode = head[0];
    const std::uint64_t size = le64(head + 1);
    if (opcode == kOpDataEnd || opcode == kOpFooter) {
      done_ = true;
      return McapNext::end;
    }
    const std::uint64_t body_offset = offset_ + 9;
    const bool needed =
        opcode == kOpChunk || opcode == kOpMessage || opcode == kOpSchema || opcode == kOpChannel;
    if (!needed) {
      if (size > file_size_ - body_offset) {
        note_truncation("inside a record");
        return McapNext::truncated;
      }
      offset_ = body_offset + size;
      continue;
    }
    const bool complete = size <= file_size_ - body_offset;
    if (complete && size > limits_.max_record_bytes) {
      error_.set(
          "mcap: record at byte %llu is %llu bytes, over the %zu-byte record buffer (raise it with "
          "?buffer=MB)",
          static_cast<unsigned long long>(offset_), static_cast<unsigned long long>(size),
          limits_.max_record_bytes);
      return fail(StatusCode::resource_exhausted);
    }
    std::size_t want = static_cast<std::size_t>(complete ? size : file_size_ - body_offset);
    if (want > limits_.max_record_bytes) want = limits_.max_record_bytes;
    if (!read_at(body_offset, record_, want, &got) && complete) {
      error_.set("mcap: read error at byte %llu", static_cast<unsigned long long>(body_offset));
      return fail(StatusCode::data_loss);
    }
    if (opcode == kOpChunk) {
      if (!load_chunk(record_, got, complete)) return fail(StatusCode::data_loss);
      if (truncated_) return McapNext::truncated;
      // A cut chunk: its whole records are read, then next() reports the truncation.
      offset_ = complete ? body_offset + size : file_size_;
      continue;
    }
    if (!complete) {
      note_truncation("inside a record");
      return McapNext::truncated;
    }
    offset_ = body_offset + size;
    bool failed = false;
    if (handle_record(opcode, record_, size, message, &failed)) return McapNext::message;
    if (failed) return fail(StatusCode::data_loss);
  }
}

}  // namespace octofuse::replay
