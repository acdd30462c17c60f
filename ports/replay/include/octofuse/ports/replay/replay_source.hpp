#pragma once
// DepthSource for recorded datasets:
//   tum:DIR      TUM RGB-D: DIR/depth.txt ("timestamp depth/NAME.png"), 16-bit PNGs at 5000
//                units/m, optional DIR/groundtruth.txt associated by nearest timestamp;
//                intrinsics from "freiburg1/2/3" in the folder name (else the ROS default).
//   icl:DIR      ICL-NUIM, TUM-compatible layout: depth.txt or associations.txt, groundtruth.txt
//                or a *.gt.freiburg file; 5000 units/m; frame-index timestamps become 30 Hz.
//   7scenes:DIR  Microsoft 7-Scenes: frame-XXXXXX.depth.png (mm, 65535 = invalid, delivered as
//                is for the lib validator), frame-XXXXXX.pose.txt (4x4 camera to world),
//                camera-intrinsics.txt; 30 Hz.
//   raw:FILE     SLAMBench .raw (raw_format.hpp); mm; 30 Hz; intrinsics must be given.
//
// open() reserves everything in one allocation (bytes_required(config)): the frame ring, one
// file buffer, the PNG decoder's scratch memory and the frame index (names, timestamps,
// ground-truth poses). next() reads and decodes into the ring without allocating.
//
// A bad frame (unreadable PNG, a 7-Scenes frame missing between others, short .raw frame, a pose
// that is not a rotation) gives FrameOutcome::skip with last_error() naming the file and the
// problem; after the last frame next() gives end_of_stream.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/error_text.hpp"
#include "octofuse/ports/replay/png_depth.hpp"
#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::replay {

enum class DatasetFormat : std::uint8_t { tum, icl_nuim, seven_scenes, slambench_raw };

enum class Pacing : std::uint8_t {
  as_fast_as_possible,  // every frame, no waiting (tests, benchmarks)
  real_time,            // frames come due at their timestamps; late reads drop frames
};
// real_time never waits longer than this for a frame: a longer gap between timestamps (a pause
// in the recording, a corrupt timestamp) is replayed as no gap.
inline constexpr std::int64_t kMaxRealTimeWait_us = 2000000;

// A monotonic clock in microseconds and a way to wait for it; tests inject a fake one.
struct ReplayClock {
  std::int64_t (*now_us)(void* context) = nullptr;
  void (*sleep_until_us)(void* context, std::int64_t time_us) = nullptr;
  void* context = nullptr;
};
// std::chrono::steady_clock and std::this_thread::sleep_until.
ReplayClock steady_replay_clock();

struct ReplayConfig {
  static constexpr std::size_t kMaxPath = 512;

  DatasetFormat format = DatasetFormat::tum;
  char path[kMaxPath] = {};  // folder (tum, icl, 7scenes) or file (raw)

  bool has_intrinsics = false;     // use `intrinsics` instead of the dataset's
  PinholeCamera intrinsics;        // width/height 0: taken from the first frame
  float depth_units_per_m = 0.0f;  // 0: the format's (5000 TUM/ICL, 1000 7-Scenes/raw)

  int max_width = 640;
  int max_height = 480;
  int max_frames = 20000;                     // frames in the index; more is an error at open()
  int ring_size = 2;                          // frames valid at once
  std::size_t max_name_bytes_per_frame = 64;  // TUM/ICL file names, on average
  double ground_truth_max_dt_s = 0.02;        // TUM association window (as associate.py)

  Pacing pacing = Pacing::as_fast_as_possible;
  ReplayClock clock;  // for real_time; unset: steady_replay_clock()
};

// Fills `config->format` and `config->path` from "tum:DIR", "icl:DIR", "7scenes:DIR" or
// "raw:FILE", leaving the other fields. invalid_argument for another prefix or an empty or too
// long path.
Status parse_replay_spec(const char* spec, ReplayConfig* config, ErrorText* error);

class ReplaySource final : public DepthSource {
 public:
  explicit ReplaySource(const ReplayConfig& config);
  ~ReplaySource() override;
  ReplaySource(const ReplaySource&) = delete;
  ReplaySource& operator=(const ReplaySource&) = delete;

