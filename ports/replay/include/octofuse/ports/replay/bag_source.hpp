#pragma once
// DepthSource for robot recordings, read without ROS:
//   mcap:FILE[?depth=TOPIC&info=TOPIC&pose=TOPIC&world=FRAME]
//   rosbag:FILE[?...the same options]
// an MCAP file (rosbag2's default storage) with ROS 2 CDR messages, or a ROS 1 bag (format 2.0)
// with the same types in ROS 1 serialisation ("sensor_msgs/Image"; TF also as tf/tfMessage):
//   depth  sensor_msgs/msg/Image: 16UC1 or mono16 (millimetres unless a depth scale is given),
//          32FC1 (metres, NaN for no data; stored at 5000 units/m unless a scale is given);
//          or sensor_msgs/msg/CompressedImage from compressed_depth_image_transport
//          ("16UC1; compressedDepth png|rvl", "32FC1; compressedDepth png|rvl"), used when the
//          bag has no raw depth image;
//   info   sensor_msgs/msg/CameraInfo: K gives the intrinsics; a distortion model with non-zero
//          coefficients is refused (octofuse takes rectified depth only);
//   pose   nav_msgs/msg/Odometry, geometry_msgs/msg/PoseStamped, or tf2_msgs/msg/TFMessage
//          (/tf and /tf_static chained from the depth image's frame up to `world`, by default the
//          root of that chain); delivered as each frame's ground truth.
// Topics left out are chosen when there is one obvious candidate (the only one of its type, or
// the only image topic with "depth" in its name); otherwise open() names the candidates.
//
// open() reads the file once to count topics and find the camera info, then next() streams it
// again in log-time order (bag_reader.hpp's reorder window). Each depth image gets the pose at
// its header stamp: the TF edges (and the pose topic) each taken at that stamp, blended between
// the transforms around it (tf_buffer.hpp). An image is held (up to hold_frames of them) until
// every edge it needs has a transform at or after its stamp; at the end of the bag, or when more
// images wait, it takes the newest, and the stream's end says how many did. Messages the window
// could not put in order end the stream with a warning (the status out_of_range, or data_loss
// with a cut's). Memory is fixed at open(): the reader's buffers (McapLimits), the frame ring
// (ring_size + hold_frames images) and the TF table with its transforms.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/ports/replay/bag_reader.hpp"
#include "octofuse/ports/replay/mcap_reader.hpp"
#include "octofuse/ports/replay/png_depth.hpp"
#include "octofuse/ports/replay/ros_messages.hpp"
#include "octofuse/ports/replay/tf_buffer.hpp"
#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::replay {

struct BagConfig {
  static constexpr std::size_t kMaxPath = 512;
  static constexpr std::size_t kMaxName = McapChannel::kMaxName;

  BagFormat format = BagFormat::mcap;  // automatic: by the file's magic (for --list)
  char path[kMaxPath] = {};
  char depth_topic[kMaxName] = {};  // empty: chosen automatically
  char info_topic[kMaxName] = {};
  char pose_topic[kMaxName] = {};
  char world_frame[kMaxName] = {};  // TF only; empty: the root of the depth frame's chain
  // read_bag_poses from TF: the odometry's frame; empty: a frame named "odom" on the chain.
  char odometry_frame[kMaxName] = {};

  bool has_intrinsics = false;     // use `intrinsics` instead of the camera info
  PinholeCamera intrinsics;        // width/height 0: taken from the first image
  float depth_units_per_m = 0.0f;  // 0: 1000 for 16-bit images, 5000 for 32FC1

  int max_width = 1280;
  int max_height = 1024;
  int ring_size = 2;
  int max_tf_frames = 64;
  // Transforms kept per TF edge (and of the pose topic), newest first: enough for a depth image
  // stamped this many transforms before the newest one read (?tf_history=N, 2 to 4096).
  int tf_history = 64;
  // Depth images held while the transforms after their stamps are read (?hold=N); 0: each image
  // takes the transforms read so far.
  int hold_frames = 4;
  McapLimits limits;
};

