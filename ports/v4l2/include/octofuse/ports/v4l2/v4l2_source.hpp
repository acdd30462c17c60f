#pragma once
// V4L2 depth cameras: memory-mapped streaming of 16-bit depth (V4L2_PIX_FMT_Z16, or Y16 with a
// configurable scale), single-planar capture only.
//
// Source spec (parsed by the programs, not here): `v4l2:/dev/videoN`, e.g.
//   octofuse::ports::V4l2Source camera("/dev/video2", octofuse::ports::V4l2Options{});
//
// Frames are views into the kernel's mmap'd buffers, not copies. Of the `buffer_count` buffers,
// the caller holds at most `buffer_count - 2` (capabilities().ring_size); the next() after that
// gives the oldest back to the driver, so at least two stay queued for capture.

#include <poll.h>
#include <sys/types.h>

#include <cstddef>
#include <cstdint>
#include <memory>

#include "octofuse/core/error_text.hpp"
#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::ports {

// The system calls the port makes, so that tests can stand in for the kernel. Same contracts as
// the POSIX functions: on failure -1 (MAP_FAILED for mmap) and errno set.
class V4l2Syscalls {
 public:
  virtual ~V4l2Syscalls() = default;
  virtual int open(const char* path, int flags) = 0;
  virtual int close(int fd) = 0;
  virtual int ioctl(int fd, unsigned long request, void* arg) = 0;
  virtual void* mmap(std::size_t length, int prot, int flags, int fd, off_t offset) = 0;
  virtual int munmap(void* address, std::size_t length) = 0;
  virtual int poll(struct pollfd* fds, nfds_t count, int timeout_ms) = 0;
  // CLOCK_MONOTONIC in microseconds (for drivers whose buffers carry no monotonic timestamp).
  virtual std::int64_t monotonic_now_us() = 0;
};

// The real calls (open(2), ioctl(2), ...); lives for the whole process.
V4l2Syscalls& system_v4l2_syscalls();

enum class V4l2DepthFormat : std::uint8_t {
  any,  // Z16 when the device offers it, else Y16
  z16,  // V4L2_PIX_FMT_Z16 ('Z16 '): depth in device units, 1 mm unless the device says otherwise
  y16,  // V4L2_PIX_FMT_Y16 ('Y16 '): 16-bit grey, used by some ToF modules for depth
};

struct V4l2Options {
  V4l2DepthFormat format = V4l2DepthFormat::any;
  int width = 0;     // 0 with height 0: keep the device's current size
  int height = 0;    // a size the device adjusts gives invalid_argument naming what it gives
  float fps = 0.0f;  // 0: keep the device's rate
  float metres_per_unit = 0.001f;  // scale of the raw values (Z16 is 1 mm by convention)
  int buffer_count = 4;            // kernel buffers, 3..V4l2Source::kMaxBuffers
  int frame_timeout_ms = 1000;     // next() waits at most this long for a frame
  // Used when valid() (its size must match the negotiated one); otherwise fx = fy from
  // horizontal_fov_deg and the principal point at the image centre (V4L2 has no intrinsics).
  PinholeCamera intrinsics;
  float horizontal_fov_deg = 87.0f;
};

class V4l2Source final : public DepthSource {
 public:
  static constexpr int kMaxBuffers = 16;
  static constexpr int kMaxOfferedFormats = 32;
  static constexpr std::size_t kMaxPathLength = 255;

  // `device_path` is copied; `syscalls` must outlive the source.
  V4l2Source(const char* device_path, const V4l2Options& options,
             V4l2Syscalls& syscalls = system_v4l2_syscalls());
  ~V4l2Source() override;
  V4l2Source(const V4l2Source&) = delete;
  V4l2Source& operator=(const V4l2Source&) = delete;

  // Opens the device, negotiates the format, maps and queues the buffers and starts streaming.
  // Returns ok; unavailable (no such device, permission denied, device gone); invalid_argument
  // (bad options, not a streaming capture device, no 16-bit depth format or a refused format or
  // size: last_error() names what the device offers); resource_exhausted (the driver gives fewer
  // than 3 or more than kMaxBuffers buffers); failed_precondition (already open); internal.
  Status open() override;

  // frame; skip with deadline_exceeded (no frame within frame_timeout_ms: the camera may resume)
  // or data_loss (a buffer flagged as an error, a short buffer, EIO); error with unavailable when
  // the device vanished (ENODEV: the source is already closed) or internal; error with
  // failed_precondition when not open. Never allocates.
  NextFrame next(DepthFrame& frame) override;

  // Stops streaming, unmaps and releases the buffers, closes the device. Safe to call twice.
  void close() override;

  PinholeCamera intrinsics() const override { return intrinsics_; }
  SourceCapabilities capabilities() const override;
  const char* last_error() const override { return error_.c_str(); }

  // After open(): the negotiated pixel format as a V4L2 fourcc and the buffers the driver gave.
  std::uint32_t pixel_format() const { return pixel_format_; }
  int buffer_count() const { return buffer_count_; }

 private:
  struct Mapping {
    void* address = nullptr;
    std::size_t length = 0;
  };

  Status fail_open(Status status);
  Status negotiate_format();
  Status map_and_queue_buffers();
  Status requeue(std::uint32_t index);
  NextFrame fail_next(Status status);
  void teardown(bool device_alive);
  int ioctl_retry(unsigned long request, void* arg);
  void describe_offered(char* text, std::size_t capacity) const;

  V4l2Syscalls& sys_;
  V4l2Options options_;
  char path_[kMaxPathLength + 1] = {};
  bool path_too_long_ = false;

  int fd_ = -1;
  bool streaming_ = false;
  std::uint32_t pixel_format_ = 0;
  int width_ = 0;
  int height_ = 0;
  std::size_t stride_bytes_ = 0;
  float nominal_rate_hz_ = 30.0f;
  PinholeCamera intrinsics_;

  std::uint32_t offered_[kMaxOfferedFormats] = {};
  int offered_count_ = 0;

  Mapping mappings_[kMaxBuffers] = {};
  int buffer_count_ = 0;
  // Buffers handed to the caller, oldest first (a FIFO over a fixed array).
  std::uint32_t held_[kMaxBuffers] = {};
  int held_head_ = 0;
  int held_count_ = 0;

  ErrorText error_;
};

// The same source behind the interface, for programs that pick a source at run time.
// Allocates once, here; nothing after open().
std::unique_ptr<DepthSource> make_v4l2_source(const char* device_path, const V4l2Options& options);

// "Z16 " from a fourcc, into `text` (at least 5 bytes); unprintable bytes become '?'.
void v4l2_fourcc_text(std::uint32_t fourcc, char* text);

}  // namespace octofuse::ports
