#pragma once
// Depth (ToF) sensors exposed through libcamera as 16-bit mono or packed mono raw streams.
// Written against libcamera 0.0.x (Debian 12), whose API moves between versions: the port uses
// only camera enumeration, one Raw-role stream, a FrameBufferAllocator and reused requests.
//
// Source spec (parsed by the programs, not here): `libcamera` (the first camera) or
// `libcamera:ID` with the id libcamera prints (`cam --list`), e.g.
//   LibcameraOptions options;  options.camera_id = "/base/soc/i2c0mux/i2c@1/imx500@1a";
//   octofuse::ports::LibcameraSource source(options);
//
// Only one LibcameraSource may be open per process: libcamera allows one CameraManager.

#include <cstddef>
#include <cstdint>
#include <memory>

#include "octofuse/core/error_text.hpp"
#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::ports {

// How depth values sit in the sensor's buffer.
enum class LibcameraPixelLayout : std::uint8_t {
  r16,        // 16 bits in a little-endian 16-bit word (DRM 'R16 ', V4L2 Y16)
  r12,        // 12 bits, low-aligned in a little-endian 16-bit word (libcamera R12)
  r10,        // 10 bits, likewise (libcamera R10)
  r12_csi2p,  // MIPI CSI-2 packed: 2 pixels in 3 bytes (libcamera R12_CSI2P)
  r10_csi2p,  // MIPI CSI-2 packed: 4 pixels in 5 bytes (libcamera R10_CSI2P)
};

// "R16", "R12_CSI2P", ...; never null.
const char* libcamera_layout_name(LibcameraPixelLayout layout);

// Bytes one row of `width` pixels needs in `layout` (before any padding the driver adds).
std::size_t libcamera_row_bytes(LibcameraPixelLayout layout, int width);

// Unpacks one frame into raw depth units (the value the sensor reports, not shifted). `stride`
// is the buffer's bytes per line, `src_bytes` how many bytes the buffer holds.
// Returns ok; invalid_argument (size <= 0, stride below libcamera_row_bytes); data_loss (the
// buffer is shorter than the frame). Never allocates.
Status convert_libcamera_pixels(LibcameraPixelLayout layout, const std::uint8_t* src,
                                std::size_t stride, std::size_t src_bytes, int width, int height,
                                std::uint16_t* dst);

struct LibcameraOptions {
  const char* camera_id = nullptr;  // copied; null or empty: the first camera libcamera lists
  LibcameraPixelLayout layout = LibcameraPixelLayout::r16;
  int width = 0;  // 0 with height 0: the size the camera proposes for a raw stream
  int height = 0;
  float metres_per_unit = 0.001f;  // depth of one raw unit (sensor specific, see README)
  int buffer_count = 4;            // requests in flight, 2..LibcameraSource::kMaxBuffers
  int ring_size = 2;               // converted frames valid at once, 1..kMaxRing
  int frame_timeout_ms = 1000;
  // Used when valid() (size must match); else fx = fy from horizontal_fov_deg, centred.
  PinholeCamera intrinsics;
  float horizontal_fov_deg = 70.0f;
};

// Checks options before any camera is touched. Returns ok or invalid_argument with the reason
// in `why`.
Status validate_libcamera_options(const LibcameraOptions& options, ErrorText& why);

class LibcameraSource final : public DepthSource {
 public:
  static constexpr int kMaxBuffers = 8;
  static constexpr int kMaxRing = 8;
  static constexpr std::size_t kMaxIdLength = 255;

  explicit LibcameraSource(const LibcameraOptions& options);  // options.camera_id is copied
  ~LibcameraSource() override;
  LibcameraSource(const LibcameraSource&) = delete;
  LibcameraSource& operator=(const LibcameraSource&) = delete;

  // Starts libcamera, finds the camera, configures one raw stream in options.layout at the
  // requested size, allocates and maps its buffers, creates the requests and starts capture.
  // Returns ok; unavailable (no camera at all, no camera with that id, the camera is busy,
  // another LibcameraSource is open); invalid_argument (bad options, or the camera adjusts the
  // format or size: last_error() says what it offers); resource_exhausted (buffers, memory);
  // failed_precondition (already open); internal.
  Status open() override;

  // frame; skip with deadline_exceeded (nothing within frame_timeout_ms) or data_loss (a buffer
  // flagged as an error or short); error with unavailable (capture stopped) or
  // failed_precondition (not open). Converts into the source's ring; allocates nothing itself.
  NextFrame next(DepthFrame& frame) override;

  void close() override;

  PinholeCamera intrinsics() const override { return intrinsics_; }
  SourceCapabilities capabilities() const override;
  const char* last_error() const override { return error_.c_str(); }

  struct Impl;  // libcamera objects; defined in the .cpp so this header needs no libcamera

 private:
  Status fail_open(Status status);

  LibcameraOptions options_;
  char camera_id_[kMaxIdLength + 1] = {};
  bool id_too_long_ = false;
  std::unique_ptr<Impl> impl_;
  PinholeCamera intrinsics_;
  float rate_hz_ = 30.0f;
  ErrorText error_;
};

std::unique_ptr<DepthSource> make_libcamera_source(const LibcameraOptions& options);

}  // namespace octofuse::ports
