#include "octofuse/ports/replay/bag_reader.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <new>

namespace octofuse::replay {

std::size_t BagReader::bytes_required(BagFormat format, const McapLimits& limits) {
  std::size_t window = 0;
  if (limits.reorder_bytes > 0) {
    window = (limits.reorder_bytes + 15) / 16 * 16 +
             static_cast<std::size_t>(limits.reorder_messages) * (sizeof(Held) + sizeof(int));
  }
  return window + (format == BagFormat::rosbag ? RosbagReader::bytes_required(limits)
                                               : McapReader::bytes_required(limits));
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
  if (limits.reorder_bytes > 0 &&
      (limits.reorder_messages < 1 || limits.reorder_messages > (1 << 20) ||
       limits.reorder_bytes > (std::size_t{1} << 40))) {
    error_.set("%s: the reorder window needs 1 to 1048576 messages", name());
    return StatusCode::invalid_argument;
  }
  const Status status =
      format_ == BagFormat::rosbag ? rosbag_.open(path, limits) : mcap_.open(path, limits);
  if (!status.ok() || limits.reorder_bytes == 0) return status;
  const std::size_t slots = static_cast<std::size_t>(limits.reorder_messages);
  const std::size_t held_offset = (limits.reorder_bytes + 15) / 16 * 16;
  const std::size_t heap_offset = held_offset + slots * sizeof(Held);
  const std::size_t total = heap_offset + slots * sizeof(int);
  window_memory_ = std::malloc(total);
  if (window_memory_ == nullptr) {
    close();
    error_.set("%s: cannot reserve %zu bytes for the reorder window", name(), total);
    return StatusCode::resource_exhausted;
  }
  window_ = static_cast<std::uint8_t*>(window_memory_);
  window_bytes_ = limits.reorder_bytes;
  held_ = static_cast<Held*>(static_cast<void*>(window_ + held_offset));
  for (std::size_t i = 0; i < slots; ++i) new (held_ + i) Held();
  heap_ = static_cast<int*>(static_cast<void*>(window_ + heap_offset));
  slots_ = limits.reorder_messages;
  reset_window();
  return ok_status();
}

void BagReader::close() {
  mcap_.close();
  rosbag_.close();
  std::free(window_memory_);
  window_memory_ = nullptr;
  window_ = nullptr;
  window_bytes_ = 0;
  held_ = nullptr;
  heap_ = nullptr;
  slots_ = 0;
  reset_window();
}

void BagReader::reset_window() {
  first_slot_ = held_count_ = heap_count_ = 0;
  arrivals_ = 0;
  given_slot_ = -1;
  pending_ = false;
  inner_state_ = McapNext::message;
  have_given_ = false;
  last_given_ns_ = 0;
  late_ = 0;
}

void BagReader::rewind() {
  if (format_ == BagFormat::rosbag) {
    rosbag_.rewind();
  } else {
    mcap_.rewind();
  }
  reset_window();
}

McapNext BagReader::inner_next(McapMessage* message) {
  return format_ == BagFormat::rosbag ? rosbag_.next(message) : mcap_.next(message);
}

bool BagReader::earlier(int a, int b) const {
  const Held& x = held_[a];
  const Held& y = held_[b];
  return x.log_time_ns < y.log_time_ns || (x.log_time_ns == y.log_time_ns && x.arrival < y.arrival);
}

void BagReader::heap_push(int slot) {
  int i = heap_count_++;
  heap_[i] = slot;
  while (i > 0) {
    const int parent = (i - 1) / 2;
    if (!earlier(heap_[i], heap_[parent])) break;
    const int t = heap_[i];
    heap_[i] = heap_[parent];
    heap_[parent] = t;
    i = parent;
  }
}

int BagReader::heap_pop() {
  const int top = heap_[0];
  heap_[0] = heap_[--heap_count_];
  int i = 0;
  for (;;) {
    const int left = 2 * i + 1;
    const int right = left + 1;
    int least = i;
    if (left < heap_count_ && earlier(heap_[left], heap_[least])) least = left;
    if (right < heap_count_ && earlier(heap_[right], heap_[least])) least = right;
    if (least == i) break;
    const int t = heap_[i];
    heap_[i] = heap_[least];
    heap_[least] = t;
    i = least;
  }
  return top;
}

// Copies the message into the window's ring after the newest held one, when it fits.
bool BagReader::hold(const McapMessage& message) {
  // An empty message takes a byte, so that held messages never share an offset; a skimmed one
  // its size in the file, so that the window fills as when it is read.
  const bool skimmed = message.data == nullptr && message.skimmed_size > 0;
  const std::size_t size = skimmed ? message.skimmed_size : message.size > 0 ? message.size : 1;
  if (held_count_ == slots_ || size > window_bytes_) return false;
  std::size_t offset = 0;
  if (held_count_ > 0) {
    const Held& front = held_[first_slot_];
    const Held& back = held_[(first_slot_ + held_count_ - 1) % slots_];
    const std::size_t head = front.offset;
    const std::size_t tail = back.offset + back.bytes;
    if (tail > head) {  // held bytes in [head, tail): free at the end, then at the start
      if (window_bytes_ - tail >= size) {
        offset = tail;
      } else if (head >= size) {
        offset = 0;
      } else {
        return false;
      }
    } else if (head - tail >= size) {  // wrapped: free in [tail, head)
      offset = tail;
    } else {
      return false;
    }
  }
  if (!skimmed && message.size > 0) std::memcpy(window_ + offset, message.data, message.size);
  const int slot = (first_slot_ + held_count_) % slots_;
  Held& h = held_[slot];
  h.channel = message.channel;
  h.log_time_ns = message.log_time_ns;
  h.publish_time_ns = message.publish_time_ns;
  h.arrival = arrivals_++;
  h.offset = offset;
  h.size = skimmed ? 0 : message.size;
  h.bytes = size;
  h.skimmed = skimmed;
  h.sequence = message.sequence;
  h.given = false;
  ++held_count_;
  heap_push(slot);
  return true;
}

McapNext BagReader::next(McapMessage* message) {
  if (window_bytes_ == 0) return inner_next(message);
  // The message given out last is done with: its bytes, and those of given messages before it
  // in the file, are free again.
  if (given_slot_ >= 0) held_[given_slot_].given = true;
  given_slot_ = -1;
  while (held_count_ > 0 && held_[first_slot_].given) {
    first_slot_ = (first_slot_ + 1) % slots_;
    --held_count_;
  }
  // Read ahead until the window is full or the file ends.
  while (inner_state_ == McapNext::message) {
    if (!pending_) {
      const McapNext got = inner_next(&pending_message_);
      if (got != McapNext::message) {
        inner_state_ = got;
        break;
      }
      pending_ = true;
    }
    if (!hold(pending_message_)) break;
    pending_ = false;
  }
  std::uint64_t log_time_ns = 0;
  if (pending_ &&
      (heap_count_ == 0 || pending_message_.log_time_ns < held_[heap_[0]].log_time_ns)) {
    // Earlier than all held (or larger than the whole window): given out as the reader has it.
    pending_ = false;
    *message = pending_message_;
    log_time_ns = message->log_time_ns;
  } else if (heap_count_ > 0) {
    const int slot = heap_pop();
    const Held& h = held_[slot];
    message->channel = h.channel;
    message->sequence = h.sequence;
    message->log_time_ns = h.log_time_ns;
    message->publish_time_ns = h.publish_time_ns;
    message->data = h.skimmed ? nullptr : window_ + h.offset;
    message->size = h.size;
    message->skimmed_size = h.skimmed ? h.bytes : 0;
    given_slot_ = slot;
    log_time_ns = h.log_time_ns;
  } else {
    return inner_state_;  // end, truncated or error, after every message before it
  }
  if (have_given_ && log_time_ns < last_given_ns_) {
    ++late_;
  } else {
    last_given_ns_ = log_time_ns;
  }
  have_given_ = true;
  return McapNext::message;
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
  if (window_bytes_ > 0) return late_;
  return format_ == BagFormat::rosbag ? rosbag_.out_of_order() : mcap_.out_of_order();
}
std::size_t BagReader::bytes_reserved() const {
  std::size_t window = 0;
  if (window_bytes_ > 0) {
    window = (window_bytes_ + 15) / 16 * 16 +
             static_cast<std::size_t>(slots_) * (sizeof(Held) + sizeof(int));
  }
  return window +
         (format_ == BagFormat::rosbag ? rosbag_.bytes_reserved() : mcap_.bytes_reserved());
}

}  // namespace octofuse::replay
