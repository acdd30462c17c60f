// libcamera glue. libcamera's headers build with -fno-exceptions -fno-rtti (libcamera itself is
// built that way), so this target keeps the strict flags. The code avoids building standard
// containers itself (they would pull in std::__throw_* helpers): libcamera returns the vectors,
// strings and smart pointers, the port only reads them.

#include <pthread.h>
#include <sys/mman.h>
#include <time.h>

#include <libcamera/camera.h>
#include <libcamera/camera_manager.h>
#include <libcamera/formats.h>
#include <libcamera/framebuffer.h>
#include <libcamera/framebuffer_allocator.h>
#include <libcamera/request.h>
#include <libcamera/stream.h>
#include <atomic>
#include <cmath>
#include <cstring>
#include <new>

#include "octofuse/core/result.hpp"
#include "octofuse/ports/libcamera/libcamera_source.hpp"

namespace octofuse::ports {
namespace {

constexpr double kPi = 3.14159265358979323846;

// libcamera allows one CameraManager per process.
std::atomic<bool> g_manager_in_use{false};

void on_request_completed(libcamera::Request* request);

libcamera::PixelFormat pixel_format_for(LibcameraPixelLayout layout) {
  switch (layout) {
    case LibcameraPixelLayout::r16:
      // DRM_FORMAT_R16; libcamera 0.0.x has no named constant for it yet.
      return libcamera::PixelFormat(static_cast<std::uint32_t>('R') | ('1' << 8) | ('6' << 16) |
                                    (static_cast<std::uint32_t>(' ') << 24));
    case LibcameraPixelLayout::r12:
      return libcamera::formats::R12;
    case LibcameraPixelLayout::r10:
      return libcamera::formats::R10;
    case LibcameraPixelLayout::r12_csi2p:
      // Named R12_CSI2P only from libcamera 0.1: fourcc 'R12 ' with the MIPI packing modifier.
      return libcamera::PixelFormat(libcamera::formats::R12.fourcc(),
                                    libcamera::formats::R10_CSI2P.modifier());
    case LibcameraPixelLayout::r10_csi2p:
      return libcamera::formats::R10_CSI2P;
  }
  return libcamera::PixelFormat();
}

}  // namespace

struct LibcameraSource::Impl {
  struct Mapping {
    void* address = nullptr;
    std::size_t length = 0;
    const std::uint8_t* plane = nullptr;
    std::size_t plane_length = 0;
  };

  Impl() {
    pthread_condattr_t attributes;
    pthread_condattr_init(&attributes);
    pthread_condattr_setclock(&attributes, CLOCK_MONOTONIC);
    pthread_cond_init(&completed_cond, &attributes);
    pthread_condattr_destroy(&attributes);
    pthread_mutex_init(&mutex, nullptr);
  }
  ~Impl() {
    pthread_cond_destroy(&completed_cond);
    pthread_mutex_destroy(&mutex);
  }

  // Runs on libcamera's thread.
  void push_completed(libcamera::Request* request) {
    pthread_mutex_lock(&mutex);
    if (completed_count < kMaxBuffers) {
      completed[(completed_head + completed_count) % kMaxBuffers] =
          static_cast<int>(request->cookie());
      ++completed_count;
    }
    pthread_cond_signal(&completed_cond);
    pthread_mutex_unlock(&mutex);
  }

  // The index of the next completed request, or -1 after `timeout_ms`.
  int wait_completed(int timeout_ms) {
    timespec deadline{};
    clock_gettime(CLOCK_MONOTONIC, &deadline);
    deadline.tv_sec += timeout_ms / 1000;
    deadline.tv_nsec += static_cast<long>(timeout_ms % 1000) * 1000000L;
    if (deadline.tv_nsec >= 1000000000L) {
      deadline.tv_sec += 1;
      deadline.tv_nsec -= 1000000000L;
    }
    pthread_mutex_lock(&mutex);
    int result = 0;
    while (completed_count == 0 && result == 0) {
      result = pthread_cond_timedwait(&completed_cond, &mutex, &deadline);
    }
    int index = -1;
    if (completed_count > 0) {
      index = completed[completed_head];
      completed_head = (completed_head + 1) % kMaxBuffers;
      --completed_count;
    }
    pthread_mutex_unlock(&mutex);
    return index;
  }

  std::unique_ptr<libcamera::CameraManager> manager;
  bool owns_manager_slot = false;
  std::shared_ptr<libcamera::Camera> camera;
  bool acquired = false;
  bool connected = false;
  bool started = false;
  std::unique_ptr<libcamera::CameraConfiguration> config;
  libcamera::Stream* stream = nullptr;
  std::unique_ptr<libcamera::FrameBufferAllocator> allocator;
  bool allocated = false;
  std::unique_ptr<libcamera::Request> requests[kMaxBuffers];
  libcamera::FrameBuffer* buffers[kMaxBuffers] = {};
  Mapping mappings[kMaxBuffers] = {};
  int buffer_count = 0;

