#include "octofuse/ports/v4l2/v4l2_source.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/mman.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <new>

#include "octofuse/core/result.hpp"

namespace octofuse::ports {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kMinBuffers = 3;  // one held by the caller, two queued for capture

const char* errno_name(int error) {
  switch (error) {
    case EAGAIN:
      return "EAGAIN";
    case EINTR:
      return "EINTR";
    case EIO:
      return "EIO";
    case ENODEV:
      return "ENODEV";
    case ENOENT:
      return "ENOENT";
    case ENXIO:
      return "ENXIO";
    case EACCES:
      return "EACCES";
    case EBUSY:
      return "EBUSY";
    case EINVAL:
      return "EINVAL";
    case ENOTTY:
      return "ENOTTY";
    case ENOMEM:
      return "ENOMEM";
    case EPIPE:
      return "EPIPE";
    default:
      return "errno";
  }
}

std::int64_t timeval_us(const timeval& t) {
  return static_cast<std::int64_t>(t.tv_sec) * 1000000 + static_cast<std::int64_t>(t.tv_usec);
}

}  // namespace

void v4l2_fourcc_text(std::uint32_t fourcc, char* text) {
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((fourcc >> (8 * i)) & 0xffu);
    text[i] = (c >= 32 && c < 127) ? c : '?';
  }
  text[4] = '\0';
}

V4l2Source::V4l2Source(const char* device_path, const V4l2Options& options, V4l2Syscalls& syscalls)
    : sys_(syscalls), options_(options) {
  const std::size_t length = device_path != nullptr ? std::strlen(device_path) : 0;
  path_too_long_ = length > kMaxPathLength;
  if (device_path != nullptr && !path_too_long_) std::memcpy(path_, device_path, length + 1);
}

V4l2Source::~V4l2Source() {
  close();
}

SourceCapabilities V4l2Source::capabilities() const {
  SourceCapabilities caps;
  caps.live = true;
  caps.has_ground_truth = false;
  caps.ring_size = buffer_count_ >= kMinBuffers ? buffer_count_ - 2 : 1;
  caps.nominal_rate_hz = nominal_rate_hz_;
  return caps;
}

int V4l2Source::ioctl_retry(unsigned long request, void* arg) {
  int result;
  do {
    result = sys_.ioctl(fd_, request, arg);
  } while (result < 0 && errno == EINTR);
  return result;
}

Status V4l2Source::fail_open(Status status) {
  teardown(true);
  return status;
}

Status V4l2Source::open() {
  if (fd_ >= 0) {
    error_.set("%s: already open", path_);
    return StatusCode::failed_precondition;
  }
  error_.clear();
  if (path_too_long_ || path_[0] == '\0') {
    error_.set("v4l2: device path is empty or longer than %zu characters", kMaxPathLength);
    return StatusCode::invalid_argument;
  }
  const V4l2Options& o = options_;
  if (o.buffer_count < kMinBuffers || o.buffer_count > kMaxBuffers || o.frame_timeout_ms <= 0 ||
      !(o.metres_per_unit > 0.0f) || !std::isfinite(o.metres_per_unit) || o.width < 0 ||
      o.height < 0 || (o.width == 0) != (o.height == 0) || !(o.fps >= 0.0f) ||
      !std::isfinite(o.fps) || !(o.horizontal_fov_deg > 0.0f && o.horizontal_fov_deg < 180.0f)) {
    error_.set(
        "%s: bad options (buffer_count %d..%d, timeout > 0, metres_per_unit > 0, both "
        "width and height or neither, fov in (0, 180) degrees)",
        path_, kMinBuffers, kMaxBuffers);
    return StatusCode::invalid_argument;
  }

  fd_ = sys_.open(path_, O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd_ < 0) {
    const int e = errno;
    fd_ = -1;
    error_.set("%s: cannot open (%s %d%s)", path_, errno_name(e), e,
               e == EACCES ? ": is the user in the 'video' group?" : "");
    return StatusCode::unavailable;
  }

  v4l2_capability cap{};
  if (ioctl_retry(VIDIOC_QUERYCAP, &cap) < 0) {
    const int e = errno;
    error_.set("%s: VIDIOC_QUERYCAP failed (%s): not a V4L2 device", path_, errno_name(e));
    return fail_open(e == ENODEV ? StatusCode::unavailable : StatusCode::invalid_argument);
  }
  const std::uint32_t caps =
      (cap.capabilities & V4L2_CAP_DEVICE_CAPS) != 0 ? cap.device_caps : cap.capabilities;
  if ((caps & V4L2_CAP_VIDEO_CAPTURE) == 0 || (caps & V4L2_CAP_STREAMING) == 0) {
    error_.set("%s: not a single-planar streaming capture device (caps 0x%08x)", path_, caps);
    return fail_open(StatusCode::invalid_argument);
  }

  OCTOFUSE_TRY(negotiate_format());
  OCTOFUSE_TRY(map_and_queue_buffers());

  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (ioctl_retry(VIDIOC_STREAMON, &type) < 0) {
    const int e = errno;
    error_.set("%s: VIDIOC_STREAMON failed (%s)", path_, errno_name(e));
    return fail_open(e == ENODEV ? StatusCode::unavailable : StatusCode::internal);
  }
  streaming_ = true;
  return ok_status();
}

