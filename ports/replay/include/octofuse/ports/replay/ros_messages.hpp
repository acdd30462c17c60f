#pragma once
// Decoding the few ROS message types a depth replay needs, from their wire form without ROS:
// ROS 2 CDR (a 4-byte encapsulation header, then little- or big-endian fields aligned to their
// size relative to the end of that header) and ROS 1 serialisation (little-endian, packed,
// strings without the terminating NUL, a sequence number first in every header). Decoders read
// straight from the message bytes: strings and image data are views into them, nothing is copied
// or allocated. Every read is bounds-checked; a short or malformed message gives false.

#include <cstddef>
#include <cstdint>

#include "octofuse/math/se3.hpp"

namespace octofuse::replay {

enum class RosWire : std::uint8_t { cdr, ros1 };

// A view of a string inside a message (not NUL-terminated).
struct RosString {
  const char* data = nullptr;
  std::uint32_t size = 0;
  bool equals(const char* text) const;
};

class RosReader {
 public:
  // false when `wire` is cdr and the encapsulation header is missing or not plain CDR.
  bool init(const std::uint8_t* data, std::size_t size, RosWire wire);

  std::uint8_t u8();
  std::uint32_t u32();
  std::int32_t i32() { return static_cast<std::int32_t>(u32()); }
  double f64();
  RosString string();
  // A uint8[] sequence: its length, then a view of the bytes.
  const std::uint8_t* bytes(std::uint32_t* size);
  // A std_msgs/Header: stamp in nanoseconds since the epoch, frame_id.
  void header(std::int64_t* stamp_ns, RosString* frame_id);

  bool ok() const { return ok_; }
  std::size_t remaining() const { return ok_ ? size_ - pos_ : 0; }

 private:
  void align(std::size_t n);
  const std::uint8_t* take(std::size_t n);

  const std::uint8_t* data_ = nullptr;
  std::size_t size_ = 0;
  std::size_t pos_ = 0;
  std::size_t origin_ = 0;  // CDR alignment is relative to the end of the encapsulation header
  bool big_endian_ = false;
  bool aligned_ = false;
  bool nul_terminated_ = false;
  bool ros1_ = false;
  bool ok_ = false;
};

// sensor_msgs/Image.
struct RosImage {
  std::int64_t stamp_ns = 0;
  RosString frame_id;
  std::uint32_t height = 0;
  std::uint32_t width = 0;
  RosString encoding;
  bool big_endian = false;
  std::uint32_t step = 0;
  const std::uint8_t* data = nullptr;
  std::uint32_t data_size = 0;
};
bool decode_image(const std::uint8_t* data, std::size_t size, RosWire wire, RosImage* image);

// sensor_msgs/CompressedImage.
struct RosCompressedImage {
  std::int64_t stamp_ns = 0;
  RosString frame_id;
  RosString format;
  const std::uint8_t* data = nullptr;
  std::uint32_t data_size = 0;
};
bool decode_compressed_image(const std::uint8_t* data, std::size_t size, RosWire wire,
                             RosCompressedImage* image);

// sensor_msgs/CameraInfo (the fields a pinhole depth camera needs).
struct RosCameraInfo {
  static constexpr int kMaxDistortion = 16;
  std::int64_t stamp_ns = 0;
  RosString frame_id;
  std::uint32_t height = 0;
  std::uint32_t width = 0;
  RosString distortion_model;
  std::uint32_t distortion_count = 0;  // may exceed kMaxDistortion; only the first are kept
  double distortion[kMaxDistortion] = {};
  double max_abs_distortion = 0.0;  // over all coefficients
  double k[9] = {};
};
bool decode_camera_info(const std::uint8_t* data, std::size_t size, RosWire wire,
                        RosCameraInfo* info);

// A pose: geometry_msgs/TransformStamped, PoseStamped or the pose of nav_msgs/Odometry.
// `child_frame` is empty for PoseStamped.
struct RosPose {
  std::int64_t stamp_ns = 0;
  RosString parent_frame;
  RosString child_frame;
  double t[3] = {};
  double q[4] = {0, 0, 0, 1};  // x y z w
};
bool decode_pose_stamped(const std::uint8_t* data, std::size_t size, RosWire wire, RosPose* pose);
bool decode_odometry(const std::uint8_t* data, std::size_t size, RosWire wire, RosPose* pose);

// The rigid transform of a pose; false when its quaternion is not a unit one (within 1e-3) or
// its translation is not finite. The quaternion is normalised first.
bool pose_to_se3(const RosPose& pose, Se3d* T);
// What a pose recorded from `T` (through a quaternion) reads back as: the recorder gives the
// run this, so a recording replays bit for bit.
Eigen::Matrix4d pose_as_replayed(const Eigen::Matrix4d& T);
// The translation and quaternion recorded for `T`.
RosPose pose_from_matrix(const Eigen::Matrix4d& T);

// tf2_msgs/TFMessage: begin() reads the count, then next() each transform.
class RosTfReader {
 public:
  bool begin(const std::uint8_t* data, std::size_t size, RosWire wire);
  std::uint32_t count() const { return count_; }
  bool next(RosPose* transform);

 private:
  RosReader reader_;
  std::uint32_t count_ = 0;
};

}  // namespace octofuse::replay
