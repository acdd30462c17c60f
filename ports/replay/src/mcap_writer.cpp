#include "octofuse/ports/replay/mcap_writer.hpp"

#include "octofuse/ports/replay/ros_messages.hpp"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>

namespace octofuse::replay {
namespace {

constexpr std::uint8_t kMagic[8] = {0x89, 'M', 'C', 'A', 'P', 0x30, '\r', '\n'};
constexpr std::uint16_t kImageChannel = 1;
constexpr std::uint16_t kInfoChannel = 2;
constexpr std::uint16_t kPoseChannel = 3;
constexpr std::uint16_t kOdometryChannel = 4;

constexpr const char* kSeparator =
    "================================================================================\n";
constexpr const char* kHeaderDefinition =
    "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
constexpr const char* kTimeDefinition = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";

// Little-endian CDR into a buffer sized at open() (the caller checks the capacity first).
struct CdrOut {
  std::uint8_t* p;
  std::size_t n = 4;
  explicit CdrOut(std::uint8_t* buffer) : p(buffer) {
    p[0] = 0;
    p[1] = 1;  // CDR_LE
    p[2] = p[3] = 0;
  }
  void align(std::size_t a) {
    while ((n - 4) % a != 0) p[n++] = 0;
  }
  void raw(const void* data, std::size_t size) {
    std::memcpy(p + n, data, size);
    n += size;
  }
  void u8(std::uint8_t v) { p[n++] = v; }
  void u32(std::uint32_t v) {
    align(4);
    for (int i = 0; i < 4; ++i) p[n++] = static_cast<std::uint8_t>(v >> (8 * i));
  }
  void f64(double v) {
    align(8);
    std::uint64_t bits = 0;
    std::memcpy(&bits, &v, 8);
    for (int i = 0; i < 8; ++i) p[n++] = static_cast<std::uint8_t>(bits >> (8 * i));
  }
  void string(const char* s) {
    const std::size_t size = std::strlen(s) + 1;
    u32(static_cast<std::uint32_t>(size));
    raw(s, size);
  }
  void header(std::int64_t stamp_ns, const char* frame_id) {
    // Floor division: a negative stamp keeps nanosec in [0, 1e9).
    std::int64_t sec = stamp_ns / 1000000000;
    std::int64_t nsec = stamp_ns % 1000000000;
    if (nsec < 0) {
      nsec += 1000000000;
      --sec;
    }
    u32(static_cast<std::uint32_t>(static_cast<std::int32_t>(sec)));
    u32(static_cast<std::uint32_t>(nsec));
    string(frame_id);
  }
};

void le(std::uint8_t* out, std::uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) out[i] = static_cast<std::uint8_t>(v >> (8 * i));
}

}  // namespace

McapWriter::~McapWriter() {
  (void)close();
}

Status McapWriter::put(const void* data, std::size_t size) {
  if (size > 0 && std::fwrite(data, 1, size, file_) != size) {
    error_.set("mcap record: write failed: %s", std::strerror(errno));
    return StatusCode::unavailable;
  }
  return ok_status();
}

Status McapWriter::message(std::uint16_t channel, std::uint64_t log_time_ns, std::size_t size) {
  std::uint8_t head[9 + 22];
  head[0] = 0x05;
  le(head + 1, 22 + size, 8);
  le(head + 9, channel, 2);
  le(head + 11, ++sequence_, 4);
  le(head + 15, log_time_ns, 8);
  le(head + 23, log_time_ns, 8);
  OCTOFUSE_TRY(put(head, sizeof(head)));
  return put(buffer_, size);
}

