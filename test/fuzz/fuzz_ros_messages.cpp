// The ROS message decoders (ROS 2 CDR and ROS 1), on arbitrary bytes: a decoded message's
// strings and data lie inside the input, and a failure is a plain false.
#include <cstddef>
#include <cstdint>

#include "octofuse/ports/replay/ros_messages.hpp"

namespace {

using namespace octofuse::replay;

void inside(const void* p, std::size_t n, const std::uint8_t* data, std::size_t size) {
  if (n == 0) return;
  const std::uint8_t* b = static_cast<const std::uint8_t*>(p);
  if (b < data || b + n > data + size) __builtin_trap();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  for (RosWire wire : {RosWire::cdr, RosWire::ros1}) {
    RosImage image;
    if (decode_image(data, size, wire, &image)) {
      inside(image.data, image.data_size, data, size);
      inside(image.encoding.data, image.encoding.size, data, size);
      inside(image.frame_id.data, image.frame_id.size, data, size);
    }
    RosCompressedImage compressed;
    if (decode_compressed_image(data, size, wire, &compressed)) {
      inside(compressed.data, compressed.data_size, data, size);
    }
    RosCameraInfo info;
    if (decode_camera_info(data, size, wire, &info)) {
      inside(info.distortion_model.data, info.distortion_model.size, data, size);
    }
    RosPose pose;
    if (decode_odometry(data, size, wire, &pose))
      inside(pose.child_frame.data, pose.child_frame.size, data, size);
    (void)decode_pose_stamped(data, size, wire, &pose);
    RosTfReader tf;
    if (tf.begin(data, size, wire)) {
      for (std::uint32_t i = 0; i < tf.count() && tf.next(&pose); ++i) {
        inside(pose.parent_frame.data, pose.parent_frame.size, data, size);
      }
    }
    octofuse::Se3d T;
    (void)pose_to_se3(pose, &T);
  }
  return 0;
}
