#include "octofuse/ports/replay/text_parsers.hpp"

#include <charconv>
#include <cmath>

#include "octofuse/math/se3.hpp"

namespace octofuse::replay {
namespace {

bool is_blank(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == ',';
}

const char* skip_blanks(const char* p, const char* end) {
  while (p < end && is_blank(*p)) ++p;
  return p;
}

// Parses up to `count` numbers from [p, end); returns how many were read, and the position after.
int parse_numbers(const char** p, const char* end, double* values, int count) {
  int parsed = 0;
  while (parsed < count && parse_double(p, end, &values[parsed])) ++parsed;
  return parsed;
}

}  // namespace

bool LineReader::next(const char** line, std::size_t* length) {
  if (p_ >= end_) return false;
  const char* start = p_;
  while (p_ < end_ && *p_ != '\n' && *p_ != '\r') ++p_;
  *line = start;
  *length = static_cast<std::size_t>(p_ - start);
  if (p_ < end_ && *p_ == '\r') ++p_;
  if (p_ < end_ && *p_ == '\n') ++p_;
  ++line_number_;
  return true;
}

bool is_blank_or_comment(const char* line, std::size_t length) {
  const char* p = skip_blanks(line, line + length);
  return p == line + length || *p == '#';
}

bool parse_double(const char** p, const char* end, double* value) {
  const char* q = *p;
  while (q < end && is_blank(*q)) ++q;
  if (q < end && *q == '+') ++q;  // from_chars takes '-' but not '+'
  if (q >= end) return false;
  double parsed = 0.0;
  const std::from_chars_result result = std::from_chars(q, end, parsed);
  if (result.ec != std::errc() || !std::isfinite(parsed)) return false;
  // A number must end at a separator, not run into letters ("1.5abc").
  if (result.ptr < end && !is_blank(*result.ptr)) return false;
  *value = parsed;
  *p = result.ptr;
  return true;
}

Status parse_timestamped_name(const char* line, std::size_t length, TimestampedName* out,
                              const char* label, int line_number, ErrorText* error) {
  const char* end = line + length;
  const char* p = line;
  if (!parse_double(&p, end, &out->timestamp_s)) {
    error->set("%s:%d: expected a timestamp at the start of the line", label, line_number);
    return StatusCode::data_loss;
  }
  if (!(out->timestamp_s >= 0.0 && out->timestamp_s <= kMaxTimestamp_s)) {
    error->set("%s:%d: timestamp %g s is outside [0, %g] s", label, line_number, out->timestamp_s,
               kMaxTimestamp_s);
    return StatusCode::data_loss;
  }
  p = skip_blanks(p, end);
  const char* name = p;
  while (p < end && *p != ' ' && *p != '\t') ++p;
  if (p == name) {
    error->set("%s:%d: expected a file name after the timestamp", label, line_number);
    return StatusCode::data_loss;
  }
  out->name = name;
  out->name_length = static_cast<std::size_t>(p - name);
  return ok_status();
}

Status parse_tum_pose_line(const char* line, std::size_t length, TimestampedPose* out,
                           const char* label, int line_number, ErrorText* error) {
  const char* p = line;
  const char* end = line + length;
  double v[8];
  const int parsed = parse_numbers(&p, end, v, 8);
  if (parsed != 8 || skip_blanks(p, end) != end) {
    error->set("%s:%d: expected 8 numbers (timestamp tx ty tz qx qy qz qw)%s", label, line_number,
               parsed == 8 ? " and nothing after them" : "");
    return StatusCode::data_loss;
  }
  if (!(v[0] >= 0.0 && v[0] <= kMaxTimestamp_s)) {
    error->set("%s:%d: timestamp %g s is outside [0, %g] s", label, line_number, v[0],
               kMaxTimestamp_s);
    return StatusCode::data_loss;
  }
  const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
  const double norm = q.norm();
  if (!(std::fabs(norm - 1.0) <= kQuaternionNormTolerance)) {
    error->set("%s:%d: quaternion has length %g, not 1 (not a rotation)", label, line_number, norm);
    return StatusCode::data_loss;
  }
  out->timestamp_s = v[0];
  out->t_W_C = Eigen::Vector3d(v[1], v[2], v[3]);
  out->q_W_C = Eigen::Quaterniond(q.coeffs() / norm);
  return ok_status();
}

Status parse_pose_matrix(const char* text, std::size_t size, Eigen::Matrix4d* T_W_C,
                         const char* label, ErrorText* error) {
  const char* p = text;
  const char* end = text + size;
  double v[16];
  const int parsed = parse_numbers(&p, end, v, 16);
  if (parsed != 16 || skip_blanks(p, end) != end) {
    error->set("%s: expected 16 numbers (a 4x4 matrix), %s", label,
               parsed == 16 ? "found more text after them" : "found fewer");
    return StatusCode::data_loss;
  }
  Eigen::Matrix4d T;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) T(r, c) = v[4 * r + c];
  }
  if (!is_rigid(T, kPoseRigidTolerance)) {
    const double det = T.topLeftCorner<3, 3>().determinant();
    error->set("%s: not a rigid transform (rotation determinant %g, last row %g %g %g %g)", label,
               det, T(3, 0), T(3, 1), T(3, 2), T(3, 3));
    return StatusCode::data_loss;
  }
  *T_W_C = T;
  return ok_status();
}

Status parse_intrinsics_matrix(const char* text, std::size_t size, PinholeCamera* camera,
                               const char* label, ErrorText* error) {
  const char* p = text;
  const char* end = text + size;
  double k[9];
  const int parsed = parse_numbers(&p, end, k, 9);
  if (parsed != 9 || skip_blanks(p, end) != end) {
    error->set("%s: expected 9 numbers (a 3x3 camera matrix), %s", label,
               parsed == 9 ? "found more text after them" : "found fewer");
    return StatusCode::data_loss;
  }
  if (!(k[0] > 0.0 && k[4] > 0.0) || k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 ||
      k[8] != 1.0) {
    error->set("%s: not a pinhole camera matrix [fx 0 cx; 0 fy cy; 0 0 1] with fx, fy > 0", label);
    return StatusCode::data_loss;
  }
  camera->fx = static_cast<float>(k[0]);
  camera->fy = static_cast<float>(k[4]);
  camera->cx = static_cast<float>(k[2]);
  camera->cy = static_cast<float>(k[5]);
  return ok_status();
}

Status parse_intrinsics_list(const char* text, PinholeCamera* camera, ErrorText* error) {
  const char* p = text;
  const char* end = text;
  while (*end != '\0') ++end;
  double v[4];
  const int parsed = parse_numbers(&p, end, v, 4);
  if (parsed != 4 || skip_blanks(p, end) != end || !(v[0] > 0.0 && v[1] > 0.0)) {
    error->set("intrinsics \"%s\": expected fx,fy,cx,cy with fx, fy > 0", text);
    return StatusCode::invalid_argument;
  }
  camera->fx = static_cast<float>(v[0]);
  camera->fy = static_cast<float>(v[1]);
  camera->cx = static_cast<float>(v[2]);
  camera->cy = static_cast<float>(v[3]);
  return ok_status();
}

}  // namespace octofuse::replay
