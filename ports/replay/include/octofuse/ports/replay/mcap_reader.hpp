#pragma once
// Streaming reader of MCAP files (https://mcap.dev/spec), the container rosbag2 writes by
// default. Reads the data section front to back, record by record, in file order (which is log
// time order for every writer that writes messages as they arrive), through chunks (none, zstd
// or lz4 compression) and loose messages alike; the summary section and indexes are not needed
// and never read. Memory is fixed at open(): one record buffer and one chunk buffer, sized by
// McapLimits.
//
// A file cut at any byte (a recorder killed, a battery run flat) reads up to its last whole
// message: next() then gives McapNext::truncated and warning() says where it ended. A chunk
// whose CRC disagrees, a record larger than the buffers or a compression this build lacks give
// McapNext::error with error() saying why.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"

struct ZSTD_DCtx_s;
struct LZ4F_dctx_s;

namespace octofuse::replay {

struct McapLimits {
  // A chunk record or a loose message, and a chunk once decompressed: 8 MiB holds a 1280 x 1024
  // 32FC1 image (rosbag2 chunks are 768 KiB, or one message when it is larger).
  std::size_t max_record_bytes = 8u << 20;
  std::size_t max_chunk_bytes = 8u << 20;
  int max_channels = 64;
  int max_schemas = 64;
  // BagReader's reorder window, which gives messages in log-time order (bag_reader.hpp): up to
  // this many bytes and messages held back; 0 bytes reads in file order.
  std::size_t reorder_bytes = 8u << 20;
  int reorder_messages = 4096;
  // ROS 1 bags: a second thread decompresses the next chunk while this one is read
  // (rosbag_reader.hpp), with buffers of its own (a record and a chunk buffer, bzip2's memory).
  // MCAP's zstd and lz4 chunks decode fast enough on the reading thread.
  bool read_ahead = true;
};

struct McapChannel {
  static constexpr std::size_t kMaxName = 128;
  std::uint16_t id = 0;
  std::uint16_t schema_id = 0;
  char topic[kMaxName] = {};
  char message_encoding[32] = {};   // "cdr" for ROS 2
  char schema_name[kMaxName] = {};  // "sensor_msgs/msg/Image"; filled when the schema is known
};

struct McapMessage {
  const McapChannel* channel = nullptr;
  std::uint32_t sequence = 0;
  std::uint64_t log_time_ns = 0;
  std::uint64_t publish_time_ns = 0;
  const std::uint8_t* data = nullptr;  // valid until the next call to next()
  std::size_t size = 0;
  // A ROS 1 message given from a chunk's index while skimming (rosbag_reader.hpp): data null,
  // size 0, and this many bytes in the file (for the reorder window's accounting); 0 otherwise.
  std::size_t skimmed_size = 0;
};

enum class McapNext : std::uint8_t { message, end, truncated, error };

class McapReader {
 public:
  McapReader() = default;
  ~McapReader();
  McapReader(const McapReader&) = delete;
  McapReader& operator=(const McapReader&) = delete;

  // Bytes open() reserves for `limits`.
  static std::size_t bytes_required(const McapLimits& limits);

  // Opens `path` and checks the magic. unavailable (no such file), data_loss (not MCAP),
  // invalid_argument (limits), resource_exhausted (no memory).
  Status open(const char* path, const McapLimits& limits = McapLimits());
  void close();
  // Back to the first record; channels seen so far are kept.
  void rewind();

  McapNext next(McapMessage* message);

  const char* error() const { return error_.c_str(); }
  const char* warning() const { return warning_.c_str(); }

  int channel_count() const { return channel_count_; }
  const McapChannel& channel_at(int index) const { return channels_[index]; }
  std::uint64_t file_size() const { return file_size_; }
  std::uint64_t position() const { return offset_; }
  // Messages whose log time went backwards (read in file order all the same).
  std::uint64_t out_of_order() const { return out_of_order_; }
  std::size_t bytes_reserved() const { return memory_bytes_; }

 private:
  struct Schema {
    std::uint16_t id = 0;
    char name[McapChannel::kMaxName] = {};
  };
  McapNext fail(StatusCode code);
  // Reads `size` bytes at `offset`; false at the end of the file (`*got` says how many came).
  bool read_at(std::uint64_t offset, std::uint8_t* out, std::size_t size, std::size_t* got);
  // Handles one record from the data section or a chunk. Returns true when it was a message.
  bool handle_record(std::uint8_t opcode, const std::uint8_t* body, std::uint64_t size,
                     McapMessage* message, bool* failed);
  bool load_chunk(const std::uint8_t* body, std::size_t size, bool complete);
  void note_truncation(const char* what);

  ErrorText error_;
  ErrorText warning_;
  McapLimits limits_;
  int fd_ = -1;
  std::uint64_t file_size_ = 0;
  std::uint64_t offset_ = 0;  // next record in the data section
  bool done_ = false;
  bool truncated_ = false;

  void* memory_ = nullptr;
  std::size_t memory_bytes_ = 0;
  std::uint8_t* record_ = nullptr;
  std::uint8_t* chunk_ = nullptr;
  McapChannel* channels_ = nullptr;
  Schema* schemas_ = nullptr;
  int channel_count_ = 0;
  int schema_count_ = 0;
  ZSTD_DCtx_s* zstd_ = nullptr;
  LZ4F_dctx_s* lz4_ = nullptr;

  // The chunk being read: its records and where the next one starts.
  const std::uint8_t* chunk_records_ = nullptr;
  std::size_t chunk_size_ = 0;
  std::size_t chunk_pos_ = 0;
  bool chunk_cut_ = false;  // the chunk's data ended early (file cut inside it)
  std::uint64_t chunk_offset_ = 0;

  std::uint64_t last_log_time_ns_ = 0;
  std::uint64_t messages_ = 0;
  std::uint64_t out_of_order_ = 0;
};

}  // namespace octofuse::replay
