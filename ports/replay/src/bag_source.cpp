#include "octofuse/ports/replay/bag_source.hpp"

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <new>

#include "octofuse/core/arena.hpp"
#include "octofuse/ports/replay/rvl.hpp"

namespace octofuse::replay {
namespace {

bool starts_with(const char* text, const char* prefix) {
  return std::strncmp(text, prefix, std::strlen(prefix)) == 0;
}

// ROS 2 names types "pkg/msg/Type", ROS 1 "pkg/Type": both are accepted.
bool is_type(const char* schema, const char* package, const char* type) {
  const std::size_t p = std::strlen(package);
  if (std::strncmp(schema, package, p) != 0 || schema[p] != '/') return false;
  const char* rest = schema + p + 1;
  if (starts_with(rest, "msg/")) rest += 4;
  return std::strcmp(rest, type) == 0;
}

BagSource::Kind kind_of(const McapChannel& channel) {
  const char* s = channel.schema_name;
  if (is_type(s, "sensor_msgs", "Image")) return BagSource::Kind::image;
  if (is_type(s, "sensor_msgs", "CompressedImage")) return BagSource::Kind::compressed;
  if (is_type(s, "sensor_msgs", "CameraInfo")) return BagSource::Kind::camera_info;
  // ROS 1's tf/tfMessage is tf2_msgs/TFMessage on the wire.
  if (is_type(s, "tf2_msgs", "TFMessage") || is_type(s, "tf", "tfMessage")) {
    return BagSource::Kind::tf;
  }
  if (is_type(s, "nav_msgs", "Odometry")) return BagSource::Kind::odometry;
  if (is_type(s, "geometry_msgs", "PoseStamped")) return BagSource::Kind::pose;
  return BagSource::Kind::other;
}

// Topics that name themselves ground truth ("/ground_truth", "/groundtruth/pose"): chosen for
// the ground truth, passed over for the odometry, when a bag has several pose topics.
bool is_ground_truth_topic(const char* topic) {
  return std::strstr(topic, "ground_truth") != nullptr ||
         std::strstr(topic, "groundtruth") != nullptr;
}

bool is_pose_kind(BagSource::Kind kind) {
  return kind == BagSource::Kind::odometry || kind == BagSource::Kind::pose;
}

bool copy_value(const char* begin, std::size_t size, char* out, std::size_t capacity) {
  if (size >= capacity) return false;
  std::memcpy(out, begin, size);
  out[size] = '\0';
  return true;
}

// A whole number of megabytes in [min_mb, max_mb] from an option's value (not terminated).
bool parse_megabytes(const char* value, std::size_t value_size, long min_mb, long max_mb,
                     std::size_t* bytes) {
  char number[16] = {};
  if (!copy_value(value, value_size, number, sizeof(number))) return false;
  char* end_number = nullptr;
  const long mb = std::strtol(number, &end_number, 10);
  if (end_number == number || *end_number != '\0' || mb < min_mb || mb > max_mb) return false;
  *bytes = static_cast<std::size_t>(mb) << 20;
  return true;
}

// A whole number in [min, max] from an option's value (not terminated).
bool parse_count(const char* value, std::size_t value_size, long min, long max, int* count) {
  char number[8] = {};
  if (!copy_value(value, value_size, number, sizeof(number))) return false;
  char* end_number = nullptr;
  const long n = std::strtol(number, &end_number, 10);
  if (end_number == number || *end_number != '\0' || n < min || n > max) return false;
  *count = static_cast<int>(n);
  return true;
}

bool host_is_big_endian() {
  const std::uint16_t one = 1;
  std::uint8_t first = 0;
  std::memcpy(&first, &one, 1);
  return first == 0;
}

}  // namespace

Status parse_bag_spec(const char* spec, BagConfig* config, ErrorText* error) {
  const char* name = "mcap";
  if (starts_with(spec, "mcap:")) {
    config->format = BagFormat::mcap;
  } else if (starts_with(spec, "rosbag:")) {
    config->format = BagFormat::rosbag;
    name = "rosbag";
  } else {
    error->set("bag: '%s' is not mcap:FILE or rosbag:FILE", spec);
    return StatusCode::invalid_argument;
  }
  const char* path = spec + std::strlen(name) + 1;
  const char* query = std::strchr(path, '?');
  const std::size_t path_size = query ? static_cast<std::size_t>(query - path) : std::strlen(path);
  if (path_size == 0 || !copy_value(path, path_size, config->path, sizeof(config->path))) {
    error->set("%s: needs a file (at most %zu bytes)", name, sizeof(config->path) - 1);
    return StatusCode::invalid_argument;
  }
  while (query != nullptr) {
    const char* key = query + 1;
    const char* end = std::strchr(key, '&');
    const char* eq = std::strchr(key, '=');
    const std::size_t item = end ? static_cast<std::size_t>(end - key) : std::strlen(key);
    if (eq == nullptr || eq > key + item) {
      error->set("%s: option '%.*s' needs KEY=VALUE", name, static_cast<int>(item), key);
      return StatusCode::invalid_argument;
    }
    const std::size_t key_size = static_cast<std::size_t>(eq - key);
    const char* value = eq + 1;
    const std::size_t value_size = item - key_size - 1;
    if (key_size == 7 && std::strncmp(key, "reorder", 7) == 0) {
      // Megabytes of the reorder window that puts messages in log-time order; 0: file order.
      if (!parse_megabytes(value, value_size, 0, 4096, &config->limits.reorder_bytes)) {
        error->set("%s: reorder=MB needs 0 to 4096", name);
        return StatusCode::invalid_argument;
      }
      query = end;
      continue;
    }
    if (key_size == 4 && std::strncmp(key, "hold", 4) == 0) {
      // Depth images held while the transforms after their stamps are read.
      if (!parse_count(value, value_size, 0, 64, &config->hold_frames)) {
        error->set("%s: hold=N needs 0 to 64 images", name);
        return StatusCode::invalid_argument;
      }
      query = end;
      continue;
    }
    if (key_size == 10 && std::strncmp(key, "tf_history", 10) == 0) {
      // Transforms kept per TF edge (and of the pose topic): an image logged this many
      // transforms after its stamp still finds the two around it.
      if (!parse_count(value, value_size, 2, 4096, &config->tf_history)) {
        error->set("%s: tf_history=N needs 2 to 4096 transforms", name);
        return StatusCode::invalid_argument;
      }
      query = end;
      continue;
    }
    if (key_size == 9 && std::strncmp(key, "readahead", 9) == 0) {
      // ROS 1 bags: decompress the next chunk on a second thread (1, the default) or not (0).
      if (value_size != 1 || (value[0] != '0' && value[0] != '1')) {
        error->set("%s: readahead= needs 0 or 1", name);
        return StatusCode::invalid_argument;
      }
      config->limits.read_ahead = value[0] == '1';
      query = end;
      continue;
    }
    if (key_size == 6 && std::strncmp(key, "buffer", 6) == 0) {
      // Megabytes for each of the reader's two buffers (record and chunk).
      std::size_t bytes = 0;
      if (!parse_megabytes(value, value_size, 1, 1024, &bytes)) {
        error->set("%s: buffer=MB needs 1 to 1024", name);
        return StatusCode::invalid_argument;
      }
      config->limits.max_record_bytes = bytes;
      config->limits.max_chunk_bytes = bytes;
      query = end;
      continue;
    }
    char* out = nullptr;
    if (key_size == 5 && std::strncmp(key, "depth", 5) == 0) out = config->depth_topic;
    if (key_size == 4 && std::strncmp(key, "info", 4) == 0) out = config->info_topic;
    if (key_size == 4 && std::strncmp(key, "pose", 4) == 0) out = config->pose_topic;
    if (key_size == 5 && std::strncmp(key, "world", 5) == 0) out = config->world_frame;
    if (key_size == 2 && std::strncmp(key, "tf", 2) == 0) out = config->odometry_frame;
    if (out == nullptr) {
      error->set(
          "%s: unknown option '%.*s' (depth, info, pose, world, tf, buffer, reorder, hold, "
          "tf_history, readahead)",
          name, static_cast<int>(key_size), key);
      return StatusCode::invalid_argument;
    }
    if (value_size == 0 || !copy_value(value, value_size, out, BagConfig::kMaxName)) {
      error->set("%s: option '%.*s' needs a value of 1 to %zu bytes", name,
                 static_cast<int>(key_size), key, BagConfig::kMaxName - 1);
      return StatusCode::invalid_argument;
    }
    query = end;
  }
  return ok_status();
}

BagSource::BagSource(const BagConfig& config) : config_(config) {}

BagSource::~BagSource() {
  close();
}

void BagSource::close() {
  reader_.close();
  std::free(memory_);
  memory_ = nullptr;
  memory_bytes_ = 0;
  ring_ = nullptr;
  ring_slots_ = 0;
  held_ = nullptr;
  held_count_ = held_first_ = 0;
  open_ = scanned_ = false;
}

SourceCapabilities BagSource::capabilities() const {
  SourceCapabilities caps;
  caps.has_ground_truth = use_tf_ || pose_channel_ >= 0;
  caps.ring_size = config_.ring_size;
  return caps;
}

BagTopic BagSource::topic(int index) const {
  BagTopic t;
  t.channel = &reader_.channel_at(index);
  t.count = counts_[index];
  t.first_log_ns = first_ns_[index];
  t.last_log_ns = last_ns_[index];
  return t;
}

Status BagSource::scan() {
  close();
  error_.clear();
  scan_warning_.clear();
  if (config_.limits.max_channels > kMaxChannels) {
    error_.set("%s: at most %d channels", prefix(), kMaxChannels);
    return StatusCode::invalid_argument;
  }
  Status status = reader_.open(config_.path, config_.format, config_.limits);
  if (!status.ok()) {
    error_.set("%s", reader_.error());
    return status;
  }
  config_.format = reader_.format();  // chosen by the magic when it was automatic
  for (int i = 0; i < kMaxChannels; ++i) {
    counts_[i] = first_ns_[i] = last_ns_[i] = 0;
    first_width_[i] = first_height_[i] = 0;
    have_info_[i] = false;
  }
  McapMessage message;
  // Only the counts, times and a few messages' bytes are needed: a ROS 1 bag's other chunks are
  // skimmed from their index records, not decompressed.
  reader_.set_skim(&BagSource::scan_wants_bytes, this);
  for (;;) {
    const McapNext got = reader_.next(&message);
    if (got == McapNext::end) break;
    if (got == McapNext::truncated) {
      scan_warning_.set("%s", reader_.warning());
      break;
    }
    if (got == McapNext::error) {
      error_.set("%s: %s", config_.path, reader_.error());
      reader_.set_skim(nullptr, nullptr);
      reader_.close();
      return StatusCode::data_loss;
    }
    const int c = static_cast<int>(message.channel - &reader_.channel_at(0));
    if (counts_[c] == 0) {
      first_ns_[c] = message.log_time_ns;
      kinds_[c] = kind_of(*message.channel);
    }
    ++counts_[c];
    last_ns_[c] = message.log_time_ns;
    if (kinds_[c] == Kind::image && first_width_[c] == 0) {
      RosImage image;
      if (decode_image(message.data, message.size, reader_.wire(), &image)) {
        first_width_[c] = static_cast<int>(image.width);
        first_height_[c] = static_cast<int>(image.height);
      }
    }
    if (kinds_[c] == Kind::camera_info && !have_info_[c]) {
      have_info_[c] =
          decode_camera_info(message.data, message.size, reader_.wire(), &first_info_[c]);
      if (have_info_[c]) {
        // The view points into the reader's buffer: keep a copy of the model's name.
        const RosString& model = first_info_[c].distortion_model;
        const std::size_t n =
            model.size < sizeof(info_model_[c]) ? model.size : sizeof(info_model_[c]) - 1;
        if (n > 0) std::memcpy(info_model_[c], model.data, n);
        info_model_[c][n] = '\0';
      }
    }
  }
  reader_.set_skim(nullptr, nullptr);
  scanned_ = true;
  if (reader_.out_of_order() > 0) note_disorder(&scan_warning_);
  return ok_status();
}

bool BagSource::scan_wants_bytes(void* self, const McapChannel& channel) {
  const BagSource& source = *static_cast<const BagSource*>(self);
  const int c = static_cast<int>(&channel - &source.reader_.channel_at(0));
  switch (kind_of(channel)) {
    case Kind::image:
      return source.first_width_[c] == 0;
    case Kind::camera_info:
      return !source.have_info_[c];
    default:
      return false;
  }
}

// What the log-time order could not fix, appended to `text` (empty or a cut's warning).
void BagSource::note_disorder(ErrorText* text) const {
  // Short: ErrorText holds 256 characters, and it may follow a cut's warning.
  char line[128];
  if (reader_.reorder_bytes() > 0) {
    const std::size_t bytes = reader_.reorder_bytes();
    const bool mib = bytes % (std::size_t{1} << 20) == 0;
    std::snprintf(line, sizeof(line),
                  "%llu messages out of log-time order, beyond the %zu %s reorder window "
                  "(?reorder=MB)",
                  static_cast<unsigned long long>(reader_.out_of_order()),
                  mib ? bytes >> 20 : bytes, mib ? "MiB" : "byte");
  } else {
    std::snprintf(line, sizeof(line), "%llu messages out of log-time order (reorder=0)",
                  static_cast<unsigned long long>(reader_.out_of_order()));
  }
  if (text->c_str()[0] != '\0') {
    text->set("%s; %s", ErrorText(*text).c_str(), line);
  } else {
    text->set("%s: %s", config_.path, line);
  }
}

int BagSource::find_topic(const char* name) const {
  for (int i = 0; i < reader_.channel_count(); ++i) {
    if (std::strcmp(reader_.channel_at(i).topic, name) == 0) return i;
  }
  return -1;
}

Status BagSource::choose_depth_topic() {
  const int n = reader_.channel_count();
  depth_channel_ = -1;
  if (config_.depth_topic[0] != '\0') {
    depth_channel_ = find_topic(config_.depth_topic);
    if (depth_channel_ < 0 ||
        (kinds_[depth_channel_] != Kind::image && kinds_[depth_channel_] != Kind::compressed)) {
      error_.set("%s: no sensor_msgs/msg/Image or CompressedImage topic '%s' in %s (see --list)",
                 prefix(), config_.depth_topic, config_.path);
      return StatusCode::invalid_argument;
    }
  } else {
    int images = 0, depth_images = 0, any = -1, depth = -1;
    for (int i = 0; i < n; ++i) {
      if (kinds_[i] != Kind::image || counts_[i] == 0) continue;
      ++images;
      any = i;
      if (std::strstr(reader_.channel_at(i).topic, "depth") != nullptr) {
        ++depth_images;
        depth = i;
      }
    }
    if (images == 0) {
      // No raw image: compressed_depth_image_transport's topics (".../compressedDepth").
      for (int i = 0; i < n; ++i) {
        if (kinds_[i] != Kind::compressed || counts_[i] == 0 ||
            std::strstr(reader_.channel_at(i).topic, "compressedDepth") == nullptr) {
          continue;
        }
        ++images;
        any = i;
      }
    }
    if (images == 1) {
      depth_channel_ = any;
    } else if (depth_images == 1) {
      depth_channel_ = depth;
    }
    if (depth_channel_ < 0) {
      if (images == 0) {
        error_.set("%s: %s has no sensor_msgs/msg/Image (or compressedDepth) messages (see --list)",
                   prefix(), config_.path);
      } else {
        error_.set(
            "%s: %s has several image topics; choose one with %s:FILE?depth=TOPIC "
            "(see --list)",
            prefix(), config_.path, prefix());
      }
      return StatusCode::invalid_argument;
    }
  }
  depth_topic_ = reader_.channel_at(depth_channel_).topic;
  return ok_status();
}

Status BagSource::choose_topics() {
  const int n = reader_.channel_count();
  OCTOFUSE_TRY(choose_depth_topic());

  // Camera info: the named one, the only one, or the one beside the depth topic.
  info_channel_ = -1;
  if (config_.info_topic[0] != '\0') {
    info_channel_ = find_topic(config_.info_topic);
    if (info_channel_ < 0 || kinds_[info_channel_] != Kind::camera_info) {
      error_.set("%s: no sensor_msgs/msg/CameraInfo topic '%s' in %s", prefix(), config_.info_topic,
                 config_.path);
      return StatusCode::invalid_argument;
    }
  } else {
    int infos = 0, any = -1, sibling = -1;
    const char* slash = std::strrchr(depth_topic_, '/');
    std::size_t prefix = slash ? static_cast<std::size_t>(slash - depth_topic_) : 0;
    if (kinds_[depth_channel_] == Kind::compressed) {
      // ".../image_raw/compressedDepth": the camera info sits beside image_raw.
      while (prefix > 0 && depth_topic_[--prefix] != '/') {
      }
    }
    for (int i = 0; i < n; ++i) {
      if (kinds_[i] != Kind::camera_info || !have_info_[i]) continue;
      ++infos;
      any = i;
      const char* topic = reader_.channel_at(i).topic;
      if (std::strncmp(topic, depth_topic_, prefix) == 0 && topic[prefix] == '/' &&
          std::strchr(topic + prefix + 1, '/') == nullptr) {
        sibling = i;
      }
    }
    info_channel_ = infos == 1 ? any : sibling;
  }
  if (config_.has_intrinsics) {
    intrinsics_ = config_.intrinsics;
  } else {
    if (info_channel_ < 0 || !have_info_[info_channel_]) {
      error_.set(
          "%s: no camera info for %s in %s; choose one with %s:FILE?info=TOPIC or give "
          "--intrinsics",
          prefix(), depth_topic_, config_.path, prefix());
      return StatusCode::invalid_argument;
    }
    const RosCameraInfo& info = first_info_[info_channel_];
    if (info.max_abs_distortion != 0.0) {
      error_.set(
          "%s: camera info on %s has %s distortion (largest coefficient %g); octofuse "
          "takes rectified depth only: rectify it, or give --intrinsics to use it as is",
          prefix(), reader_.channel_at(info_channel_).topic,
          info_model_[info_channel_][0] ? info_model_[info_channel_] : "unnamed",
          info.max_abs_distortion);
      return StatusCode::invalid_argument;
    }
    intrinsics_.fx = static_cast<float>(info.k[0]);
    intrinsics_.fy = static_cast<float>(info.k[4]);
    intrinsics_.cx = static_cast<float>(info.k[2]);
    intrinsics_.cy = static_cast<float>(info.k[5]);
    intrinsics_.width = static_cast<int>(info.width);
    intrinsics_.height = static_cast<int>(info.height);
    if (!(intrinsics_.fx > 0.0f && intrinsics_.fy > 0.0f)) {
      error_.set("%s: camera info on %s has no focal length (K[0], K[4] not > 0)", prefix(),
                 reader_.channel_at(info_channel_).topic);
      return StatusCode::invalid_argument;
    }
  }
  if (intrinsics_.width == 0 || intrinsics_.height == 0) {
    intrinsics_.width = first_width_[depth_channel_];
    intrinsics_.height = first_height_[depth_channel_];
  }
  if (intrinsics_.width <= 0 || intrinsics_.height <= 0 || intrinsics_.width > config_.max_width ||
      intrinsics_.height > config_.max_height) {
    error_.set("%s: depth images of %dx%d on %s (at most %dx%d)", prefix(), intrinsics_.width,
               intrinsics_.height, depth_topic_, config_.max_width, config_.max_height);
    return StatusCode::resource_exhausted;
  }

  // Poses: the named topic, the only odometry or pose topic, else TF when there is any.
  pose_channel_ = -1;
  use_tf_ = false;
  pose_topic_ = "";
  int tf_topics = 0;
  for (int i = 0; i < n; ++i) tf_topics += kinds_[i] == Kind::tf && counts_[i] > 0;
  if (std::strcmp(config_.pose_topic, "none") == 0) {
    // No ground truth from the bag (a recording whose only pose topic is its odometry).
  } else if (config_.pose_topic[0] != '\0') {
    const int c = find_topic(config_.pose_topic);
    if (c < 0 ||
        (kinds_[c] != Kind::odometry && kinds_[c] != Kind::pose && kinds_[c] != Kind::tf)) {
      error_.set("%s: no Odometry, PoseStamped or TFMessage topic '%s' in %s", prefix(),
                 config_.pose_topic, config_.path);
      return StatusCode::invalid_argument;
    }
    if (kinds_[c] == Kind::tf) {
      use_tf_ = true;
    } else {
      pose_channel_ = c;
    }
    pose_topic_ = reader_.channel_at(c).topic;
  } else {
    int poses = 0, any = -1, named = 0, truth = -1;
    for (int i = 0; i < n; ++i) {
      if (is_pose_kind(kinds_[i]) && counts_[i] > 0) {
        ++poses;
        any = i;
        if (is_ground_truth_topic(reader_.channel_at(i).topic)) {
          ++named;
          truth = i;
        }
      }
    }
    if (poses > 1 && named == 1) {
      poses = 1;  // the one that says it is the ground truth
      any = truth;
    }
    if (poses > 1) {
      error_.set("%s: %s has several pose topics; choose one with %s:FILE?pose=TOPIC", prefix(),
                 config_.path, prefix());
      return StatusCode::invalid_argument;
    }
    if (poses == 1) {
      pose_channel_ = any;
      pose_topic_ = reader_.channel_at(any).topic;
    } else if (tf_topics > 0) {
      use_tf_ = true;
      pose_topic_ = "/tf";
    }
  }
  return ok_status();
}

// The pose tracking's memory: the TF table and its transforms, the pose topic's transforms and
// the held images' records.
template <typename Arena>
Status BagSource::reserve_tracking(Arena& arena) {
  OCTOFUSE_TRY(tf_.reserve(arena, config_.max_tf_frames, config_.tf_history));
  Result<TfSample*> pose_samples =
      arena.template allocate_array<TfSample>(static_cast<std::size_t>(config_.tf_history));
  if (!pose_samples.ok()) return pose_samples.status();
  Result<Held*> held =
      arena.template allocate_array<Held>(static_cast<std::size_t>(config_.hold_frames) + 1);
  if (!held.ok()) return held.status();
  pose_history_.attach(pose_samples.value(), config_.tf_history);
  held_ = held.value();
  held_first_ = held_count_ = 0;
  pose_child_[0] = '\0';
  stream_ended_ = false;
  pose_past_end_ = pose_not_waited_ = pose_history_short_ = 0;
  return ok_status();
}

bool BagSource::valid_tracking_config() const {
  return config_.max_tf_frames >= 1 && config_.max_tf_frames <= 4096 && config_.tf_history >= 2 &&
         config_.tf_history <= 4096 && config_.hold_frames >= 0 && config_.hold_frames <= 64;
}

Status BagSource::open() {
  Status status = scan();
  if (!status.ok()) return status;
  if (config_.max_width <= 0 || config_.max_height <= 0 || config_.max_width > 16384 ||
      config_.max_height > 16384 || config_.ring_size < 1 || config_.ring_size > 64 ||
      !valid_tracking_config() || !(config_.depth_units_per_m >= 0.0f)) {
    error_.set("%s: invalid configuration", prefix());
    close();
    return StatusCode::invalid_argument;
  }
  status = choose_topics();
  if (!status.ok()) {
    close();
    return status;
  }
  // Frames given out stay valid for ring_size calls; held ones wait in the ring beside them.
  ring_slots_ = config_.ring_size + config_.hold_frames;
  const std::size_t ring_bytes = static_cast<std::size_t>(intrinsics_.width) *
                                 static_cast<std::size_t>(intrinsics_.height) *
                                 sizeof(std::uint16_t) * static_cast<std::size_t>(ring_slots_);
  const std::size_t slots = static_cast<std::size_t>(ring_slots_);
  ArenaSizer sizer;
  (void)sizer.allocate_bytes(ring_bytes, kArenaAlignment);
  (void)sizer.allocate_array<int>(2 * slots);
  (void)reserve_tracking(sizer);
  (void)png_.reserve(sizer);
  memory_bytes_ = sizer.bytes_used();
  memory_ = std::aligned_alloc(kArenaAlignment, align_up(memory_bytes_, kArenaAlignment));
  if (memory_ == nullptr) {
    error_.set("%s: cannot reserve %zu bytes", prefix(), memory_bytes_);
    close();
    return StatusCode::resource_exhausted;
  }
  LinearArena arena(memory_, memory_bytes_);
  ring_ = static_cast<std::uint16_t*>(arena.allocate_bytes(ring_bytes, kArenaAlignment).value());
  free_slots_ = arena.allocate_array<int>(2 * slots).value();
  given_slots_ = free_slots_ + slots;
  // Slot 0 on top: with no image waiting, only ring_size slots are ever used (cache).
  for (int i = 0; i < ring_slots_; ++i) free_slots_[i] = ring_slots_ - 1 - i;
  free_count_ = ring_slots_;
  given_first_ = given_count_ = 0;
  OCTOFUSE_CHECK(reserve_tracking(arena).ok());  // sized by the same calls
  OCTOFUSE_CHECK(png_.reserve(arena).ok());
  odometry_mode_ = false;
  sequence_ = 0;
  frames_without_pose_ = 0;
  reader_.rewind();
  error_.clear();
  open_ = true;
  return ok_status();
}

// The slot the next image is decoded into: free, neither held nor among the ring_size - 1 given
// out last (the frame given out now makes ring_size).
std::uint16_t* BagSource::ring_slot() const {
  return ring_ + static_cast<std::size_t>(free_slots_[free_count_ - 1]) *
                     static_cast<std::size_t>(intrinsics_.width) *
                     static_cast<std::size_t>(intrinsics_.height);
}

void BagSource::hold(std::uint16_t* pixels, float units_per_m, std::int64_t stamp_ns,
                     const RosString& frame_id, std::int64_t log_time_ns) {
  Held& h = held_[(held_first_ + held_count_) % (config_.hold_frames + 1)];
  ++held_count_;
  h.time_ns = stamp_ns != 0 ? stamp_ns : log_time_ns;
  const std::size_t n = frame_id.size < sizeof(h.frame_id) ? frame_id.size : 0;
  if (n > 0) std::memcpy(h.frame_id, frame_id.data, n);
  h.frame_id[n] = '\0';
  h.pixels = pixels;
  h.units_per_m = units_per_m;
  h.slot = pixels != nullptr ? free_slots_[--free_count_] : -1;
}

// A held image's slot, given out now: free again once ring_size - 1 more have been given out.
void BagSource::give_out(int slot) {
  given_slots_[(given_first_ + given_count_) % ring_slots_] = slot;
  ++given_count_;
  if (given_count_ > config_.ring_size - 1) {
    free_slots_[free_count_++] = given_slots_[given_first_];
    given_first_ = (given_first_ + 1) % ring_slots_;
    --given_count_;
  }
}

// The pose of a held image at its time: T_W_C (the ground truth) or, in odometry mode, T_O_C.
TfAt BagSource::resolve(const Held& image, bool final, Se3d* T, unsigned* stale) const {
  const int camera = tf_.find(image.frame_id, std::strlen(image.frame_id));
  const TfAt unknown = final ? TfAt::none : TfAt::wait;  // a frame /tf may still name
  if (odometry_mode_ || use_tf_) {
    if (camera < 0) return unknown;
    int to = -1;  // the root of the chain
    if (odometry_mode_ && config_.odometry_frame[0] == '\0') {
      auto is_odom = [](const char* name) {
        const std::size_t size = std::strlen(name);
        return std::strcmp(name, "odom") == 0 ||
               (size > 5 && std::strcmp(name + size - 5, "/odom") == 0);
      };
      for (int f = camera, steps = 0; f >= 0 && steps <= tf_.count(); f = tf_.parent(f), ++steps) {
        if (is_odom(tf_.name(f))) {
          to = f;
          break;
        }
      }
      if (to < 0) return unknown;
    } else {
      const char* target = odometry_mode_ ? config_.odometry_frame : config_.world_frame;
      if (target[0] != '\0') {
        to = tf_.find(target, std::strlen(target));
        if (to < 0) return unknown;
      }
    }
    const TfAt at = tf_.chain_at(camera, to, image.time_ns, final, T, stale);
    return at == TfAt::none ? unknown : at;
  }
  if (pose_channel_ < 0) return TfAt::none;
  Se3d T_W_B;
  const TfAt at = pose_history_.at(image.time_ns, final, &T_W_B, stale);
  if (at != TfAt::ready) return at;
  // The pose is of its child frame (the robot's body): add the body-to-camera TF when known.
  const int body = tf_.find(pose_child_, std::strlen(pose_child_));
  Se3d T_B_C;
  if (camera >= 0 && body >= 0 && camera != body) {
    const TfAt chain = tf_.chain_at(camera, body, image.time_ns, final, &T_B_C, stale);
    if (chain == TfAt::wait) return TfAt::wait;
    if (chain == TfAt::ready) {
      *T = T_W_B * T_B_C;
      return TfAt::ready;
    }
  }
  *T = T_W_B;  // the pose is the camera's
  return TfAt::ready;
}

// Reads on until the oldest held image can be given out: every edge of its chain has a
// transform at or after its stamp, the file has ended, or more than hold_frames images wait.
// `decode`: images are converted into the ring (next()); without it only their stamps and
// frames are kept (the odometry's poses).
BagSource::Pull BagSource::pull(bool decode, Held* image, bool* has_pose, Se3d* T,
                                NextFrame* skip) {
  const int held_capacity = config_.hold_frames + 1;
  McapMessage message;
  bool recheck = true;  // the oldest held image may be ready: new transforms, images or the end
  for (;;) {
    if (held_count_ > 0 && recheck) {
      recheck = false;
      const Held& front = held_[held_first_];
      unsigned stale = kTfExact;
      TfAt at = resolve(front, stream_ended_, T, &stale);
      const bool crowded = held_count_ > config_.hold_frames;
      if (at == TfAt::wait && crowded) at = resolve(front, true, T, &(stale = kTfExact));
      if (at != TfAt::wait) {
        *image = front;
        held_first_ = (held_first_ + 1) % held_capacity;
        --held_count_;
        *has_pose = at == TfAt::ready;
        if (stale & kTfPastEnd) ++(stream_ended_ ? pose_past_end_ : pose_not_waited_);
        if (stale & kTfHistoryShort) ++pose_history_short_;
        return Pull::image;
      }
    }
    if (stream_ended_) return Pull::ended;
    const McapNext got = reader_.next(&message);
    if (got == McapNext::end || got == McapNext::truncated) {
      stream_ended_ = true;
      end_state_ = got;
      recheck = true;
      continue;
    }
    if (got == McapNext::error) {
      error_.set("%s: %s", config_.path, reader_.error());
      return Pull::failed;
    }
    const int c = static_cast<int>(message.channel - &reader_.channel_at(0));
    const Kind kind = kinds_[c];
    if (kind == Kind::tf) {
      const char* topic = message.channel->topic;
      const std::size_t topic_size = std::strlen(topic);
      const bool is_static =
          topic_size >= 9 && std::strcmp(topic + topic_size - 9, "tf_static") == 0;
      RosTfReader tf;
      RosPose transform;
      if (!tf.begin(message.data, message.size, reader_.wire())) continue;
      for (std::uint32_t i = 0; i < tf.count() && tf.next(&transform); ++i) {
        recheck |= tf_.add(transform, static_cast<std::int64_t>(message.log_time_ns), is_static);
      }
      continue;
    }
    if (c == pose_channel_) {
      RosPose pose;
      Se3d checked;
      const bool decoded =
          kind == Kind::odometry
              ? decode_odometry(message.data, message.size, reader_.wire(), &pose)
              : decode_pose_stamped(message.data, message.size, reader_.wire(), &pose);
      if (decoded && pose_to_se3(pose, &checked)) {
        TfSample s;
        s.stamp_ns =
            pose.stamp_ns != 0 ? pose.stamp_ns : static_cast<std::int64_t>(message.log_time_ns);
        std::memcpy(s.t, pose.t, sizeof(s.t));
        std::memcpy(s.q, pose.q, sizeof(s.q));
        pose_history_.push(s, false);
        recheck = true;
        const RosString& child = pose.child_frame;
        const std::size_t n = child.size < sizeof(pose_child_) ? child.size : 0;
        if (n > 0) std::memcpy(pose_child_, child.data, n);
        pose_child_[n] = '\0';
      }
      continue;
    }
    if (c != depth_channel_) continue;
    const std::int64_t log_time_ns = static_cast<std::int64_t>(message.log_time_ns);
    if (kind == Kind::compressed) {
      RosCompressedImage compressed;
      if (!decode_compressed_image(message.data, message.size, reader_.wire(), &compressed)) {
        if (!decode) continue;
        error_.set("%s: message %llu on %s is not a valid sensor_msgs/msg/CompressedImage",
                   config_.path, static_cast<unsigned long long>(message.sequence), depth_topic_);
        *skip = NextFrame::skipped(StatusCode::data_loss);
        return Pull::skipped;
      }
      recheck = true;
      if (!decode) {
        hold(nullptr, 0.0f, compressed.stamp_ns, compressed.frame_id, log_time_ns);
        continue;
      }
      *skip = convert_compressed(compressed, log_time_ns);
      if (skip->outcome != FrameOutcome::frame) return Pull::skipped;
      continue;
    }
    RosImage raw;
    if (!decode_image(message.data, message.size, reader_.wire(), &raw)) {
      if (!decode) continue;
      error_.set("%s: message %llu on %s is not a valid sensor_msgs/msg/Image", config_.path,
                 static_cast<unsigned long long>(message.sequence), depth_topic_);
      *skip = NextFrame::skipped(StatusCode::data_loss);
      return Pull::skipped;
    }
    recheck = true;
    if (!decode) {
      hold(nullptr, 0.0f, raw.stamp_ns, raw.frame_id, log_time_ns);
      continue;
    }
    *skip = convert(raw, log_time_ns);
    if (skip->outcome != FrameOutcome::frame) return Pull::skipped;
  }
}

// How many frames took a transform from before their stamp, appended to `text`.
void BagSource::note_tf(ErrorText* text) const {
  char line[320];
  int used = 0;
  auto add = [&](std::uint64_t count, const char* what) {
    if (count == 0 || used < 0 || used >= static_cast<int>(sizeof(line))) return;
    used += std::snprintf(line + used, sizeof(line) - static_cast<std::size_t>(used), "%s%llu %s",
                          used ? "; " : "", static_cast<unsigned long long>(count), what);
  };
  add(pose_past_end_, "frames past the last /tf took its newest transform");
  add(pose_not_waited_, "frames took the transforms read so far (more than hold=N waited)");
  add(pose_history_short_,
      "frames older than the transforms kept took the oldest (?tf_history=N keeps more)");
  if (used <= 0) return;
  if (text->c_str()[0] != '\0') {
    text->set("%s; %s", ErrorText(*text).c_str(), line);
  } else {
    text->set("%s: %s", config_.path, line);
  }
}

NextFrame BagSource::convert(const RosImage& image, std::int64_t log_time_ns) {
  const int width = static_cast<int>(image.width);
  const int height = static_cast<int>(image.height);
  if (width != intrinsics_.width || height != intrinsics_.height) {
    error_.set("%s: image of %dx%d, the camera has %dx%d", depth_topic_, width, height,
               intrinsics_.width, intrinsics_.height);
    return NextFrame::skipped(StatusCode::invalid_argument);
  }
  const bool is16 = image.encoding.equals("16UC1") || image.encoding.equals("mono16");
  const bool is32 = image.encoding.equals("32FC1");
  if (!is16 && !is32) {
    error_.set("%s: encoding '%.*s' is not depth (16UC1, mono16, 32FC1)", depth_topic_,
               static_cast<int>(image.encoding.size),
               image.encoding.data ? image.encoding.data : "");
    return NextFrame::skipped(StatusCode::invalid_argument);
  }
  const std::size_t pixel_bytes = is16 ? 2 : 4;
  const std::uint64_t row_bytes = static_cast<std::uint64_t>(width) * pixel_bytes;
  if (image.step < row_bytes ||
      static_cast<std::uint64_t>(image.step) * static_cast<std::uint64_t>(height) >
          image.data_size) {
    error_.set("%s: %u bytes of data for %dx%d %s rows of %u bytes", depth_topic_, image.data_size,
               width, height, is16 ? "16-bit" : "float", image.step);
    return NextFrame::skipped(StatusCode::data_loss);
  }
  const bool swap = image.big_endian != host_is_big_endian();
  std::uint16_t* out = ring_slot();
  const float units =
      config_.depth_units_per_m > 0.0f ? config_.depth_units_per_m : (is16 ? 1000.0f : 5000.0f);
  for (int y = 0; y < height; ++y) {
    const std::uint8_t* row = image.data + static_cast<std::size_t>(y) * image.step;
    std::uint16_t* dst = out + static_cast<std::size_t>(y) * static_cast<std::size_t>(width);
    if (is16) {
      std::memcpy(dst, row, static_cast<std::size_t>(row_bytes));
      if (swap) {
        for (int x = 0; x < width; ++x) {
          dst[x] = static_cast<std::uint16_t>((dst[x] >> 8) | (dst[x] << 8));
        }
      }
    } else {
      for (int x = 0; x < width; ++x) {
        std::uint8_t b[4];
        std::memcpy(b, row + 4 * x, 4);
        if (swap) {
          std::uint8_t t = b[0];
          b[0] = b[3];
          b[3] = t;
          t = b[1];
          b[1] = b[2];
          b[2] = t;
        }
        float m = 0.0f;
        std::memcpy(&m, b, 4);
        const float u = m * units + 0.5f;
        // NaN, negative and out-of-range depths are "no data".
        dst[x] = (u >= 1.0f && u < 65535.5f) ? static_cast<std::uint16_t>(u) : 0;
      }
    }
  }
  hold(out, units, image.stamp_ns, image.frame_id, log_time_ns);
  return NextFrame::got_frame();
}

// compressed_depth_image_transport: a 12-byte header (int32 format, float quantisation A, B),
// then a 16-bit PNG or, for rvl, int32 width, height and the RVL stream. 32FC1 is stored as
// quantised inverse depth: metres = A / (v - B), 0 for no data.
NextFrame BagSource::convert_compressed(const RosCompressedImage& image, std::int64_t log_time_ns) {
  const char* format = image.format.data != nullptr ? image.format.data : "";
  const std::size_t format_size = image.format.size;
  auto has = [&](const char* word) {
    const std::size_t n = std::strlen(word);
    for (std::size_t i = 0; i + n <= format_size; ++i) {
      if (std::strncmp(format + i, word, n) == 0) return true;
    }
    return false;
  };
  const bool is16 = has("16UC1") || has("mono16");
  const bool is32 = has("32FC1");
  const bool rvl = has("rvl");
  if (!has("compressedDepth") || (!is16 && !is32)) {
    error_.set("%s: compressed format '%.*s' is not compressedDepth of 16UC1 or 32FC1",
               depth_topic_, static_cast<int>(format_size), format);
    return NextFrame::skipped(StatusCode::invalid_argument);
  }
  if (image.data_size < 12) {
    error_.set("%s: compressedDepth data of %u bytes has no header", depth_topic_, image.data_size);
    return NextFrame::skipped(StatusCode::data_loss);
  }
  auto le32 = [](const std::uint8_t* p) {
    return std::uint32_t{p[0]} | (std::uint32_t{p[1]} << 8) | (std::uint32_t{p[2]} << 16) |
           (std::uint32_t{p[3]} << 24);
  };
  float quant[2];
  for (int i = 0; i < 2; ++i) {
    const std::uint32_t bits = le32(image.data + 4 + 4 * i);
    std::memcpy(&quant[i], &bits, 4);
  }
  const std::uint8_t* payload = image.data + 12;
  const std::size_t payload_size = image.data_size - 12;
  std::uint16_t* out = ring_slot();
  const std::size_t pixel_count =
      static_cast<std::size_t>(intrinsics_.width) * static_cast<std::size_t>(intrinsics_.height);
  if (rvl) {
    std::uint32_t size[2] = {0, 0};
    if (payload_size < 8) {
      error_.set("%s: RVL data of %zu bytes has no size", depth_topic_, payload_size);
      return NextFrame::skipped(StatusCode::data_loss);
    }
    size[0] = le32(payload);
    size[1] = le32(payload + 4);
    if (size[0] != static_cast<std::uint32_t>(intrinsics_.width) ||
        size[1] != static_cast<std::uint32_t>(intrinsics_.height)) {
      error_.set("%s: RVL image of %ux%u, the camera has %dx%d", depth_topic_, size[0], size[1],
                 intrinsics_.width, intrinsics_.height);
      return NextFrame::skipped(StatusCode::invalid_argument);
    }
    if (!decode_rvl(payload + 8, payload_size - 8, out, pixel_count)) {
      error_.set("%s: corrupt or truncated RVL data", depth_topic_);
      return NextFrame::skipped(StatusCode::data_loss);
    }
  } else {
    int width = 0, height = 0;
    if (!png_.decode(payload, payload_size, out, intrinsics_.width, intrinsics_.height, &width,
                     &height, depth_topic_, &error_)
             .ok()) {
      return NextFrame::skipped(StatusCode::data_loss);
    }
    if (width != intrinsics_.width || height != intrinsics_.height) {
      error_.set("%s: PNG of %dx%d, the camera has %dx%d", depth_topic_, width, height,
                 intrinsics_.width, intrinsics_.height);
      return NextFrame::skipped(StatusCode::invalid_argument);
    }
  }
  float units =
      config_.depth_units_per_m > 0.0f ? config_.depth_units_per_m : (is16 ? 1000.0f : 5000.0f);
  if (is32) {
    for (std::size_t i = 0; i < pixel_count; ++i) {
      if (out[i] == 0) continue;
      const float m = quant[0] / (static_cast<float>(out[i]) - quant[1]);
      const float u = m * units + 0.5f;
      out[i] = (u >= 1.0f && u < 65535.5f) ? static_cast<std::uint16_t>(u) : 0;
    }
  }
  hold(out, units, image.stamp_ns, image.frame_id, log_time_ns);
  return NextFrame::got_frame();
}

NextFrame BagSource::next(DepthFrame& frame) {
  if (!open_) {
    error_.set("%s: next() before a successful open()", prefix());
    return NextFrame::failed(StatusCode::failed_precondition);
  }
  Held image;
  bool has_pose = false;
  Se3d T_W_C;
  NextFrame skip;
  const Pull pulled = pull(true, &image, &has_pose, &T_W_C, &skip);
  if (pulled == Pull::failed) return NextFrame::failed(StatusCode::data_loss);
  if (pulled == Pull::skipped) return skip;
  if (pulled == Pull::ended) {
    const bool late_poses = pose_past_end_ + pose_not_waited_ + pose_history_short_ > 0;
    if (end_state_ == McapNext::truncated) {
      error_.set("%s: %s", config_.path, reader_.warning());
      if (reader_.out_of_order() > 0) note_disorder(&error_);
      note_tf(&error_);
      return NextFrame{FrameOutcome::end_of_stream, StatusCode::data_loss};
    }
    if (reader_.out_of_order() == 0 && !late_poses) return NextFrame::ended();
    // Not lost, but not in order or not at their stamps either: the run says so.
    error_.clear();
    if (reader_.out_of_order() > 0) note_disorder(&error_);
    note_tf(&error_);
    return NextFrame{FrameOutcome::end_of_stream, StatusCode::out_of_range};
  }
  give_out(image.slot);
  frame.depth_raw =
      ImageView<const std::uint16_t>(image.pixels, intrinsics_.width, intrinsics_.height);
  frame.metres_per_unit = 1.0f / image.units_per_m;
  frame.timestamp_us = image.time_ns / 1000;
  frame.sequence = sequence_++;
  frame.has_ground_truth = false;
  frame.T_W_C_ground_truth = Eigen::Matrix4d::Identity();
  if (use_tf_ || pose_channel_ >= 0) {
    if (has_pose) {
      frame.has_ground_truth = true;
      frame.T_W_C_ground_truth = T_W_C.matrix();
    } else {
      ++frames_without_pose_;
    }
  }
  return NextFrame::got_frame();
}

Status read_bag_poses(const BagConfig& config,
                      void (*on_pose)(void* context, std::int64_t stamp_ns, const Se3d& T),
                      void* context, ErrorText* error, ErrorText* warning) {
  BagSource source(config);
  const Status status = source.read_odometry(on_pose, context);
  if (!status.ok()) error->set("%s", source.last_error());
  if (status.ok() && warning != nullptr) {
    warning->clear();
    source.note_tf(warning);
  }
  return status;
}

Status BagSource::read_odometry(void (*on_pose)(void* context, std::int64_t stamp_ns,
                                                const Se3d& T),
                                void* context) {
  OCTOFUSE_TRY(scan());
  const int n = reader_.channel_count();
  // The topic: named; else the only Odometry / PoseStamped one, or the only one that does not
  // call itself ground truth; else TF when the bag has it.
  int chosen = -1;
  bool tf = config_.odometry_frame[0] != '\0';
  int tf_topics = 0;
  for (int i = 0; i < n; ++i) tf_topics += kinds_[i] == Kind::tf && counts_[i] > 0;
  if (config_.pose_topic[0] != '\0') {
    chosen = find_topic(config_.pose_topic);
    if (chosen < 0 || (!is_pose_kind(kinds_[chosen]) && kinds_[chosen] != Kind::tf)) {
      error_.set("%s: no Odometry, PoseStamped or TFMessage topic '%s'", config_.path,
                 config_.pose_topic);
      return StatusCode::invalid_argument;
    }
    if (kinds_[chosen] == Kind::tf) tf = true;
  } else if (!tf) {
    int poses = 0, any = -1, others = 0, other = -1, second = -1;
    for (int i = 0; i < n; ++i) {
      if (!is_pose_kind(kinds_[i]) || counts_[i] == 0) continue;
      if (poses == 1) second = i;
      ++poses;
      if (any < 0) any = i;
      if (!is_ground_truth_topic(reader_.channel_at(i).topic)) {
        ++others;
        other = i;
      }
    }
    if (poses == 1) {
      chosen = any;
    } else if (poses > 1 && others == 1) {
      chosen = other;
    } else if (poses > 1) {
      error_.set("%s has several pose topics (%s, %s); choose one with %s:FILE?pose=TOPIC",
                 config_.path, reader_.channel_at(any).topic, reader_.channel_at(second).topic,
                 prefix());
      return StatusCode::invalid_argument;
    } else if (tf_topics > 0) {
      tf = true;
    } else {
      error_.set("%s: no Odometry or PoseStamped messages and no /tf", config_.path);
      return StatusCode::invalid_argument;
    }
  }
  if (tf) return read_tf_poses(on_pose, context);

  reader_.rewind();
  McapMessage message;
  std::uint64_t poses = 0;
  for (;;) {
    const McapNext got = reader_.next(&message);
    if (got == McapNext::end || got == McapNext::truncated) break;
    if (got == McapNext::error) {
      error_.set("%s: %s", config_.path, reader_.error());
      return StatusCode::data_loss;
    }
    if (message.channel != &reader_.channel_at(chosen)) continue;
    RosPose pose;
    const bool decoded =
        kinds_[chosen] == Kind::odometry
            ? decode_odometry(message.data, message.size, reader_.wire(), &pose)
            : decode_pose_stamped(message.data, message.size, reader_.wire(), &pose);
    Se3d T;
    if (!decoded || !pose_to_se3(pose, &T)) {
      error_.set("%s: pose message %llu on %s is malformed or not a rotation", config_.path,
                 static_cast<unsigned long long>(message.sequence), message.channel->topic);
      return StatusCode::data_loss;
    }
    const std::int64_t stamp_ns =
        pose.stamp_ns != 0 ? pose.stamp_ns : static_cast<std::int64_t>(message.log_time_ns);
    on_pose(context, stamp_ns, T);
    ++poses;
  }
  if (poses == 0) {
    error_.set("%s: no Odometry or PoseStamped messages on %s", config_.path,
               reader_.channel_at(chosen).topic);
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

// The camera's pose in the odometry's frame from /tf: at each depth image, the chain from the
// image's frame up to the odometry frame, as the transforms read so far give it.
Status BagSource::read_tf_poses(void (*on_pose)(void* context, std::int64_t stamp_ns,
                                                const Se3d& T),
                                void* context) {
  OCTOFUSE_TRY(choose_depth_topic());
  if (!valid_tracking_config()) {
    error_.set("%s: invalid configuration", prefix());
    return StatusCode::invalid_argument;
  }
  ArenaSizer sizer;
  (void)reserve_tracking(sizer);
  memory_bytes_ = sizer.bytes_used();
  memory_ = std::aligned_alloc(kArenaAlignment, align_up(memory_bytes_, kArenaAlignment));
  if (memory_ == nullptr) {
    error_.set("%s: cannot reserve %zu bytes", prefix(), memory_bytes_);
    return StatusCode::resource_exhausted;
  }
  LinearArena arena(memory_, memory_bytes_);
  OCTOFUSE_CHECK(reserve_tracking(arena).ok());  // sized by the same calls
  odometry_mode_ = true;
  use_tf_ = false;
  pose_channel_ = -1;
  reader_.rewind();
  std::uint64_t poses = 0;
  std::uint64_t images = 0;
  char camera_name[TfBuffer::kMaxName] = {};
  for (;;) {
    Held image;
    bool has_pose = false;
    Se3d T_O_C;
    NextFrame skip;
    const Pull pulled = pull(false, &image, &has_pose, &T_O_C, &skip);
    if (pulled == Pull::failed) return StatusCode::data_loss;
    if (pulled != Pull::image) break;
    ++images;
    if (tf_.find(image.frame_id, std::strlen(image.frame_id)) >= 0) {
      std::memcpy(camera_name, image.frame_id, sizeof(camera_name));
    }
    if (!has_pose) continue;
    on_pose(context, image.time_ns, T_O_C);
    ++poses;
  }
  if (poses == 0) {
    // Name the chain the images' frame has, so that the odometry frame can be chosen from it.
    char chain[256] = {};
    std::size_t used = 0;
    const int camera = camera_name[0] ? tf_.find(camera_name, std::strlen(camera_name)) : -1;
    for (int f = camera, steps = 0; f >= 0 && steps <= tf_.count(); f = tf_.parent(f), ++steps) {
      const int wrote = std::snprintf(chain + used, sizeof(chain) - used, "%s%s",
                                      used ? " -> " : "", tf_.name(f));
      if (wrote < 0 || used + static_cast<std::size_t>(wrote) >= sizeof(chain)) break;
      used += static_cast<std::size_t>(wrote);
    }
    if (images == 0) {
      error_.set("%s: no depth images on %s to take the odometry's TF poses at", config_.path,
                 depth_topic_);
    } else if (camera < 0) {
      error_.set("%s: /tf never names the depth images' frame: no odometry poses", config_.path);
    } else if (config_.odometry_frame[0] != '\0') {
      error_.set("%s: no TF chain from '%s' to '%s' (the chain: %s)", config_.path, camera_name,
                 config_.odometry_frame, chain);
    } else {
      error_.set(
          "%s: no Odometry or PoseStamped topic, and the TF chain of the depth images (%s) has "
          "no 'odom' frame; name the odometry's frame with %s:FILE?tf=FRAME",
          config_.path, chain, prefix());
    }
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

}  // namespace octofuse::replay
