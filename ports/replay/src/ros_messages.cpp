#include "octofuse/ports/replay/ros_messages.hpp"

#include <cmath>
#include <cstring>

#include <Eigen/Geometry>

namespace octofuse::replay {

bool RosString::equals(const char* text) const {
  const std::size_t n = std::strlen(text);
  return n == size && (n == 0 || std::memcmp(data, text, n) == 0);
}

bool RosReader::init(const std::uint8_t* data, std::size_t size, RosWire wire) {
  data_ = data;
  size_ = size;
  ros1_ = wire == RosWire::ros1;
  ok_ = true;
  if (ros1_) {
    pos_ = origin_ = 0;
    big_endian_ = aligned_ = nul_terminated_ = false;
    return true;
  }
  // Encapsulation: 0x0000 CDR_BE, 0x0001 CDR_LE; options follow (ignored).
  if (size < 4 || data[0] != 0 || data[1] > 1) {
    ok_ = false;
    return false;
  }
  big_endian_ = data[1] == 0;
  aligned_ = nul_terminated_ = true;
  pos_ = origin_ = 4;
  return true;
}

void RosReader::align(std::size_t n) {
  if (!aligned_ || !ok_) return;
  const std::size_t rel = pos_ - origin_;
  const std::size_t pad = (n - rel % n) % n;
  if (pad > size_ - pos_) {
    ok_ = false;
    return;
  }
  pos_ += pad;
}

const std::uint8_t* RosReader::take(std::size_t n) {
  if (!ok_ || n > size_ - pos_) {
    ok_ = false;
    return nullptr;
  }
  const std::uint8_t* p = data_ + pos_;
  pos_ += n;
  return p;
}

std::uint8_t RosReader::u8() {
  const std::uint8_t* p = take(1);
  return p == nullptr ? 0 : p[0];
}

std::uint32_t RosReader::u32() {
  align(4);
  const std::uint8_t* p = take(4);
  if (p == nullptr) return 0;
  if (big_endian_) {
    return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) |
           std::uint32_t{p[3]};
  }
  return std::uint32_t{p[0]} | (std::uint32_t{p[1]} << 8) | (std::uint32_t{p[2]} << 16) |
         (std::uint32_t{p[3]} << 24);
}

double RosReader::f64() {
  align(8);
  const std::uint8_t* p = take(8);
  if (p == nullptr) return 0.0;
  std::uint64_t bits = 0;
  for (int i = 0; i < 8; ++i) {
    const int shift = big_endian_ ? 8 * (7 - i) : 8 * i;
    bits |= std::uint64_t{p[i]} << shift;
  }
  double value = 0.0;
  std::memcpy(&value, &bits, sizeof(value));
  return value;
}

RosString RosReader::string() {
  RosString s;
  const std::uint32_t n = u32();
  const std::uint8_t* p = take(n);
  if (p == nullptr) return s;
  s.data = reinterpret_cast<const char*>(p);
  s.size = n;
  // CDR counts the NUL; a string without one is malformed.
  if (nul_terminated_) {
    if (n == 0 || p[n - 1] != 0) {
      ok_ = false;
      return RosString{};
    }
    s.size = n - 1;
  }
  return s;
}

const std::uint8_t* RosReader::bytes(std::uint32_t* size) {
  *size = u32();
  const std::uint8_t* p = take(*size);
  if (p == nullptr) *size = 0;
  return p;
}

void RosReader::header(std::int64_t* stamp_ns, RosString* frame_id) {
  if (ros1_) (void)u32();  // seq
  const std::uint32_t sec = u32();
  const std::uint32_t nsec = u32();
  // ROS 2 stamps are signed seconds, ROS 1 unsigned.
  const std::int64_t seconds =
      ros1_ ? std::int64_t{sec} : std::int64_t{static_cast<std::int32_t>(sec)};
  *stamp_ns = seconds * 1000000000 + std::int64_t{nsec};
  *frame_id = string();
}

bool decode_image(const std::uint8_t* data, std::size_t size, RosWire wire, RosImage* image) {
  RosReader r;
  if (!r.init(data, size, wire)) return false;
  r.header(&image->stamp_ns, &image->frame_id);
  image->height = r.u32();
  image->width = r.u32();
  image->encoding = r.string();
  image->big_endian = r.u8() != 0;
  image->step = r.u32();
  image->data = r.bytes(&image->data_size);
  return r.ok();
}

