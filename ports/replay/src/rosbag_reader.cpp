#include "octofuse/ports/replay/rosbag_reader.hpp"

#include <fcntl.h>
#include <pthread.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <new>

#include "little_endian.hpp"
#include "octofuse/core/arena.hpp"

#if defined(OCTOFUSE_REPLAY_HAVE_BZ2)
#include <bzlib.h>
#endif
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
#include <lz4frame.h>
#endif

namespace octofuse::replay {
namespace {

constexpr char kMagic[] = "#ROSBAG V2.0\n";
constexpr std::size_t kMagicSize = 13;
constexpr std::uint8_t kOpMessage = 0x02;
constexpr std::uint8_t kOpBagHeader = 0x03;
constexpr std::uint8_t kOpIndexData = 0x04;
constexpr std::uint8_t kOpChunk = 0x05;
constexpr std::uint8_t kOpChunkInfo = 0x06;
constexpr std::uint8_t kOpConnection = 0x07;
// The read-ahead worker looks past at most this many index records for the next chunk (ROS 1
// writes one per connection after each chunk).
constexpr int kMaxReadAheadSkips = 256;
// Skimming: messages of one chunk given from its index records at most (a 768 kB chunk of 48-byte
// IMU messages holds 16 000), and the largest index record header read.
constexpr std::size_t kMaxSkimEntries = 16384;
constexpr std::size_t kMaxSkimHeaderBytes = 256;
// A message record's lengths and header as ROS 1 writes them (op, conn, time): 4 + 38 + 4 bytes.
constexpr std::uint32_t kMessageRecordOverhead = 46;
// The worker's nice value (Linux: per thread).
constexpr int kReadAheadNice = 19;
// Record headers hold a few short fields (op, conn, time, topic, compression, size).
constexpr std::size_t kMaxHeaderBytes = 64u << 10;
// bzip2's decompressor: its state (about 64 KiB) and one block of up to 900 kB as 32-bit entries.
[[maybe_unused]] constexpr std::size_t kBz2ScratchBytes = (4u << 20) + (128u << 10);

using detail::le32;
using detail::le64;

struct View {
  const std::uint8_t* data = nullptr;
  std::uint32_t size = 0;
};

#if defined(OCTOFUSE_REPLAY_HAVE_BZ2)
// bzip2 allocates through these: a bump allocator over memory reserved at open().
void* bz2_alloc(void* opaque, int n, int m) {
  auto* scratch = static_cast<RosbagReader::Scratch*>(opaque);
  if (n < 0 || m < 0) return nullptr;
  const std::uint64_t bytes = static_cast<std::uint64_t>(n) * static_cast<std::uint64_t>(m);
  const std::size_t start = align_up(scratch->used, 16);
  if (start > scratch->size || bytes > scratch->size - start) return nullptr;
  scratch->used = start + static_cast<std::size_t>(bytes);
  return scratch->base + start;
}
void bz2_free(void*, void*) {}
#endif

}  // namespace

// The fields of a record header this reader uses; `present` says which were there.
struct RosbagReader::Header {
  bool ok = true;
  bool has_op = false;
  std::uint8_t op = 0;
  bool has_conn = false;
  std::uint32_t conn = 0;
  bool has_time = false;
  std::uint64_t time_ns = 0;
  bool has_size = false;
  std::uint32_t size = 0;
  bool has_index_pos = false;
  std::uint64_t index_pos = 0;
  bool has_ver = false;
  std::uint32_t ver = 0;
  bool has_count = false;
  std::uint32_t count = 0;
  View topic;
  View compression;
  View type;  // connection headers (a connection record's data)

  // A chunk's compression field is `name` ("none", "bz2", "lz4").
  bool compressed_with(const char* name) const {
    return compression.size == std::strlen(name) &&
           std::memcmp(compression.data, name, compression.size) == 0;
  }

