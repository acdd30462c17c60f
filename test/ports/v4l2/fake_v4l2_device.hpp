#pragma once
// A small stand-in for a V4L2 capture driver (videobuf2 semantics as the kernel documents them):
// formats are adjusted, never refused, by S_FMT; buffers cycle idle -> queued (QBUF) -> done
// (captured) -> dequeued (DQBUF) in FIFO order; DQBUF on a non-blocking fd with nothing done
// gives EAGAIN; a disconnected device answers ioctls and mmap with ENODEV and poll with
// POLLERR | POLLHUP; REQBUFS 0 while buffers are mapped gives EBUSY. Errors can be injected
// (EINTR, EIO). All storage is fixed: the fake itself never allocates after construction.

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/mman.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <vector>

#include "octofuse/ports/v4l2/v4l2_source.hpp"

namespace octofuse::test {

class FakeV4l2Device final : public ports::V4l2Syscalls {
 public:
  static constexpr int kFd = 7;
  static constexpr int kMaxBuffers = 8;
  static constexpr const char* kPath = "/dev/video-fake";
  static constexpr std::int64_t kFramePeriod_us = 33333;

  enum class State : std::uint8_t { idle, queued, done, dequeued };

  struct Size {
    std::uint32_t width;
    std::uint32_t height;
  };

  // Configuration (set before open()).
  std::vector<std::uint32_t> formats{V4L2_PIX_FMT_YUYV, V4L2_PIX_FMT_Z16};
  std::vector<Size> sizes{{64, 48}, {32, 24}};
  std::uint32_t row_padding_bytes = 32;  // bytesperline = 2 * width + padding
  std::uint32_t min_buffers = 2;         // REQBUFS raises a smaller count to this
  bool monotonic_timestamps = true;

  // Injected failures, consumed by the next matching call.
  std::vector<int> dqbuf_errors;  // errno values for the next DQBUF calls
  std::vector<int> poll_errors;   // errno values for the next poll calls
  // poll() "waits" this many frame periods and captures a frame each time it is called with
  // nothing done; when 0, poll times out (the clock advances by the timeout).
  int frames_on_poll = 1000000;

  FakeV4l2Device() { storage_.resize(kMaxBuffers * kBufferBytes); }

  // Capture one frame into the oldest queued buffer: pixel (x, y) = base + x + y (mod 2^16).
  // Returns false when no buffer was queued (a dropped frame, as a driver would drop it).
  bool capture(std::uint16_t base, std::uint32_t bytesused_override = 0, bool flag_error = false) {
    now_us_ += kFramePeriod_us;
    ++sequence_;
    if (queued_count_ == 0) return false;
    const int index = queued_[queued_head_];
    queued_head_ = (queued_head_ + 1) % kMaxBuffers;
    --queued_count_;
    const std::uint32_t stride = bytes_per_line();
    std::uint8_t* data = &storage_[static_cast<std::size_t>(index) * kBufferBytes];
    for (std::uint32_t y = 0; y < format_.height; ++y) {
      // memcpy per pixel: the row start is not known to be 2-byte aligned for the compiler.
      std::uint8_t* row = data + y * stride;
      for (std::uint32_t x = 0; x < format_.width; ++x) {
        const auto value = static_cast<std::uint16_t>(base + x + y);
        std::memcpy(row + 2 * x, &value, sizeof(value));
      }
    }
    Buffer& b = buffers_[index];
    b.state = State::done;
    b.bytesused = bytesused_override != 0 ? bytesused_override : size_image();
    b.sequence = sequence_ - 1;
    b.timestamp_us = now_us_;
    b.error = flag_error;
    done_[(done_head_ + done_count_) % kMaxBuffers] = index;
    ++done_count_;
    return true;
  }

  void disconnect() { gone_ = true; }

  // Observations for tests.
  int open_count() const { return open_count_; }
  int mapped_count() const {
    int n = 0;
    for (int i = 0; i < kMaxBuffers; ++i) n += buffers_[i].mapped ? 1 : 0;
    return n;
  }
  int buffer_count() const { return buffer_count_; }
  bool streaming() const { return streaming_; }
  State state(int index) const { return buffers_[index].state; }
  int queued_count() const { return queued_count_; }
  std::int64_t now_us() const { return now_us_; }
  std::uint32_t bytes_per_line() const { return format_.width * 2 + row_padding_bytes; }
  std::uint32_t size_image() const { return bytes_per_line() * format_.height; }

