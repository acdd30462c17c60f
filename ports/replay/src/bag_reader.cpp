#include "octofuse/ports/replay/bag_reader.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace octofuse::replay {

std::size_t BagReader::bytes_required(BagFormat format, const McapLimits& limits) {
  return format == BagFormat::rosbag ? RosbagReader::bytes_required(limits)
                                     : McapReader::bytes_required(limits);
}

Status BagReader::open(const char* path, BagFormat format, const McapLimits& limits) {
  close();
  error_.clear();
  if (format == BagFormat::automatic) {
    const int fd = ::open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK);
    if (fd < 0) {
      error_.set("%s: cannot open: %s", path, std::strerror(errno));
      return StatusCode::unavailable;
    }
    char magic[8] = {};
    const ssize_t got = ::read(fd, magic, sizeof(magic));
    ::close(fd);
    format =
        got == 8 && std::memcmp(magic, "#ROSBAG ", 8) == 0 ? BagFormat::rosbag : BagFormat::mcap;
  }
  format_ = format;
  return format_ == BagFormat::rosbag ? rosbag_.open(path, limits) : mcap_.open(path, limits);
}

void BagReader::close() {
  mcap_.close();
  rosbag_.close();
}

void BagReader::rewind() {
  if (format_ == BagFormat::rosbag) {
    rosbag_.rewind();
  } else {
    mcap_.rewind();
  }
}

McapNext BagReader::next(McapMessage* message) {
  return format_ == BagFormat::rosbag ? rosbag_.next(message) : mcap_.next(message);
}

const char* BagReader::error() const {
  if (error_.c_str()[0] != '\0') return error_.c_str();
  return format_ == BagFormat::rosbag ? rosbag_.error() : mcap_.error();
}
const char* BagReader::warning() const {
  return format_ == BagFormat::rosbag ? rosbag_.warning() : mcap_.warning();
}
int BagReader::channel_count() const {
  return format_ == BagFormat::rosbag ? rosbag_.channel_count() : mcap_.channel_count();
}
const McapChannel& BagReader::channel_at(int index) const {
  return format_ == BagFormat::rosbag ? rosbag_.channel_at(index) : mcap_.channel_at(index);
}
std::uint64_t BagReader::file_size() const {
  return format_ == BagFormat::rosbag ? rosbag_.file_size() : mcap_.file_size();
}
std::uint64_t BagReader::position() const {
  return format_ == BagFormat::rosbag ? rosbag_.position() : mcap_.position();
}
std::uint64_t BagReader::out_of_order() const {
  return format_ == BagFormat::rosbag ? rosbag_.out_of_order() : mcap_.out_of_order();
}
std::size_t BagReader::bytes_reserved() const {
  return format_ == BagFormat::rosbag ? rosbag_.bytes_reserved() : mcap_.bytes_reserved();
}

}  // namespace octofuse::replay
