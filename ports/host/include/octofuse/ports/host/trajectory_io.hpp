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

// Writes poses one per line as they come (octofuse-replay appends one per frame). Each line is
// flushed to the kernel as it is appended, so a process killed at any instant leaves whole lines
// only; it is not fsync'ed (a power cut may lose the last seconds, see the README).
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
// data_loss (a line that is not exactly 8 numbers, a quaternion whose length is not 1 within
// kQuaternionNormTolerance, timestamps going backwards, a line over 1022 characters); the message
// names the file and line.
inline constexpr double kQuaternionNormTolerance = 1e-2;
Status write_tum_trajectory(const char* path, const std::vector<TimedPose>& poses,
                            ErrorText* error);

// Calls `sink(pose, context)` for each pose in file order. Same codes as read_tum_trajectory.
using TimedPoseSink = void (*)(const TimedPose& pose, void* context);
Status for_each_tum_pose(const char* path, TimedPoseSink sink, void* context, ErrorText* error);

// Header-only so the std::vector growth is compiled into the (host) caller, not this library.
inline Status read_tum_trajectory(const char* path, std::vector<TimedPose>* poses,
                                  ErrorText* error) {
  poses->clear();
  const Status status = for_each_tum_pose(
      path,
      [](const TimedPose& pose, void* context) {
        static_cast<std::vector<TimedPose>*>(context)->push_back(pose);
      },
      poses, error);
  if (!status.ok()) poses->clear();
  return status;
}

// The pose at `timestamp_s` in a trajectory sorted by time (as read_tum_trajectory returns it):
// the position interpolated linearly and the rotation by slerp between the poses either side.
// No extrapolation: a time before the first or after the last pose by at most `tolerance_s`
// takes that end pose; further out there is no pose (false). Equal timestamps take the later pose.
bool interpolate_pose(const std::vector<TimedPose>& poses, double timestamp_s, double tolerance_s,
                      Se3d* T_W_C);

}  // namespace octofuse::host
