#pragma once
// Trajectory error against ground truth, as the TUM RGB-D benchmark defines it.
// ATE: associate estimate and ground truth by nearest timestamp (within max_dt_s), align the
// estimate's positions to the ground truth's with Horn's closed-form (quaternion) rigid
// alignment, then statistics of the remaining position differences.
// RPE (per-frame delta): for consecutive associated pairs i, i+1 the error
// E_i = (Q_i^-1 Q_i+1)^-1 (P_i^-1 P_i+1) with Q ground truth and P estimate; translation |t(E)|
// and rotation angle(E) statistics. No alignment is needed for RPE.

#include <algorithm>
#include <cstddef>
#include <vector>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/ports/host/host_buffer.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"

namespace octofuse::host {

struct ErrorStats {
  double rmse = 0.0;
  double mean = 0.0;
  double median = 0.0;
  double max = 0.0;
};

// Summary of `count` values (none gives all zeros).
ErrorStats error_stats(const double* values, std::size_t count);
inline ErrorStats error_stats(const std::vector<double>& values) {
  return error_stats(values.data(), values.size());
}

// Index pairs (estimate, ground truth) matched by nearest timestamp within `max_dt_s`; each
// ground-truth pose is used at most once (greedy by smallest time difference, as TUM's
// associate.py). Both inputs sorted by time. Pairs come out in estimate order.
struct AssociatedPair {
  std::size_t estimate;
  std::size_t ground_truth;
};
HostBuffer<AssociatedPair> associate_by_time(const std::vector<TimedPose>& estimate,
                                             const std::vector<TimedPose>& ground_truth,
                                             double max_dt_s);

// Rigid transform T_gt_est minimising sum |p_gt_i - T p_est_i|^2 (Horn 1987, unit quaternions).
// Needs at least 3 non-collinear points for a unique rotation; with fewer the rotation is the
// best the data allows (identity for 1 point).
Se3d horn_alignment(const Eigen::Vector3d* p_est, const Eigen::Vector3d* p_gt, std::size_t count);
inline Se3d horn_alignment(const std::vector<Eigen::Vector3d>& p_est,
                           const std::vector<Eigen::Vector3d>& p_gt) {
  return horn_alignment(p_est.data(), p_gt.data(), std::min(p_est.size(), p_gt.size()));
}

struct AteResult {
  std::size_t pairs = 0;
  ErrorStats translation_m;
  Se3d T_gt_est = Se3d::Identity();  // the alignment applied to the estimate
};
// invalid_argument when fewer than 3 pairs associate (message says how many).
Result<AteResult> compute_ate(const std::vector<TimedPose>& estimate,
                              const std::vector<TimedPose>& ground_truth, double max_dt_s,
                              ErrorText* error);

struct RpeResult {
  std::size_t pairs = 0;  // number of deltas
  ErrorStats translation_m;
  ErrorStats rotation_rad;
};
// invalid_argument when fewer than 2 pairs associate.
Result<RpeResult> compute_rpe(const std::vector<TimedPose>& estimate,
                              const std::vector<TimedPose>& ground_truth, double max_dt_s,
                              ErrorText* error);

}  // namespace octofuse::host
