#pragma once
// Checks what a DepthSource delivers, once, in lib: every port hands its frames through one
// FrameValidator before the pipeline touches them. It also converts raw depth units to float
// metres (invalid pixels become 0) into a buffer the caller owns. No allocation, ever.

#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/image_view.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/sensor/depth_frame.hpp"

namespace octofuse {

// Raw value a sensor writes for "too far / no return" (Kinect v1, 7-Scenes). It and 0 are no
// measurement; any other value beyond far_m is a measured surface beyond the range, which free
// space takes as its ray seen free out to far_m. A port whose sensor writes some other code for
// "no return" must map it to 0.
inline constexpr std::uint16_t kSaturatedDepthRaw = 65535;

struct FrameValidatorConfig {
  float near_m = 0.4f;  // depth below this is out of range (becomes 0)
  float far_m = 4.0f;   // depth above this is out of range (becomes 0)
  // Frames with fewer valid pixels than this fraction are reported as nearly empty.
  float min_valid_fraction = 0.01f;
  double rigid_tolerance = 1e-4;  // for the ground-truth pose, see is_rigid()
};

// What one frame held; filled by validate() for every frame it got far enough to inspect.
struct FrameReport {
  std::uint32_t pixel_count = 0;
  std::uint32_t valid_pixels = 0;         // in [near_m, far_m], converted
  std::uint32_t zero_pixels = 0;          // raw 0: no measurement
  std::uint32_t saturated_pixels = 0;     // raw 65535
  std::uint32_t out_of_range_pixels = 0;  // a measurement outside [near_m, far_m]
  std::uint32_t beyond_far_pixels = 0;    // of those, beyond far_m (the ray saw no surface nearer)
  std::uint64_t dropped_before = 0;       // sequence numbers skipped since the previous frame
  bool nearly_empty = false;              // valid_pixels < min_valid_fraction * pixel_count

  float valid_fraction() const {
    return pixel_count == 0 ? 0.0f
                            : static_cast<float>(valid_pixels) / static_cast<float>(pixel_count);
  }
};

class FrameValidator {
 public:
  // Expects frames of camera.width x camera.height.
  // Returns ok, or invalid_argument (camera not valid(), near/far not finite with
  // 0 <= near < far, min_valid_fraction outside [0, 1], tolerance not finite and > 0).
  Status init(const PinholeCamera& camera, const FrameValidatorConfig& config);

  // Checks `frame` and writes depth in metres to `depth_m` (camera-sized; 0 = invalid pixel).
  // When `beyond_far` is not empty (camera-sized), it is written for every accepted frame: 1 where
  // the sensor measured a surface beyond far_m (no depth, but the ray saw nothing nearer: free
  // space's evidence), else 0.
  // Returns
  //   ok                   the frame is good; `report` and `depth_m` are filled.
  //   data_loss            well-formed but nearly empty (see FrameReport::nearly_empty); `depth_m`
  //                        and `report` are filled and the frame counts as accepted.
  //   invalid_argument     wrong size, null pixels, stride < width, metres_per_unit not finite
  //                        and > 0, timestamp not strictly after the last accepted frame,
  //                        sequence number not after the last one, ground truth not finite or
  //                        not rigid. The frame is rejected: time/sequence state is unchanged and
  //                        `depth_m` is not written.
  //   failed_precondition  init() has not succeeded, or `depth_m` (or a non-empty `beyond_far`)
  //                        is not camera-sized.
  // last_error() explains every non-ok result.
  Status validate(const DepthFrame& frame, ImageView<float> depth_m, FrameReport* report,
                  ImageView<std::uint8_t> beyond_far = {});

  // Forgets the previous frame (a new stream begins); totals are kept.
  void restart_stream() { have_previous_ = false; }

  const char* last_error() const { return error_.c_str(); }
  std::uint64_t frames_accepted() const { return frames_accepted_; }
  std::uint64_t frames_rejected() const { return frames_rejected_; }
  std::uint64_t frames_dropped() const { return frames_dropped_; }  // from sequence gaps
  const FrameValidatorConfig& config() const { return config_; }

 private:
  Status reject(Status why);

  PinholeCamera camera_;
  FrameValidatorConfig config_;
  bool initialised_ = false;
  bool have_previous_ = false;
  std::int64_t previous_timestamp_us_ = 0;
  std::uint64_t previous_sequence_ = 0;
  std::uint64_t frames_accepted_ = 0;
  std::uint64_t frames_rejected_ = 0;
  std::uint64_t frames_dropped_ = 0;
  ErrorText error_;
};

}  // namespace octofuse
