#pragma once
// LoopingSource: replays another DepthSource over and over, for runs longer than a recording (the
// soak in octofuse-bench). At the end of each pass the inner source is closed and opened again;
// timestamps and sequence numbers are shifted so that they keep increasing across passes (the
// first frame of a pass comes one nominal frame period after the last frame of the previous one),
// which the frame validator requires. Depth and ground truth pass through unchanged: the camera
// is back at the first frame's pose at the start of every pass, a jump the caller has to bridge
// (the runner relocalises the pipeline there; see loop_started()).
//
// Reopening the inner source is its own open(): a replay source reserves its buffers again (the
// same size) between passes, never per frame.

#include <cstdint>
#include <memory>

#include "octofuse/core/error_text.hpp"
#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::examples {

class LoopingSource final : public DepthSource {
 public:
  explicit LoopingSource(std::unique_ptr<DepthSource> inner);
  ~LoopingSource() override;
  LoopingSource(const LoopingSource&) = delete;
  LoopingSource& operator=(const LoopingSource&) = delete;

  // Opens the inner source; its status passes through (last_error() says why); invalid_argument
  // without one.
  Status open() override;
  // The inner source's frames, skips and errors, pass after pass, never end_of_stream unless the
  // first pass delivered no frame (nothing to loop). Errors: the inner source's; reopening it
  // fails (its open() status); a later pass delivers no frame or other intrinsics (data_loss);
  // shifted timestamps would overflow (out_of_range); next() before open() (failed_precondition).
  NextFrame next(DepthFrame& frame) override;
  void close() override;
  PinholeCamera intrinsics() const override { return camera_; }
  SourceCapabilities capabilities() const override { return capabilities_; }
  const char* last_error() const override { return error_.c_str(); }
  // Over every pass so far.
  std::uint64_t frames_dropped() const override {
    return dropped_before_pass_ + (inner_ != nullptr ? inner_->frames_dropped() : 0);
  }

  // The pass the last delivered frame belongs to (0: the first).
  int loop() const { return loop_; }
  // True when the last delivered frame is the first frame of a pass after the first: the camera
  // has jumped back to the first frame's pose.
  bool loop_started() const { return loop_started_; }
  // Frames delivered in the first pass (its length once a second pass has begun).
  std::uint64_t frames_in_first_loop() const { return frames_in_first_loop_; }

 private:
  NextFrame fail(Status why, const char* context);

  std::unique_ptr<DepthSource> inner_;
  std::uint64_t dropped_before_pass_ = 0;  // the inner source's drops in earlier passes
  ErrorText error_;
  bool open_ = false;
  PinholeCamera camera_;  // the inner source's, as first opened
  SourceCapabilities capabilities_;
  std::int64_t period_us_ = 33333;  // from the inner source's nominal rate
  int loop_ = 0;
  bool loop_started_ = false;
  bool align_next_ = false;  // the next frame starts a pass: compute the offsets from it
  std::uint64_t frames_in_loop_ = 0;
  std::uint64_t frames_in_first_loop_ = 0;
  bool have_output_ = false;
  std::int64_t last_timestamp_us_ = 0;
  std::uint64_t last_sequence_ = 0;
  std::int64_t timestamp_offset_us_ = 0;
  std::uint64_t sequence_offset_ = 0;  // modulo 2^64
};

}  // namespace octofuse::examples