  // V4l2Syscalls
  int open(const char* path, int flags) override {
    if (std::strcmp(path, kPath) != 0 || gone_) return fail(ENOENT);
    if ((flags & O_NONBLOCK) == 0) return fail(EINVAL);  // the fake only models non-blocking I/O
    ++open_count_;
    return kFd;
  }
  int close(int fd) override {
    if (fd != kFd || open_count_ == 0) return fail(EBADF);
    --open_count_;
    return 0;
  }
  void* mmap(std::size_t length, int prot, int flags, int fd, off_t offset) override {
    (void)prot;
    if (fd != kFd || (flags & MAP_SHARED) == 0) return fail_map(EINVAL);
    if (gone_) return fail_map(ENODEV);
    const auto index = static_cast<int>(offset / static_cast<off_t>(kBufferBytes));
    if (offset % static_cast<off_t>(kBufferBytes) != 0 || index >= buffer_count_ ||
        length > size_image())
      return fail_map(EINVAL);
    buffers_[index].mapped = true;
    return &storage_[static_cast<std::size_t>(index) * kBufferBytes];
  }
  int munmap(void* address, std::size_t length) override {
    (void)length;
    for (int i = 0; i < kMaxBuffers; ++i) {
      if (address == &storage_[static_cast<std::size_t>(i) * kBufferBytes]) {
        buffers_[i].mapped = false;
        return 0;
      }
    }
    return fail(EINVAL);
  }
  int poll(struct pollfd* fds, nfds_t count, int timeout_ms) override {
    if (count != 1 || fds[0].fd != kFd) return fail(EINVAL);
    if (!poll_errors.empty()) {
      const int e = poll_errors.front();
      poll_errors.erase(poll_errors.begin());
      return fail(e);
    }
    fds[0].revents = 0;
    if (gone_) {
      fds[0].revents = POLLERR | POLLHUP;
      return 1;
    }
    if (!streaming_ || (queued_count_ == 0 && done_count_ == 0)) {
      fds[0].revents = POLLERR;  // vb2: nothing can ever complete
      return 1;
    }
    if (done_count_ == 0 && frames_on_poll > 0) {
      --frames_on_poll;
      capture(static_cast<std::uint16_t>(1000 + sequence_));
    }
    if (done_count_ > 0) {
      fds[0].revents = POLLIN | POLLRDNORM;
      return 1;
    }
    now_us_ += static_cast<std::int64_t>(timeout_ms) * 1000;
    return 0;
  }
  std::int64_t monotonic_now_us() override { return now_us_; }