void V4l2Source::describe_offered(char* text, std::size_t capacity) const {
  std::size_t used = 0;
  text[0] = '\0';
  for (int i = 0; i < offered_count_ && used + 8 < capacity; ++i) {
    char fourcc[5];
    v4l2_fourcc_text(offered_[i], fourcc);
    used += static_cast<std::size_t>(
        std::snprintf(text + used, capacity - used, "%s'%s'", i > 0 ? ", " : "", fourcc));
  }
  if (offered_count_ == 0) std::snprintf(text, capacity, "nothing");
}

Status V4l2Source::negotiate_format() {
  offered_count_ = 0;
  for (std::uint32_t index = 0; offered_count_ < kMaxOfferedFormats; ++index) {
    v4l2_fmtdesc desc{};
    desc.index = index;
    desc.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (ioctl_retry(VIDIOC_ENUM_FMT, &desc) < 0) {
      if (errno == ENODEV) {
        error_.set("%s: device vanished", path_);
        return fail_open(StatusCode::unavailable);
      }
      break;  // EINVAL ends the list
    }
    offered_[offered_count_++] = desc.pixelformat;
  }
  bool has_z16 = false;
  bool has_y16 = false;
  for (int i = 0; i < offered_count_; ++i) {
    has_z16 = has_z16 || offered_[i] == V4L2_PIX_FMT_Z16;
    has_y16 = has_y16 || offered_[i] == V4L2_PIX_FMT_Y16;
  }
  std::uint32_t wanted = 0;
  switch (options_.format) {
    case V4l2DepthFormat::any:
      wanted = has_z16 ? V4L2_PIX_FMT_Z16 : V4L2_PIX_FMT_Y16;
      break;
    case V4l2DepthFormat::z16:
      wanted = V4L2_PIX_FMT_Z16;
      break;
    case V4l2DepthFormat::y16:
      wanted = V4L2_PIX_FMT_Y16;
      break;
  }
  char offered_text[160];
  describe_offered(offered_text, sizeof(offered_text));
  char wanted_text[5];
  v4l2_fourcc_text(wanted, wanted_text);
  if ((wanted == V4L2_PIX_FMT_Z16 && !has_z16) || (wanted == V4L2_PIX_FMT_Y16 && !has_y16)) {
    error_.set("%s: no '%s' depth format; the device offers %s", path_, wanted_text, offered_text);
    return fail_open(StatusCode::invalid_argument);
  }

  v4l2_format format{};
  format.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (ioctl_retry(VIDIOC_G_FMT, &format) < 0) {
    const int e = errno;
    error_.set("%s: VIDIOC_G_FMT failed (%s)", path_, errno_name(e));
    return fail_open(e == ENODEV ? StatusCode::unavailable : StatusCode::internal);
  }
  format.fmt.pix.pixelformat = wanted;
  format.fmt.pix.field = V4L2_FIELD_NONE;
  if (options_.width > 0) {
    format.fmt.pix.width = static_cast<std::uint32_t>(options_.width);
    format.fmt.pix.height = static_cast<std::uint32_t>(options_.height);
  }
  format.fmt.pix.bytesperline = 0;  // let the driver choose the padding
  if (ioctl_retry(VIDIOC_S_FMT, &format) < 0) {
    const int e = errno;
    error_.set("%s: VIDIOC_S_FMT '%s' refused (%s); the device offers %s", path_, wanted_text,
               errno_name(e), offered_text);
    return fail_open(e == ENODEV ? StatusCode::unavailable : StatusCode::invalid_argument);
  }
  const v4l2_pix_format& pix = format.fmt.pix;
  if (pix.pixelformat != wanted) {
    char given[5];
    v4l2_fourcc_text(pix.pixelformat, given);
    error_.set("%s: asked for '%s', the device gives '%s'; it offers %s", path_, wanted_text, given,
               offered_text);
    return fail_open(StatusCode::invalid_argument);
  }
  if (options_.width > 0 && (static_cast<int>(pix.width) != options_.width ||
                             static_cast<int>(pix.height) != options_.height)) {
    error_.set("%s: asked for %dx%d '%s', the device gives %ux%u", path_, options_.width,
               options_.height, wanted_text, pix.width, pix.height);
    return fail_open(StatusCode::invalid_argument);
  }
  const std::size_t row_bytes = static_cast<std::size_t>(pix.width) * 2u;
  const std::size_t stride = pix.bytesperline != 0 ? pix.bytesperline : row_bytes;
  if (pix.width == 0 || pix.height == 0 || pix.width > 16384 || pix.height > 16384 ||
      stride < row_bytes || stride % 2 != 0 ||
      (pix.sizeimage != 0 && pix.sizeimage < stride * pix.height)) {
    error_.set("%s: driver reports an inconsistent format (%ux%u, %u bytes per line, %u bytes)",
               path_, pix.width, pix.height, pix.bytesperline, pix.sizeimage);
    return fail_open(StatusCode::internal);
  }
  pixel_format_ = wanted;
  width_ = static_cast<int>(pix.width);
  height_ = static_cast<int>(pix.height);
  stride_bytes_ = stride;

  // Frame rate: optional for drivers; one that cannot set it keeps its own.
  v4l2_streamparm parm{};
  parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (options_.fps > 0.0f) {
    parm.parm.capture.timeperframe.numerator = 1000;
    parm.parm.capture.timeperframe.denominator =
        static_cast<std::uint32_t>(std::lround(options_.fps * 1000.0f));
    if (ioctl_retry(VIDIOC_S_PARM, &parm) < 0 && errno == ENODEV) {
      error_.set("%s: device vanished", path_);
      return fail_open(StatusCode::unavailable);
    }
  }
  parm = v4l2_streamparm{};
  parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  nominal_rate_hz_ = options_.fps > 0.0f ? options_.fps : 30.0f;
  if (ioctl_retry(VIDIOC_G_PARM, &parm) == 0 && parm.parm.capture.timeperframe.numerator != 0 &&
      parm.parm.capture.timeperframe.denominator != 0) {
    nominal_rate_hz_ = static_cast<float>(parm.parm.capture.timeperframe.denominator) /
                       static_cast<float>(parm.parm.capture.timeperframe.numerator);
  }

  if (options_.intrinsics.valid()) {
    if (options_.intrinsics.width != width_ || options_.intrinsics.height != height_) {
      error_.set("%s: intrinsics are for %dx%d, the device gives %dx%d", path_,
                 options_.intrinsics.width, options_.intrinsics.height, width_, height_);
      return fail_open(StatusCode::invalid_argument);
    }
    intrinsics_ = options_.intrinsics;
  } else {
    const double half_fov_rad =
        0.5 * static_cast<double>(options_.horizontal_fov_deg) * kPi / 180.0;
    const float f = static_cast<float>(0.5 * width_ / std::tan(half_fov_rad));
    intrinsics_.fx = f;
    intrinsics_.fy = f;
    intrinsics_.cx = 0.5f * static_cast<float>(width_ - 1);
    intrinsics_.cy = 0.5f * static_cast<float>(height_ - 1);
    intrinsics_.width = width_;
    intrinsics_.height = height_;
  }
  return ok_status();
}

