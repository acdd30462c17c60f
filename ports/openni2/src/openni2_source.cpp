#include "octofuse/ports/openni2/openni2_source.hpp"

#include <OniCAPI.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <new>

#include "octofuse/core/result.hpp"

namespace octofuse::ports {
namespace {

constexpr std::size_t kAlignPixels = 32;  // pool slots start on 64-byte boundaries

OniDeviceHandle as_device(void* handle) {
  return static_cast<OniDeviceHandle>(handle);
}
OniStreamHandle as_stream(void* handle) {
  return static_cast<OniStreamHandle>(handle);
}

const char* unit_name(int format) {
  switch (format) {
    case ONI_PIXEL_FORMAT_DEPTH_1_MM:
      return "1mm";
    case ONI_PIXEL_FORMAT_DEPTH_100_UM:
      return "100um";
    case ONI_PIXEL_FORMAT_SHIFT_9_2:
      return "shift9.2";
    case ONI_PIXEL_FORMAT_SHIFT_9_3:
      return "shift9.3";
    default:
      return "non-depth";
  }
}

void* pool_alloc_callback(int size, void* cookie) {
  return static_cast<OpenNi2Source*>(cookie)->pool_acquire(size);
}
void pool_free_callback(void* data, void* cookie) {
  static_cast<OpenNi2Source*>(cookie)->pool_release(data);
}

}  // namespace

bool openni2_uri_is_recording(const char* uri) {
  if (uri == nullptr) return false;
  const std::size_t length = std::strlen(uri);
  if (length < 4) return false;
  const char* tail = uri + length - 4;
  return tail[0] == '.' && (tail[1] == 'o' || tail[1] == 'O') &&
         (tail[2] == 'n' || tail[2] == 'N') && (tail[3] == 'i' || tail[3] == 'I');
}

OpenNi2Source::OpenNi2Source(const OpenNi2Options& options) : options_(options) {
  const std::size_t length = options.uri != nullptr ? std::strlen(options.uri) : 0;
  uri_too_long_ = length > kMaxUriLength;
  if (length > 0 && !uri_too_long_) std::memcpy(uri_, options.uri, length + 1);
  options_.uri = nullptr;  // the copy in uri_ is the one used
}

OpenNi2Source::~OpenNi2Source() {
  teardown();
}

SourceCapabilities OpenNi2Source::capabilities() const {
  SourceCapabilities caps;
  caps.live = !playback_;
  caps.has_ground_truth = false;
  caps.ring_size = options_.ring_size;
  caps.nominal_rate_hz = rate_hz_;
  return caps;
}

void* OpenNi2Source::pool_acquire(int size) {
  if (size <= 0 || static_cast<std::size_t>(size) > pool_slot_bytes_ || !memory_) return nullptr;
  for (int i = 0; i < kPoolBuffers; ++i) {
    bool expected = false;
    if (pool_used_[i].compare_exchange_strong(expected, true)) {
      const std::size_t slot_pixels = pool_slot_bytes_ / sizeof(std::uint16_t);
      return memory_.get() + static_cast<std::size_t>(options_.ring_size) * frame_pixels_ +
             static_cast<std::size_t>(i) * slot_pixels;
    }
  }
  return nullptr;  // OpenNI2 drops the frame; the sequence numbers show the gap
}

void OpenNi2Source::pool_release(void* buffer) {
  if (!memory_ || buffer == nullptr) return;
  const std::size_t slot_pixels = pool_slot_bytes_ / sizeof(std::uint16_t);
  const std::uint16_t* first =
      memory_.get() + static_cast<std::size_t>(options_.ring_size) * frame_pixels_;
  const auto offset = static_cast<std::size_t>(static_cast<const std::uint16_t*>(buffer) - first);
  const std::size_t index = offset / slot_pixels;
  if (index < static_cast<std::size_t>(kPoolBuffers)) pool_used_[index].store(false);
}

Status OpenNi2Source::fail_open(Status status) {
  teardown();
  return status;
}

Status OpenNi2Source::open() {
  if (initialized_) {
    error_.set("openni2: already open");
    return StatusCode::failed_precondition;
  }
  error_.clear();
  const OpenNi2Options& o = options_;
  if (uri_too_long_ || o.ring_size < 1 || o.ring_size > kMaxRing || o.frame_timeout_ms <= 0 ||
      o.width < 0 || o.height < 0 || o.fps < 0 ||
      ((o.width == 0) != (o.height == 0) || (o.width == 0) != (o.fps == 0))) {
    error_.set(
        "openni2: bad options (uri up to %zu characters, ring_size 1..%d, timeout > 0, "
        "width, height and fps all set or all 0)",
        kMaxUriLength, kMaxRing);
    return StatusCode::invalid_argument;
  }
  playback_ = openni2_uri_is_recording(uri_);

  if (oniInitialize(ONI_API_VERSION) != ONI_STATUS_OK) {
    error_.set("openni2: initialisation failed: %s", oniGetExtendedError());
    oniShutdown();  // OpenNI2 counts initialisations, failed ones too
    return StatusCode::unavailable;
  }
  initialized_ = true;

  OniDeviceHandle device = nullptr;
  if (oniDeviceOpen(uri_[0] != '\0' ? uri_ : nullptr, &device) != ONI_STATUS_OK) {
    error_.set("openni2: cannot open %s: %s", uri_[0] != '\0' ? uri_ : "the first device",
               oniGetExtendedError());
    return fail_open(StatusCode::unavailable);
  }
  device_ = device;

  if (oniDeviceGetSensorInfo(device, ONI_SENSOR_DEPTH) == nullptr) {
    error_.set("openni2: %s has no depth sensor", uri_[0] != '\0' ? uri_ : "the device");
    return fail_open(StatusCode::invalid_argument);
  }
  if (!playback_) {
    const OniImageRegistrationMode mode =
        o.registration ? ONI_IMAGE_REGISTRATION_DEPTH_TO_COLOR : ONI_IMAGE_REGISTRATION_OFF;
    if (o.registration && !oniDeviceIsImageRegistrationModeSupported(device, mode)) {
      error_.set("openni2: the device does not support depth-to-colour registration");
      return fail_open(StatusCode::invalid_argument);
    }
    if (oniDeviceIsPropertySupported(device, ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION) &&
        oniDeviceSetProperty(device, ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION, &mode, sizeof(mode)) !=
            ONI_STATUS_OK &&
        o.registration) {
      error_.set("openni2: switching registration on failed: %s", oniGetExtendedError());
      return fail_open(StatusCode::invalid_argument);
    }
  }

  OniStreamHandle stream = nullptr;
  if (oniDeviceCreateStream(device, ONI_SENSOR_DEPTH, &stream) != ONI_STATUS_OK) {
    error_.set("openni2: cannot create the depth stream: %s", oniGetExtendedError());
    return fail_open(StatusCode::unavailable);
  }
  stream_ = stream;
  OCTOFUSE_TRY(select_mode());

  float hfov_rad = 0.0f;
  float vfov_rad = 0.0f;
  int size = sizeof(float);
  const bool have_h = oniStreamGetProperty(stream, ONI_STREAM_PROPERTY_HORIZONTAL_FOV, &hfov_rad,
                                           &size) == ONI_STATUS_OK;
  size = sizeof(float);
  const bool have_v = oniStreamGetProperty(stream, ONI_STREAM_PROPERTY_VERTICAL_FOV, &vfov_rad,
                                           &size) == ONI_STATUS_OK;
  if (!have_h || !have_v || !(hfov_rad > 0.0f && hfov_rad < 3.1f) ||
      !(vfov_rad > 0.0f && vfov_rad < 3.1f)) {
    error_.set("openni2: the depth stream reports no usable field of view (%g, %g rad)",
               static_cast<double>(hfov_rad), static_cast<double>(vfov_rad));
    return fail_open(StatusCode::data_loss);
  }
  intrinsics_.width = width_;
  intrinsics_.height = height_;
  intrinsics_.fx = static_cast<float>(width_ / (2.0 * std::tan(0.5 * hfov_rad)));
  intrinsics_.fy = static_cast<float>(height_ / (2.0 * std::tan(0.5 * vfov_rad)));
  intrinsics_.cx = 0.5f * static_cast<float>(width_);
  intrinsics_.cy = 0.5f * static_cast<float>(height_);

  if (playback_) {
    // Manual speed: a frame becomes available when the previous one was read, so none is
    // dropped; no repeat, so the recording ends.
    const float manual_speed = -1.0f;
    const OniBool repeat = FALSE;
    if (oniDeviceSetProperty(device, ONI_DEVICE_PROPERTY_PLAYBACK_SPEED, &manual_speed,
                             sizeof(manual_speed)) != ONI_STATUS_OK ||
        oniDeviceSetProperty(device, ONI_DEVICE_PROPERTY_PLAYBACK_REPEAT_ENABLED, &repeat,
                             sizeof(repeat)) != ONI_STATUS_OK) {
      error_.set("openni2: %s: cannot set up playback: %s", uri_, oniGetExtendedError());
      return fail_open(StatusCode::data_loss);
    }
    size = sizeof(int);
    recorded_frames_ = 0;
    if (oniStreamGetProperty(stream, ONI_STREAM_PROPERTY_NUMBER_OF_FRAMES, &recorded_frames_,
                             &size) != ONI_STATUS_OK ||
        recorded_frames_ < 0) {
      recorded_frames_ = 0;  // unknown: the end shows as a timeout
    }
  }

  // The ring and OpenNI2's frame buffers: one allocation, here.
  frame_pixels_ =
      (static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_) + kAlignPixels - 1) /
      kAlignPixels * kAlignPixels;
  pool_slot_bytes_ = frame_pixels_ * sizeof(std::uint16_t);
  const std::size_t total = frame_pixels_ * static_cast<std::size_t>(o.ring_size + kPoolBuffers);
  memory_.reset(new (std::nothrow) std::uint16_t[total]);
  if (!memory_) {
    error_.set("openni2: cannot reserve %zu bytes for frames", total * sizeof(std::uint16_t));
    return fail_open(StatusCode::resource_exhausted);
  }
  for (auto& used : pool_used_) used.store(false);
  if (oniStreamSetFrameBuffersAllocator(stream, pool_alloc_callback, pool_free_callback, this) !=
      ONI_STATUS_OK) {
    error_.set("openni2: cannot install the frame buffer pool: %s", oniGetExtendedError());
    return fail_open(StatusCode::internal);
  }
  if (oniStreamStart(stream) != ONI_STATUS_OK) {
    error_.set("openni2: cannot start the depth stream: %s", oniGetExtendedError());
    return fail_open(StatusCode::unavailable);
  }
  started_ = true;
  frames_read_ = 0;
  ring_next_ = 0;
  return ok_status();
}

