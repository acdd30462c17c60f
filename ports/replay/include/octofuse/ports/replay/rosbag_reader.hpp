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
// Skimming (set_skim(), for a first pass that needs the bytes of a few messages only): ROS 1
// writes after each chunk an index record per connection, with each message's time and place in
// the chunk. A chunk whose index records name only connections already declared, none of which
// the caller wants the bytes of, is not decompressed: its messages are given from those records,
// in the chunk's order, with their connection and time and no data (size 0; skimmed_size: the
// space to the next message less a message record's header as ROS 1 writes it). Any other chunk
// (no index records after it: a bag cut there or never closed; an unknown connection; one that is
// wanted) is read as without skimming, so counts, times, order, disorder and cuts come out the
// same, and only a corrupt chunk that was skimmed goes unnoticed until it is read.
//
// Read-ahead (McapLimits::read_ahead, on by default, for a bag whose first chunk is compressed):
// decompressing a bz2 chunk costs about as much as a 1 cm frame's integration, so a worker thread
// started at open() decompresses the next
// chunk, with its own copy of those buffers, while the caller reads this one's messages. The
// caller's next() then takes the worker's chunk buffer in exchange for its own (a message's data
// stays valid until the next call, as without it). The worker goes past index records only: a
// message or connection record, a chunk that is cut, unfinished, uncompressed or too large, ends
// its look and the caller reads that record itself, as without read-ahead, with the same errors,
// warnings and bytes. It moves work to another core, not away: the process's CPU time is the same.
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
  // connection), and besides them for read-ahead when it starts it.
  static std::size_t bytes_required(const McapLimits& limits);
  static std::size_t read_ahead_bytes(const McapLimits& limits);

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

  // Chunks read ahead by the worker and taken by next() (0 without read-ahead).
  std::uint64_t chunks_read_ahead() const { return chunks_read_ahead_; }

  // Skims chunks whose connections `wants` answers false for (asked again at each chunk: the
  // answer may change as the caller learns); null: every chunk read. No read-ahead meanwhile.
  using WantsData = bool (*)(void* context, const McapChannel& channel);
  void set_skim(WantsData wants, void* context);
  std::uint64_t chunks_skimmed() const { return chunks_skimmed_; }

  // A record header's fields, bzip2's allocator, a decompressor and the read-ahead worker:
  // public for the implementation file only.
  struct Header;
  struct Scratch {
    std::uint8_t* base = nullptr;
    std::size_t size = 0;
    std::size_t used = 0;
  };
  // One thread's decompressor: its output buffer (max_chunk_bytes) and the libraries' state.
  struct Inflater {
    std::uint8_t* out = nullptr;
    Scratch bz2;
    LZ4F_dctx_s* lz4 = nullptr;
  };
  struct Inflated {
    bool good = false;   // no error from the library
    bool ended = false;  // the stream ended (its checksums checked)
    std::size_t size = 0;
  };
  struct ReadAhead;
  void read_ahead_job();

 private:
  bool read_at(std::uint64_t offset, std::uint8_t* out, std::size_t size, std::size_t* got) const;
  // One record (top level or inside a chunk). Returns true when it was a message.
  bool handle_record(const Header& header, const std::uint8_t* data, std::uint32_t data_size,
                     McapMessage* message, bool* failed);
  // `ahead`: the worker's result for this chunk, whose bytes are in main_.out already.
  bool load_chunk(const Header& header, const std::uint8_t* data, std::size_t size, bool complete,
                  const Inflated* ahead);
  Inflated inflate(Inflater& inflater, bool bz2, const std::uint8_t* data, std::size_t size) const;
  void note_truncation(const char* what);
  // The lengths and header of the record at `at` (the header read into `buffer`, at most
  // `capacity` bytes), parsed; its data is not read and may run past the file's end.
  enum class RecordHead : std::uint8_t { whole, cut, too_large, malformed };
  RecordHead read_record_head(std::uint64_t at, std::uint8_t* buffer, std::size_t capacity,
                              Header* header, std::uint64_t* data_offset,
                              std::uint32_t* data_size) const;
  bool first_chunk_compressed() const;
  // The index records after the chunk whose data spans [data_offset, data_offset + data_size)
  // into skim_entries_ when the chunk can be skimmed.
  bool try_skim(std::uint64_t data_offset, std::uint32_t data_size, std::uint32_t chunk_size);
  // Read-ahead: start, hand the worker the record at `offset`, take its chunk if it is the one at
  // `offset` (waits for the worker's current job), forget its result, stop.
  bool start_read_ahead();
  void request_read_ahead(std::uint64_t offset);
  bool take_read_ahead(std::uint64_t offset, Inflated* inflated);
  void drop_read_ahead();
  void stop_read_ahead();

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
  McapChannel* channels_ = nullptr;
  std::uint32_t* connection_ids_ = nullptr;
  int channel_count_ = 0;
  Inflater main_;  // the caller's; main_.out is the chunk buffer messages point into
  ReadAhead* ahead_ = nullptr;
  void* ahead_memory_ = nullptr;
  std::uint64_t chunks_read_ahead_ = 0;

  struct SkimEntry {
    std::uint32_t offset = 0;  // in the decompressed chunk
    std::uint32_t channel = 0;
    std::uint64_t time_ns = 0;
    std::size_t size = 0;  // its data's size, from its place and the next message's
  };
  WantsData skim_wants_ = nullptr;
  void* skim_context_ = nullptr;
  std::uint8_t* skim_header_ = nullptr;
  SkimEntry* skim_entries_ = nullptr;
  std::size_t skim_count_ = 0;
  std::size_t skim_pos_ = 0;
  std::uint64_t chunks_skimmed_ = 0;

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