Status McapWriter::open(const char* path, const PinholeCamera& camera, bool odometry) {
  (void)close();
  error_.clear();
  if (!(camera.fx > 0.0f && camera.fy > 0.0f) || camera.width <= 0 || camera.height <= 0 ||
      camera.width > 16384 || camera.height > 16384) {
    error_.set("mcap record: the camera needs fx, fy > 0 and a size up to 16384");
    return StatusCode::invalid_argument;
  }
  camera_ = camera;
  buffer_bytes_ =
      4096 + static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height) * 4;
  buffer_ = static_cast<std::uint8_t*>(std::malloc(buffer_bytes_));
  if (buffer_ == nullptr) {
    error_.set("mcap record: cannot reserve %zu bytes", buffer_bytes_);
    return StatusCode::resource_exhausted;
  }
  file_ = std::fopen(path, "wb");
  if (file_ == nullptr) {
    error_.set("mcap record: cannot create %s: %s", path, std::strerror(errno));
    std::free(buffer_);
    buffer_ = nullptr;
    return StatusCode::unavailable;
  }
  frames_ = 0;
  sequence_ = 0;
  odometry_ = odometry;

  // Header, schemas (ros2msg definitions, as rosbag2 writes them) and channels.
  auto record = [&](std::uint8_t opcode, std::size_t size) {
    std::uint8_t head[9];
    head[0] = opcode;
    le(head + 1, size, 8);
    return put(head, 9);
  };
  auto string = [&](const char* s) {
    std::uint8_t n[4];
    const std::size_t size = std::strlen(s);
    le(n, size, 4);
    const Status status = put(n, 4);
    return status.ok() ? put(s, size) : status;
  };
  OCTOFUSE_TRY(put(kMagic, 8));
  OCTOFUSE_TRY(record(0x01, 8 + 4 + 15));
  OCTOFUSE_TRY(string("ros2"));
  OCTOFUSE_TRY(string("octofuse-record"));

  char image_def[1024];
  std::snprintf(image_def, sizeof(image_def),
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 "
                "is_bigendian\nuint32 step\nuint8[] data\n%s%s%s%s",
                kSeparator, kHeaderDefinition, kSeparator, kTimeDefinition);
  char info_def[2048];
  std::snprintf(info_def, sizeof(info_def),
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
                "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 "
                "binning_y\nsensor_msgs/RegionOfInterest roi\n%s%s%s%s%sMSG: "
                "sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 "
                "height\nuint32 width\nbool do_rectify\n",
                kSeparator, kHeaderDefinition, kSeparator, kTimeDefinition, kSeparator);
  char pose_def[1536];
  std::snprintf(pose_def, sizeof(pose_def),
                "std_msgs/Header header\ngeometry_msgs/Pose pose\n%s%s%s%s%sMSG: "
                "geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion "
                "orientation\n%sMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n%sMSG: "
                "geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
                kSeparator, kHeaderDefinition, kSeparator, kTimeDefinition, kSeparator, kSeparator,
                kSeparator);
  char odometry_def[3072];
  std::snprintf(odometry_def, sizeof(odometry_def),
                "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance "
                "pose\ngeometry_msgs/TwistWithCovariance twist\n%s%s%s%s%sMSG: "
                "geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] "
                "covariance\n%sMSG: geometry_msgs/Pose\ngeometry_msgs/Point "
                "position\ngeometry_msgs/Quaternion orientation\n%sMSG: "
                "geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n%sMSG: "
                "geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w "
                "1\n%sMSG: geometry_msgs/TwistWithCovariance\ngeometry_msgs/Twist "
                "twist\nfloat64[36] covariance\n%sMSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 "
                "linear\ngeometry_msgs/Vector3 angular\n%sMSG: geometry_msgs/Vector3\nfloat64 "
                "x\nfloat64 y\nfloat64 z\n",
                kSeparator, kHeaderDefinition, kSeparator, kTimeDefinition, kSeparator, kSeparator,
                kSeparator, kSeparator, kSeparator, kSeparator, kSeparator);
  struct Definition {
    std::uint16_t id;
    const char* name;
    const char* text;
    const char* topic;
  };
  const Definition definitions[4] = {
      {kImageChannel, "sensor_msgs/msg/Image", image_def, "/camera/depth/image_raw"},
      {kInfoChannel, "sensor_msgs/msg/CameraInfo", info_def, "/camera/depth/camera_info"},
      {kPoseChannel, "geometry_msgs/msg/PoseStamped", pose_def, "/ground_truth"},
      {kOdometryChannel, "nav_msgs/msg/Odometry", odometry_def, "/odom"},
  };
  const int declared = odometry ? 4 : 3;
  for (int i = 0; i < declared; ++i) {
    const Definition& d = definitions[i];
    std::uint8_t id[2];
    le(id, d.id, 2);
    OCTOFUSE_TRY(record(0x03, 2 + 4 + std::strlen(d.name) + 4 + 7 + 4 + std::strlen(d.text)));
    OCTOFUSE_TRY(put(id, 2));
    OCTOFUSE_TRY(string(d.name));
    OCTOFUSE_TRY(string("ros2msg"));
    OCTOFUSE_TRY(string(d.text));
  }
  for (int i = 0; i < declared; ++i) {
    const Definition& d = definitions[i];
    std::uint8_t ids[4];
    le(ids, d.id, 2);
    le(ids + 2, d.id, 2);
    const char* qos = "";
    OCTOFUSE_TRY(record(0x04, 4 + 4 + std::strlen(d.topic) + 4 + 3 + 4 + std::strlen(qos)));
    OCTOFUSE_TRY(put(ids, 4));
    OCTOFUSE_TRY(string(d.topic));
    OCTOFUSE_TRY(string("cdr"));
    std::uint8_t empty_map[4] = {0, 0, 0, 0};
    OCTOFUSE_TRY(put(empty_map, 4));
  }
  if (std::fflush(file_) != 0) {
    error_.set("mcap record: write failed: %s", std::strerror(errno));
    return StatusCode::unavailable;
  }
  return ok_status();
}