// Fills `config` from "mcap:FILE?key=value&..." or "rosbag:FILE?..." (keys depth, info, pose,
// world, tf, buffer, reorder, hold, tf_history, readahead).
// invalid_argument for another prefix, an empty path, an unknown key or a value too long.
Status parse_bag_spec(const char* spec, BagConfig* config, ErrorText* error);

// Every pose on a bag's Odometry or PoseStamped topic (`config.pose_topic`, or the only such
// topic), in file order, for use as the odometry prior: `on_pose(context, stamp_ns, T)` with the
// pose of the message's child frame (the camera's, when the bag records the camera) in its
// parent frame. invalid_argument when there is no such topic or several; data_loss for a
// corrupt bag. A bag cut short gives the poses before the cut. From TF: the camera's pose in the
// odometry's frame at each depth image's stamp; `warning` (when given) says when some took an
// earlier transform (the bag ended first).
Status read_bag_poses(const BagConfig& config,
                      void (*on_pose)(void* context, std::int64_t stamp_ns, const Se3d& T),
                      void* context, ErrorText* error, ErrorText* warning = nullptr);

// What a topic holds, for --list and the automatic choice.
struct BagTopic {
  const McapChannel* channel = nullptr;
  std::uint64_t count = 0;
  std::uint64_t first_log_ns = 0;
  std::uint64_t last_log_ns = 0;
};

class BagSource final : public DepthSource {
 public:
  explicit BagSource(const BagConfig& config);
  ~BagSource() override;
  BagSource(const BagSource&) = delete;
  BagSource& operator=(const BagSource&) = delete;

  // Reads the whole file once (counts, camera info) and chooses the topics. unavailable (no
  // file), data_loss (not MCAP, corrupt), invalid_argument (no depth topic, ambiguous topics, no
  // intrinsics, a distortion it cannot honour), resource_exhausted.
  Status open() override;
  NextFrame next(DepthFrame& frame) override;
  void close() override;
  PinholeCamera intrinsics() const override { return intrinsics_; }
  SourceCapabilities capabilities() const override;
  const char* last_error() const override { return error_.c_str(); }

  // Only the first pass (no topic choice): for listing a bag. Then topic_count()/topic() and
  // scan_warning() (a cut file) are valid.
  Status scan();
  int topic_count() const { return reader_.channel_count(); }
  BagTopic topic(int index) const;
  const char* scan_warning() const { return scan_warning_.c_str(); }

  // read_bag_poses' work: scans the bag, chooses the odometry and streams its poses.
  Status read_odometry(void (*on_pose)(void* context, std::int64_t stamp_ns, const Se3d& T),
                       void* context);

  // Frames whose pose could not be found (no TF chain to the world, no pose yet).
  std::uint64_t frames_without_pose() const { return frames_without_pose_; }
  // Frames whose pose took a transform from before their stamp: the bag ended first, more than
  // hold_frames images were waiting, or (history_short) the stamp was older than tf_history
  // transforms of an edge.
  std::uint64_t frames_pose_past_end() const { return pose_past_end_; }
  std::uint64_t frames_pose_not_waited() const { return pose_not_waited_; }
  std::uint64_t frames_pose_history_short() const { return pose_history_short_; }
  // Those counts as one line appended to `text` (nothing when all are 0).
  void note_tf(ErrorText* text) const;
  std::size_t bytes_reserved() const { return memory_bytes_ + reader_.bytes_reserved(); }
  const char* depth_topic() const { return depth_topic_; }
  const char* pose_topic() const { return pose_topic_; }

  // Channel kinds, indexed like the reader's channels.
  enum class Kind : std::uint8_t { other, image, compressed, camera_info, tf, odometry, pose };

