#include "octofuse/sensor/frame_validator.hpp"

#include <cinttypes>
#include <cmath>

#include "octofuse/math/se3.hpp"

namespace octofuse {

Status FrameValidator::init(const PinholeCamera& camera, const FrameValidatorConfig& config) {
  initialised_ = false;
  have_previous_ = false;
  if (!camera.valid()) {
    error_.set("frame validator: invalid camera (%dx%d, fx %g fy %g)", camera.width, camera.height,
               static_cast<double>(camera.fx), static_cast<double>(camera.fy));
    return StatusCode::invalid_argument;
  }
  if (!std::isfinite(config.near_m) || !std::isfinite(config.far_m) || config.near_m < 0.0f ||
      !(config.near_m < config.far_m)) {
    error_.set("frame validator: bad depth range [%g, %g] m", static_cast<double>(config.near_m),
               static_cast<double>(config.far_m));
    return StatusCode::invalid_argument;
  }
  if (!(config.min_valid_fraction >= 0.0f && config.min_valid_fraction <= 1.0f)) {
    error_.set("frame validator: min_valid_fraction %g outside [0, 1]",
               static_cast<double>(config.min_valid_fraction));
    return StatusCode::invalid_argument;
  }
  if (!std::isfinite(config.rigid_tolerance) || !(config.rigid_tolerance > 0.0)) {
    error_.set("frame validator: rigid_tolerance must be finite and > 0");
    return StatusCode::invalid_argument;
  }
  camera_ = camera;
  config_ = config;
  initialised_ = true;
  error_.clear();
  return ok_status();
}

Status FrameValidator::reject(Status why) {
  ++frames_rejected_;
  return why;
}

Status FrameValidator::validate(const DepthFrame& frame, ImageView<float> depth_m,
                                FrameReport* report, ImageView<std::uint8_t> beyond_far) {
  FrameReport local;
  FrameReport& out = report != nullptr ? *report : local;
  out = FrameReport();
  error_.clear();

  if (!initialised_) {
    error_.set("frame validator: validate() before a successful init()");
    return StatusCode::failed_precondition;
  }
  if (depth_m.data == nullptr || depth_m.width != camera_.width ||
      depth_m.height != camera_.height || depth_m.stride < depth_m.width) {
    error_.set("frame validator: output buffer is %dx%d, expected %dx%d", depth_m.width,
               depth_m.height, camera_.width, camera_.height);
    return StatusCode::failed_precondition;
  }
  const bool mark_beyond = !beyond_far.empty();
  if (mark_beyond && (beyond_far.width != camera_.width || beyond_far.height != camera_.height ||
                      beyond_far.stride < beyond_far.width)) {
    error_.set("frame validator: beyond-far mask is %dx%d, expected %dx%d", beyond_far.width,
               beyond_far.height, camera_.width, camera_.height);
    return StatusCode::failed_precondition;
  }

  const ImageView<const std::uint16_t>& raw = frame.depth_raw;
  if (raw.data == nullptr || raw.width != camera_.width || raw.height != camera_.height ||
      raw.stride < raw.width) {
    error_.set("frame %" PRIu64 ": depth is %dx%d (stride %td, %s), expected %dx%d", frame.sequence,
               raw.width, raw.height, raw.stride, raw.data == nullptr ? "no pixels" : "pixels",
               camera_.width, camera_.height);
    return reject(StatusCode::invalid_argument);
  }
  if (!std::isfinite(frame.metres_per_unit) || !(frame.metres_per_unit > 0.0f)) {
    error_.set("frame %" PRIu64 ": metres_per_unit %g is not finite and > 0", frame.sequence,
               static_cast<double>(frame.metres_per_unit));
    return reject(StatusCode::invalid_argument);
  }
  if (have_previous_ && frame.timestamp_us <= previous_timestamp_us_) {
    error_.set("frame %" PRIu64 ": timestamp %" PRId64 " us is not after the previous %" PRId64
               " us",
               frame.sequence, frame.timestamp_us, previous_timestamp_us_);
    return reject(StatusCode::invalid_argument);
  }
  if (have_previous_ && frame.sequence <= previous_sequence_) {
    error_.set("frame %" PRIu64 ": sequence number is not after the previous %" PRIu64,
               frame.sequence, previous_sequence_);
    return reject(StatusCode::invalid_argument);
  }
  if (frame.has_ground_truth) {
    if (!frame.T_W_C_ground_truth.allFinite()) {
      error_.set("frame %" PRIu64 ": ground-truth pose has non-finite entries", frame.sequence);
      return reject(StatusCode::invalid_argument);
    }
    if (!is_rigid(frame.T_W_C_ground_truth, config_.rigid_tolerance)) {
      error_.set("frame %" PRIu64 ": ground-truth pose is not a rigid transform", frame.sequence);
      return reject(StatusCode::invalid_argument);
    }
  }

  // The frame is well-formed: accept it, then convert and count pixels.
  out.dropped_before = have_previous_ ? frame.sequence - previous_sequence_ - 1 : 0;
  frames_dropped_ += out.dropped_before;
  have_previous_ = true;
  previous_timestamp_us_ = frame.timestamp_us;
  previous_sequence_ = frame.sequence;
  ++frames_accepted_;

  const float scale = frame.metres_per_unit;
  const float near_m = config_.near_m;
  const float far_m = config_.far_m;
  std::uint32_t zero = 0;
  std::uint32_t saturated = 0;
  std::uint32_t out_of_range = 0;
  std::uint32_t beyond = 0;
  std::uint32_t valid = 0;
  for (int y = 0; y < raw.height; ++y) {
    const std::uint16_t* in_row = raw.row(y);
    float* out_row = depth_m.row(y);
    std::uint8_t* beyond_row = mark_beyond ? beyond_far.row(y) : nullptr;
    for (int x = 0; x < raw.width; ++x) {
      const std::uint16_t value = in_row[x];
      float metres = 0.0f;
      std::uint8_t is_beyond = 0;
      if (value == 0) {
        ++zero;
      } else if (value == kSaturatedDepthRaw) {
        ++saturated;
      } else {
        const float d = static_cast<float>(value) * scale;
        if (d < near_m || d > far_m) {
          ++out_of_range;
          is_beyond = d > far_m ? 1 : 0;
          beyond += is_beyond;
        } else {
          metres = d;
          ++valid;
        }
      }
      out_row[x] = metres;
      if (mark_beyond) beyond_row[x] = is_beyond;
    }
  }
  out.pixel_count = static_cast<std::uint32_t>(raw.pixel_count());
  out.zero_pixels = zero;
  out.saturated_pixels = saturated;
  out.out_of_range_pixels = out_of_range;
  out.beyond_far_pixels = beyond;
  out.valid_pixels = valid;
  out.nearly_empty = static_cast<double>(valid) <
                     static_cast<double>(config_.min_valid_fraction) * out.pixel_count;
  if (out.nearly_empty) {
    error_.set("frame %" PRIu64
               ": only %u of %u pixels valid (%u zero, %u saturated, %u outside "
               "[%g, %g] m)",
               frame.sequence, valid, out.pixel_count, zero, saturated, out_of_range,
               static_cast<double>(near_m), static_cast<double>(far_m));
    return StatusCode::data_loss;
  }
  return ok_status();
}

}  // namespace octofuse
