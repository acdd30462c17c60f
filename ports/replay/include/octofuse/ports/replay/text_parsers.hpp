#pragma once
// Parsers for the small text files of recorded datasets. They work on a buffer already in memory,
// never allocate and never read past `size` (they are fuzzed). Errors are data_loss with a
// message "<label>:<line>: <what is wrong>", where `label` is the file the caller read.

#include <cstddef>
#include <cstdint>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/math/camera.hpp"

namespace octofuse::replay {

// Walks a buffer line by line ('\n', '\r\n' or '\r' endings; a missing final newline is fine).
class LineReader {
 public:
  LineReader(const char* text, std::size_t size) : p_(text), end_(text + size) {}
  // The next line without its ending; false at the end of the buffer.
  bool next(const char** line, std::size_t* length);
  int line_number() const { return line_number_; }

 private:
  const char* p_;
  const char* end_;
  int line_number_ = 0;
};

// True for lines with only blanks, or whose first non-blank character is '#'.
bool is_blank_or_comment(const char* line, std::size_t length);

// Reads a decimal floating-point number (optional sign, fraction, exponent) after skipping
// blanks; advances `*p`. Locale-independent. False (and `*p` unchanged) when there is none or it
// is not finite.
bool parse_double(const char** p, const char* end, double* value);

// Timestamps are seconds in [0, kMaxTimestamp_s] (a little over 3000 years: Unix times and frame
// indices fit; microseconds of it fit in 64 bits); others are data_loss.
inline constexpr double kMaxTimestamp_s = 1e11;

// "timestamp name [more columns]" as in TUM's depth.txt / rgb.txt and ICL-NUIM's
// associations.txt (only the first two columns are used). `name` points into `line`.
struct TimestampedName {
  double timestamp_s = 0.0;
  const char* name = nullptr;
  std::size_t name_length = 0;
};
Status parse_timestamped_name(const char* line, std::size_t length, TimestampedName* out,
                              const char* label, int line_number, ErrorText* error);

// "timestamp tx ty tz qx qy qz qw" (TUM groundtruth.txt, ICL-NUIM *.gt.freiburg). The
// quaternion must have unit length within kQuaternionNormTolerance (else it is not a rotation);
// it is returned normalised.
inline constexpr double kQuaternionNormTolerance = 1e-2;
struct TimestampedPose {
  double timestamp_s = 0.0;
  Eigen::Vector3d t_W_C = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_W_C = Eigen::Quaterniond::Identity();
};
Status parse_tum_pose_line(const char* line, std::size_t length, TimestampedPose* out,
                           const char* label, int line_number, ErrorText* error);

// 7-Scenes frame-XXXXXX.pose.txt: 16 numbers, a row-major 4x4 camera-to-world transform. The
// result must be rigid (rotation within kPoseRigidTolerance, last row 0 0 0 1).
inline constexpr double kPoseRigidTolerance = 1e-3;
Status parse_pose_matrix(const char* text, std::size_t size, Eigen::Matrix4d* T_W_C,
                         const char* label, ErrorText* error);

// 7-Scenes camera-intrinsics.txt: a row-major 3x3 K = [fx 0 cx; 0 fy cy; 0 0 1]. Sets fx, fy,
// cx, cy of `camera` (width and height untouched). Zero skew and a last row 0 0 1 are required.
Status parse_intrinsics_matrix(const char* text, std::size_t size, PinholeCamera* camera,
                               const char* label, ErrorText* error);

// "fx,fy,cx,cy" as given on a command line (--intrinsics); invalid_argument when malformed.
Status parse_intrinsics_list(const char* text, PinholeCamera* camera, ErrorText* error);

}  // namespace octofuse::replay