Status V4l2Source::map_and_queue_buffers() {
  v4l2_requestbuffers request{};
  request.count = static_cast<std::uint32_t>(options_.buffer_count);
  request.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  request.memory = V4L2_MEMORY_MMAP;
  if (ioctl_retry(VIDIOC_REQBUFS, &request) < 0) {
    const int e = errno;
    error_.set("%s: VIDIOC_REQBUFS failed (%s): no mmap streaming", path_, errno_name(e));
    return fail_open(e == ENODEV ? StatusCode::unavailable : StatusCode::invalid_argument);
  }
  // The driver may give fewer or more than asked; record them first so teardown releases them.
  buffer_count_ = static_cast<int>(request.count);
  if (request.count < static_cast<std::uint32_t>(kMinBuffers) ||
      request.count > static_cast<std::uint32_t>(kMaxBuffers)) {
    error_.set("%s: the driver gives %u buffers, the port needs %d..%d", path_, request.count,
               kMinBuffers, kMaxBuffers);
    buffer_count_ = buffer_count_ > kMaxBuffers ? 0 : buffer_count_;
    return fail_open(StatusCode::resource_exhausted);
  }
  for (int i = 0; i < buffer_count_; ++i) {
    v4l2_buffer buffer{};
    buffer.index = static_cast<std::uint32_t>(i);
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    if (ioctl_retry(VIDIOC_QUERYBUF, &buffer) < 0) {
      const int e = errno;
      error_.set("%s: VIDIOC_QUERYBUF %d failed (%s)", path_, i, errno_name(e));
      return fail_open(e == ENODEV ? StatusCode::unavailable : StatusCode::internal);
    }
    if (buffer.length < stride_bytes_ * static_cast<std::size_t>(height_)) {
      error_.set("%s: buffer %d holds %u bytes, a frame needs %zu", path_, i, buffer.length,
                 stride_bytes_ * static_cast<std::size_t>(height_));
      return fail_open(StatusCode::internal);
    }
    void* address = sys_.mmap(buffer.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_,
                              static_cast<off_t>(buffer.m.offset));
    if (address == MAP_FAILED) {
      const int e = errno;
      error_.set("%s: mmap of buffer %d failed (%s)", path_, i, errno_name(e));
      return fail_open(e == ENODEV ? StatusCode::unavailable : StatusCode::resource_exhausted);
    }
    mappings_[i].address = address;
    mappings_[i].length = buffer.length;
  }
  for (int i = 0; i < buffer_count_; ++i) {
    const Status queued = requeue(static_cast<std::uint32_t>(i));
    if (!queued.ok()) return fail_open(queued);
  }
  held_head_ = 0;
  held_count_ = 0;
  return ok_status();
}

