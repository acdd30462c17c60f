#pragma once
// TUM RGB-D trajectory files: one pose per line, "timestamp tx ty tz qx qy qz qw" (seconds,
// metres, unit quaternion), camera to world; lines starting with '#' are comments.

#include <cstdio>
#include <vector>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse::host {

struct TimedPose {
  double timestamp_s = 0.0;
  Se3d T_W_C = Se3d::Identity();
};

// Writes poses one per line as they come (octofuse-replay appends one per frame).
class TumTrajectoryWriter {
 public:
  TumTrajectoryWriter() = default;
  TumTrajectoryWriter(const TumTrajectoryWriter&) = delete;
  TumTrajectoryWriter& operator=(const TumTrajectoryWriter&) = delete;
  ~TumTrajectoryWriter();

  // unavailable when the file cannot be created.
  Status open(const char* path);
  // data_loss on a write error; failed_precondition when not open.
  Status append(const TimedPose& pose);
  // Flushes and closes; data_loss when the final write fails.
  Status close();
  const char* last_error() const { return error_.c_str(); }

 private:
  std::FILE* file_ = nullptr;
  char path_[512] = {};
  ErrorText error_;
};

// Whole-file helpers. write: unavailable / data_loss. read: unavailable (missing file),
// data_loss (a line that does not parse, a zero quaternion, timestamps going backwards); the
// message names the file and line.
Status write_tum_trajectory(const char* path, const std::vector<TimedPose>& poses,
                            ErrorText* error);
Status read_tum_trajectory(const char* path, std::vector<TimedPose>* poses, ErrorText* error);

}  // namespace octofuse::host