Status OpenNi2Source::select_mode() {
  OniStreamHandle stream = as_stream(stream_);
  OniVideoMode mode{};
  int size = sizeof(mode);
  if (oniStreamGetProperty(stream, ONI_STREAM_PROPERTY_VIDEO_MODE, &mode, &size) != ONI_STATUS_OK) {
    error_.set("openni2: cannot read the depth video mode: %s", oniGetExtendedError());
    return fail_open(StatusCode::internal);
  }
  if (!playback_ && options_.width > 0) {
    const int wanted_format = options_.units == OpenNi2DepthUnits::millimetre
                                  ? ONI_PIXEL_FORMAT_DEPTH_1_MM
                                  : ONI_PIXEL_FORMAT_DEPTH_100_UM;
    const OniSensorInfo* info = oniStreamGetSensorInfo(stream);
    const OniVideoMode* found = nullptr;
    char listed[ErrorText::kCapacity - 96] = {};
    std::size_t used = 0;
    for (int i = 0; info != nullptr && i < info->numSupportedVideoModes; ++i) {
      const OniVideoMode& m = info->pSupportedVideoModes[i];
      if (m.resolutionX == options_.width && m.resolutionY == options_.height &&
          m.fps == options_.fps && static_cast<int>(m.pixelFormat) == wanted_format) {
        found = &m;
      }
      if (used + 32 < sizeof(listed)) {
        used += static_cast<std::size_t>(
            std::snprintf(listed + used, sizeof(listed) - used, "%s%dx%d@%d %s", i > 0 ? ", " : "",
                          m.resolutionX, m.resolutionY, m.fps, unit_name(m.pixelFormat)));
      }
    }
    if (found == nullptr) {
      error_.set("openni2: no depth mode %dx%d@%d %s; the device lists %s", options_.width,
                 options_.height, options_.fps, unit_name(wanted_format), listed);
      return fail_open(StatusCode::invalid_argument);
    }
    mode = *found;
    if (oniStreamSetProperty(stream, ONI_STREAM_PROPERTY_VIDEO_MODE, &mode, sizeof(mode)) !=
        ONI_STATUS_OK) {
      error_.set("openni2: the device refused mode %dx%d@%d: %s", mode.resolutionX,
                 mode.resolutionY, mode.fps, oniGetExtendedError());
      return fail_open(StatusCode::invalid_argument);
    }
    size = sizeof(mode);
    if (oniStreamGetProperty(stream, ONI_STREAM_PROPERTY_VIDEO_MODE, &mode, &size) !=
        ONI_STATUS_OK) {
      error_.set("openni2: cannot read the depth video mode: %s", oniGetExtendedError());
      return fail_open(StatusCode::internal);
    }
  }
  if (mode.pixelFormat == ONI_PIXEL_FORMAT_DEPTH_1_MM) {
    metres_per_unit_ = 0.001f;
  } else if (mode.pixelFormat == ONI_PIXEL_FORMAT_DEPTH_100_UM) {
    metres_per_unit_ = 0.0001f;
  } else {
    error_.set("openni2: depth stream delivers %s pixels, not metric depth",
               unit_name(mode.pixelFormat));
    return fail_open(StatusCode::invalid_argument);
  }
  if (mode.resolutionX <= 0 || mode.resolutionY <= 0 || mode.resolutionX > 16384 ||
      mode.resolutionY > 16384) {
    error_.set("openni2: depth stream reports size %dx%d", mode.resolutionX, mode.resolutionY);
    return fail_open(StatusCode::data_loss);
  }
  width_ = mode.resolutionX;
  height_ = mode.resolutionY;
  rate_hz_ = mode.fps > 0 ? static_cast<float>(mode.fps) : 30.0f;
  return ok_status();
}