  // Parses `size` bytes of "u32 length, name=value" fields.
  void parse(const std::uint8_t* p, std::size_t n) {
    std::size_t pos = 0;
    while (ok && pos < n) {
      if (n - pos < 4) {
        ok = false;
        return;
      }
      const std::uint32_t field = le32(p + pos);
      pos += 4;
      if (field > n - pos) {
        ok = false;
        return;
      }
      const std::uint8_t* f = p + pos;
      pos += field;
      const void* eq = std::memchr(f, '=', field);
      if (eq == nullptr) {
        ok = false;
        return;
      }
      const std::size_t name = static_cast<std::size_t>(static_cast<const std::uint8_t*>(eq) - f);
      const std::uint8_t* value = f + name + 1;
      const std::uint32_t value_size = static_cast<std::uint32_t>(field - name - 1);
      auto is = [&](const char* key) {
        return std::strlen(key) == name && std::memcmp(f, key, name) == 0;
      };
      auto fixed = [&](std::uint32_t bytes) {
        if (value_size != bytes) ok = false;
        return value_size == bytes;
      };
      if (is("op")) {
        if (fixed(1)) {
          op = value[0];
          has_op = true;
        }
      } else if (is("conn")) {
        if (fixed(4)) {
          conn = le32(value);
          has_conn = true;
        }
      } else if (is("time")) {
        if (fixed(8)) {
          time_ns = std::uint64_t{le32(value)} * 1000000000u + std::uint64_t{le32(value + 4)};
          has_time = true;
        }
      } else if (is("size")) {
        if (fixed(4)) {
          size = le32(value);
          has_size = true;
        }
      } else if (is("index_pos")) {
        if (fixed(8)) {
          index_pos = le64(value);
          has_index_pos = true;
        }
      } else if (is("ver")) {
        if (fixed(4)) {
          ver = le32(value);
          has_ver = true;
        }
      } else if (is("count")) {
        if (fixed(4)) {
          count = le32(value);
          has_count = true;
        }
      } else if (is("topic")) {
        topic = View{value, value_size};
      } else if (is("compression")) {
        compression = View{value, value_size};
      } else if (is("type")) {
        type = View{value, value_size};
      }
    }
  }
};

// The worker's state. The fields under `mutex` say what it is doing; its buffers are its own
// while a job runs, and the caller's to swap only while none does.
struct RosbagReader::ReadAhead {
  pthread_t thread{};
  bool started = false;  // joined by close()
  pthread_mutex_t mutex = PTHREAD_MUTEX_INITIALIZER;
  pthread_cond_t wake = PTHREAD_COND_INITIALIZER;  // a job or stop for the worker
  pthread_cond_t idle = PTHREAD_COND_INITIALIZER;  // the job is done
  bool stop = false;
  bool requested = false;
  bool working = false;
  std::uint64_t from = 0;  // the record the job starts at
  bool have = false;       // a decompressed chunk, of the chunk record at `chunk_at`
  std::uint64_t chunk_at = 0;
  Inflated result;
  std::uint8_t* header = nullptr;  // kMaxHeaderBytes
  std::uint8_t* record = nullptr;  // max_record_bytes
  Inflater inflater;
};

namespace {

void* read_ahead_main(void* reader) {
  static_cast<RosbagReader*>(reader)->read_ahead_job();
  return nullptr;
}

}  // namespace

RosbagReader::~RosbagReader() {
  close();
}

std::size_t RosbagReader::read_ahead_bytes(const McapLimits& limits) {
  ArenaSizer sizer;
  (void)sizer.allocate_array<ReadAhead>(1);
  (void)sizer.allocate_bytes(kMaxHeaderBytes, 16);
  (void)sizer.allocate_bytes(limits.max_record_bytes, 16);
  (void)sizer.allocate_bytes(limits.max_chunk_bytes, 16);
#if defined(OCTOFUSE_REPLAY_HAVE_BZ2)
  (void)sizer.allocate_bytes(kBz2ScratchBytes, 16);
#endif
  return sizer.bytes_used();
}

std::size_t RosbagReader::bytes_required(const McapLimits& limits) {
  ArenaSizer sizer;
  (void)sizer.allocate_bytes(kMaxHeaderBytes, 16);
  (void)sizer.allocate_bytes(limits.max_record_bytes, 16);
  (void)sizer.allocate_bytes(limits.max_chunk_bytes, 16);
  (void)sizer.allocate_array<McapChannel>(static_cast<std::size_t>(limits.max_channels));
  (void)sizer.allocate_array<std::uint32_t>(static_cast<std::size_t>(limits.max_channels));
  (void)sizer.allocate_bytes(kMaxSkimHeaderBytes, 16);
  (void)sizer.allocate_array<SkimEntry>(kMaxSkimEntries);
#if defined(OCTOFUSE_REPLAY_HAVE_BZ2)
  (void)sizer.allocate_bytes(kBz2ScratchBytes, 16);
#endif
  return sizer.bytes_used();
}

Status RosbagReader::open(const char* path, const McapLimits& limits) {
  close();
  error_.clear();
  warning_.clear();
  if (limits.max_record_bytes < 64 || limits.max_chunk_bytes < 64 || limits.max_channels < 1 ||
      limits.max_channels > 65536) {
    error_.set("rosbag: invalid limits");
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
  std::uint8_t magic[kMagicSize];
  std::size_t got = 0;
  const bool have_magic = read_at(0, magic, kMagicSize, &got);
  if (!have_magic || std::memcmp(magic, kMagic, kMagicSize) != 0) {
    if (got >= 9 && std::memcmp(magic, kMagic, 9) == 0) {
      error_.set("%s: ROS 1 bag format '%.*s' is not supported (only 2.0)", path,
                 static_cast<int>(got > 12 ? 3 : got - 9), reinterpret_cast<char*>(magic) + 9);
    } else {
      error_.set("%s: not a ROS 1 bag (no #ROSBAG V2.0 magic at the start)", path);
    }
    close();
    return StatusCode::data_loss;
  }
  memory_bytes_ = bytes_required(limits);
  memory_ = std::aligned_alloc(kArenaAlignment, align_up(memory_bytes_, kArenaAlignment));
  ahead_memory_ = nullptr;
  if (memory_ == nullptr) {
    error_.set("rosbag: cannot reserve %zu bytes", memory_bytes_);
    close();
    return StatusCode::resource_exhausted;
  }
  LinearArena arena(memory_, memory_bytes_);
  header_ = static_cast<std::uint8_t*>(arena.allocate_bytes(kMaxHeaderBytes, 16).value());
  record_ = static_cast<std::uint8_t*>(arena.allocate_bytes(limits.max_record_bytes, 16).value());
  main_.out = static_cast<std::uint8_t*>(arena.allocate_bytes(limits.max_chunk_bytes, 16).value());
  channels_ =
      arena.allocate_array<McapChannel>(static_cast<std::size_t>(limits.max_channels)).value();
  connection_ids_ =
      arena.allocate_array<std::uint32_t>(static_cast<std::size_t>(limits.max_channels)).value();
  skim_header_ = static_cast<std::uint8_t*>(arena.allocate_bytes(kMaxSkimHeaderBytes, 16).value());
  skim_entries_ = arena.allocate_array<SkimEntry>(kMaxSkimEntries).value();
  auto make_inflater = [](LinearArena& from, Inflater* inflater) {
#if defined(OCTOFUSE_REPLAY_HAVE_BZ2)
    inflater->bz2.base =
        static_cast<std::uint8_t*>(from.allocate_bytes(kBz2ScratchBytes, 16).value());
    inflater->bz2.size = kBz2ScratchBytes;
#endif
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
    if (LZ4F_isError(LZ4F_createDecompressionContext(&inflater->lz4, LZ4F_VERSION))) {
      inflater->lz4 = nullptr;
    }
#endif
    (void)from;
    (void)inflater;
  };
  make_inflater(arena, &main_);

  // The bag header record: op 0x03 and the index position (0 while recording).
  std::uint8_t head[4];
  if (!read_at(kMagicSize, head, 4, &got)) {
    error_.set("%s: ROS 1 bag cut inside its bag header record", path);
    close();
    return StatusCode::data_loss;
  }
  const std::uint32_t header_size = le32(head);
  std::uint8_t length[4];
  if (header_size > kMaxHeaderBytes || !read_at(kMagicSize + 4, header_, header_size, &got) ||
      !read_at(kMagicSize + 4 + header_size, length, 4, &got)) {
    error_.set("%s: ROS 1 bag with a bag header record of %u bytes (cut or corrupt)", path,
               header_size);
    close();
    return StatusCode::data_loss;
  }
  Header header;
  header.parse(header_, header_size);
  if (!header.ok || !header.has_op || header.op != kOpBagHeader) {
    error_.set("%s: ROS 1 bag without a valid bag header record", path);
    close();
    return StatusCode::data_loss;
  }
  first_record_ = kMagicSize + 8 + std::uint64_t{header_size} + le32(length);
  index_pos_ = header.has_index_pos ? header.index_pos : 0;
  if (index_pos_ != 0 && index_pos_ < first_record_) {
    error_.set("%s: ROS 1 bag header's index position %llu is inside the header", path,
               static_cast<unsigned long long>(index_pos_));
    close();
    return StatusCode::data_loss;
  }
  // Read-ahead where it pays: a bag whose first chunk is compressed (rosbag compresses every
  // chunk of a bag alike); an uncompressed bag keeps the memory.
  if (limits.read_ahead && first_chunk_compressed()) {
    const std::size_t bytes = read_ahead_bytes(limits);
    ahead_memory_ = std::aligned_alloc(kArenaAlignment, align_up(bytes, kArenaAlignment));
    if (ahead_memory_ == nullptr) {
      error_.set("rosbag: cannot reserve %zu bytes for read-ahead", bytes);
      close();
      return StatusCode::resource_exhausted;
    }
    memory_bytes_ += bytes;
    LinearArena ahead_arena(ahead_memory_, bytes);
    ahead_ = new (ahead_arena.allocate_array<ReadAhead>(1).value()) ReadAhead();
    ahead_->header =
        static_cast<std::uint8_t*>(ahead_arena.allocate_bytes(kMaxHeaderBytes, 16).value());
    ahead_->record =
        static_cast<std::uint8_t*>(ahead_arena.allocate_bytes(limits.max_record_bytes, 16).value());
    ahead_->inflater.out =
        static_cast<std::uint8_t*>(ahead_arena.allocate_bytes(limits.max_chunk_bytes, 16).value());
    make_inflater(ahead_arena, &ahead_->inflater);
    if (!start_read_ahead()) {
      error_.set("rosbag: cannot start the read-ahead thread");
      close();
      return StatusCode::resource_exhausted;
    }
  }
  rewind();
  return ok_status();
}

RosbagReader::RecordHead RosbagReader::read_record_head(std::uint64_t at, std::uint8_t* buffer,
                                                        std::size_t capacity, Header* header,
                                                        std::uint64_t* data_offset,
                                                        std::uint32_t* data_size) const {
  std::uint8_t word[4];
  std::size_t got = 0;
  if (at > file_size_ || file_size_ - at < 8 || !read_at(at, word, 4, &got)) {
    return RecordHead::cut;
  }
  const std::uint32_t header_size = le32(word);
  if (header_size > file_size_ - at - 8) return RecordHead::cut;
  if (header_size > capacity) return RecordHead::too_large;
  if (!read_at(at + 4, buffer, header_size, &got) ||
      !read_at(at + 4 + header_size, word, 4, &got)) {
    return RecordHead::cut;
  }
  header->parse(buffer, header_size);
  if (!header->ok || !header->has_op) return RecordHead::malformed;
  *data_offset = at + 8 + header_size;
  *data_size = le32(word);
  return RecordHead::whole;
}

bool RosbagReader::first_chunk_compressed() const {
  // The first record after the bag header, as next() would read it (a cut or odd bag: false).
  Header header;
  std::uint64_t data_offset = 0;
  std::uint32_t data_size = 0;
  if (read_record_head(first_record_, header_, kMaxHeaderBytes, &header, &data_offset,
                       &data_size) != RecordHead::whole) {
    return false;
  }
  return header.op == kOpChunk && (header.compressed_with("bz2") || header.compressed_with("lz4"));
}

void RosbagReader::close() {
  stop_read_ahead();
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  auto free_inflater = [](Inflater* inflater) {
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
    if (inflater->lz4 != nullptr) LZ4F_freeDecompressionContext(inflater->lz4);
#endif
    *inflater = Inflater();
  };
  free_inflater(&main_);
  if (ahead_ != nullptr) {
    free_inflater(&ahead_->inflater);
    ahead_->~ReadAhead();
    ahead_ = nullptr;
  }
  std::free(ahead_memory_);
  ahead_memory_ = nullptr;
  std::free(memory_);
  memory_ = nullptr;
  memory_bytes_ = 0;
  channel_count_ = 0;
}

bool RosbagReader::start_read_ahead() {
  // The worker reads fd_, file_size_, index_pos_ and limits_, which stay as they are until
  // close() has joined it.
  ahead_->started = pthread_create(&ahead_->thread, nullptr, read_ahead_main, this) == 0;
  return ahead_->started;
}

void RosbagReader::stop_read_ahead() {
  if (ahead_ == nullptr) return;
  pthread_mutex_lock(&ahead_->mutex);
  ahead_->stop = true;
  pthread_cond_signal(&ahead_->wake);
  pthread_mutex_unlock(&ahead_->mutex);
  if (ahead_->started) pthread_join(ahead_->thread, nullptr);
  ahead_->started = false;
}

void RosbagReader::request_read_ahead(std::uint64_t offset) {
  if (ahead_ == nullptr) return;
  pthread_mutex_lock(&ahead_->mutex);
  // One job at a time: the caller asks after taking (or dropping) the last result.
  if (!ahead_->stop && !ahead_->requested && !ahead_->working) {
    ahead_->requested = true;
    ahead_->from = offset;
    ahead_->have = false;
    pthread_cond_signal(&ahead_->wake);
  }
  pthread_mutex_unlock(&ahead_->mutex);
}

bool RosbagReader::take_read_ahead(std::uint64_t offset, Inflated* inflated) {
  if (ahead_ == nullptr) return false;
  pthread_mutex_lock(&ahead_->mutex);
  while (ahead_->requested || ahead_->working) pthread_cond_wait(&ahead_->idle, &ahead_->mutex);
  const bool hit = ahead_->have && ahead_->chunk_at == offset;
  if (hit) {
    std::uint8_t* mine = main_.out;
    main_.out = ahead_->inflater.out;
    ahead_->inflater.out = mine;
    *inflated = ahead_->result;
    ++chunks_read_ahead_;
  }
  ahead_->have = false;
  pthread_mutex_unlock(&ahead_->mutex);
  return hit;
}

void RosbagReader::drop_read_ahead() {
  if (ahead_ == nullptr) return;
  pthread_mutex_lock(&ahead_->mutex);
  while (ahead_->requested || ahead_->working) pthread_cond_wait(&ahead_->idle, &ahead_->mutex);
  ahead_->have = false;
  pthread_mutex_unlock(&ahead_->mutex);
}

void RosbagReader::read_ahead_job() {
  // Below the pipeline's threads: where they keep every core busy the worker takes what they
  // leave (and the caller waits for it at the next chunk), instead of slowing their frames.
  (void)::setpriority(PRIO_PROCESS, static_cast<id_t>(::syscall(SYS_gettid)), kReadAheadNice);
  ReadAhead& ahead = *ahead_;
  for (;;) {
    pthread_mutex_lock(&ahead.mutex);
    while (!ahead.stop && !ahead.requested) pthread_cond_wait(&ahead.wake, &ahead.mutex);
    if (ahead.stop) {
      pthread_mutex_unlock(&ahead.mutex);
      return;
    }
    ahead.requested = false;
    ahead.working = true;
    std::uint64_t at = ahead.from;
    pthread_mutex_unlock(&ahead.mutex);

    // Past index records to the next chunk; anything else is the caller's to read.
    bool have = false;
    std::uint64_t chunk_at = 0;
    Inflated result;
    for (int skip = 0; skip < kMaxReadAheadSkips; ++skip) {
      if (index_pos_ != 0 && at >= index_pos_) break;
      Header header;
      std::uint64_t data_offset = 0;
      std::uint32_t data_size = 0;
      if (read_record_head(at, ahead.header, kMaxHeaderBytes, &header, &data_offset, &data_size) !=
              RecordHead::whole ||
          data_size > file_size_ - data_offset) {
        break;
      }
      if (header.op == kOpIndexData || header.op == kOpChunkInfo) {
        at = data_offset + data_size;
        continue;
      }
      if (header.op != kOpChunk || !header.has_size || data_size == 0 ||
          data_size > limits_.max_record_bytes || header.size > limits_.max_chunk_bytes) {
        break;
      }
      const bool bz2 = header.compressed_with("bz2");
      const bool lz4 = header.compressed_with("lz4");
#if !defined(OCTOFUSE_REPLAY_HAVE_BZ2)
      if (bz2) break;
#endif
#if !defined(OCTOFUSE_REPLAY_HAVE_LZ4)
      if (lz4) break;
#endif
      if (!bz2 && !lz4) break;
      std::size_t got = 0;
      if (!read_at(data_offset, ahead.record, data_size, &got)) break;
      result = inflate(ahead.inflater, bz2, ahead.record, data_size);
      have = true;
      chunk_at = at;
      break;
    }

    pthread_mutex_lock(&ahead.mutex);
    ahead.working = false;
    ahead.have = have;
    ahead.chunk_at = chunk_at;
    ahead.result = result;
    pthread_cond_broadcast(&ahead.idle);
    pthread_mutex_unlock(&ahead.mutex);
  }
}

void RosbagReader::set_skim(WantsData wants, void* context) {
  skim_wants_ = wants;
  skim_context_ = context;
}

bool RosbagReader::try_skim(std::uint64_t data_offset, std::uint32_t data_size,
                            std::uint32_t chunk_size) {
  std::uint64_t at = data_offset + data_size;
  std::size_t entries = 0;
  int records = 0;
  // The index records must end at a whole record or the index section: a file that ends among
  // them (cut, or never closed) may have lost some, and the chunk is read instead.
  for (;;) {
    if (index_pos_ != 0 && at == index_pos_) break;
    if (index_pos_ != 0 && at > index_pos_) return false;
    Header header;
    std::uint64_t entries_at = 0;
    std::uint32_t size = 0;
    const RecordHead head =
        read_record_head(at, skim_header_, kMaxSkimHeaderBytes, &header, &entries_at, &size);
    if (head == RecordHead::too_large) break;  // not an index record: those are short
    if (head != RecordHead::whole) return false;
    if (header.op != kOpIndexData) break;
    // An index record this reader cannot vouch for: the chunk is read instead.
    if (!header.has_ver || header.ver != 1 || !header.has_conn || !header.has_count ||
        std::uint64_t{header.count} * 12u != size || size > file_size_ - entries_at ||
        header.count > kMaxSkimEntries - entries || size > limits_.max_record_bytes) {
      return false;
    }
    int channel = -1;
    for (int i = 0; i < channel_count_; ++i) {
      if (connection_ids_[i] == header.conn) channel = i;
    }
    // A connection first seen here has its record in the chunk; a wanted one, its bytes.
    if (channel < 0 || skim_wants_(skim_context_, channels_[channel])) return false;
    std::size_t got = 0;
    if (!read_at(entries_at, record_, size, &got)) return false;
    for (std::uint32_t e = 0; e < header.count; ++e) {
      const std::uint8_t* p = record_ + 12u * e;
      SkimEntry& entry = skim_entries_[entries++];
      entry.time_ns = std::uint64_t{le32(p)} * 1000000000u + std::uint64_t{le32(p + 4)};
      entry.offset = le32(p + 8);
      entry.channel = static_cast<std::uint32_t>(channel);
      if (entry.offset >= chunk_size) return false;
    }
    ++records;
    at = entries_at + size;
  }
  if (records == 0) return false;  // cut or never closed: nothing to go by
  // The chunk's order: by place in the chunk (each message has its own).
  std::sort(skim_entries_, skim_entries_ + entries,
            [](const SkimEntry& a, const SkimEntry& b) { return a.offset < b.offset; });
  for (std::size_t e = 0; e < entries; ++e) {
    const std::uint32_t end = e + 1 < entries ? skim_entries_[e + 1].offset : chunk_size;
    if (end <= skim_entries_[e].offset) return false;  // two messages in one place
    const std::uint32_t record = end - skim_entries_[e].offset;
    skim_entries_[e].size = record > kMessageRecordOverhead ? record - kMessageRecordOverhead : 1;
  }
  skim_count_ = entries;
  skim_pos_ = 0;
  return true;
}

void RosbagReader::rewind() {
  drop_read_ahead();
  skim_count_ = skim_pos_ = 0;
  offset_ = first_record_;
  done_ = truncated_ = false;
  chunk_records_ = nullptr;
  chunk_size_ = chunk_pos_ = 0;
  chunk_cut_ = false;
  chunk_unfinished_ = false;
  last_time_ns_ = 0;
  messages_ = out_of_order_ = 0;
  warning_.clear();
}

bool RosbagReader::read_at(std::uint64_t offset, std::uint8_t* out, std::size_t size,
                           std::size_t* got) const {
  *got = 0;
  while (*got < size) {
    const ssize_t n = ::pread(fd_, out + *got, size - *got, static_cast<off_t>(offset + *got));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    *got += static_cast<std::size_t>(n);
  }
  return true;
}

void RosbagReader::note_truncation(const char* what) {
  truncated_ = done_ = true;
  warning_.set(
      "bag cut short at byte %llu of %llu (%s); read up to the last whole message (%llu "
      "messages, last log time %.6f s)",
      static_cast<unsigned long long>(offset_), static_cast<unsigned long long>(file_size_), what,
      static_cast<unsigned long long>(messages_), static_cast<double>(last_time_ns_) * 1e-9);
}

bool RosbagReader::handle_record(const Header& header, const std::uint8_t* data,
                                 std::uint32_t data_size, McapMessage* message, bool* failed) {
  const unsigned long long at =
      static_cast<unsigned long long>(chunk_records_ ? chunk_offset_ : offset_);
  if (header.op == kOpConnection) {
    Header fields;
    fields.parse(data, data_size);
    if (!header.has_conn || !fields.ok || fields.type.size == 0) {
      error_.set("rosbag: malformed connection record at byte %llu", at);
      *failed = true;
      return false;
    }
    for (int i = 0; i < channel_count_; ++i) {
      if (connection_ids_[i] == header.conn) return false;
    }
    if (channel_count_ >= limits_.max_channels) {
      error_.set("rosbag: more than %d connections", limits_.max_channels);
      *failed = true;
      return false;
    }
    const View topic = header.topic.size > 0 ? header.topic : fields.topic;
    McapChannel channel;
    if (topic.size >= sizeof(channel.topic) || fields.type.size >= sizeof(channel.schema_name)) {
      error_.set("rosbag: connection at byte %llu has a topic or type over %zu bytes", at,
                 McapChannel::kMaxName - 1);
      *failed = true;
      return false;
    }
    channel.id = static_cast<std::uint16_t>(channel_count_);
    // An empty field may have no data pointer, which memcpy must not be given even for 0 bytes.
    if (topic.size > 0) std::memcpy(channel.topic, topic.data, topic.size);
    if (fields.type.size > 0) std::memcpy(channel.schema_name, fields.type.data, fields.type.size);
    std::memcpy(channel.message_encoding, "ros1", 5);
    connection_ids_[channel_count_] = header.conn;
    channels_[channel_count_++] = channel;
    return false;
  }
  if (header.op == kOpMessage) {
    if (!header.has_conn || !header.has_time) {
      error_.set("rosbag: malformed message record at byte %llu", at);
      *failed = true;
      return false;
    }
    message->channel = nullptr;
    for (int i = 0; i < channel_count_; ++i) {
      if (connection_ids_[i] == header.conn) message->channel = &channels_[i];
    }
    if (message->channel == nullptr) {
      error_.set("rosbag: message on connection %u, which no connection record declared",
                 header.conn);
      *failed = true;
      return false;
    }
    message->sequence = static_cast<std::uint32_t>(messages_);
    message->log_time_ns = header.time_ns;
    message->publish_time_ns = header.time_ns;
    message->data = data;
    message->size = data_size;
    message->skimmed_size = 0;
    if (messages_ > 0 && header.time_ns < last_time_ns_) ++out_of_order_;
    last_time_ns_ = header.time_ns;
    ++messages_;
    return true;
  }
  return false;  // index data, chunk info, a second bag header: not needed to replay
}

RosbagReader::Inflated RosbagReader::inflate(Inflater& inflater, bool bz2, const std::uint8_t* data,
                                             std::size_t size) const {
  // Decompressed into the whole buffer, so that data longer than the header says shows, and
  // to the end of the stream, so that its checksums are checked.
  const std::size_t capacity = limits_.max_chunk_bytes;
  Inflated done;
  (void)capacity;  // a build without either library
  (void)data;
  (void)size;
  if (bz2) {
#if defined(OCTOFUSE_REPLAY_HAVE_BZ2)
    bz_stream stream;
    std::memset(&stream, 0, sizeof(stream));
    stream.bzalloc = bz2_alloc;
    stream.bzfree = bz2_free;
    stream.opaque = &inflater.bz2;
    inflater.bz2.used = 0;
    if (BZ2_bzDecompressInit(&stream, 0, 0) == BZ_OK) {
      done.good = true;
      std::size_t in_pos = 0;
      // bzip2 counts in unsigned int: feed and drain in pieces.
      for (;;) {
        const std::size_t in_piece = size - in_pos > (1u << 30) ? (1u << 30) : size - in_pos;
        const std::size_t out_piece =
            capacity - done.size > (1u << 30) ? (1u << 30) : capacity - done.size;
        stream.next_in = const_cast<char*>(reinterpret_cast<const char*>(data + in_pos));
        stream.avail_in = static_cast<unsigned>(in_piece);
        stream.next_out = reinterpret_cast<char*>(inflater.out + done.size);
        stream.avail_out = static_cast<unsigned>(out_piece);
        const int rc = BZ2_bzDecompress(&stream);
        const std::size_t used_in = in_piece - stream.avail_in;
        const std::size_t made = out_piece - stream.avail_out;
        in_pos += used_in;
        done.size += made;
        if (rc == BZ_STREAM_END) {
          done.ended = true;
          break;
        }
        if (rc != BZ_OK) {
          done.good = false;
          break;
        }
        if (used_in == 0 && made == 0) break;  // the input ran out (a cut chunk)
      }
      BZ2_bzDecompressEnd(&stream);
    }
#endif
    return done;
  }
#if defined(OCTOFUSE_REPLAY_HAVE_LZ4)
  if (inflater.lz4 != nullptr) {
    LZ4F_resetDecompressionContext(inflater.lz4);
    std::size_t in_pos = 0;
    done.good = true;
    while (in_pos < size) {
      std::size_t dst_size = capacity - done.size;
      std::size_t src_size = size - in_pos;
      const std::size_t rc = LZ4F_decompress(inflater.lz4, inflater.out + done.size, &dst_size,
                                             data + in_pos, &src_size, nullptr);
      if (LZ4F_isError(rc)) {
        done.good = false;
        break;
      }
      done.size += dst_size;
      in_pos += src_size;
      if (rc == 0) {
        done.ended = true;
        break;
      }
      if (dst_size == 0 && src_size == 0) break;
    }
  }
#endif
  (void)inflater;
  return done;
}

bool RosbagReader::load_chunk(const Header& header, const std::uint8_t* data, std::size_t size,
                              bool complete, const Inflated* ahead) {
  if (!header.has_size || header.compression.data == nullptr) {
    error_.set("rosbag: chunk at byte %llu without compression or size",
               static_cast<unsigned long long>(offset_));
    return false;
  }
  chunk_offset_ = offset_;
  chunk_pos_ = 0;
  chunk_cut_ = !complete;
  chunk_unfinished_ = false;
  if (header.compressed_with("none")) {
    chunk_records_ = data;
    chunk_size_ = size;
    if (complete && size != header.size) {
      error_.set("rosbag: chunk at byte %llu holds %zu bytes, its header says %u",
                 static_cast<unsigned long long>(offset_), size, header.size);
      chunk_records_ = nullptr;
      return false;
    }
    return true;
  }
  if (header.size > limits_.max_chunk_bytes) {
    error_.set(
        "rosbag: chunk at byte %llu holds %u bytes, over the %zu-byte chunk buffer (raise it "
        "with ?buffer=MB)",
        static_cast<unsigned long long>(offset_), header.size, limits_.max_chunk_bytes);
    return false;
  }
  const bool bz2 = header.compressed_with("bz2");
  if (!bz2 && !header.compressed_with("lz4")) {
    error_.set("rosbag: chunk at byte %llu: unknown compression '%.*s'",
               static_cast<unsigned long long>(offset_),
               static_cast<int>(header.compression.size < 32 ? header.compression.size : 32),
               reinterpret_cast<const char*>(header.compression.data));
    return false;
  }
#if !defined(OCTOFUSE_REPLAY_HAVE_BZ2)
  if (bz2) {
    error_.set("rosbag: bz2 chunks are not supported in this build (no libbz2)");
    return false;
  }
#endif
#if !defined(OCTOFUSE_REPLAY_HAVE_LZ4)
  if (!bz2) {
    error_.set("rosbag: lz4 chunks are not supported in this build (no liblz4)");
    return false;
  }
#endif
  const Inflated inflated = ahead != nullptr ? *ahead : inflate(main_, bz2, data, size);
  if (complete && (!inflated.good || !inflated.ended || inflated.size != header.size)) {
    error_.set("rosbag: chunk at byte %llu: corrupt %s data (%zu of %u bytes)",
               static_cast<unsigned long long>(offset_), bz2 ? "bz2" : "lz4", inflated.size,
               header.size);
    return false;
  }
  chunk_records_ = main_.out;
  chunk_size_ = inflated.size;
  return true;
}

McapNext RosbagReader::next(McapMessage* message) {
  if (fd_ < 0) {
    error_.set("rosbag: next() before a successful open()");
    return McapNext::error;
  }
  for (;;) {
    if (skim_pos_ < skim_count_) {
      const SkimEntry& entry = skim_entries_[skim_pos_++];
      message->channel = &channels_[entry.channel];
      message->sequence = static_cast<std::uint32_t>(messages_);
      message->log_time_ns = entry.time_ns;
      message->publish_time_ns = entry.time_ns;
      message->data = nullptr;
      message->size = 0;
      message->skimmed_size = entry.size;
      if (messages_ > 0 && entry.time_ns < last_time_ns_) ++out_of_order_;
      last_time_ns_ = entry.time_ns;
      ++messages_;
      return McapNext::message;
    }
    while (chunk_records_ != nullptr) {
      const std::size_t left = chunk_size_ - chunk_pos_;
      if (left == 0) {
        chunk_records_ = nullptr;
        if (chunk_cut_) {
          offset_ = chunk_offset_;
          note_truncation(chunk_unfinished_ ? "an unfinished chunk: the recorder did not close "
                                              "the bag"
                                            : "inside a chunk");
          return McapNext::truncated;
        }
        break;
      }
      const std::uint8_t* at = chunk_records_ + chunk_pos_;
      std::uint32_t header_size = 0, data_size = 0;
      bool whole = left >= 4;
      if (whole) {
        header_size = le32(at);
        whole = header_size <= left - 4 && left - 4 - header_size >= 4;
      }
      if (whole) {
        data_size = le32(at + 4 + header_size);
        whole = data_size <= left - 8 - header_size;
      }
      if (!whole) {
        chunk_records_ = nullptr;
        if (chunk_cut_) {
          offset_ = chunk_offset_;
          note_truncation(chunk_unfinished_ ? "an unfinished chunk: the recorder did not close "
                                              "the bag"
                                            : "inside a chunk");
          return McapNext::truncated;
        }
        error_.set("rosbag: chunk at byte %llu: a record runs past the chunk's end",
                   static_cast<unsigned long long>(chunk_offset_));
        done_ = true;
        return McapNext::error;
      }
      chunk_pos_ += 8 + std::size_t{header_size} + data_size;
      Header header;
      header.parse(at + 4, header_size);
      if (!header.ok || !header.has_op || header.op == kOpChunk) {
        chunk_records_ = nullptr;
        error_.set("rosbag: chunk at byte %llu: malformed record header",
                   static_cast<unsigned long long>(chunk_offset_));
        done_ = true;
        return McapNext::error;
      }
      bool failed = false;
      if (handle_record(header, at + 8 + header_size, data_size, message, &failed)) {
        return McapNext::message;
      }
      if (failed) {
        chunk_records_ = nullptr;
        done_ = true;
        return McapNext::error;
      }
    }
    if (done_) return truncated_ ? McapNext::truncated : McapNext::end;
    if (index_pos_ != 0 && offset_ == index_pos_) {
      done_ = true;  // the index section: connections and chunk infos again, not needed
      return McapNext::end;
    }
    if (index_pos_ != 0 && offset_ > index_pos_) {
      error_.set("rosbag: the bag header's index position %llu is not at a record",
                 static_cast<unsigned long long>(index_pos_));
      done_ = true;
      return McapNext::error;
    }

    std::uint8_t head[4];
    std::size_t got = 0;
    if (offset_ > file_size_) {
      offset_ = file_size_;
      note_truncation("inside the bag header record");
      return McapNext::truncated;
    }
    if (!read_at(offset_, head, 4, &got)) {
      note_truncation(got > 0           ? "inside a record header"
                      : index_pos_ == 0 ? "no index: the recorder did not close the bag"
                                        : "before the index");
      return McapNext::truncated;
    }
    const std::uint32_t header_size = le32(head);
    if (header_size > kMaxHeaderBytes) {
      if (header_size > file_size_ - offset_ - 4) {
        note_truncation("inside a record header");
        return McapNext::truncated;
      }
      error_.set("rosbag: record at byte %llu has a header of %u bytes (at most %zu)",
                 static_cast<unsigned long long>(offset_), header_size, kMaxHeaderBytes);
      done_ = true;
      return McapNext::error;
    }
    std::uint8_t length[4];
    if (!read_at(offset_ + 4, header_, header_size, &got) ||
        !read_at(offset_ + 4 + header_size, length, 4, &got)) {
      note_truncation("inside a record header");
      return McapNext::truncated;
    }
    Header header;
    header.parse(header_, header_size);
    if (!header.ok || !header.has_op) {
      error_.set("rosbag: malformed record header at byte %llu",
                 static_cast<unsigned long long>(offset_));
      done_ = true;
      return McapNext::error;
    }
    const std::uint32_t data_size = le32(length);
    const std::uint64_t data_offset = offset_ + 8 + header_size;
    const bool complete = data_size <= file_size_ - data_offset;
    const bool needed =
        header.op == kOpChunk || header.op == kOpMessage || header.op == kOpConnection;
    if (!needed) {
      if (!complete) {
        note_truncation("inside a record");
        return McapNext::truncated;
      }
      offset_ = data_offset + data_size;
      continue;
    }
    if (header.op == kOpChunk && complete && data_size == 0 && header.has_size &&
        header.size == 0) {
      // A chunk whose recorder never came back to write its sizes: an uncompressed one's
      // records follow as they are; a compressed one's stream runs to the end of the file, of
      // a length unknown: decoded as far as it goes, as a cut chunk.
      if (header.compressed_with("none")) {
        offset_ = data_offset;
        continue;
      }
      Header open_chunk = header;
      open_chunk.size = limits_.max_chunk_bytes > 0xFFFFFFFFu
                            ? 0xFFFFFFFFu
                            : static_cast<std::uint32_t>(limits_.max_chunk_bytes);
      std::uint64_t rest = file_size_ - data_offset;
      if (rest > limits_.max_record_bytes) rest = limits_.max_record_bytes;
      (void)read_at(data_offset, record_, static_cast<std::size_t>(rest), &got);
      if (!load_chunk(open_chunk, record_, got, false, nullptr)) {
        done_ = true;
        return McapNext::error;
      }
      chunk_unfinished_ = true;
      offset_ = file_size_;
      continue;
    }
    if (complete && data_size > limits_.max_record_bytes) {
      error_.set(
          "rosbag: record at byte %llu is %u bytes, over the %zu-byte record buffer (raise it "
          "with ?buffer=MB)",
          static_cast<unsigned long long>(offset_), data_size, limits_.max_record_bytes);
      done_ = true;
      return McapNext::error;
    }
    if (header.op == kOpChunk && complete && skim_wants_ != nullptr && data_size > 0 &&
        header.has_size && try_skim(data_offset, data_size, header.size)) {
      ++chunks_skimmed_;
      offset_ = data_offset + data_size;
      continue;
    }
    if (header.op == kOpChunk && complete) {
      Inflated ahead;
      if (take_read_ahead(offset_, &ahead)) {
        if (!load_chunk(header, nullptr, 0, true, &ahead)) {
          done_ = true;
          return McapNext::error;
        }
        offset_ = data_offset + data_size;
        if (skim_wants_ == nullptr) request_read_ahead(offset_);
        continue;
      }
    }
    // In 64 bits before the clamp: what is left of the file may exceed a 32-bit size_t.
    std::uint64_t available = complete ? data_size : file_size_ - data_offset;
    if (available > limits_.max_record_bytes) available = limits_.max_record_bytes;
    const std::size_t want = static_cast<std::size_t>(available);
    if (!read_at(data_offset, record_, want, &got) && complete) {
      error_.set("rosbag: read error at byte %llu", static_cast<unsigned long long>(data_offset));
      done_ = true;
      return McapNext::error;
    }
    if (header.op == kOpChunk) {
      if (!load_chunk(header, record_, got, complete, nullptr)) {
        done_ = true;
        return McapNext::error;
      }
      offset_ = complete ? data_offset + data_size : file_size_;
      // Worth a worker's look only after a compressed chunk: the next is likely one too.
      if (complete && chunk_records_ == main_.out && skim_wants_ == nullptr) {
        request_read_ahead(offset_);
      }
      continue;
    }
    if (!complete) {
      note_truncation("inside a record");
      return McapNext::truncated;
    }
    offset_ = data_offset + data_size;
    bool failed = false;
    if (handle_record(header, record_, data_size, message, &failed)) return McapNext::message;
    if (failed) {
      done_ = true;
      return McapNext::error;
    }
  }
}

}  // namespace octofuse::replay
