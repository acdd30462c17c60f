#include "octofuse/ports/replay/replay_source.hpp"

#include <dirent.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>
#include <thread>

#include "octofuse/pipeline/steady_clock.hpp"
#include "octofuse/ports/replay/raw_format.hpp"
#include "octofuse/ports/replay/text_parsers.hpp"

namespace octofuse::replay {
namespace {

constexpr std::int64_t kMicrosecondsPerSecond = 1000000;
constexpr double kSyntheticRateHz = 30.0;  // 7-Scenes, .raw and ICL-NUIM frame indices
// Text index files (depth.txt, groundtruth.txt) are read whole at open(); bigger is corruption.
constexpr std::size_t kMaxTextFileBytes = 256u * 1024u * 1024u;

std::int64_t synthetic_timestamp_us(std::size_t index) {
  return static_cast<std::int64_t>(index) * kMicrosecondsPerSecond / 30;
}

// Callers pass timestamps the parsers bounded by kMaxTimestamp_s, so this cannot overflow.
std::int64_t seconds_to_us(double seconds) {
  return static_cast<std::int64_t>(std::llround(seconds * 1e6));
}

bool is_directory(const char* path) {
  struct stat info;
  return ::stat(path, &info) == 0 && S_ISDIR(info.st_mode);
}

bool is_file(const char* path) {
  struct stat info;
  return ::stat(path, &info) == 0 && S_ISREG(info.st_mode);
}

bool join(char* out, std::size_t capacity, const char* dir, const char* name,
          std::size_t name_length) {
  const int written =
      std::snprintf(out, capacity, "%s/%.*s", dir, static_cast<int>(name_length), name);
  return written > 0 && static_cast<std::size_t>(written) < capacity;
}

// A whole text file in a temporary heap buffer: index files are read once at open().
struct TextFile {
  char* data = nullptr;
  std::size_t size = 0;
  TextFile() = default;
  TextFile(const TextFile&) = delete;
  TextFile& operator=(const TextFile&) = delete;
  ~TextFile() { std::free(data); }
};

Status read_text_file(const char* path, TextFile* file, ErrorText* error) {
  const int fd = ::open(path, O_RDONLY | O_NONBLOCK);
  if (fd < 0) {
    error->set("%s: cannot open (%s)", path, std::strerror(errno));
    return StatusCode::unavailable;
  }
  struct stat info;
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    ::close(fd);
    error->set("%s: not a regular file", path);
    return StatusCode::data_loss;
  }
  const std::size_t size = static_cast<std::size_t>(info.st_size);
  if (size > kMaxTextFileBytes) {
    ::close(fd);
    error->set("%s: %zu bytes is too large for an index file", path, size);
    return StatusCode::data_loss;
  }
  file->data = static_cast<char*>(std::malloc(size + 1));
  if (file->data == nullptr) {
    ::close(fd);
    error->set("%s: no memory for %zu bytes", path, size);
    return StatusCode::resource_exhausted;
  }
  std::size_t done = 0;
  while (done < size) {
    const ssize_t got = ::read(fd, file->data + done, size - done);
    if (got <= 0) {
      if (got < 0 && errno == EINTR) continue;
      ::close(fd);
      error->set("%s: read failed after %zu of %zu bytes", path, done, size);
      return StatusCode::data_loss;
    }
    done += static_cast<std::size_t>(got);
  }
  ::close(fd);
  file->data[size] = '\0';
  file->size = size;
  return ok_status();
}

bool read_exact_at(int fd, void* out, std::size_t bytes, std::uint64_t offset) {
  std::uint8_t* p = static_cast<std::uint8_t*>(out);
  std::size_t done = 0;
  while (done < bytes) {
    const ssize_t got = ::pread(fd, p + done, bytes - done, static_cast<off_t>(offset + done));
    if (got <= 0) {
      if (got < 0 && errno == EINTR) continue;
      return false;
    }
    done += static_cast<std::size_t>(got);
  }
  return true;
}

PinholeCamera tum_default_intrinsics(const char* path) {
  // Calibrations published with the TUM RGB-D benchmark; the ROS default for anything else.
  PinholeCamera camera{525.0f, 525.0f, 319.5f, 239.5f, 640, 480};
  if (std::strstr(path, "freiburg1") != nullptr)
    camera = {517.3f, 516.5f, 318.6f, 255.3f, 640, 480};
  if (std::strstr(path, "freiburg2") != nullptr)
    camera = {520.9f, 521.0f, 325.1f, 249.7f, 640, 480};
  if (std::strstr(path, "freiburg3") != nullptr)
    camera = {535.4f, 539.2f, 320.1f, 247.6f, 640, 480};
  return camera;
}

// The highest N of DIR/frame-NNNNNN.depth.png (the listing, so a missing frame in the middle
// does not end the sequence); -1 when there is none or the folder cannot be listed.
long highest_seven_scenes_frame(const char* dir) {
  DIR* listing = ::opendir(dir);
  if (listing == nullptr) return -1;
  long highest = -1;
  while (const dirent* entry = ::readdir(listing)) {
    constexpr const char kPrefix[] = "frame-";
    constexpr const char kSuffix[] = ".depth.png";
    constexpr std::size_t kPrefixLength = sizeof(kPrefix) - 1;
    constexpr std::size_t kDigits = 6;
    if (std::strlen(entry->d_name) != kPrefixLength + kDigits + sizeof(kSuffix) - 1 ||
        std::strncmp(entry->d_name, kPrefix, kPrefixLength) != 0 ||
        std::strcmp(entry->d_name + kPrefixLength + kDigits, kSuffix) != 0) {
      continue;
    }
    long index = 0;
    bool digits = true;
    for (std::size_t i = 0; i < kDigits && digits; ++i) {
      const char c = entry->d_name[kPrefixLength + i];
      digits = c >= '0' && c <= '9';
      index = index * 10 + (c - '0');
    }
    if (digits && index > highest) highest = index;
  }
  ::closedir(listing);
  return highest;
}

// Finds the first DIR/*.gt.freiburg (ICL-NUIM's ground truth name).
bool find_icl_ground_truth(const char* dir, char* out, std::size_t capacity) {
  DIR* listing = ::opendir(dir);
  if (listing == nullptr) return false;
  bool found = false;
  char best[256] = {};
  while (const dirent* entry = ::readdir(listing)) {
    const std::size_t length = std::strlen(entry->d_name);
    constexpr const char kSuffix[] = ".gt.freiburg";
    constexpr std::size_t kSuffixLength = sizeof(kSuffix) - 1;
    if (length > kSuffixLength && length < sizeof(best) &&
        std::strcmp(entry->d_name + length - kSuffixLength, kSuffix) == 0 &&
        (!found || std::strcmp(entry->d_name, best) < 0)) {
      std::snprintf(best, sizeof(best), "%s", entry->d_name);
      found = true;
    }
  }
  ::closedir(listing);
  return found && join(out, capacity, dir, best, std::strlen(best));
}

void steady_sleep_until_us(void* /*context*/, std::int64_t time_us) {
  std::this_thread::sleep_until(
      std::chrono::steady_clock::time_point(std::chrono::microseconds(time_us)));
}

}  // namespace

