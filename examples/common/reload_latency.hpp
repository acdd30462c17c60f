#pragma once
// ReloadLatencyProbe: a BlockStore that passes every call to the store it wraps and measures how
// long stored blocks take to come back. The pipeline asks the store holds() for exactly the
// stored blocks its integration needs in a frame and leaves out (the frame's read budget is
// spent); take() reads a block back. For each block read back the probe counts the frames that
// left it out before (each one fused without it) and the frames from the first of them to the
// read (the camera may have looked away in between). A block read in the frame that first needs
// it, or before (the view's read-ahead), counts 0 in both. The pipeline cannot count this itself:
// it keeps no state per stored block between frames.

#include <array>
#include <cstddef>
#include <cstdint>
#include <unordered_map>

#include "octofuse/map/block_store.hpp"
#include "octofuse/ports/host/json_writer.hpp"

namespace octofuse::examples {

// Reads back by a count of frames: buckets 0 .. kReloadLatencyBuckets - 2 exact, the last one
// that many or more; the largest count exact.
inline constexpr std::size_t kReloadLatencyBuckets = 256;

struct FrameCountHistogram {
  std::array<std::uint64_t, kReloadLatencyBuckets> reads{};
  std::uint64_t max_frames = 0;

  void add(std::uint64_t frames);
  // The reads that counted at least one frame, and the count at the given share (0..1) of them
  // (the last bucket counts as its lower bound); 0 when none did.
  std::uint64_t nonzero() const;
  std::uint64_t frames_at(double share) const;
};

struct ReloadLatency {
  FrameCountHistogram frames_left_out;  // frames that needed the block and went without it
  FrameCountHistogram frames_waited;    // from the first of them to the frame that read it
  std::uint64_t waiting = 0;            // left out and not read back yet
};

// Reads back counted in `a` and not in `b` (a later and an earlier copy of one probe's counts);
// the maxima are those of the buckets that grew (exact below the last one), `waiting` is a's.
ReloadLatency reload_latency_since(const ReloadLatency& a, const ReloadLatency& b);

// An object: "read" (every block read back), "left_out" (those that had been left out),
// "waiting" (left out, not read back yet), and "frames_left_out" and "frames_waited", each with
// "median", "p90", "p99" and "max" over the reads that had been left out and "reads_by_frames"
// (all reads by frames, up to the last bucket used).
void write_reload_latency_json(host::JsonWriter& json, const ReloadLatency& latency);

class ReloadLatencyProbe final : public BlockStore {
 public:
  // `inner` and `out` outlive the probe; `out` is updated as blocks are read back.
  ReloadLatencyProbe(BlockStore* inner, ReloadLatency* out);

  // The frame about to be processed (an increasing count), and its end: a read counts once the
  // pipeline has kept the block (a take() that release() follows at once is undone: a pool was
  // full, and the block waits on).
  void begin_frame(std::uint64_t frame);
  void end_frame() { count_taken(); }

  Status put(std::uint64_t block_morton, const std::uint8_t* record, std::size_t size) override;
  std::size_t find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi, std::uint64_t* keys,
                          std::size_t capacity) override;
  bool holds(std::uint64_t block_morton) override;
  Result<std::size_t> take(std::uint64_t block_morton, std::uint8_t* record,
                           std::size_t capacity) override;
  void release(std::uint64_t block_morton) override;

 private:
  struct LeftOut {
    std::uint64_t first_frame = 0;
    std::uint64_t last_frame = 0;
    std::uint64_t frames = 0;  // distinct frames that left it out
  };
  void count_taken();

  BlockStore* inner_;
  ReloadLatency* out_;
  std::uint64_t frame_ = 0;
  // Blocks left out and not read back yet.
  std::unordered_map<std::uint64_t, LeftOut> left_out_;
  // The last block taken, until the next call shows it was kept.
  bool taken_pending_ = false;
  std::uint64_t taken_key_ = 0;
  bool taken_was_left_out_ = false;
  LeftOut taken_left_out_;
};

}  // namespace octofuse::examples
