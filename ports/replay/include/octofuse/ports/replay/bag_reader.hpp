#pragma once
// The container under a bag source: an MCAP file (ROS 2, CDR messages; mcap_reader.hpp) or a
// ROS 1 bag (format 2.0, ROS 1 serialisation; rosbag_reader.hpp), read through one interface so
// that the bag source's topic choice, TF chaining and depth conversion serve both.

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
  static std::size_t bytes_required(BagFormat format, const McapLimits& limits);

  // As McapReader::open / RosbagReader::open; `automatic` reads the first bytes to choose.
  Status open(const char* path, BagFormat format, const McapLimits& limits);
  void close();
  void rewind();
  McapNext next(McapMessage* message);

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
  std::uint64_t out_of_order() const;
  std::size_t bytes_reserved() const;

 private:
  BagFormat format_ = BagFormat::mcap;
  McapReader mcap_;
  RosbagReader rosbag_;
  ErrorText error_;  // an error before either reader was opened
};

}  // namespace octofuse::replay
