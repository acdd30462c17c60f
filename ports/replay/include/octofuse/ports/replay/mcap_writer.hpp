#pragma once
// Records depth frames as a ROS 2 bag in MCAP (https://mcap.dev/spec), which `ros2 bag` (MCAP
// storage) and Foxglove open: per frame a sensor_msgs/msg/CameraInfo on
// /camera/depth/camera_info, a sensor_msgs/msg/Image on /camera/depth/image_raw (16UC1 in
// millimetres when the frame is in millimetres, else 32FC1 in metres with NaN for no data) and,
// when the frame has one, its pose as geometry_msgs/msg/PoseStamped on /ground_truth (frame
// "world") and, when the run has an odometry (--odometry), the odometry's pose of the camera as
// nav_msgs/msg/Odometry on /odom (frame "odom", child "camera_depth"). Messages are written
// unchunked, each as soon as it is given, so a recorder killed at
// any byte leaves a file that replays to its last whole message (mcap_reader.hpp); close()
// writes the data end and footer. All buffers are reserved at open().

#include <cstdint>
#include <cstdio>

#include <Eigen/Core>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/sensor/depth_frame.hpp"

namespace octofuse::replay {

class McapWriter {
 public:
  McapWriter() = default;
  ~McapWriter();
  McapWriter(const McapWriter&) = delete;
  McapWriter& operator=(const McapWriter&) = delete;

  // Creates `path` for frames of `camera` (its width and height bound the frames). unavailable
  // (cannot create), invalid_argument (camera), resource_exhausted (no memory).
  // `odometry`: declare the /odom topic.
  Status open(const char* path, const PinholeCamera& camera, bool odometry = false);
  // Appends one frame and, when given (and the recording has /odom), the odometry's pose of the
  // camera at its time. invalid_argument for a frame of another size; unavailable on a write
  // error (disk full).
  Status write(const DepthFrame& frame, const Eigen::Matrix4d* T_O_C = nullptr);
  // Writes the end records and closes; ok when nothing was open.
  Status close();

  const char* last_error() const { return error_.c_str(); }
  std::uint64_t frames_written() const { return frames_; }

 private:
  Status put(const void* data, std::size_t size);
  Status message(std::uint16_t channel, std::uint64_t log_time_ns, std::size_t size);

  ErrorText error_;
  std::FILE* file_ = nullptr;
  PinholeCamera camera_;
  std::uint8_t* buffer_ = nullptr;  // one CDR message
  std::size_t buffer_bytes_ = 0;
  std::uint64_t frames_ = 0;
  std::uint32_t sequence_ = 0;
  bool odometry_ = false;
};

}  // namespace octofuse::replay
