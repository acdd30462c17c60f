// The dataset text parsers (depth.txt / associations.txt lines, groundtruth.txt lines, 7-Scenes
// pose.txt and camera-intrinsics.txt, --intrinsics lists). The first byte picks the parser.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "octofuse/math/se3.hpp"
#include "octofuse/ports/replay/text_parsers.hpp"

namespace {

constexpr std::size_t kMaxInputBytes = 1 << 16;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0 || size >= kMaxInputBytes) return 0;
  const std::uint8_t selector = data[0];
  const std::size_t length = size - 1;
  // A heap copy sized to the input (plus the NUL parse_intrinsics_list needs), so AddressSanitizer
  // catches any read past it.
  char* text = new char[length + 1];
  std::memcpy(text, data + 1, length);
  text[length] = '\0';
  namespace rp = octofuse::replay;
  octofuse::ErrorText error;
  switch (selector % 5) {
    case 0: {
      rp::LineReader lines(text, length);
      const char* line;
      std::size_t line_length;
      while (lines.next(&line, &line_length)) {
        if (line < text || line + line_length > text + length) __builtin_trap();
        if (rp::is_blank_or_comment(line, line_length)) continue;
        rp::TimestampedName name;
        if (rp::parse_timestamped_name(line, line_length, &name, "depth.txt", lines.line_number(),
                                       &error)
                .ok()) {
          if (name.name_length == 0 || name.name < line ||
              name.name + name.name_length > line + line_length) {
            __builtin_trap();
          }
        }
      }
      break;
    }
    case 1: {
      rp::LineReader lines(text, length);
      const char* line;
      std::size_t line_length;
      while (lines.next(&line, &line_length)) {
        rp::TimestampedPose pose;
        if (rp::parse_tum_pose_line(line, line_length, &pose, "groundtruth.txt",
                                    lines.line_number(), &error)
                .ok() &&
            std::fabs(pose.q_W_C.norm() - 1.0) > 1e-9) {
          __builtin_trap();
        }
      }
      break;
    }
    case 2: {
      Eigen::Matrix4d T;
      if (rp::parse_pose_matrix(text, length, &T, "pose.txt", &error).ok() &&
          !octofuse::is_rigid(T, 2e-3)) {
        __builtin_trap();
      }
      break;
    }
    case 3: {
      octofuse::PinholeCamera camera;
      if (rp::parse_intrinsics_matrix(text, length, &camera, "camera-intrinsics.txt", &error)
              .ok() &&
          !(camera.fx > 0.0f && camera.fy > 0.0f)) {
        __builtin_trap();
      }
      break;
    }
    case 4: {
      octofuse::PinholeCamera camera;
      rp::parse_intrinsics_list(text, &camera, &error).ignore();
      break;
    }
  }
  delete[] text;
  return 0;
}