ReplayClock steady_replay_clock() {
  ReplayClock clock;
  clock.now_us = &octofuse::steady_now_us;
  clock.sleep_until_us = &steady_sleep_until_us;
  return clock;
}

Status parse_replay_spec(const char* spec, ReplayConfig* config, ErrorText* error) {
  struct Prefix {
    const char* text;
    DatasetFormat format;
  };
  static constexpr Prefix kPrefixes[] = {{"tum:", DatasetFormat::tum},
                                         {"icl:", DatasetFormat::icl_nuim},
                                         {"7scenes:", DatasetFormat::seven_scenes},
                                         {"raw:", DatasetFormat::slambench_raw}};
  for (const Prefix& prefix : kPrefixes) {
    const std::size_t length = std::strlen(prefix.text);
    if (std::strncmp(spec, prefix.text, length) != 0) continue;
    const char* path = spec + length;
    const std::size_t path_length = std::strlen(path);
    if (path_length == 0) {
      error->set("source \"%s\": the path after \"%s\" is empty", spec, prefix.text);
      return StatusCode::invalid_argument;
    }
    if (path_length >= ReplayConfig::kMaxPath) {
      error->set("source \"%.64s...\": path longer than %zu characters", spec,
                 ReplayConfig::kMaxPath - 1);
      return StatusCode::invalid_argument;
    }
    config->format = prefix.format;
    std::memcpy(config->path, path, path_length + 1);
    // "DIR/" and "DIR" name the same folder; messages read better without the slash.
    for (std::size_t n = path_length; n > 1 && config->path[n - 1] == '/'; --n) {
      config->path[n - 1] = '\0';
    }
    return ok_status();
  }
  error->set("source \"%s\": expected tum:DIR, icl:DIR, 7scenes:DIR or raw:FILE", spec);
  return StatusCode::invalid_argument;
}