Status McapWriter::write(const DepthFrame& frame, const Eigen::Matrix4d* T_O_C) {
  if (file_ == nullptr) {
    error_.set("mcap record: write() before a successful open()");
    return StatusCode::failed_precondition;
  }
  const ImageView<const std::uint16_t>& depth = frame.depth_raw;
  if (depth.width != camera_.width || depth.height != camera_.height) {
    error_.set("mcap record: frame of %dx%d, the recording is %dx%d", depth.width, depth.height,
               camera_.width, camera_.height);
    return StatusCode::invalid_argument;
  }
  const std::int64_t stamp_ns = frame.timestamp_us * 1000;
  const std::uint64_t log_ns = stamp_ns > 0 ? static_cast<std::uint64_t>(stamp_ns) : 0;

  if (frame.has_ground_truth) {
    CdrOut c(buffer_);
    c.header(stamp_ns, "world");
    const RosPose pose = pose_from_matrix(frame.T_W_C_ground_truth);
    for (double t : pose.t) c.f64(t);
    for (double q : pose.q) c.f64(q);
    OCTOFUSE_TRY(message(kPoseChannel, log_ns, c.n));
  }
  if (odometry_ && T_O_C != nullptr) {
    CdrOut c(buffer_);
    c.header(stamp_ns, "odom");
    c.string("camera_depth");
    const RosPose pose = pose_from_matrix(*T_O_C);
    for (double t : pose.t) c.f64(t);
    for (double q : pose.q) c.f64(q);
    for (int i = 0; i < 36 + 6 + 36; ++i) c.f64(0.0);  // covariance unknown, twist, covariance
    OCTOFUSE_TRY(message(kOdometryChannel, log_ns, c.n));
  }
  {
    CdrOut c(buffer_);
    c.header(stamp_ns, "camera_depth");
    c.u32(static_cast<std::uint32_t>(camera_.height));
    c.u32(static_cast<std::uint32_t>(camera_.width));
    c.string("plumb_bob");
    c.u32(5);
    for (int i = 0; i < 5; ++i) c.f64(0.0);
    const double fx = camera_.fx, fy = camera_.fy, cx = camera_.cx, cy = camera_.cy;
    const double k[9] = {fx, 0, cx, 0, fy, cy, 0, 0, 1};
    for (double v : k) c.f64(v);
    const double r[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    for (double v : r) c.f64(v);
    const double p[12] = {fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0};
    for (double v : p) c.f64(v);
    for (int i = 0; i < 6; ++i) c.u32(0);  // binning, roi offsets and size
    c.u8(0);                               // do_rectify
    OCTOFUSE_TRY(message(kInfoChannel, log_ns, c.n));
  }
  {
    // Millimetres stay 16UC1, the ROS convention; any other scale becomes metres in 32FC1.
    const bool millimetres = frame.metres_per_unit == 0.001f;
    CdrOut c(buffer_);
    c.header(stamp_ns, "camera_depth");
    c.u32(static_cast<std::uint32_t>(depth.height));
    c.u32(static_cast<std::uint32_t>(depth.width));
    c.string(millimetres ? "16UC1" : "32FC1");
    c.u8(0);
    const std::size_t pixel = millimetres ? 2 : 4;
    c.u32(static_cast<std::uint32_t>(static_cast<std::size_t>(depth.width) * pixel));
    c.u32(static_cast<std::uint32_t>(depth.pixel_count() * pixel));
    for (int y = 0; y < depth.height; ++y) {
      const std::uint16_t* row = depth.row(y);
      for (int x = 0; x < depth.width; ++x) {
        if (millimetres) {
          c.p[c.n++] = static_cast<std::uint8_t>(row[x]);
          c.p[c.n++] = static_cast<std::uint8_t>(row[x] >> 8);
        } else {
          const float m = row[x] == 0 ? std::numeric_limits<float>::quiet_NaN()
                                      : static_cast<float>(row[x]) * frame.metres_per_unit;
          c.raw(&m, 4);
        }
      }
    }
    OCTOFUSE_TRY(message(kImageChannel, log_ns, c.n));
  }
  ++frames_;
  // Each frame reaches the file before the next one is taken: a kill loses at most this one.
  if (std::fflush(file_) != 0) {
    error_.set("mcap record: write failed: %s", std::strerror(errno));
    return StatusCode::unavailable;
  }
  return ok_status();
}

Status McapWriter::close() {
  Status status = ok_status();
  if (file_ != nullptr) {
    // Data end (no CRC: 0), an empty summary and the footer.
    std::uint8_t tail[9 + 4 + 9 + 20 + 8];
    tail[0] = 0x0F;
    le(tail + 1, 4, 8);
    le(tail + 9, 0, 4);
    tail[13] = 0x02;
    le(tail + 14, 20, 8);
    std::memset(tail + 22, 0, 20);
    std::memcpy(tail + 42, kMagic, 8);
    status = put(tail, sizeof(tail));
    if (std::fclose(file_) != 0 && status.ok()) {
      error_.set("mcap record: close failed: %s", std::strerror(errno));
      status = StatusCode::unavailable;
    }
    file_ = nullptr;
  }
  std::free(buffer_);
  buffer_ = nullptr;
  return status;
}

}  // namespace octofuse::replay
