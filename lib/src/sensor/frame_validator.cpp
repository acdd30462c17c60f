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

namespace {

struct PixelCounts {
  std::uint32_t zero = 0;
  std::uint32_t saturated = 0;
  std::uint32_t valid = 0;
  std::uint32_t beyond = 0;
};

// The raw values whose metres lie in [near_m, far_m]: value * scale never decreases as value grows
// (the product of a positive scale rounds monotonically), so they are one interval, found once a
// frame by bisection with the row loop's own expression. `first` is at least 1 and `last` at most
// 65534, so the interval holds no zero (no return) and no saturated value.
struct RawRange {
  std::uint16_t first = kSaturatedDepthRaw;  // none: no measured value reaches near_m
  std::uint16_t last = 0;                    // none: every measured value is beyond far_m
};

inline float raw_to_metres(std::uint16_t value, float scale) {
  return static_cast<float>(value) * scale;
}

RawRange raw_range(float scale, float near_m, float far_m) {
  RawRange r;
  std::uint32_t lo = 1;
  std::uint32_t hi = kSaturatedDepthRaw;  // the smallest value reaching near_m is in [lo, hi]
  while (lo < hi) {
    const std::uint32_t mid = (lo + hi) / 2;
    if (raw_to_metres(static_cast<std::uint16_t>(mid), scale) >= near_m) {
      hi = mid;
    } else {
      lo = mid + 1;
    }
  }
  r.first = static_cast<std::uint16_t>(lo);
  lo = 0;  // 0 m is within far_m (far_m > near_m >= 0): the bisection's floor
  hi = kSaturatedDepthRaw - 1u;
  while (lo < hi) {
    const std::uint32_t mid = (lo + hi + 1) / 2;
    if (raw_to_metres(static_cast<std::uint16_t>(mid), scale) <= far_m) {
      lo = mid;
    } else {
      hi = mid - 1;
    }
  }
  r.last = static_cast<std::uint16_t>(lo);
  return r;
}

// One row of raw depth to metres (0 outside [near_m, far_m] or without a measurement), and the
// beyond-far mark. Branch-free, and the tests in 16-bit integers (8 pixels a 128-bit register, not
// 4 floats), so the compiler converts several pixels per instruction. Counted in 16 bits per chunk
// of at most 2^15 pixels, then added to the 32-bit totals.
template <bool kMark>
void convert_row(const std::uint16_t* raw, float* metres, std::uint8_t* beyond_far, int width,
                 float scale, RawRange range, PixelCounts& counts) {
  constexpr int kChunk = 1 << 15;
  std::uint32_t zero = 0;
  std::uint32_t saturated = 0;
  std::uint32_t valid = 0;
  std::uint32_t beyond = 0;
  for (int x0 = 0; x0 < width; x0 += kChunk) {
    const int end = width - x0 < kChunk ? width : x0 + kChunk;
    std::uint16_t chunk_zero = 0;
    std::uint16_t chunk_saturated = 0;
    std::uint16_t chunk_valid = 0;
    std::uint16_t chunk_beyond = 0;
    for (int x = x0; x < end; ++x) {
      const std::uint16_t value = raw[x];
      const bool is_zero = value == 0;
      const bool is_saturated = value == kSaturatedDepthRaw;
      const bool in_range = (value >= range.first) & (value <= range.last);
      const bool is_beyond = (value > range.last) & !is_saturated;
      chunk_zero = static_cast<std::uint16_t>(chunk_zero + is_zero);
      chunk_saturated = static_cast<std::uint16_t>(chunk_saturated + is_saturated);
      chunk_valid = static_cast<std::uint16_t>(chunk_valid + in_range);
      chunk_beyond = static_cast<std::uint16_t>(chunk_beyond + is_beyond);
      metres[x] = in_range ? raw_to_metres(value, scale) : 0.0f;
      if (kMark) beyond_far[x] = static_cast<std::uint8_t>(is_beyond);
    }
    zero += chunk_zero;
    saturated += chunk_saturated;
    valid += chunk_valid;
    beyond += chunk_beyond;
  }
  counts.zero += zero;
  counts.saturated += saturated;
  counts.valid += valid;
  counts.beyond += beyond;
}

}  // namespace

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
  const RawRange range = raw_range(scale, config_.near_m, config_.far_m);
  PixelCounts counts;
  for (int y = 0; y < raw.height; ++y) {
    if (mark_beyond) {
      convert_row<true>(raw.row(y), depth_m.row(y), beyond_far.row(y), raw.width, scale, range,
                        counts);
    } else {
      convert_row<false>(raw.row(y), depth_m.row(y), nullptr, raw.width, scale, range, counts);
    }
  }
  const std::uint32_t zero = counts.zero;
  const std::uint32_t saturated = counts.saturated;
  const std::uint32_t valid = counts.valid;
  const std::uint32_t beyond = counts.beyond;
  const std::uint32_t out_of_range =
      static_cast<std::uint32_t>(raw.width) * static_cast<std::uint32_t>(raw.height) - zero -
      saturated - valid;
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
               static_cast<double>(config_.near_m), static_cast<double>(config_.far_m));
    return StatusCode::data_loss;
  }
  return ok_status();
}

}  // namespace octofuse