ReplaySource::ReplaySource(const ReplayConfig& config) : config_(config) {}

ReplaySource::~ReplaySource() {
  close();
}

std::size_t ReplaySource::file_buffer_bytes() const {
  if (config_.format == DatasetFormat::slambench_raw) return 0;  // read straight into the ring
  // The largest max_width x max_height 16-bit PNG: stored deflate blocks, one filter byte per row,
  // plus room for chunk overhead.
  const std::size_t pixels =
      static_cast<std::size_t>(config_.max_width) * static_cast<std::size_t>(config_.max_height);
  return 2 * pixels + static_cast<std::size_t>(config_.max_height) + pixels / 8192 * 8 + 256 * 1024;
}

std::size_t ReplaySource::bytes_required(const ReplayConfig& config) {
  ReplaySource sizing(config);
  ArenaSizer sizer;
  sizing.reserve(sizer).ignore();  // the sizer never fails
  return sizer.bytes_used();
}

SourceCapabilities ReplaySource::capabilities() const {
  SourceCapabilities caps;
  caps.live = config_.pacing == Pacing::real_time;
  caps.has_ground_truth = any_ground_truth_;
  caps.ring_size = config_.ring_size;
  caps.nominal_rate_hz = static_cast<float>(kSyntheticRateHz);
  return caps;
}

Status ReplaySource::open() {
  close();
  error_.clear();
  if (config_.path[0] == '\0' || config_.max_width <= 0 || config_.max_height <= 0 ||
      config_.max_width > 16384 || config_.max_height > 16384 || config_.ring_size < 1 ||
      config_.ring_size > 64 || config_.max_frames < 1 || config_.max_name_bytes_per_frame < 8 ||
      !(config_.depth_units_per_m >= 0.0f) || !(config_.ground_truth_max_dt_s >= 0.0)) {
    error_.set(
        "replay: invalid configuration (path, sizes 1..16384, ring 1..64, max_frames >= 1, "
        "depth scale >= 0)");
    return StatusCode::invalid_argument;
  }
  if (config_.has_intrinsics && !(config_.intrinsics.fx > 0.0f && config_.intrinsics.fy > 0.0f)) {
    error_.set("replay: given intrinsics need fx, fy > 0");
    return StatusCode::invalid_argument;
  }
  if (config_.pacing == Pacing::real_time &&
      (config_.clock.now_us == nullptr || config_.clock.sleep_until_us == nullptr)) {
    config_.clock = steady_replay_clock();
  }

  memory_bytes_ = bytes_required(config_);
  memory_ = std::aligned_alloc(kArenaAlignment, align_up(memory_bytes_, kArenaAlignment));
  if (memory_ == nullptr) {
    error_.set("replay: cannot reserve %zu bytes", memory_bytes_);
    return StatusCode::resource_exhausted;
  }
  LinearArena arena(memory_, memory_bytes_);
  Status status = reserve(arena);
  OCTOFUSE_CHECK(status.ok());  // sized by the same reserve()

  switch (config_.format) {
    case DatasetFormat::tum:
    case DatasetFormat::icl_nuim:
      status = open_folder_list();
      break;
    case DatasetFormat::seven_scenes:
      status = open_seven_scenes();
      break;
    case DatasetFormat::slambench_raw:
      status = open_raw();
      break;
  }
  if (status.ok()) status = probe_first_frame();
  if (!status.ok()) {
    close();
    return status;
  }
  open_ = true;
  return ok_status();
}

void ReplaySource::close() {
  if (raw_fd_ >= 0) ::close(raw_fd_);
  raw_fd_ = -1;
  std::free(memory_);
  memory_ = nullptr;
  memory_bytes_ = 0;
  ring_ = nullptr;
  file_buffer_ = nullptr;
  entries_ = nullptr;
  names_ = nullptr;
  open_ = false;
  frame_count_ = 0;
  names_used_ = 0;
  next_index_ = 0;
  delivered_ = 0;
  frames_dropped_ = 0;
  any_ground_truth_ = false;
  clock_started_ = false;
}

