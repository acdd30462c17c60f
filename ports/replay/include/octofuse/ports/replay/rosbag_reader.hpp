#pragma once
// Streaming reader of ROS 1 bags, format 2.0 (http://wiki.ros.org/Bags/Format/2.0), the format
// public RGB-D sequences (TUM RGB-D among them) are distributed in. Read from the specification:
// Debian's ROS 1 C++ reader (rosbag_storage) throws exceptions and pulls in Boost and the ROS
// console and time libraries, which the port's rules (no exceptions, fixed memory) exclude.
//
// Reads the records front to back in file order, through chunks (none, bz2 or lz4, the latter
// being roslz4's output, a standard LZ4 frame) and loose message records alike, up to the index
// section the bag header points at; the index itself is not needed and never read. Channels and
// messages are reported in the MCAP reader's types (McapChannel with the ROS 1 type as its
// schema name and "ros1" as its encoding; McapMessage with the record's time as its log time).
// Memory is fixed at open(): a record header buffer, one record buffer and one chunk buffer
// (McapLimits), and bzip2's working memory.
//
// A file cut at any byte, or a bag whose recorder never closed it (no index position in its
// header), reads up to its last whole message: next() then gives McapNext::truncated and
// warning() says where it ended. A malformed record, a record larger than the buffers or a
// compression this build lacks give McapNext::error with error() saying why.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/ports/replay/mcap_reader.hpp"

struct LZ4F_dctx_s;

namespace octofuse::replay {

class RosbagReader {
 public:
  RosbagReader() = default;
  ~RosbagReader();
  RosbagReader(const RosbagReader&) = delete;
  RosbagReader& operator=(const RosbagReader&) = delete;

  // Bytes open() reserves for `limits` (max_schemas is not used: ROS 1 names the type in the
  // connection).
  static std::size_t bytes_required(const McapLimits& limits);

  // Opens `path`, checks the magic and reads the bag header. unavailable (no such file),
  // data_loss (not a ROS 1 bag, another format version, a malformed bag header),
  // invalid_argument (limits), resource_exhausted (no memory).
  Status open(const char* path, const McapLimits& limits = McapLimits());
  void close();
  // Back to the first record after the bag header; connections seen so far are kept.
  void rewind();

  McapNext next(McapMessage* message);

  const char* error() const { return error_.c_str(); }
  const char* warning() const { return warning_.c_str(); }

  int channel_count() const { return channel_count_; }
  const McapChannel& channel_at(int index) const { return channels_[index]; }
  std::uint64_t file_size() const { return file_size_; }
  std::uint64_t position() const { return offset_; }
  std::uint64_t out_of_order() const { return out_of_order_; }
  std::size_t bytes_reserved() const { return memory_bytes_; }

  // A record header's fields, and bzip2's allocator: public for the implementation file only.
  struct Header;
  struct Scratch {
    std::uint8_t* base = nullptr;
    std::size_t size = 0;
    std::size_t used = 0;
  };

 private:
  bool read_at(std::uint64_t offset, std::uint8_t* out, std::size_t size, std::size_t* got);
  // One record (top level or inside a chunk). Returns true when it was a message.
  bool handle_record(const Header& header, const std::uint8_t* data, std::uint32_t data_size,
                     McapMessage* message, bool* failed);
  bool load_chunk(const Header& header, const std::uint8_t* data, std::size_t size, bool complete);
  void note_truncation(const char* what);

  ErrorText error_;
  ErrorText warning_;
  McapLimits limits_;
  int fd_ = -1;
  std::uint64_t file_size_ = 0;
  std::uint64_t first_record_ = 0;  // after the bag header
  std::uint64_t index_pos_ = 0;     // 0: the recorder never closed the bag
  std::uint64_t offset_ = 0;        // next top-level record
  bool done_ = false;
  bool truncated_ = false;

  void* memory_ = nullptr;
  std::size_t memory_bytes_ = 0;
  std::uint8_t* header_ = nullptr;
  std::uint8_t* record_ = nullptr;
  std::uint8_t* chunk_ = nullptr;
  McapChannel* channels_ = nullptr;
  std::uint32_t* connection_ids_ = nullptr;
  int channel_count_ = 0;
  Scratch bz2_;
  LZ4F_dctx_s* lz4_ = nullptr;

  const std::uint8_t* chunk_records_ = nullptr;
  std::size_t chunk_size_ = 0;
  std::size_t chunk_pos_ = 0;
  bool chunk_cut_ = false;
  bool chunk_unfinished_ = false;  // its sizes were never written: the recorder was killed
  std::uint64_t chunk_offset_ = 0;

  std::uint64_t last_time_ns_ = 0;
  std::uint64_t messages_ = 0;
  std::uint64_t out_of_order_ = 0;
};

}  // namespace octofuse::replay