NextFrame OpenNi2Source::next(DepthFrame& frame) {
  if (!started_) {
    error_.set("openni2: next() before a successful open()");
    return NextFrame::failed(StatusCode::failed_precondition);
  }
  if (playback_ && recorded_frames_ > 0 && frames_read_ >= recorded_frames_) {
    return NextFrame::ended();
  }
  OniStreamHandle stream = as_stream(stream_);
  int ready_index = -1;
  const OniStatus waited = oniWaitForAnyStream(&stream, 1, &ready_index, options_.frame_timeout_ms);
  if (waited == ONI_STATUS_TIME_OUT) {
    if (playback_) return NextFrame::ended();
    error_.set("openni2: no depth frame within %d ms", options_.frame_timeout_ms);
    return NextFrame::skipped(StatusCode::deadline_exceeded);
  }
  if (waited != ONI_STATUS_OK) {
    error_.set("openni2: waiting for a frame failed: %s", oniGetExtendedError());
    return NextFrame::failed(StatusCode::unavailable);
  }
  OniFrame* oni_frame = nullptr;
  if (oniStreamReadFrame(stream, &oni_frame) != ONI_STATUS_OK || oni_frame == nullptr) {
    error_.set("openni2: reading a frame failed: %s", oniGetExtendedError());
    return NextFrame::failed(StatusCode::unavailable);
  }
  const std::size_t row_bytes = static_cast<std::size_t>(width_) * sizeof(std::uint16_t);
  const std::size_t stride =
      oni_frame->stride > 0 ? static_cast<std::size_t>(oni_frame->stride) : row_bytes;
  if (oni_frame->width != width_ || oni_frame->height != height_ || oni_frame->data == nullptr ||
      stride < row_bytes || oni_frame->dataSize < 0 ||
      static_cast<std::size_t>(oni_frame->dataSize) <
          stride * static_cast<std::size_t>(height_ - 1) + row_bytes) {
    error_.set("openni2: frame %d is %dx%d with %d bytes, expected %dx%d", oni_frame->frameIndex,
               oni_frame->width, oni_frame->height, oni_frame->dataSize, width_, height_);
    oniFrameRelease(oni_frame);
    ++frames_read_;
    return NextFrame::skipped(StatusCode::data_loss);
  }
  std::uint16_t* slot = memory_.get() + static_cast<std::size_t>(ring_next_) * frame_pixels_;
  ring_next_ = (ring_next_ + 1) % options_.ring_size;
  const auto* source = static_cast<const unsigned char*>(oni_frame->data);
  for (int y = 0; y < height_; ++y) {
    std::memcpy(slot + static_cast<std::size_t>(y) * static_cast<std::size_t>(width_),
                source + static_cast<std::size_t>(y) * stride, row_bytes);
  }
  frame.depth_raw = ImageView<const std::uint16_t>(slot, width_, height_);
  frame.metres_per_unit = metres_per_unit_;
  frame.timestamp_us = static_cast<std::int64_t>(oni_frame->timestamp);
  frame.sequence = static_cast<std::uint64_t>(oni_frame->frameIndex);
  frame.has_ground_truth = false;
  oniFrameRelease(oni_frame);
  ++frames_read_;
  return NextFrame::got_frame();
}

void OpenNi2Source::teardown() {
  if (stream_ != nullptr) {
    if (started_) oniStreamStop(as_stream(stream_));
    oniStreamDestroy(as_stream(stream_));  // returns every pooled buffer
  }
  stream_ = nullptr;
  started_ = false;
  if (device_ != nullptr) oniDeviceClose(as_device(device_));
  device_ = nullptr;
  if (initialized_) oniShutdown();
  initialized_ = false;
  memory_.reset();
}

void OpenNi2Source::close() {
  teardown();
}

std::unique_ptr<DepthSource> make_openni2_source(const OpenNi2Options& options) {
  return std::unique_ptr<DepthSource>(new (std::nothrow) OpenNi2Source(options));
}

}  // namespace octofuse::ports