Status ReplaySource::open_folder_list() {
  const char* dir = config_.path;
  const bool icl = config_.format == DatasetFormat::icl_nuim;
  metres_per_unit_ =
      1.0f / (config_.depth_units_per_m > 0.0f ? config_.depth_units_per_m : 5000.0f);
  if (icl) {
    intrinsics_ = PinholeCamera{481.2f, 480.0f, 319.5f, 239.5f, 640, 480};
  } else {
    intrinsics_ = tum_default_intrinsics(dir);
  }
  if (!is_directory(dir)) {
    error_.set("%s: no such directory", dir);
    return StatusCode::unavailable;
  }
  char list_path[ReplayConfig::kMaxPath + 32];
  std::snprintf(list_path, sizeof(list_path), "%s/depth.txt", dir);
  if (icl && !is_file(list_path)) {
    std::snprintf(list_path, sizeof(list_path), "%s/associations.txt", dir);
  }
  TextFile list;
  OCTOFUSE_TRY(read_text_file(list_path, &list, &error_));

  const std::size_t name_capacity =
      static_cast<std::size_t>(config_.max_frames) * config_.max_name_bytes_per_frame;
  LineReader lines(list.data, list.size);
  const char* line;
  std::size_t length;
  double previous_s = 0.0;
  bool all_integral = true;
  while (lines.next(&line, &length)) {
    if (is_blank_or_comment(line, length)) continue;
    TimestampedName item;
    OCTOFUSE_TRY(
        parse_timestamped_name(line, length, &item, list_path, lines.line_number(), &error_));
    if (frame_count_ > 0 && !(item.timestamp_s > previous_s)) {
      error_.set("%s:%d: timestamp %.6f goes backwards or repeats (previous %.6f)", list_path,
                 lines.line_number(), item.timestamp_s, previous_s);
      return StatusCode::data_loss;
    }
    if (frame_count_ == static_cast<std::size_t>(config_.max_frames)) {
      error_.set("%s: more than %d frames (raise max_frames)", list_path, config_.max_frames);
      return StatusCode::resource_exhausted;
    }
    if (item.name_length > name_capacity - names_used_) {
      error_.set("%s:%d: file names exceed the %zu bytes reserved for them", list_path,
                 lines.line_number(), name_capacity);
      return StatusCode::resource_exhausted;
    }
    previous_s = item.timestamp_s;
    all_integral = all_integral && item.timestamp_s == std::floor(item.timestamp_s);
    FrameEntry& entry = entries_[frame_count_++];
    entry = FrameEntry();
    entry.timestamp_us = seconds_to_us(item.timestamp_s);
    entry.file_offset = names_used_;
    entry.name_length = static_cast<std::uint32_t>(item.name_length);
    std::memcpy(names_ + names_used_, item.name, item.name_length);
    names_used_ += item.name_length;
  }
  if (frame_count_ == 0) {
    error_.set("%s: lists no frames", list_path);
    return StatusCode::data_loss;
  }
  // ICL-NUIM numbers its frames 0, 1, 2...: those are indices at 30 Hz, not seconds.
  double time_scale = 1.0;
  if (icl && all_integral) {
    time_scale = 1.0 / kSyntheticRateHz;
    for (std::size_t i = 0; i < frame_count_; ++i) {
      entries_[i].timestamp_us =
          seconds_to_us(static_cast<double>(entries_[i].timestamp_us) * 1e-6 * time_scale);
    }
  }

  char gt_path[ReplayConfig::kMaxPath + 32];
  std::snprintf(gt_path, sizeof(gt_path), "%s/groundtruth.txt", dir);
  if (!is_file(gt_path) && !(icl && find_icl_ground_truth(dir, gt_path, sizeof(gt_path)))) {
    return ok_status();  // ground truth is optional
  }
  return associate_ground_truth(gt_path, time_scale);
}