  int ioctl(int fd, unsigned long request, void* arg) override {
    if (fd != kFd || open_count_ == 0) return fail(EBADF);
    if (gone_) return fail(ENODEV);
    switch (request) {
      case VIDIOC_QUERYCAP: {
        auto* cap = static_cast<v4l2_capability*>(arg);
        *cap = v4l2_capability{};
        std::strcpy(reinterpret_cast<char*>(cap->driver), "fake");
        cap->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        cap->capabilities = cap->device_caps | V4L2_CAP_DEVICE_CAPS;
        return 0;
      }
      case VIDIOC_ENUM_FMT: {
        auto* desc = static_cast<v4l2_fmtdesc*>(arg);
        if (desc->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || desc->index >= formats.size())
          return fail(EINVAL);
        desc->pixelformat = formats[desc->index];
        return 0;
      }
      case VIDIOC_G_FMT: {
        auto* f = static_cast<v4l2_format*>(arg);
        if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return fail(EINVAL);
        fill_format(f->fmt.pix);
        return 0;
      }
      case VIDIOC_S_FMT: {
        auto* f = static_cast<v4l2_format*>(arg);
        if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return fail(EINVAL);
        if (buffer_count_ > 0) return fail(EBUSY);
        // Adjust, as drivers must: an unknown format becomes the first offered one, a size the
        // nearest supported one (by width).
        bool known = false;
        for (std::uint32_t fmt : formats) known = known || fmt == f->fmt.pix.pixelformat;
        format_.pixelformat = known ? f->fmt.pix.pixelformat : formats.front();
        Size best = sizes.front();
        for (const Size& s : sizes) {
          if (distance(s.width, f->fmt.pix.width) < distance(best.width, f->fmt.pix.width))
            best = s;
        }
        format_.width = best.width;
        format_.height = best.height;
        fill_format(f->fmt.pix);
        return 0;
      }
      case VIDIOC_S_PARM:
      case VIDIOC_G_PARM: {
        auto* p = static_cast<v4l2_streamparm*>(arg);
        if (p->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return fail(EINVAL);
        if (request == VIDIOC_S_PARM) time_per_frame_ = p->parm.capture.timeperframe;
        p->parm.capture = v4l2_captureparm{};
        p->parm.capture.capability = V4L2_CAP_TIMEPERFRAME;
        p->parm.capture.timeperframe = time_per_frame_;
        return 0;
      }
      case VIDIOC_REQBUFS: {
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        if (r->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || r->memory != V4L2_MEMORY_MMAP)
          return fail(EINVAL);
        if (streaming_ || mapped_count() > 0) return fail(EBUSY);
        std::uint32_t n = r->count;
        if (n > 0 && n < min_buffers) n = min_buffers;
        if (n > kMaxBuffers) n = kMaxBuffers;
        r->count = n;
        buffer_count_ = static_cast<int>(n);
        for (Buffer& b : buffers_) b = Buffer{};
        queued_count_ = done_count_ = 0;
        return 0;
      }
      case VIDIOC_QUERYBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (!valid_buffer_arg(*b)) return fail(EINVAL);
        b->length = size_image();
        b->m.offset = static_cast<std::uint32_t>(b->index * kBufferBytes);
        return 0;
      }
      case VIDIOC_QBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (!valid_buffer_arg(*b)) return fail(EINVAL);
        Buffer& buffer = buffers_[b->index];
        if (buffer.state == State::queued || buffer.state == State::done) return fail(EINVAL);
        buffer.state = State::queued;
        queued_[(queued_head_ + queued_count_) % kMaxBuffers] = static_cast<int>(b->index);
        ++queued_count_;
        return 0;
      }
      case VIDIOC_DQBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (b->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || b->memory != V4L2_MEMORY_MMAP)
          return fail(EINVAL);
        if (!dqbuf_errors.empty()) {
          const int e = dqbuf_errors.front();
          dqbuf_errors.erase(dqbuf_errors.begin());
          return fail(e);
        }
        if (!streaming_) return fail(EINVAL);
        if (done_count_ == 0) return fail(EAGAIN);
        const int index = done_[done_head_];
        done_head_ = (done_head_ + 1) % kMaxBuffers;
        --done_count_;
        Buffer& buffer = buffers_[index];
        buffer.state = State::dequeued;
        b->index = static_cast<std::uint32_t>(index);
        b->bytesused = buffer.bytesused;
        b->sequence = buffer.sequence;
        b->field = V4L2_FIELD_NONE;
        b->timestamp.tv_sec = static_cast<time_t>(buffer.timestamp_us / 1000000);
        b->timestamp.tv_usec = static_cast<suseconds_t>(buffer.timestamp_us % 1000000);
        b->flags = (monotonic_timestamps ? V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
                                         : V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN) |
                   (buffer.error ? V4L2_BUF_FLAG_ERROR : 0u);
        return 0;
      }
      case VIDIOC_STREAMON:
      case VIDIOC_STREAMOFF: {
        if (*static_cast<int*>(arg) != V4L2_BUF_TYPE_VIDEO_CAPTURE) return fail(EINVAL);
        if (request == VIDIOC_STREAMON) {
          if (buffer_count_ == 0) return fail(EINVAL);
          streaming_ = true;
        } else {
          // STREAMOFF returns every buffer to the application, dequeued or not.
          streaming_ = false;
          for (int i = 0; i < buffer_count_; ++i) buffers_[i].state = State::idle;
          queued_count_ = done_count_ = 0;
        }
        return 0;
      }
      default:
        return fail(ENOTTY);
    }
  }

 private:
  static constexpr std::size_t kBufferBytes = 8192 * 2;  // page aligned, >= largest size_image()

  struct Buffer {
    State state = State::idle;
    bool mapped = false;
    bool error = false;
    std::uint32_t bytesused = 0;
    std::uint32_t sequence = 0;
    std::int64_t timestamp_us = 0;
  };

  static int fail(int error) {
    errno = error;
    return -1;
  }
  static void* fail_map(int error) {
    errno = error;
    return MAP_FAILED;
  }
  static std::uint32_t distance(std::uint32_t a, std::uint32_t b) { return a > b ? a - b : b - a; }
  bool valid_buffer_arg(const v4l2_buffer& b) const {
    return b.type == V4L2_BUF_TYPE_VIDEO_CAPTURE && b.memory == V4L2_MEMORY_MMAP &&
           b.index < static_cast<std::uint32_t>(buffer_count_);
  }
  void fill_format(v4l2_pix_format& pix) const {
    pix = v4l2_pix_format{};
    pix.width = format_.width;
    pix.height = format_.height;
    pix.pixelformat = format_.pixelformat;
    pix.field = V4L2_FIELD_NONE;
    pix.bytesperline = bytes_per_line();
    pix.sizeimage = size_image();
  }

  v4l2_pix_format format_{64, 48, V4L2_PIX_FMT_YUYV, V4L2_FIELD_NONE, 0, 0, 0, 0, 0, {0}, 0, 0};
  v4l2_fract time_per_frame_{1, 30};
  std::vector<std::uint8_t> storage_;
  Buffer buffers_[kMaxBuffers];
  int buffer_count_ = 0;
  int queued_[kMaxBuffers] = {};
  int queued_head_ = 0;
  int queued_count_ = 0;
  int done_[kMaxBuffers] = {};
  int done_head_ = 0;
  int done_count_ = 0;
  bool streaming_ = false;
  bool gone_ = false;
  int open_count_ = 0;
  std::uint32_t sequence_ = 0;
  std::int64_t now_us_ = 1000000;
};

}  // namespace octofuse::test
