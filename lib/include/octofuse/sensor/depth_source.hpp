#pragma once
// The hardware abstraction layer for depth sensors. Every way depth gets into octofuse (a live
// camera, a recorded dataset, a synthetic scene) is a DepthSource. Ports do I/O only; checking
// what they deliver happens once, in lib (frame_validator.hpp).

#include <cstdint>

#include "octofuse/core/status.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/sensor/depth_frame.hpp"

namespace octofuse {

enum class FrameOutcome : std::uint8_t {
  frame,          // `frame` holds a new frame
  skip,           // a bad frame was dropped; call next() again (last_error() says why)
  end_of_stream,  // a recording ended; the source stays open until close()
  error,          // the source failed (status and last_error() say why); close() it
};

struct [[nodiscard]] NextFrame {
  FrameOutcome outcome = FrameOutcome::error;
  Status status = StatusCode::internal;  // ok for frame; end_of_stream; the cause otherwise

  static NextFrame got_frame() { return {FrameOutcome::frame, ok_status()}; }
  static NextFrame skipped(Status why) { return {FrameOutcome::skip, why}; }
  static NextFrame ended() { return {FrameOutcome::end_of_stream, StatusCode::end_of_stream}; }
  static NextFrame failed(Status why) { return {FrameOutcome::error, why}; }
};

struct SourceCapabilities {
  bool live = false;              // a real sensor (frames are dropped if not read in time)
  bool has_ground_truth = false;  // frames carry T_W_C_ground_truth
  int ring_size = 1;              // frames that stay valid at once
  float nominal_rate_hz = 30.0f;
};

class DepthSource {
 public:
  virtual ~DepthSource() = default;

  // Reserves every buffer the source will use; no allocation after this returns ok.
  // Returns ok, unavailable (no device, missing folder), invalid_argument (bad configuration),
  // data_loss (unreadable index or calibration file), resource_exhausted.
  virtual Status open() = 0;

  // The next frame, see FrameOutcome. Calling before a successful open() gives
  // error/failed_precondition.
  virtual NextFrame next(DepthFrame& frame) = 0;

  virtual void close() = 0;

  // Native-resolution intrinsics; valid after open().
  virtual PinholeCamera intrinsics() const = 0;
  virtual SourceCapabilities capabilities() const = 0;

  // Human-readable cause of the last failure or skip ("depth/000012.png: truncated"); never null.
  virtual const char* last_error() const = 0;

  // Frames the source had but never delivered nor reported as skipped, since open(): a live
  // camera's frames overwritten before they were read, a real-time replay's frames passed over
  // while the reader was late. With the delivered and skipped ones, every frame is accounted for.
  virtual std::uint64_t frames_dropped() const { return 0; }
};

}  // namespace octofuse