Status ReplaySource::associate_ground_truth(const char* gt_path, double time_scale) {
  TextFile text;
  OCTOFUSE_TRY(read_text_file(gt_path, &text, &error_));
  LineReader lines(text.data, text.size);

  // Both lists are sorted by time, so one merge pass finds each frame's nearest pose: `before`
  // is the latest pose at or before the frame, `after` the first one later.
  TimestampedPose before, after;
  std::int64_t before_us = 0, after_us = 0;
  bool have_before = false, have_after = false;
  bool seen_any = false;
  double last_s = 0.0;
  auto read_pose = [&](TimestampedPose* pose, std::int64_t* time_us, bool* got) -> Status {
    const char* line;
    std::size_t length;
    *got = false;
    while (lines.next(&line, &length)) {
      if (is_blank_or_comment(line, length)) continue;
      OCTOFUSE_TRY(parse_tum_pose_line(line, length, pose, gt_path, lines.line_number(), &error_));
      if (seen_any && !(pose->timestamp_s > last_s)) {
        error_.set("%s:%d: timestamp %.6f goes backwards or repeats (previous %.6f)", gt_path,
                   lines.line_number(), pose->timestamp_s, last_s);
        return StatusCode::data_loss;
      }
      seen_any = true;
      last_s = pose->timestamp_s;
      *time_us = seconds_to_us(pose->timestamp_s * time_scale);
      *got = true;
      return ok_status();
    }
    return ok_status();
  };
  OCTOFUSE_TRY(read_pose(&after, &after_us, &have_after));
  const std::int64_t max_dt_us = seconds_to_us(config_.ground_truth_max_dt_s);
  for (std::size_t i = 0; i < frame_count_; ++i) {
    FrameEntry& entry = entries_[i];
    while (have_after && after_us <= entry.timestamp_us) {
      before = after;
      before_us = after_us;
      have_before = true;
      OCTOFUSE_TRY(read_pose(&after, &after_us, &have_after));
    }
    const TimestampedPose* best = nullptr;
    std::int64_t best_dt = max_dt_us + 1;
    if (have_before && entry.timestamp_us - before_us < best_dt) {
      best = &before;
      best_dt = entry.timestamp_us - before_us;
    }
    if (have_after && after_us - entry.timestamp_us < best_dt) {
      best = &after;
      best_dt = after_us - entry.timestamp_us;
    }
    if (best == nullptr) continue;
    entry.has_pose = true;
    entry.pose[0] = best->t_W_C.x();
    entry.pose[1] = best->t_W_C.y();
    entry.pose[2] = best->t_W_C.z();
    entry.pose[3] = best->q_W_C.x();
    entry.pose[4] = best->q_W_C.y();
    entry.pose[5] = best->q_W_C.z();
    entry.pose[6] = best->q_W_C.w();
    any_ground_truth_ = true;
  }
  return ok_status();
}

Status ReplaySource::open_seven_scenes() {
  const char* dir = config_.path;
  metres_per_unit_ =
      1.0f / (config_.depth_units_per_m > 0.0f ? config_.depth_units_per_m : 1000.0f);
  if (!is_directory(dir)) {
    error_.set("%s: no such directory", dir);
    return StatusCode::unavailable;
  }
  if (!config_.has_intrinsics) {
    char path[ReplayConfig::kMaxPath + 32];
    std::snprintf(path, sizeof(path), "%s/camera-intrinsics.txt", dir);
    std::size_t size = 0;
    OCTOFUSE_TRY(read_into_file_buffer(path, &size));
    intrinsics_ = PinholeCamera{};
    OCTOFUSE_TRY(parse_intrinsics_matrix(reinterpret_cast<const char*>(file_buffer_), size,
                                         &intrinsics_, path, &error_));
  }
  char path[ReplayConfig::kMaxPath + 32];
  if (!frame_path(0, path, sizeof(path))) {
    error_.set("%s: path too long", dir);
    return StatusCode::invalid_argument;
  }
  // Frames 0 to the highest number present: a missing one in between is skipped by next() (it
  // fails to load) and counted, instead of ending the sequence there.
  const long highest = is_file(path) ? highest_seven_scenes_frame(dir) : -1;
  if (highest >= config_.max_frames) {
    error_.set("%s: frame-%06ld.depth.png: more than %d frames (raise max_frames)", dir, highest,
               config_.max_frames);
    return StatusCode::resource_exhausted;
  }
  for (long i = 0; i <= highest; ++i) {
    FrameEntry& entry = entries_[frame_count_];
    entry = FrameEntry();
    entry.timestamp_us = synthetic_timestamp_us(frame_count_);
    ++frame_count_;
  }
  if (frame_count_ == 0) {
    error_.set("%s: no frame-000000.depth.png", dir);
    return StatusCode::data_loss;
  }
  std::snprintf(path, sizeof(path), "%s/frame-000000.pose.txt", dir);
  any_ground_truth_ = is_file(path);
  return ok_status();
}