Status V4l2Source::requeue(std::uint32_t index) {
  v4l2_buffer buffer{};
  buffer.index = index;
  buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buffer.memory = V4L2_MEMORY_MMAP;
  if (ioctl_retry(VIDIOC_QBUF, &buffer) < 0) {
    const int e = errno;
    error_.set("%s: VIDIOC_QBUF %u failed (%s)", path_, index, errno_name(e));
    return e == ENODEV ? StatusCode::unavailable : StatusCode::internal;
  }
  return ok_status();
}

NextFrame V4l2Source::fail_next(Status status) {
  if (status.code() == StatusCode::unavailable) teardown(false);
  return NextFrame::failed(status);
}

NextFrame V4l2Source::next(DepthFrame& frame) {
  if (fd_ < 0 || !streaming_) {
    error_.set("v4l2: next() before a successful open()");
    return NextFrame::failed(StatusCode::failed_precondition);
  }
  // The caller's ring is full: the oldest frame goes back to the driver.
  if (held_count_ >= buffer_count_ - 2) {
    const Status queued = requeue(held_[held_head_]);
    if (!queued.ok()) return fail_next(queued);
    held_head_ = (held_head_ + 1) % kMaxBuffers;
    --held_count_;
  }

  const std::int64_t deadline_us =
      sys_.monotonic_now_us() + static_cast<std::int64_t>(options_.frame_timeout_ms) * 1000;
  v4l2_buffer buffer{};
  for (;;) {
    buffer = v4l2_buffer{};
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    if (sys_.ioctl(fd_, VIDIOC_DQBUF, &buffer) == 0) break;
    const int e = errno;
    if (e == EINTR) continue;
    if (e == ENODEV) {
      error_.set("%s: device vanished (ENODEV); closed", path_);
      return fail_next(StatusCode::unavailable);
    }
    if (e == EIO) {
      // Transient per the V4L2 spec (e.g. signal loss); whether a buffer was dequeued is unknown,
      // so nothing is requeued here.
      error_.set("%s: VIDIOC_DQBUF: EIO (transient capture error)", path_);
      return NextFrame::skipped(StatusCode::data_loss);
    }
    if (e != EAGAIN) {
      error_.set("%s: VIDIOC_DQBUF failed (%s %d)", path_, errno_name(e), e);
      return fail_next(StatusCode::internal);
    }
    // Nothing ready: wait for the driver, at most until the deadline.
    const std::int64_t left_us = deadline_us - sys_.monotonic_now_us();
    if (left_us <= 0) {
      error_.set("%s: no frame within %d ms", path_, options_.frame_timeout_ms);
      return NextFrame::skipped(StatusCode::deadline_exceeded);
    }
    pollfd fds{};
    fds.fd = fd_;
    fds.events = POLLIN;
    const int ready = sys_.poll(&fds, 1, static_cast<int>((left_us + 999) / 1000));
    if (ready < 0) {
      if (errno == EINTR) continue;
      error_.set("%s: poll failed (%s)", path_, errno_name(errno));
      return fail_next(StatusCode::internal);
    }
    if (ready == 0) {
      error_.set("%s: no frame within %d ms", path_, options_.frame_timeout_ms);
      return NextFrame::skipped(StatusCode::deadline_exceeded);
    }
    if ((fds.revents & POLLIN) == 0 && (fds.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) {
      // Ask the driver why: a vanished device answers DQBUF with ENODEV.
      buffer = v4l2_buffer{};
      buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      buffer.memory = V4L2_MEMORY_MMAP;
      if (sys_.ioctl(fd_, VIDIOC_DQBUF, &buffer) == 0) break;
      const int why = errno;
      if (why == ENODEV) {
        error_.set("%s: device vanished (ENODEV); closed", path_);
        return fail_next(StatusCode::unavailable);
      }
      if (why == EINTR || why == EAGAIN) continue;
      error_.set("%s: poll reports an error (revents 0x%x, DQBUF %s)", path_, fds.revents,
                 errno_name(why));
      return fail_next(StatusCode::internal);
    }
  }

  if (buffer.index >= static_cast<std::uint32_t>(buffer_count_)) {
    error_.set("%s: driver returned buffer %u of %d", path_, buffer.index, buffer_count_);
    return fail_next(StatusCode::internal);
  }
  const std::size_t needed =
      stride_bytes_ * static_cast<std::size_t>(height_ - 1) + static_cast<std::size_t>(width_) * 2u;
  const bool flagged = (buffer.flags & V4L2_BUF_FLAG_ERROR) != 0;
  if (flagged || buffer.bytesused < needed) {
    if (flagged) {
      error_.set("%s: frame %u flagged as corrupt by the driver", path_, buffer.sequence);
    } else {
      error_.set("%s: frame %u is short: %u of %zu bytes", path_, buffer.sequence, buffer.bytesused,
                 needed);
    }
    const Status queued = requeue(buffer.index);
    if (!queued.ok()) return fail_next(queued);
    return NextFrame::skipped(StatusCode::data_loss);
  }

  held_[(held_head_ + held_count_) % kMaxBuffers] = buffer.index;
  ++held_count_;
  const bool monotonic =
      (buffer.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
  frame.depth_raw = ImageView<const std::uint16_t>(
      static_cast<const std::uint16_t*>(mappings_[buffer.index].address), width_, height_,
      static_cast<std::ptrdiff_t>(stride_bytes_ / 2u));
  frame.metres_per_unit = options_.metres_per_unit;
  frame.timestamp_us = monotonic ? timeval_us(buffer.timestamp) : sys_.monotonic_now_us();
  frame.sequence = buffer.sequence;
  frame.has_ground_truth = false;
  return NextFrame::got_frame();
}

void V4l2Source::teardown(bool device_alive) {
  if (fd_ >= 0 && device_alive) {
    if (streaming_) {
      int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      ioctl_retry(VIDIOC_STREAMOFF, &type);
    }
  }
  streaming_ = false;
  for (int i = 0; i < kMaxBuffers; ++i) {
    if (mappings_[i].address != nullptr) sys_.munmap(mappings_[i].address, mappings_[i].length);
    mappings_[i] = Mapping{};
  }
  if (fd_ >= 0 && device_alive && buffer_count_ > 0) {
    v4l2_requestbuffers release{};
    release.count = 0;
    release.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    release.memory = V4L2_MEMORY_MMAP;
    ioctl_retry(VIDIOC_REQBUFS, &release);
  }
  if (fd_ >= 0) sys_.close(fd_);
  fd_ = -1;
  buffer_count_ = 0;
  held_head_ = 0;
  held_count_ = 0;
}

void V4l2Source::close() {
  teardown(true);
}

std::unique_ptr<DepthSource> make_v4l2_source(const char* device_path, const V4l2Options& options) {
  return std::unique_ptr<DepthSource>(new (std::nothrow) V4l2Source(device_path, options));
}

}  // namespace octofuse::ports
