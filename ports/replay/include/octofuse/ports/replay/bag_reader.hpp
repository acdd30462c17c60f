#pragma once
// The container under a bag source: an MCAP file (ROS 2, CDR messages; mcap_reader.hpp) or a
// ROS 1 bag (format 2.0, ROS 1 serialisation; rosbag_reader.hpp), read through one interface so
// that the bag source's topic choice, TF chaining and depth conversion serve both.
//
// Messages come in log-time order. Both containers are read front to back, and a bag whose
// chunks overlap in time (a recorder that chunks each topic apart, a merged bag) holds messages
// in the file after later ones. A reorder window merges them without an index and in fixed
// memory: messages are copied into it as read, and the earliest is given out once the window is
// full (McapLimits::reorder_bytes and reorder_messages) or the file ends. A message that arrives
// after a later one has been given out (it lay further back in the file than the window
// reaches) is given out at once, out of order, and counted (out_of_order()). Ties keep file
// order. A message larger than the whole window is given out without it, after the window
// empties. reorder_bytes 0: file order, disorder only counted.

#include <cstddef>
#include <cstdint>

#include "octofuse/ports/replay/mcap_reader.hpp"
#include "octofuse/ports/replay/ros_messages.hpp"
#include "octofuse/ports/replay/rosbag_reader.hpp"

namespace octofuse::replay {

// `automatic` tells the two apart by their magic bytes (for --list).
enum class BagFormat : std::uint8_t { mcap, rosbag, automatic };

class BagReader {
 public:
  BagReader() = default;
  ~BagReader() { close(); }
  BagReader(const BagReader&) = delete;
  BagReader& operator=(const BagReader&) = delete;

  static std::size_t bytes_required(BagFormat format, const McapLimits& limits);

  // As McapReader::open / RosbagReader::open; `automatic` reads the first bytes to choose.
  Status open(const char* path, BagFormat format, const McapLimits& limits);
  void close();
  void rewind();
  McapNext next(McapMessage* message);
  // ROS 1 bags: skim the chunks whose connections `wants` answers false for, giving their
  // messages without data (rosbag_reader.hpp); MCAP: every message is read. Null: off.
  void set_skim(RosbagReader::WantsData wants, void* context) { rosbag_.set_skim(wants, context); }
  std::uint64_t chunks_skimmed() const {
    return format_ == BagFormat::rosbag ? rosbag_.chunks_skimmed() : 0;
  }

  BagFormat format() const { return format_; }
  // How the messages are serialised: CDR in MCAP, ROS 1 in a ROS 1 bag.
  RosWire wire() const { return format_ == BagFormat::rosbag ? RosWire::ros1 : RosWire::cdr; }
  // "mcap" or "rosbag", for messages.
  const char* name() const { return format_ == BagFormat::rosbag ? "rosbag" : "mcap"; }

  const char* error() const;
  const char* warning() const;
  int channel_count() const;
  const McapChannel& channel_at(int index) const;
  std::uint64_t file_size() const;
  std::uint64_t position() const;
  // Messages given out before one with an earlier log time (with the window: those the window
  // could not put in order).
  std::uint64_t out_of_order() const;
  // The window's size in bytes (0: none).
  std::size_t reorder_bytes() const { return window_bytes_; }
  std::size_t bytes_reserved() const;

 private:
  struct Held {
    const McapChannel* channel = nullptr;
    std::uint64_t log_time_ns = 0;
    std::uint64_t publish_time_ns = 0;
    std::uint64_t arrival = 0;  // file order, for ties
    std::size_t offset = 0;     // in the window
    std::size_t size = 0;       // of the message's data (0 when skimmed)
    std::size_t bytes = 0;      // taken in the window: at least 1, the file's size when skimmed
    bool skimmed = false;
    std::uint32_t sequence = 0;
    bool given = false;  // given out: its bytes are free once the messages before it are
  };
  McapNext inner_next(McapMessage* message);
  bool hold(const McapMessage& message);  // false: no room
  bool earlier(int a, int b) const;
  void heap_push(int slot);
  int heap_pop();
  void reset_window();

  BagFormat format_ = BagFormat::mcap;
  McapReader mcap_;
  RosbagReader rosbag_;
  ErrorText error_;  // an error before either reader was opened

  // The reorder window: message bytes in a ring, in file order; Held records in a ring of the
  // same order (slots), and a min-heap of the slots not yet given out.
  void* window_memory_ = nullptr;
  std::uint8_t* window_ = nullptr;
  std::size_t window_bytes_ = 0;
  Held* held_ = nullptr;
  int* heap_ = nullptr;
  int slots_ = 0;
  int first_slot_ = 0;  // the oldest held message in file order
  int held_count_ = 0;
  int heap_count_ = 0;
  std::uint64_t arrivals_ = 0;
  int given_slot_ = -1;   // the message given out last, from the window
  bool pending_ = false;  // a message read but not yet held (no room)
  McapMessage pending_message_;
  McapNext inner_state_ = McapNext::message;  // end, truncated or error once the file is read
  bool have_given_ = false;
  std::uint64_t last_given_ns_ = 0;
  std::uint64_t late_ = 0;
};

}  // namespace octofuse::replay