Status ReplaySource::open_raw() {
  const char* file = config_.path;
  metres_per_unit_ =
      1.0f / (config_.depth_units_per_m > 0.0f ? config_.depth_units_per_m : 1000.0f);
  raw_fd_ = ::open(file, O_RDONLY | O_NONBLOCK);
  if (raw_fd_ < 0) {
    error_.set("%s: cannot open (%s)", file, std::strerror(errno));
    return StatusCode::unavailable;
  }
  struct stat info;
  if (::fstat(raw_fd_, &info) != 0 || !S_ISREG(info.st_mode)) {
    error_.set("%s: not a regular file", file);
    return StatusCode::unavailable;
  }
  if (!config_.has_intrinsics) {
    error_.set("%s: a .raw recording has no intrinsics; give them (fx,fy,cx,cy)", file);
    return StatusCode::invalid_argument;
  }
  raw_file_size_ = static_cast<std::uint64_t>(info.st_size);
  std::uint64_t offset = 0;
  std::uint64_t frame_bytes = 0;  // the last whole frame's size
  bool resyncing = false;         // the last entry did not parse
  while (offset < raw_file_size_) {
    // A damaged tail longer than the index: its last slot stands for the rest of the file.
    if (resyncing && frame_count_ == static_cast<std::size_t>(config_.max_frames)) break;
    if (frame_count_ == static_cast<std::size_t>(config_.max_frames)) {
      error_.set("%s: more than %d frames (raise max_frames)", file, config_.max_frames);
      return StatusCode::resource_exhausted;
    }
    FrameEntry& entry = entries_[frame_count_];
    entry = FrameEntry();
    entry.timestamp_us = synthetic_timestamp_us(frame_count_);
    entry.file_offset = offset;
    ++frame_count_;
    // A frame that cannot be parsed stays as a bad entry, so next() reports it (skip). The format
    // has no markers to find the next frame by; a recording's frames all have one size, so the
    // index goes on one frame's size further, each slot that does not parse counted as a frame
    // skipped. Without a whole frame before it, nothing after it can be located.
    std::uint8_t depth_header[8], rgb_header[8];
    RawFrameLayout layout;
    ErrorText scratch;
    if (raw_file_size_ - offset < 8 || !read_exact_at(raw_fd_, depth_header, 8, offset) ||
        !parse_raw_frame_header(depth_header, nullptr, offset, raw_file_size_, config_.max_width,
                                config_.max_height, &layout, file, &scratch)
             .ok() ||
        !read_exact_at(raw_fd_, rgb_header, 8,
                       layout.depth_offset + 2ull * layout.depth_width * layout.depth_height) ||
        !parse_raw_frame_header(depth_header, rgb_header, offset, raw_file_size_, config_.max_width,
                                config_.max_height, &layout, file, &scratch)
             .ok()) {
      entry.bad = true;
      resyncing = true;
      if (frame_bytes == 0) break;
      offset = raw_file_size_ - offset > frame_bytes ? offset + frame_bytes : raw_file_size_;
      continue;
    }
    resyncing = false;
    frame_bytes = layout.next_offset - offset;
    offset = layout.next_offset;
  }
  if (frame_count_ == 0) {
    error_.set("%s: empty file", file);
    return StatusCode::data_loss;
  }
  return ok_status();
}

Status ReplaySource::probe_first_frame() {
  // The first frame fixes the image size for the intrinsics; a dataset whose first frame
  // is unreadable is refused here rather than failing on every next().
  int width = 0, height = 0;
  Status status = load_depth(0, ring_, &width, &height);
  if (!status.ok()) return status;
  if (config_.has_intrinsics) intrinsics_ = config_.intrinsics;
  if (!config_.has_intrinsics || intrinsics_.width <= 0 || intrinsics_.height <= 0) {
    intrinsics_.width = width;
    intrinsics_.height = height;
  }
  return ok_status();
}