  // Returns ok; unavailable (folder or file missing); invalid_argument (bad config, missing
  // intrinsics for raw, first frame not 16-bit gray); data_loss (unparsable index, calibration or
  // ground truth file, timestamps going backwards, unreadable first frame); resource_exhausted
  // (more frames than max_frames, names too long, first frame larger than max size, no memory).
  Status open() override;
  NextFrame next(DepthFrame& frame) override;
  void close() override;
  PinholeCamera intrinsics() const override { return intrinsics_; }
  SourceCapabilities capabilities() const override;
  const char* last_error() const override { return error_.c_str(); }

  // Bytes open() takes for `config`, in one allocation.
  static std::size_t bytes_required(const ReplayConfig& config);

  std::size_t frame_count() const { return frame_count_; }
  std::uint64_t frames_dropped() const override { return frames_dropped_; }
  // real_time: gaps between timestamps longer than kMaxRealTimeWait_us replayed as no gap.
  std::uint64_t gaps_shortened() const { return gaps_shortened_; }
  float metres_per_unit() const { return metres_per_unit_; }
  const ReplayConfig& config() const { return config_; }

  // One index entry per frame; public for the reserve() template.
  struct FrameEntry {
    std::int64_t timestamp_us = 0;
    std::uint64_t file_offset = 0;  // raw: frame start; TUM/ICL: name offset in the name pool
    std::uint32_t name_length = 0;
    bool bad = false;  // raw: a frame known at open() to be unreadable (skip it)
    bool has_pose = false;
    double pose[7] = {};  // tx ty tz qx qy qz qw (TUM/ICL ground truth)
  };

  template <typename Arena>
  Status reserve(Arena& arena);

 private:
  Status open_folder_list();  // TUM and ICL-NUIM
  Status open_seven_scenes();
  Status open_raw();
  Status associate_ground_truth(const char* gt_path, double time_scale);
  Status probe_first_frame();
  Status read_into_file_buffer(const char* path, std::size_t* size);
  Status load_depth(std::size_t index, std::uint16_t* pixels, int* width, int* height);
  Status load_pose(std::size_t index, DepthFrame& frame);
  bool frame_path(std::size_t index, char* out, std::size_t capacity) const;
  std::size_t file_buffer_bytes() const;

  ReplayConfig config_;
  ErrorText error_;
  bool open_ = false;
  void* memory_ = nullptr;
  std::size_t memory_bytes_ = 0;

  // Carved by reserve().
  std::uint16_t* ring_ = nullptr;
  std::uint8_t* file_buffer_ = nullptr;
  FrameEntry* entries_ = nullptr;
  char* names_ = nullptr;
  PngDepthDecoder png_;

  std::size_t frame_count_ = 0;
  std::size_t names_used_ = 0;
  std::size_t next_index_ = 0;
  std::uint64_t delivered_ = 0;
  std::uint64_t frames_dropped_ = 0;
  std::uint64_t gaps_shortened_ = 0;
  int raw_fd_ = -1;
  std::uint64_t raw_file_size_ = 0;
  bool any_ground_truth_ = false;
  float metres_per_unit_ = 0.001f;
  PinholeCamera intrinsics_;

  bool clock_started_ = false;
  std::int64_t clock_start_us_ = 0;
  std::int64_t data_start_us_ = 0;
};

template <typename Arena>
Status ReplaySource::reserve(Arena& arena) {
  // Raw byte buffers are not value-initialised: every byte is written before it is read.
  const std::size_t frame_pixels =
      static_cast<std::size_t>(config_.max_width) * static_cast<std::size_t>(config_.max_height);
  Result<void*> ring = arena.allocate_bytes(
      frame_pixels * static_cast<std::size_t>(config_.ring_size) * sizeof(std::uint16_t),
      kArenaAlignment);
  if (!ring.ok()) return ring.status();
  Result<void*> file = arena.allocate_bytes(file_buffer_bytes(), 16);
  if (!file.ok()) return file.status();
  Result<FrameEntry*> entries =
      arena.template allocate_array<FrameEntry>(static_cast<std::size_t>(config_.max_frames));
  if (!entries.ok()) return entries.status();
  Result<void*> names = arena.allocate_bytes(
      static_cast<std::size_t>(config_.max_frames) * config_.max_name_bytes_per_frame, 1);
  if (!names.ok()) return names.status();
  if (config_.format != DatasetFormat::slambench_raw) OCTOFUSE_TRY(png_.reserve(arena));
  ring_ = static_cast<std::uint16_t*>(ring.value());
  file_buffer_ = static_cast<std::uint8_t*>(file.value());
  entries_ = entries.value();
  names_ = static_cast<char*>(names.value());
  return ok_status();
}

}  // namespace octofuse::replay
