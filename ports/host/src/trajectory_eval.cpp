#include "octofuse/ports/host/trajectory_eval.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

namespace octofuse::host {

ErrorStats error_stats(const double* input, std::size_t count) {
  ErrorStats stats;
  if (count == 0) return stats;
  HostBuffer<double> values;
  values.resize(count);
  for (std::size_t i = 0; i < count; ++i) values[i] = input[i];
  double sum = 0.0, sum_sq = 0.0;
  for (double v : values) {
    sum += v;
    sum_sq += v * v;
    stats.max = std::max(stats.max, v);
  }
  const double n = static_cast<double>(values.size());
  stats.mean = sum / n;
  stats.rmse = std::sqrt(sum_sq / n);
  std::sort(values.begin(), values.end());
  const std::size_t mid = values.size() / 2;
  stats.median = values.size() % 2 == 1 ? values[mid] : 0.5 * (values[mid - 1] + values[mid]);
  return stats;
}

HostBuffer<AssociatedPair> associate_by_time(const std::vector<TimedPose>& estimate,
                                             const std::vector<TimedPose>& ground_truth,
                                             double max_dt_s) {
  // Candidates within max_dt_s, then greedy by smallest |dt| with each side used once.
  struct Candidate {
    double dt;
    std::size_t e;
    std::size_t g;
  };
  HostBuffer<Candidate> candidates;
  std::size_t g_begin = 0;
  for (std::size_t e = 0; e < estimate.size(); ++e) {
    const double t = estimate[e].timestamp_s;
    while (g_begin < ground_truth.size() && ground_truth[g_begin].timestamp_s < t - max_dt_s) {
      ++g_begin;
    }
    for (std::size_t g = g_begin;
         g < ground_truth.size() && ground_truth[g].timestamp_s <= t + max_dt_s; ++g) {
      candidates.push_back({std::fabs(ground_truth[g].timestamp_s - t), e, g});
    }
  }
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const Candidate& a, const Candidate& b) { return a.dt < b.dt; });
  HostBuffer<unsigned char> e_used, g_used;
  e_used.resize(estimate.size());
  g_used.resize(ground_truth.size());
  HostBuffer<AssociatedPair> pairs;
  for (const Candidate& c : candidates) {
    if (e_used[c.e] || g_used[c.g]) continue;
    e_used[c.e] = 1;
    g_used[c.g] = 1;
    pairs.push_back({c.e, c.g});
  }
  std::sort(pairs.begin(), pairs.end(), [](const AssociatedPair& a, const AssociatedPair& b) {
    return a.estimate < b.estimate;
  });
  return pairs;
}

Se3d horn_alignment(const Eigen::Vector3d* p_est, const Eigen::Vector3d* p_gt, std::size_t n) {
  Se3d T = Se3d::Identity();
  if (n == 0) return T;
  Eigen::Vector3d mean_est = Eigen::Vector3d::Zero(), mean_gt = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    mean_est += p_est[i];
    mean_gt += p_gt[i];
  }
  mean_est /= static_cast<double>(n);
  mean_gt /= static_cast<double>(n);
  // S = sum (est - mean)(gt - mean)^T; Horn's N matrix; its top eigenvector is the rotation.
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    S += (p_est[i] - mean_est) * (p_gt[i] - mean_gt).transpose();
  }
  Eigen::Matrix4d N;
  const double sxx = S(0, 0), sxy = S(0, 1), sxz = S(0, 2);
  const double syx = S(1, 0), syy = S(1, 1), syz = S(1, 2);
  const double szx = S(2, 0), szy = S(2, 1), szz = S(2, 2);
  N << sxx + syy + szz, syz - szy, szx - sxz, sxy - syx,  //
      syz - szy, sxx - syy - szz, sxy + syx, szx + sxz,   //
      szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy,  //
      sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> solver(N);
  const Eigen::Vector4d q = solver.eigenvectors().col(3);  // largest eigenvalue, (w, x, y, z)
  const Eigen::Quaterniond rotation(q(0), q(1), q(2), q(3));
  T.linear() = rotation.normalized().toRotationMatrix();
  T.translation() = mean_gt - T.linear() * mean_est;
  return T;
}

Result<AteResult> compute_ate(const std::vector<TimedPose>& estimate,
                              const std::vector<TimedPose>& ground_truth, double max_dt_s,
                              ErrorText* error) {
  const HostBuffer<AssociatedPair> pairs = associate_by_time(estimate, ground_truth, max_dt_s);
  if (pairs.size() < 3) {
    if (error != nullptr) {
      error->set("ATE: only %zu poses associate within %.3f s (need 3)", pairs.size(), max_dt_s);
    }
    return StatusCode::invalid_argument;
  }
  HostBuffer<Eigen::Vector3d> p_est, p_gt;
  for (const AssociatedPair& pair : pairs) {
    p_est.push_back(estimate[pair.estimate].T_W_C.translation());
    p_gt.push_back(ground_truth[pair.ground_truth].T_W_C.translation());
  }
  AteResult result;
  result.pairs = pairs.size();
  result.T_gt_est = horn_alignment(p_est.data(), p_gt.data(), p_est.size());
  HostBuffer<double> errors;
  for (std::size_t i = 0; i < p_est.size(); ++i) {
    errors.push_back((result.T_gt_est * p_est[i] - p_gt[i]).norm());
  }
  result.translation_m = error_stats(errors.data(), errors.size());
  return result;
}

Result<RpeResult> compute_rpe(const std::vector<TimedPose>& estimate,
                              const std::vector<TimedPose>& ground_truth, double max_dt_s,
                              ErrorText* error) {
  const HostBuffer<AssociatedPair> pairs = associate_by_time(estimate, ground_truth, max_dt_s);
  if (pairs.size() < 2) {
    if (error != nullptr) {
      error->set("RPE: only %zu poses associate within %.3f s (need 2)", pairs.size(), max_dt_s);
    }
    return StatusCode::invalid_argument;
  }
  HostBuffer<double> translation, rotation;
  for (std::size_t i = 0; i + 1 < pairs.size(); ++i) {
    const Se3d& P0 = estimate[pairs[i].estimate].T_W_C;
    const Se3d& P1 = estimate[pairs[i + 1].estimate].T_W_C;
    const Se3d& Q0 = ground_truth[pairs[i].ground_truth].T_W_C;
    const Se3d& Q1 = ground_truth[pairs[i + 1].ground_truth].T_W_C;
    const Se3d E = (Q0.inverse() * Q1).inverse() * (P0.inverse() * P1);
    translation.push_back(E.translation().norm());
    // Angle from the trace, clamped against rounding just outside [-1, 1].
    const double c = std::clamp((E.linear().trace() - 1.0) * 0.5, -1.0, 1.0);
    rotation.push_back(std::acos(c));
  }
  RpeResult result;
  result.pairs = translation.size();
  result.translation_m = error_stats(translation.data(), translation.size());
  result.rotation_rad = error_stats(rotation.data(), rotation.size());
  return result;
}

}  // namespace octofuse::host
