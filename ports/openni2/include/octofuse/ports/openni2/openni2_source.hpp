#pragma once
// OpenNI2 depth cameras (PrimeSense, Kinect via libfreenect's driver, Asus Xtion, Orbbec) and
// OpenNI2 `.oni` recordings, through the OpenNI2 C API.
//
// Source specs (parsed by the programs, not here):
//   `openni2`        the first device OpenNI2 finds     OpenNi2Source(OpenNi2Options{})
//   `openni2:URI`    a device by URI                    options.uri = "URI"
//   `oni:FILE`       a recording (Debian's libOniFile)  options.uri = "FILE.oni"
//
// Each next() copies the newest depth frame into a ring the source owns (OpenNI2's own frame
// buffers come from a fixed pool set up at open()), so frames stay valid for ring_size calls
// whatever OpenNI2 does with its buffers.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>

#include "octofuse/core/error_text.hpp"
#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::ports {

enum class OpenNi2DepthUnits : std::uint8_t {
  millimetre,          // ONI_PIXEL_FORMAT_DEPTH_1_MM
  hundred_micrometre,  // ONI_PIXEL_FORMAT_DEPTH_100_UM
};

struct OpenNi2Options {
  // Null or empty: the first device. A path ending in ".oni": that recording (mode settings
  // below are ignored, a recording has one mode). Anything else: a device URI.
  const char* uri = nullptr;
  int width = 640;  // 0 with height 0 and fps 0: keep the device's current mode
  int height = 480;
  int fps = 30;
  OpenNi2DepthUnits units = OpenNi2DepthUnits::millimetre;
  bool registration = false;  // depth-to-colour registration (changes the intrinsics: off)
  int frame_timeout_ms = 2000;
  int ring_size = 2;  // frames that stay valid at once, 1..OpenNi2Source::kMaxRing
};

class OpenNi2Source final : public DepthSource {
 public:
  static constexpr int kMaxRing = 8;
  static constexpr int kPoolBuffers = 8;  // OpenNI2-side frame buffers (driver, stream, recorder)
  static constexpr std::size_t kMaxUriLength = 511;

  explicit OpenNi2Source(const OpenNi2Options& options);  // options.uri is copied
  ~OpenNi2Source() override;
  OpenNi2Source(const OpenNi2Source&) = delete;
  OpenNi2Source& operator=(const OpenNi2Source&) = delete;

  // Initialises OpenNI2, opens the device or recording, selects the depth mode, switches
  // registration, reserves the ring and starts the depth stream.
  // Returns ok; unavailable (no device, OpenNI2 or its drivers not found, file missing);
  // invalid_argument (bad options, a mode the device does not list (last_error() names the
  // modes it does), registration not supported, no depth sensor); failed_precondition (already
  // open); resource_exhausted (ring memory).
  Status open() override;

  // frame; end_of_stream after the last frame of a recording; skip with deadline_exceeded (no
  // frame within frame_timeout_ms from a device) or data_loss (a frame of the wrong size); error
  // with unavailable (device lost), internal, or failed_precondition (not open).
  // Never allocates.
  NextFrame next(DepthFrame& frame) override;

  void close() override;

  // From the device's fields of view, as OpenNI2's own depth-to-world conversion does:
  // fx = width / (2 tan(hfov / 2)), principal point at (width / 2, height / 2).
  PinholeCamera intrinsics() const override { return intrinsics_; }
  SourceCapabilities capabilities() const override;
  const char* last_error() const override { return error_.c_str(); }

  bool is_recording() const { return playback_; }
  int recorded_frame_count() const { return recorded_frames_; }  // recordings only, after open()

  // Frame buffer pool handed to OpenNI2 (called from OpenNI2's threads).
  void* pool_acquire(int size);
  void pool_release(void* buffer);

 private:
  Status fail_open(Status status);
  Status select_mode();
  void teardown();

  OpenNi2Options options_;
  char uri_[kMaxUriLength + 1] = {};
  bool uri_too_long_ = false;

  bool initialized_ = false;
  void* device_ = nullptr;  // OniDeviceHandle
  void* stream_ = nullptr;  // OniStreamHandle
  bool started_ = false;
  bool playback_ = false;
  int recorded_frames_ = 0;
  int frames_read_ = 0;

  int width_ = 0;
  int height_ = 0;
  float metres_per_unit_ = 0.001f;
  float rate_hz_ = 30.0f;
  PinholeCamera intrinsics_;

  std::unique_ptr<std::uint16_t[]> memory_;  // ring, then pool, one allocation at open()
  std::size_t frame_pixels_ = 0;
  std::size_t pool_slot_bytes_ = 0;
  std::atomic<bool> pool_used_[kPoolBuffers] = {};
  int ring_next_ = 0;

  ErrorText error_;
};

std::unique_ptr<DepthSource> make_openni2_source(const OpenNi2Options& options);

// True when `uri` names a recording (ends in ".oni", any case).
bool openni2_uri_is_recording(const char* uri);

}  // namespace octofuse::ports
