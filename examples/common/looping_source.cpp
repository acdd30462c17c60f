#include "looping_source.hpp"

#include <cmath>
#include <utility>

namespace octofuse::examples {

LoopingSource::LoopingSource(std::unique_ptr<DepthSource> inner) : inner_(std::move(inner)) {}

LoopingSource::~LoopingSource() {
  close();
}

NextFrame LoopingSource::fail(Status why, const char* context) {
  error_.set("%s%s", context, inner_->last_error());
  return NextFrame::failed(why);
}

Status LoopingSource::open() {
  close();
  error_.clear();
  dropped_before_pass_ = 0;
  if (inner_ == nullptr) {
    error_.set("loop: no source to loop");
    return StatusCode::invalid_argument;
  }
  const Status status = inner_->open();
  if (!status.ok()) {
    error_.set("%s", inner_->last_error());
    return status;
  }
  open_ = true;
  camera_ = inner_->intrinsics();
  capabilities_ = inner_->capabilities();
  const double rate_hz = static_cast<double>(capabilities_.nominal_rate_hz);
  // A source without a usable rate gets 30 Hz spacing between passes (only the order matters to
  // the validator; the spacing is what a camera at that rate would give).
  period_us_ = std::isfinite(rate_hz) && rate_hz >= 0.01 && rate_hz <= 1e6
                   ? static_cast<std::int64_t>(std::llround(1e6 / rate_hz))
                   : 33333;
  return ok_status();
}

void LoopingSource::close() {
  if (open_) inner_->close();
  open_ = false;
  loop_ = 0;
  loop_started_ = false;
  align_next_ = false;
  frames_in_loop_ = 0;
  frames_in_first_loop_ = 0;
  have_output_ = false;
  last_timestamp_us_ = 0;
  last_sequence_ = 0;
  timestamp_offset_us_ = 0;
  sequence_offset_ = 0;
}

NextFrame LoopingSource::next(DepthFrame& frame) {
  if (!open_) {
    error_.set("loop: next() before a successful open()");
    return NextFrame::failed(StatusCode::failed_precondition);
  }
  for (;;) {
    const NextFrame got = inner_->next(frame);
    if (got.outcome == FrameOutcome::frame) break;
    if (got.outcome == FrameOutcome::skip) {
      error_.set("%s", inner_->last_error());
      return got;
    }
    if (got.outcome == FrameOutcome::error) return fail(got.status, "");
    // End of a pass.
    if (frames_in_loop_ == 0) {
      if (loop_ == 0) {  // nothing to loop
        error_.set("loop: the source delivered no frame");
        return NextFrame::ended();
      }
      error_.set("loop: pass %d delivered no frame (the first delivered %llu)", loop_,
                 static_cast<unsigned long long>(frames_in_first_loop_));
      return NextFrame::failed(StatusCode::data_loss);
    }
    if (loop_ == 0) frames_in_first_loop_ = frames_in_loop_;
    dropped_before_pass_ += inner_->frames_dropped();
    inner_->close();
    const Status reopened = inner_->open();
    if (!reopened.ok()) {
      open_ = false;  // the inner source is closed
      error_.set("loop: reopening for pass %d: %s", loop_ + 1, inner_->last_error());
      return NextFrame::failed(reopened);
    }
    const PinholeCamera camera = inner_->intrinsics();
    if (camera.fx != camera_.fx || camera.fy != camera_.fy || camera.cx != camera_.cx ||
        camera.cy != camera_.cy || camera.width != camera_.width ||
        camera.height != camera_.height) {
      error_.set("loop: the source's intrinsics changed when reopened for pass %d", loop_ + 1);
      return NextFrame::failed(StatusCode::data_loss);
    }
    ++loop_;
    frames_in_loop_ = 0;
    align_next_ = have_output_;
  }

  loop_started_ = align_next_;
  if (align_next_) {
    // The first frame of a pass follows the last one delivered by one frame period.
    std::int64_t due_us = 0;
    if (__builtin_add_overflow(last_timestamp_us_, period_us_, &due_us) ||
        __builtin_sub_overflow(due_us, frame.timestamp_us, &timestamp_offset_us_)) {
      error_.set("loop: timestamps of pass %d would overflow", loop_);
      return NextFrame::failed(StatusCode::out_of_range);
    }
    sequence_offset_ = last_sequence_ + 1 - frame.sequence;
    align_next_ = false;
  }
  std::int64_t timestamp_us = 0;
  if (__builtin_add_overflow(frame.timestamp_us, timestamp_offset_us_, &timestamp_us)) {
    error_.set("loop: timestamps of pass %d would overflow", loop_);
    return NextFrame::failed(StatusCode::out_of_range);
  }
  frame.timestamp_us = timestamp_us;
  frame.sequence += sequence_offset_;
  last_timestamp_us_ = frame.timestamp_us;
  last_sequence_ = frame.sequence;
  have_output_ = true;
  ++frames_in_loop_;
  error_.clear();
  return NextFrame::got_frame();
}

}  // namespace octofuse::examples