bool decode_compressed_image(const std::uint8_t* data, std::size_t size, RosWire wire,
                             RosCompressedImage* image) {
  RosReader r;
  if (!r.init(data, size, wire)) return false;
  r.header(&image->stamp_ns, &image->frame_id);
  image->format = r.string();
  image->data = r.bytes(&image->data_size);
  return r.ok();
}

bool decode_camera_info(const std::uint8_t* data, std::size_t size, RosWire wire,
                        RosCameraInfo* info) {
  RosReader r;
  if (!r.init(data, size, wire)) return false;
  r.header(&info->stamp_ns, &info->frame_id);
  info->height = r.u32();
  info->width = r.u32();
  info->distortion_model = r.string();
  info->distortion_count = r.u32();
  // Each coefficient takes 8 bytes: a count the message cannot hold is corruption, caught before
  // the loop runs for billions of iterations.
  if (!r.ok() || info->distortion_count > r.remaining() / 8) return false;
  info->max_abs_distortion = 0.0;
  for (std::uint32_t i = 0; i < info->distortion_count; ++i) {
    const double d = r.f64();
    if (i < static_cast<std::uint32_t>(RosCameraInfo::kMaxDistortion)) info->distortion[i] = d;
    const double a = std::fabs(d);
    if (!(a <= info->max_abs_distortion)) info->max_abs_distortion = a;  // NaN sticks
  }
  for (double& k : info->k) k = r.f64();
  return r.ok();
}

namespace {

void read_pose(RosReader& r, RosPose* pose) {
  for (double& t : pose->t) t = r.f64();
  for (double& q : pose->q) q = r.f64();
}

}  // namespace

bool decode_pose_stamped(const std::uint8_t* data, std::size_t size, RosWire wire, RosPose* pose) {
  RosReader r;
  if (!r.init(data, size, wire)) return false;
  r.header(&pose->stamp_ns, &pose->parent_frame);
  pose->child_frame = RosString{};
  read_pose(r, pose);
  return r.ok();
}

bool decode_odometry(const std::uint8_t* data, std::size_t size, RosWire wire, RosPose* pose) {
  RosReader r;
  if (!r.init(data, size, wire)) return false;
  r.header(&pose->stamp_ns, &pose->parent_frame);
  pose->child_frame = r.string();
  read_pose(r, pose);  // pose.pose; covariance and twist are not needed
  return r.ok();
}

bool pose_to_se3(const RosPose& pose, Se3d* T) {
  const Eigen::Quaterniond q(pose.q[3], pose.q[0], pose.q[1], pose.q[2]);
  const double n = q.norm();
  if (!(std::fabs(n - 1.0) < 1e-3) || !std::isfinite(pose.t[0] + pose.t[1] + pose.t[2])) {
    return false;
  }
  T->setIdentity();
  T->linear() = q.normalized().toRotationMatrix();
  T->translation() = Eigen::Vector3d(pose.t[0], pose.t[1], pose.t[2]);
  return true;
}

RosPose pose_from_matrix(const Eigen::Matrix4d& T) {
  RosPose pose;
  const Eigen::Quaterniond q(Eigen::Matrix3d(T.topLeftCorner<3, 3>()));
  for (int i = 0; i < 3; ++i) pose.t[i] = T(i, 3);
  pose.q[0] = q.x();
  pose.q[1] = q.y();
  pose.q[2] = q.z();
  pose.q[3] = q.w();
  return pose;
}

Eigen::Matrix4d pose_as_replayed(const Eigen::Matrix4d& T) {
  Se3d replayed;
  if (!pose_to_se3(pose_from_matrix(T), &replayed)) return T;
  return replayed.matrix();
}

bool RosTfReader::begin(const std::uint8_t* data, std::size_t size, RosWire wire) {
  if (!reader_.init(data, size, wire)) return false;
  count_ = reader_.u32();
  return reader_.ok();
}

bool RosTfReader::next(RosPose* transform) {
  reader_.header(&transform->stamp_ns, &transform->parent_frame);
  transform->child_frame = reader_.string();
  read_pose(reader_, transform);
  return reader_.ok();
}

}  // namespace octofuse::replay
