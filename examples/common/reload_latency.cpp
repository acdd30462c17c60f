#include "reload_latency.hpp"

#include <algorithm>

namespace octofuse::examples {

void FrameCountHistogram::add(std::uint64_t frames) {
  ++reads[std::min<std::uint64_t>(frames, kReloadLatencyBuckets - 1)];
  max_frames = std::max(max_frames, frames);
}

std::uint64_t FrameCountHistogram::nonzero() const {
  std::uint64_t n = 0;
  for (std::size_t i = 1; i < kReloadLatencyBuckets; ++i) n += reads[i];
  return n;
}

std::uint64_t FrameCountHistogram::frames_at(double share) const {
  const std::uint64_t n = nonzero();
  if (n == 0) return 0;
  // The smallest count c with at least ceil(share * n) of the reads at most c (rank 1 at least).
  const double clamped = std::min(1.0, std::max(0.0, share));
  const std::uint64_t rank = std::max<std::uint64_t>(
      1, static_cast<std::uint64_t>(clamped * static_cast<double>(n) + 0.999999));
  std::uint64_t seen = 0;
  for (std::size_t i = 1; i < kReloadLatencyBuckets; ++i) {
    seen += reads[i];
    if (seen >= rank) return i;
  }
  return kReloadLatencyBuckets - 1;
}

namespace {

FrameCountHistogram histogram_since(const FrameCountHistogram& a, const FrameCountHistogram& b) {
  FrameCountHistogram d;
  for (std::size_t i = 0; i < kReloadLatencyBuckets; ++i) d.reads[i] = a.reads[i] - b.reads[i];
  for (std::size_t i = kReloadLatencyBuckets; i-- > 0;) {
    if (d.reads[i] == 0) continue;
    d.max_frames = i + 1 == kReloadLatencyBuckets ? a.max_frames : i;
    break;
  }
  return d;
}

void write_histogram_json(host::JsonWriter& json, const FrameCountHistogram& h) {
  std::size_t used = 0;
  for (std::size_t i = 0; i < kReloadLatencyBuckets; ++i) {
    if (h.reads[i] > 0) used = i + 1;
  }
  json.begin_object();
  json.key("median").value(h.frames_at(0.5));
  json.key("p90").value(h.frames_at(0.9));
  json.key("p99").value(h.frames_at(0.99));
  json.key("max").value(h.max_frames);
  json.key("reads_by_frames").begin_array();
  for (std::size_t i = 0; i < used; ++i) json.value(h.reads[i]);
  json.end_array();
  json.end_object();
}

}  // namespace

ReloadLatency reload_latency_since(const ReloadLatency& a, const ReloadLatency& b) {
  ReloadLatency d;
  d.frames_left_out = histogram_since(a.frames_left_out, b.frames_left_out);
  d.frames_waited = histogram_since(a.frames_waited, b.frames_waited);
  d.waiting = a.waiting;
  return d;
}

void write_reload_latency_json(host::JsonWriter& json, const ReloadLatency& latency) {
  std::uint64_t read = 0;
  for (std::uint64_t n : latency.frames_left_out.reads) read += n;
  json.begin_object();
  json.key("read").value(read);
  json.key("left_out").value(latency.frames_left_out.nonzero());
  json.key("waiting").value(latency.waiting);
  json.key("frames_left_out");
  write_histogram_json(json, latency.frames_left_out);
  json.key("frames_waited");
  write_histogram_json(json, latency.frames_waited);
  json.end_object();
}

ReloadLatencyProbe::ReloadLatencyProbe(BlockStore* inner, ReloadLatency* out)
    : inner_(inner), out_(out) {
  // A few frames' worth of blocks left out (17-18 a frame on 7-Scenes under 16 MB) without a
  // rehash; the entries themselves are the host's, as the host store's own index is.
  left_out_.reserve(4096);
}

void ReloadLatencyProbe::begin_frame(std::uint64_t frame) {
  count_taken();
  frame_ = frame;
}

void ReloadLatencyProbe::count_taken() {
  if (!taken_pending_) return;
  taken_pending_ = false;
  if (taken_was_left_out_) {
    out_->frames_left_out.add(taken_left_out_.frames);
    out_->frames_waited.add(frame_ - taken_left_out_.first_frame);
  } else {
    out_->frames_left_out.add(0);
    out_->frames_waited.add(0);
  }
}

Status ReloadLatencyProbe::put(std::uint64_t block_morton, const std::uint8_t* record,
                               std::size_t size) {
  count_taken();
  return inner_->put(block_morton, record, size);
}

std::size_t ReloadLatencyProbe::find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                                            std::uint64_t* keys, std::size_t capacity) {
  count_taken();
  return inner_->find_in_box(lo, hi, keys, capacity);
}

bool ReloadLatencyProbe::holds(std::uint64_t block_morton) {
  count_taken();
  const bool held = inner_->holds(block_morton);
  // The pipeline asks only about blocks its integration needs and is about to leave out.
  if (held) {
    const auto [it, first] = left_out_.try_emplace(block_morton);
    LeftOut& entry = it->second;
    if (first) {
      entry.first_frame = frame_;
      entry.last_frame = frame_;
      entry.frames = 1;
      out_->waiting = left_out_.size();
    } else if (entry.last_frame != frame_) {
      entry.last_frame = frame_;
      ++entry.frames;
    }
  }
  return held;
}

Result<std::size_t> ReloadLatencyProbe::take(std::uint64_t block_morton, std::uint8_t* record,
                                             std::size_t capacity) {
  count_taken();
  const Result<std::size_t> size = inner_->take(block_morton, record, capacity);
  if (!size.ok()) return size;
  taken_pending_ = true;
  taken_key_ = block_morton;
  taken_was_left_out_ = false;
  const auto it = left_out_.find(block_morton);
  if (it != left_out_.end()) {
    taken_was_left_out_ = true;
    taken_left_out_ = it->second;
    left_out_.erase(it);
    out_->waiting = left_out_.size();
  }
  return size;
}

void ReloadLatencyProbe::release(std::uint64_t block_morton) {
  if (taken_pending_ && block_morton == taken_key_) {
    // Not restored: it waits on, as it did before the take.
    taken_pending_ = false;
    if (taken_was_left_out_) {
      left_out_.emplace(block_morton, taken_left_out_);
      out_->waiting = left_out_.size();
    }
  } else {
    count_taken();
  }
  inner_->release(block_morton);
}

}  // namespace octofuse::examples