bool ReplaySource::frame_path(std::size_t index, char* out, std::size_t capacity) const {
  if (config_.format == DatasetFormat::seven_scenes) {
    const int written =
        std::snprintf(out, capacity, "%s/frame-%06zu.depth.png", config_.path, index);
    return written > 0 && static_cast<std::size_t>(written) < capacity;
  }
  const FrameEntry& entry = entries_[index];
  return join(out, capacity, config_.path, names_ + entry.file_offset, entry.name_length);
}

Status ReplaySource::read_into_file_buffer(const char* path, std::size_t* size) {
  const int fd = ::open(path, O_RDONLY | O_NONBLOCK);
  if (fd < 0) {
    error_.set("%s: cannot open (%s)", path, std::strerror(errno));
    return StatusCode::unavailable;
  }
  struct stat info;
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    ::close(fd);
    error_.set("%s: not a regular file", path);
    return StatusCode::data_loss;
  }
  const std::uint64_t file_size = static_cast<std::uint64_t>(info.st_size);
  if (file_size > file_buffer_bytes()) {
    ::close(fd);
    error_.set("%s: %llu bytes, more than a %dx%d 16-bit PNG can need (%zu)", path,
               static_cast<unsigned long long>(file_size), config_.max_width, config_.max_height,
               file_buffer_bytes());
    return StatusCode::data_loss;
  }
  const bool ok = read_exact_at(fd, file_buffer_, static_cast<std::size_t>(file_size), 0);
  ::close(fd);
  if (!ok) {
    error_.set("%s: read failed", path);
    return StatusCode::data_loss;
  }
  *size = static_cast<std::size_t>(file_size);
  return ok_status();
}

Status ReplaySource::load_depth(std::size_t index, std::uint16_t* pixels, int* width, int* height) {
  if (config_.format == DatasetFormat::slambench_raw) {
    const FrameEntry& entry = entries_[index];
    std::uint8_t depth_header[8], rgb_header[8];
    RawFrameLayout layout;
    const char* file = config_.path;
    if (raw_file_size_ - entry.file_offset < 8) {
      error_.set("%s: short frame at byte %llu: only %llu bytes left", file,
                 static_cast<unsigned long long>(entry.file_offset),
                 static_cast<unsigned long long>(raw_file_size_ - entry.file_offset));
      return StatusCode::data_loss;
    }
    if (!read_exact_at(raw_fd_, depth_header, 8, entry.file_offset)) {
      error_.set("%s: read failed at byte %llu", file,
                 static_cast<unsigned long long>(entry.file_offset));
      return StatusCode::data_loss;
    }
    OCTOFUSE_TRY(parse_raw_frame_header(depth_header, nullptr, entry.file_offset, raw_file_size_,
                                        config_.max_width, config_.max_height, &layout, file,
                                        &error_));
    const std::size_t count = static_cast<std::size_t>(layout.depth_width) *
                              static_cast<std::size_t>(layout.depth_height);
    if (!read_exact_at(raw_fd_, rgb_header, 8, layout.depth_offset + 2 * count)) {
      error_.set("%s: read failed at byte %llu", file,
                 static_cast<unsigned long long>(layout.depth_offset + 2 * count));
      return StatusCode::data_loss;
    }
    OCTOFUSE_TRY(parse_raw_frame_header(depth_header, rgb_header, entry.file_offset, raw_file_size_,
                                        config_.max_width, config_.max_height, &layout, file,
                                        &error_));
    if (!read_exact_at(raw_fd_, pixels, 2 * count, layout.depth_offset)) {
      error_.set("%s: read failed in the depth of the frame at byte %llu", file,
                 static_cast<unsigned long long>(entry.file_offset));
      return StatusCode::data_loss;
    }
    little_endian_to_host(pixels, count);
    *width = static_cast<int>(layout.depth_width);
    *height = static_cast<int>(layout.depth_height);
    return ok_status();
  }
  char path[ReplayConfig::kMaxPath + 64];
  if (!frame_path(index, path, sizeof(path))) {
    error_.set("%s: frame %zu: path too long", config_.path, index);
    return StatusCode::data_loss;
  }
  std::size_t size = 0;
  const Status read = read_into_file_buffer(path, &size);
  if (!read.ok()) return read.code() == StatusCode::unavailable ? StatusCode::data_loss : read;
  return png_.decode(file_buffer_, size, pixels, config_.max_width, config_.max_height, width,
                     height, path, &error_);
}

