#include "octofuse/ports/host/trajectory_io.hpp"
#include "octofuse/ports/host/read_file.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>

namespace octofuse::host {
namespace {

bool write_pose(std::FILE* file, const TimedPose& pose) {
  const Eigen::Vector3d t = pose.T_W_C.translation();
  Eigen::Quaterniond q(pose.T_W_C.rotation());
  q.normalize();
  // %.9g keeps sub-micrometre positions; TUM tools accept any float syntax.
  return std::fprintf(file, "%.6f %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n", pose.timestamp_s, t.x(),
                      t.y(), t.z(), q.x(), q.y(), q.z(), q.w()) > 0;
}

}  // namespace

TumTrajectoryWriter::~TumTrajectoryWriter() {
  close().ignore();
}

Status TumTrajectoryWriter::open(const char* path) {
  close().ignore();
  std::snprintf(path_, sizeof(path_), "%s", path);
  file_ = std::fopen(path, "w");
  if (file_ == nullptr) {
    error_.set("%s: cannot create (%s)", path, std::strerror(errno));
    return StatusCode::unavailable;
  }
  if (std::fputs("# timestamp tx ty tz qx qy qz qw (camera to world)\n", file_) < 0 ||
      std::fflush(file_) != 0) {
    error_.set("%s: write failed", path_);
    return StatusCode::data_loss;
  }
  return ok_status();
}

Status TumTrajectoryWriter::append(const TimedPose& pose) {
  if (file_ == nullptr) {
    error_.set("trajectory writer: not open");
    return StatusCode::failed_precondition;
  }
  // Flushed per line: a killed process leaves every line it appended, each whole (one write(2)).
  if (!write_pose(file_, pose) || std::fflush(file_) != 0) {
    error_.set("%s: write failed", path_);
    return StatusCode::data_loss;
  }
  return ok_status();
}

Status TumTrajectoryWriter::close() {
  if (file_ == nullptr) return ok_status();
  const bool ok = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!ok) {
    error_.set("%s: write failed on close", path_);
    return StatusCode::data_loss;
  }
  return ok_status();
}

Status write_tum_trajectory(const char* path, const std::vector<TimedPose>& poses,
                            ErrorText* error) {
  TumTrajectoryWriter writer;
  Status status = writer.open(path);
  for (std::size_t i = 0; status.ok() && i < poses.size(); ++i) status = writer.append(poses[i]);
  if (status.ok()) status = writer.close();
  if (!status.ok() && error != nullptr) error->set("%s", writer.last_error());
  return status;
}

Status for_each_tum_pose(const char* path, TimedPoseSink sink, void* context, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  bool have_previous = false;
  double previous_s = 0.0;
  std::FILE* file = open_regular_for_reading(path);
  if (file == nullptr) {
    err.set("%s: cannot open (%s)", path, open_failure_text(errno));
    return StatusCode::unavailable;
  }
  char line[1024];
  int line_number = 0;
  Status status;
  while (std::fgets(line, sizeof(line), file) != nullptr) {
    ++line_number;
    const std::size_t length = std::strlen(line);
    if (length == sizeof(line) - 1 && line[length - 1] != '\n' && !std::feof(file)) {
      // The rest would be read as a line of its own.
      err.set("%s:%d: line longer than %zu characters", path, line_number, sizeof(line) - 2);
      status = StatusCode::data_loss;
      break;
    }
    const char* p = line;
    while (*p == ' ' || *p == '\t') ++p;
    if (*p == '#' || *p == '\n' || *p == '\r' || *p == '\0') continue;
    double v[8];
    int parsed = 0;
    for (; parsed < 8; ++parsed) {
      char* end = nullptr;
      v[parsed] = std::strtod(p, &end);
      if (end == p || !std::isfinite(v[parsed])) break;
      p = end;
    }
    while (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n') ++p;
    if (parsed != 8 || *p != '\0') {
      err.set("%s:%d: expected 8 numbers (timestamp tx ty tz qx qy qz qw)%s, got %d", path,
              line_number, parsed == 8 ? " and nothing after them" : "", parsed);
      status = StatusCode::data_loss;
      break;
    }
    // A unit quaternion as written to a few digits; far from it is a cut or corrupt line.
    Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
    const double norm = q.norm();
    if (!(std::fabs(norm - 1.0) <= kQuaternionNormTolerance)) {
      err.set("%s:%d: quaternion has length %g, not 1", path, line_number, norm);
      status = StatusCode::data_loss;
      break;
    }
    if (have_previous && v[0] < previous_s) {
      err.set("%s:%d: timestamp %.6f goes backwards (previous %.6f)", path, line_number, v[0],
              previous_s);
      status = StatusCode::data_loss;
      break;
    }
    TimedPose pose;
    pose.timestamp_s = v[0];
    pose.T_W_C.linear() = q.normalized().toRotationMatrix();
    pose.T_W_C.translation() = Eigen::Vector3d(v[1], v[2], v[3]);
    sink(pose, context);
    have_previous = true;
    previous_s = v[0];
  }
  std::fclose(file);
  return status;
}

bool interpolate_pose(const std::vector<TimedPose>& poses, double timestamp_s, double tolerance_s,
                      Se3d* T_W_C) {
  if (poses.empty() || !std::isfinite(timestamp_s)) return false;
  const TimedPose& first = poses.front();
  const TimedPose& last = poses.back();
  if (timestamp_s <= first.timestamp_s) {
    if (first.timestamp_s - timestamp_s > tolerance_s) return false;
    *T_W_C = first.T_W_C;
    return true;
  }
  if (timestamp_s >= last.timestamp_s) {
    if (timestamp_s - last.timestamp_s > tolerance_s) return false;
    *T_W_C = last.T_W_C;
    return true;
  }
  // First pose strictly after the time; the one before it is at or before it.
  const auto after =
      std::upper_bound(poses.begin(), poses.end(), timestamp_s,
                       [](double t, const TimedPose& pose) { return t < pose.timestamp_s; });
  const TimedPose& b = *after;
  const TimedPose& a = *(after - 1);
  const double span_s = b.timestamp_s - a.timestamp_s;
  const double w = span_s > 0.0 ? (timestamp_s - a.timestamp_s) / span_s : 1.0;
  const Eigen::Quaterniond qa(a.T_W_C.rotation());
  const Eigen::Quaterniond qb(b.T_W_C.rotation());
  Se3d out = Se3d::Identity();
  out.linear() = qa.slerp(w, qb).normalized().toRotationMatrix();
  out.translation() = (1.0 - w) * a.T_W_C.translation() + w * b.T_W_C.translation();
  *T_W_C = out;
  return true;
}

}  // namespace octofuse::host