 private:
  Status choose_topics();
  Status choose_depth_topic();
  // scan()'s answer to the reader: the bytes of a channel's messages are needed while its first
  // image's size or first camera info is not known yet.
  static bool scan_wants_bytes(void* self, const McapChannel& channel);
  int find_topic(const char* name) const;
  void note_disorder(ErrorText* text) const;
  Status read_tf_poses(void (*on_pose)(void* context, std::int64_t stamp_ns, const Se3d& T),
                       void* context);

  // A depth image waiting for the transforms after its stamp.
  struct Held {
    std::int64_t time_ns = 0;  // header stamp, or log time when the stamp is 0
    char frame_id[TfBuffer::kMaxName] = {};
    std::uint16_t* pixels = nullptr;  // in the ring (none when only poses are read)
    int slot = -1;
    float units_per_m = 0.0f;
  };
  // What pull() gives: the oldest held image with its pose.
  enum class Pull : std::uint8_t { image, skipped, ended, failed };
  template <typename Arena>
  Status reserve_tracking(Arena& arena);
  Pull pull(bool decode, Held* image, bool* has_pose, Se3d* T, NextFrame* skip);
  TfAt resolve(const Held& image, bool final, Se3d* T, unsigned* stale) const;
  bool valid_tracking_config() const;
  NextFrame convert(const RosImage& image, std::int64_t log_time_ns);
  NextFrame convert_compressed(const RosCompressedImage& image, std::int64_t log_time_ns);
  void hold(std::uint16_t* pixels, float units_per_m, std::int64_t stamp_ns,
            const RosString& frame_id, std::int64_t log_time_ns);
  std::uint16_t* ring_slot() const;
  void give_out(int slot);

  BagConfig config_;
  ErrorText error_;
  ErrorText scan_warning_;
  const char* prefix() const { return config_.format == BagFormat::rosbag ? "rosbag" : "mcap"; }

  BagReader reader_;
  bool open_ = false;
  bool scanned_ = false;

  void* memory_ = nullptr;
  std::size_t memory_bytes_ = 0;
  std::uint16_t* ring_ = nullptr;
  int ring_slots_ = 0;
  int* free_slots_ = nullptr;  // a stack of ring slots free to decode into
  int free_count_ = 0;
  int* given_slots_ = nullptr;  // the slots of the frames given out last, oldest first
  int given_first_ = 0;
  int given_count_ = 0;
  TfBuffer tf_;
  PngDepthDecoder png_;
  TfHistory pose_history_;  // the pose topic's (its child frame's pose in the world)
  Held* held_ = nullptr;    // a ring of hold_frames + 1
  int held_first_ = 0;
  int held_count_ = 0;
  bool odometry_mode_ = false;  // read_tf_poses: chain to the odometry's frame
  bool stream_ended_ = false;
  McapNext end_state_ = McapNext::end;

  static constexpr int kMaxChannels = 256;
  Kind kinds_[kMaxChannels] = {};
  std::uint64_t counts_[kMaxChannels] = {};
  std::uint64_t first_ns_[kMaxChannels] = {};
  std::uint64_t last_ns_[kMaxChannels] = {};
  int first_width_[kMaxChannels] = {};
  int first_height_[kMaxChannels] = {};
  RosCameraInfo first_info_[kMaxChannels];
  bool have_info_[kMaxChannels] = {};
  char info_model_[kMaxChannels][32] = {};

  const char* depth_topic_ = "";
  const char* pose_topic_ = "";
  int depth_channel_ = -1;
  int info_channel_ = -1;
  int pose_channel_ = -1;  // odometry or pose topic; -1 with use_tf_ for TF
  bool use_tf_ = false;
  char pose_child_[TfBuffer::kMaxName] = {};

  PinholeCamera intrinsics_;
  std::uint64_t sequence_ = 0;
  std::uint64_t frames_without_pose_ = 0;
  std::uint64_t pose_past_end_ = 0;
  std::uint64_t pose_not_waited_ = 0;
  std::uint64_t pose_history_short_ = 0;
};

}  // namespace octofuse::replay