Status ReplaySource::load_pose(std::size_t index, DepthFrame& frame) {
  frame.has_ground_truth = false;
  frame.T_W_C_ground_truth.setIdentity();
  if (config_.format == DatasetFormat::seven_scenes) {
    char path[ReplayConfig::kMaxPath + 64];
    std::snprintf(path, sizeof(path), "%s/frame-%06zu.pose.txt", config_.path, index);
    if (!is_file(path)) return ok_status();  // ground truth is optional per frame
    std::size_t size = 0;
    OCTOFUSE_TRY(read_into_file_buffer(path, &size));
    Eigen::Matrix4d T_W_C;
    OCTOFUSE_TRY(parse_pose_matrix(reinterpret_cast<const char*>(file_buffer_), size, &T_W_C, path,
                                   &error_));
    frame.T_W_C_ground_truth = T_W_C;
    frame.has_ground_truth = true;
    return ok_status();
  }
  const FrameEntry& entry = entries_[index];
  if (!entry.has_pose) return ok_status();
  const Eigen::Quaterniond q(entry.pose[6], entry.pose[3], entry.pose[4], entry.pose[5]);
  frame.T_W_C_ground_truth.topLeftCorner<3, 3>() = q.toRotationMatrix();
  frame.T_W_C_ground_truth.topRightCorner<3, 1>() =
      Eigen::Vector3d(entry.pose[0], entry.pose[1], entry.pose[2]);
  frame.has_ground_truth = true;
  return ok_status();
}

NextFrame ReplaySource::next(DepthFrame& frame) {
  if (!open_) {
    error_.set("replay: next() before a successful open()");
    return NextFrame::failed(StatusCode::failed_precondition);
  }
  if (next_index_ >= frame_count_) return NextFrame::ended();

  if (config_.pacing == Pacing::real_time) {
    const ReplayClock& clock = config_.clock;
    if (!clock_started_) {
      clock_started_ = true;
      clock_start_us_ = clock.now_us(clock.context);
      data_start_us_ = entries_[next_index_].timestamp_us;
    } else {
      const std::int64_t elapsed_us = clock.now_us(clock.context) - clock_start_us_;
      // A camera overwrites frames nobody read: skip to the newest one already due.
      while (next_index_ + 1 < frame_count_ &&
             entries_[next_index_ + 1].timestamp_us - data_start_us_ <= elapsed_us) {
        ++next_index_;
        ++frames_dropped_;
      }
      std::int64_t due_us = clock_start_us_ + entries_[next_index_].timestamp_us - data_start_us_;
      if (due_us - (clock_start_us_ + elapsed_us) > kMaxRealTimeWait_us) {
        // A pause in the recording (or a corrupt timestamp): replay it as no pause, restarting
        // the clock at this frame, rather than sleeping through it.
        clock_start_us_ += elapsed_us;
        data_start_us_ = entries_[next_index_].timestamp_us;
        due_us = clock_start_us_;
        ++gaps_shortened_;
      }
      if (due_us > clock_start_us_ + elapsed_us) clock.sleep_until_us(clock.context, due_us);
    }
  }

  const std::size_t index = next_index_++;
  const std::size_t frame_pixels =
      static_cast<std::size_t>(config_.max_width) * static_cast<std::size_t>(config_.max_height);
  std::uint16_t* pixels =
      ring_ + static_cast<std::size_t>(delivered_ % static_cast<std::uint64_t>(config_.ring_size)) *
                  frame_pixels;
  int width = 0, height = 0;
  const Status loaded = load_depth(index, pixels, &width, &height);
  if (!loaded.ok()) return NextFrame::skipped(loaded);
  const Status posed = load_pose(index, frame);
  if (!posed.ok()) return NextFrame::skipped(posed);
  frame.depth_raw = ImageView<const std::uint16_t>(pixels, width, height);
  frame.metres_per_unit = metres_per_unit_;
  frame.timestamp_us = entries_[index].timestamp_us;
  frame.sequence = index;
  ++delivered_;
  return NextFrame::got_frame();
}

}  // namespace octofuse::replay