  pthread_mutex_t mutex;
  pthread_cond_t completed_cond;
  int completed[kMaxBuffers] = {};
  int completed_head = 0;
  int completed_count = 0;

  std::unique_ptr<std::uint16_t[]> ring;
  std::size_t frame_pixels = 0;
  int ring_next = 0;
  int width = 0;
  int height = 0;
  std::size_t stride = 0;
};

namespace {

// The open source's state, for the completion callback. A plain function, not a member: libcamera
// binds members through a template that also builds a std::make_shared path for queued calls
// (and with it std::__throw_bad_alloc), a plain function is called directly. One source at a time
// is open (one CameraManager per process), so one pointer suffices.
std::atomic<LibcameraSource::Impl*> g_active{nullptr};

void on_request_completed(libcamera::Request* request) {
  LibcameraSource::Impl* active = g_active.load();
  if (active != nullptr) active->push_completed(request);
}

}  // namespace

LibcameraSource::LibcameraSource(const LibcameraOptions& options) : options_(options) {
  const std::size_t length = options.camera_id != nullptr ? std::strlen(options.camera_id) : 0;
  id_too_long_ = length > kMaxIdLength;
  if (length > 0 && !id_too_long_) std::memcpy(camera_id_, options.camera_id, length + 1);
  options_.camera_id = nullptr;  // camera_id_ is the copy in use
}

LibcameraSource::~LibcameraSource() {
  close();
}

SourceCapabilities LibcameraSource::capabilities() const {
  SourceCapabilities caps;
  caps.live = true;
  caps.has_ground_truth = false;
  caps.ring_size = options_.ring_size;
  caps.nominal_rate_hz = rate_hz_;
  return caps;
}

Status LibcameraSource::fail_open(Status status) {
  close();
  return status;
}

Status LibcameraSource::open() {
  if (impl_) {
    error_.set("libcamera: already open");
    return StatusCode::failed_precondition;
  }
  error_.clear();
  LibcameraOptions checked = options_;
  checked.camera_id = camera_id_;
  if (id_too_long_) {
    error_.set("libcamera: camera id longer than %zu characters", kMaxIdLength);
    return StatusCode::invalid_argument;
  }
  OCTOFUSE_TRY(validate_libcamera_options(checked, error_));

  impl_.reset(new (std::nothrow) Impl());
  if (!impl_) {
    error_.set("libcamera: out of memory");
    return StatusCode::resource_exhausted;
  }
  Impl& s = *impl_;
  bool expected = false;
  if (!g_manager_in_use.compare_exchange_strong(expected, true)) {
    error_.set("libcamera: another libcamera source is open in this process");
    return fail_open(StatusCode::unavailable);
  }
  s.owns_manager_slot = true;
  s.manager.reset(new (std::nothrow) libcamera::CameraManager());
  if (!s.manager || s.manager->start() != 0) {
    error_.set("libcamera: the camera manager did not start");
    return fail_open(StatusCode::unavailable);
  }

  {
    // Returned by value: built inside libcamera, only read and destroyed here.
    const std::vector<std::shared_ptr<libcamera::Camera>> cameras = s.manager->cameras();
    if (cameras.empty()) {
      error_.set(
          "libcamera: no cameras found (is a sensor connected and its pipeline handler "
          "built into libcamera?)");
      return fail_open(StatusCode::unavailable);
    }
    if (camera_id_[0] == '\0') {
      s.camera = cameras[0];
    } else {
      for (std::size_t i = 0; i < cameras.size() && !s.camera; ++i) {
        if (std::strcmp(cameras[i]->id().c_str(), camera_id_) == 0) s.camera = cameras[i];
      }
      if (!s.camera) {
        error_.set("libcamera: no camera '%s'; %zu found, the first is '%s'", camera_id_,
                   cameras.size(), cameras[0]->id().c_str());
        return fail_open(StatusCode::unavailable);
      }
    }
  }
  if (s.camera->acquire() != 0) {
    error_.set("libcamera: camera '%s' is in use", s.camera->id().c_str());
    return fail_open(StatusCode::unavailable);
  }
  s.acquired = true;

  // An empty role list gives an empty configuration; the one raw stream is added by hand so no
  // std::vector has to be built here.
  s.config = s.camera->generateConfiguration();
  if (!s.config) {
    error_.set("libcamera: camera '%s' gives no configuration", s.camera->id().c_str());
    return fail_open(StatusCode::internal);
  }
  libcamera::StreamConfiguration wanted;
  wanted.pixelFormat = pixel_format_for(options_.layout);
  wanted.size = libcamera::Size(static_cast<unsigned>(options_.width),
                                static_cast<unsigned>(options_.height));
  wanted.bufferCount = static_cast<unsigned>(options_.buffer_count);
  s.config->addConfiguration(wanted);
  const libcamera::CameraConfiguration::Status validity = s.config->validate();
  libcamera::StreamConfiguration& given = s.config->at(0);
  if (validity == libcamera::CameraConfiguration::Invalid ||
      given.pixelFormat != wanted.pixelFormat ||
      (options_.width > 0 &&
       (given.size.width != wanted.size.width || given.size.height != wanted.size.height))) {
    error_.set("libcamera: camera '%s' cannot stream %s %dx%d; it proposes %s %ux%u",
               s.camera->id().c_str(), libcamera_layout_name(options_.layout), options_.width,
               options_.height, given.pixelFormat.toString().c_str(), given.size.width,
               given.size.height);
    return fail_open(StatusCode::invalid_argument);
  }
  if (given.bufferCount < 2 || given.bufferCount > static_cast<unsigned>(kMaxBuffers)) {
    error_.set("libcamera: the camera wants %u buffers, the port handles 2..%d", given.bufferCount,
               kMaxBuffers);
    return fail_open(StatusCode::resource_exhausted);
  }
  s.width = static_cast<int>(given.size.width);
  s.height = static_cast<int>(given.size.height);
  s.stride = given.stride != 0 ? given.stride : libcamera_row_bytes(options_.layout, s.width);
  if (s.width <= 0 || s.height <= 0 || s.stride < libcamera_row_bytes(options_.layout, s.width)) {
    error_.set("libcamera: inconsistent stream %dx%d with stride %zu", s.width, s.height, s.stride);
    return fail_open(StatusCode::internal);
  }
  if (s.camera->configure(s.config.get()) != 0) {
    error_.set("libcamera: configuring camera '%s' failed", s.camera->id().c_str());
    return fail_open(StatusCode::invalid_argument);
  }
  s.stream = given.stream();

  s.allocator.reset(new (std::nothrow) libcamera::FrameBufferAllocator(s.camera));
  if (!s.allocator || s.allocator->allocate(s.stream) < 2) {
    error_.set("libcamera: cannot allocate capture buffers");
    return fail_open(StatusCode::resource_exhausted);
  }
  s.allocated = true;
  const auto& buffers = s.allocator->buffers(s.stream);
  s.buffer_count = static_cast<int>(buffers.size() < static_cast<std::size_t>(kMaxBuffers)
                                        ? buffers.size()
                                        : static_cast<std::size_t>(kMaxBuffers));
  for (int i = 0; i < s.buffer_count; ++i) {
    libcamera::FrameBuffer* buffer = buffers[static_cast<std::size_t>(i)].get();
    s.buffers[i] = buffer;
    const libcamera::FrameBuffer::Plane& plane = buffer->planes()[0];
    const std::size_t length = static_cast<std::size_t>(plane.offset) + plane.length;
    void* address = mmap(nullptr, length, PROT_READ, MAP_SHARED, plane.fd.get(), 0);
    if (address == MAP_FAILED) {
      error_.set("libcamera: cannot map buffer %d", i);
      return fail_open(StatusCode::resource_exhausted);
    }
    s.mappings[i].address = address;
    s.mappings[i].length = length;
    s.mappings[i].plane = static_cast<const std::uint8_t*>(address) + plane.offset;
    s.mappings[i].plane_length = plane.length;
    s.requests[i] = s.camera->createRequest(static_cast<std::uint64_t>(i));
    if (!s.requests[i] || s.requests[i]->addBuffer(s.stream, buffer) != 0) {
      error_.set("libcamera: cannot create request %d", i);
      return fail_open(StatusCode::resource_exhausted);
    }
  }

  s.frame_pixels = static_cast<std::size_t>(s.width) * static_cast<std::size_t>(s.height);
  s.ring.reset(new (std::nothrow)
                   std::uint16_t[s.frame_pixels * static_cast<std::size_t>(options_.ring_size)]);
  if (!s.ring) {
    error_.set("libcamera: cannot reserve the frame ring");
    return fail_open(StatusCode::resource_exhausted);
  }

  if (options_.intrinsics.valid()) {
    if (options_.intrinsics.width != s.width || options_.intrinsics.height != s.height) {
      error_.set("libcamera: intrinsics are for %dx%d, the stream is %dx%d",
                 options_.intrinsics.width, options_.intrinsics.height, s.width, s.height);
      return fail_open(StatusCode::invalid_argument);
    }
    intrinsics_ = options_.intrinsics;
  } else {
    const double half_fov = 0.5 * static_cast<double>(options_.horizontal_fov_deg) * kPi / 180.0;
    const auto f = static_cast<float>(0.5 * s.width / std::tan(half_fov));
    intrinsics_ = PinholeCamera{f,
                                f,
                                0.5f * static_cast<float>(s.width - 1),
                                0.5f * static_cast<float>(s.height - 1),
                                s.width,
                                s.height};
  }

  g_active.store(&s);
  s.camera->requestCompleted.connect(&on_request_completed);
  s.connected = true;
  if (s.camera->start() != 0) {
    error_.set("libcamera: camera '%s' did not start", s.camera->id().c_str());
    return fail_open(StatusCode::unavailable);
  }
  s.started = true;
  for (int i = 0; i < s.buffer_count; ++i) {
    if (s.camera->queueRequest(s.requests[i].get()) != 0) {
      error_.set("libcamera: cannot queue request %d", i);
      return fail_open(StatusCode::internal);
    }
  }
  return ok_status();
}

NextFrame LibcameraSource::next(DepthFrame& frame) {
  if (!impl_ || !impl_->started) {
    error_.set("libcamera: next() before a successful open()");
    return NextFrame::failed(StatusCode::failed_precondition);
  }
  Impl& s = *impl_;
  const int index = s.wait_completed(options_.frame_timeout_ms);
  if (index < 0 || index >= s.buffer_count) {
    error_.set("libcamera: no frame within %d ms", options_.frame_timeout_ms);
    return NextFrame::skipped(StatusCode::deadline_exceeded);
  }
  libcamera::Request* request = s.requests[index].get();
  if (request->status() == libcamera::Request::RequestCancelled) {
    error_.set("libcamera: capture stopped (request cancelled)");
    return NextFrame::failed(StatusCode::unavailable);
  }
  const libcamera::FrameMetadata& metadata = s.buffers[index]->metadata();
  std::size_t bytes = s.mappings[index].plane_length;
  if (!metadata.planes().empty() && metadata.planes()[0].bytesused < bytes) {
    bytes = metadata.planes()[0].bytesused;
  }
  Status converted = StatusCode::data_loss;
  std::uint16_t* slot = s.ring.get() + static_cast<std::size_t>(s.ring_next) * s.frame_pixels;
  if (metadata.status == libcamera::FrameMetadata::FrameSuccess) {
    converted = convert_libcamera_pixels(options_.layout, s.mappings[index].plane, s.stride, bytes,
                                         s.width, s.height, slot);
  }
  const std::uint64_t timestamp_ns = metadata.timestamp;
  const unsigned sequence = metadata.sequence;
  const bool success = metadata.status == libcamera::FrameMetadata::FrameSuccess;

  // The pixels are copied: the buffer goes straight back to the camera.
  request->reuse(libcamera::Request::ReuseBuffers);
  if (s.camera->queueRequest(request) != 0) {
    error_.set("libcamera: requeueing a request failed");
    return NextFrame::failed(StatusCode::unavailable);
  }
  if (!converted.ok()) {
    error_.set("libcamera: frame %u %s (%zu bytes)", sequence,
               success ? "is short" : "flagged as an error", bytes);
    return NextFrame::skipped(StatusCode::data_loss);
  }
  s.ring_next = (s.ring_next + 1) % options_.ring_size;
  frame.depth_raw = ImageView<const std::uint16_t>(slot, s.width, s.height);
  frame.metres_per_unit = options_.metres_per_unit;
  frame.timestamp_us = static_cast<std::int64_t>(timestamp_ns / 1000u);  // CLOCK_MONOTONIC
  frame.sequence = sequence;
  frame.has_ground_truth = false;
  return NextFrame::got_frame();
}

void LibcameraSource::close() {
  if (!impl_) return;
  Impl& s = *impl_;
  if (s.started) s.camera->stop();  // completes pending requests as cancelled
  s.started = false;
  if (s.connected) s.camera->requestCompleted.disconnect();
  s.connected = false;
  if (g_active.load() == &s) g_active.store(nullptr);
  for (int i = 0; i < kMaxBuffers; ++i) {
    s.requests[i].reset();
    if (s.mappings[i].address != nullptr) munmap(s.mappings[i].address, s.mappings[i].length);
    s.mappings[i] = Impl::Mapping{};
    s.buffers[i] = nullptr;
  }
  if (s.allocated) s.allocator->free(s.stream);
  s.allocated = false;
  s.allocator.reset();
  s.config.reset();
  if (s.acquired) s.camera->release();
  s.acquired = false;
  s.camera.reset();
  if (s.manager) s.manager->stop();
  s.manager.reset();
  if (s.owns_manager_slot) g_manager_in_use.store(false);
  impl_.reset();
}

std::unique_ptr<DepthSource> make_libcamera_source(const LibcameraOptions& options) {
  return std::unique_ptr<DepthSource>(new (std::nothrow) LibcameraSource(options));
}

}  // namespace octofuse::ports
