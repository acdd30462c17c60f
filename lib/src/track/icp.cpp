#include "octofuse/track/icp.hpp"

#include <cmath>

#include <Eigen/Cholesky>

#include "octofuse/core/lanes.hpp"

namespace octofuse {

namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

// The finest level's checkerboard needs a model over at least this share of the image.
constexpr double kCheckerboardMinModelFraction = 0.5;
// The 2 x 2 phases (x % 2 + 2 (y % 2)) in the order the quarter passes take them: the diagonal
// first, so that any two passes in a row cover both parities of x and of y.
constexpr int kQuarterOrder[4] = {0, 3, 1, 2};

// A rotation and translation as 4-lane columns (the fourth lane unused): R p + t in a few vector
// operations. Each lane adds as Eigen's scalar 3 x 3 product does, R(i,0) x + (R(i,1) y +
// R(i,2) z), then t(i), so the results are Eigen's, bit for bit.
struct RigidLanes {
  Lanes4 c0, c1, c2, t;

  static RigidLanes from(const Eigen::Matrix3f& R, const Eigen::Vector3f& t) {
    RigidLanes out;
    out.c0 = Lanes4{R(0, 0), R(1, 0), R(2, 0), 0.0f};
    out.c1 = Lanes4{R(0, 1), R(1, 1), R(2, 1), 0.0f};
    out.c2 = Lanes4{R(0, 2), R(1, 2), R(2, 2), 0.0f};
    out.t = Lanes4{t.x(), t.y(), t.z(), 0.0f};
    return out;
  }
  Lanes4 rotate(const Eigen::Vector3f& p) const { return c0 * p.x() + (c1 * p.y() + c2 * p.z()); }
  Lanes4 rotate(Lanes4 p) const { return c0 * p[0] + (c1 * p[1] + c2 * p[2]); }
  Lanes4 apply(const Eigen::Vector3f& p) const { return rotate(p) + t; }
  Lanes4 apply(Lanes4 p) const { return rotate(p) + t; }
};

// Everything one association pass reads; shared by all tasks.
struct Pass {
  ImageView<const Eigen::Vector3f> vertices_C;
  ImageView<const Eigen::Vector3f> normals_C;
  ConstSurfaceMap model_W;
  PinholeCamera camera;  // level 0, the model's
  RigidLanes T_W_C;
  RigidLanes T_Cref_W;
  float max_distance_sq_m2;
  float min_normal_dot;
  double inv_knee_m;  // 0: equal weights
  // -1: every pixel; 0 / 1: only pixels with (x + y) % 2 == parity; 2 + q (q in 0..3): only
  // pixels with x % 2 == q % 2 and y % 2 == q / 2 (one of each 2 x 2).
  int parity;
};

// The pair sums of a batch of pairs in float lanes, added into the double sums (Partial) batch by
// batch: the products of float inputs and 64 of them summed round by at most about 64 x 2^-24
// (4e-6) of the sums, far below what moves a Gauss-Newton step, in fewer instructions than
// double sums (7-Scenes at 1 cm: ICP 34.7 -> 32.1 M a frame).
class BatchSums {
 public:
  static constexpr int kBatch = 64;

  // j = (n, p x n) of one pair, w its weight (1 for equal weights), r its residual.
  void add(const float (&j)[6], float w, float r) {
    const Lanes4 j0123 = {j[0], j[1], j[2], j[3]};
    const Lanes4 j45 = {j[4], j[5], 0.0f, 0.0f};
    const Lanes4 wj0123 = j0123 * w;
    const Lanes4 wj45 = j45 * w;
    s00_ += wj0123[0] * j0123;
    s01_ += wj0123[0] * j45;
    s10_ += wj0123[1] * j0123;
    s11_ += wj0123[1] * j45;
    s20_ += wj0123[2] * j0123;
    s21_ += wj0123[2] * j45;
    s30_ += wj0123[3] * j0123;
    s31_ += wj0123[3] * j45;
    s4_ += wj45[0] * j45;
    s5_ += wj45[1] * j45;
    r0_ += wj0123 * r;
    r1_ += wj45 * r;
    ++count_;
  }
  bool full() const { return count_ == kBatch; }

  // Adds the batch into `out` (row-major upper triangle of J^T W J, and J^T W r) and starts a
  // new one. Rows 0-3 are two vectors each (columns 0-3, then 4, 5 and two unused lanes), rows 4
  // and 5 one each.
  void flush(IcpTracker::Partial& out) {
    if (count_ == 0) return;
    const Lanes4 rows[6][2] = {{s00_, s01_}, {s10_, s11_}, {s20_, s21_},
                               {s30_, s31_}, {s4_, s4_},   {s5_, s5_}};
    int k = 0;
    for (int a = 0; a < 6; ++a) {
      for (int b = a; b < 6; ++b) {
        const float v = a < 4 ? rows[a][b >> 2][b & 3] : rows[a][0][b - 4];
        out.jtj[k++] += static_cast<double>(v);
      }
    }
    for (int a = 0; a < 6; ++a) out.jtr[a] += static_cast<double>(a < 4 ? r0_[a] : r1_[a - 4]);
    *this = BatchSums();
  }

 private:
  Lanes4 s00_ = {}, s01_ = {}, s10_ = {}, s11_ = {}, s20_ = {}, s21_ = {}, s30_ = {}, s31_ = {};
  Lanes4 s4_ = {}, s5_ = {}, r0_ = {}, r1_ = {};
  int count_ = 0;
};

// kWeighted: pairs weighed by depth (pass.inv_knee_m > 0); otherwise every weight is 1 and is
// not computed (the sums multiply by 1, which changes nothing).
template <bool kWeighted>
void accumulate_rows(const Pass& pass, std::size_t task, IcpTracker::Partial& out) {
  // Sums in a local, stored once at the end: the compiler cannot keep sums that live behind
  // `out` in registers across the image reads.
  IcpTracker::Partial sums{};
  BatchSums batch;
  const int width = pass.vertices_C.width;
  const TaskRange rows =
      task_range(static_cast<std::size_t>(pass.vertices_C.height), task, kTrackTasks);
  const unsigned model_w_u = static_cast<unsigned>(pass.model_W.width());
  const unsigned model_h_u = static_cast<unsigned>(pass.model_W.height());
  const bool quarter = pass.parity >= 2;
  for (std::size_t row = rows.begin; row < rows.end; ++row) {
    const int y = static_cast<int>(row);
    if (quarter && (y & 1) != ((pass.parity - 2) >> 1)) continue;
    const Eigen::Vector3f* v_row = pass.vertices_C.row(y);
    const Eigen::Vector3f* n_row = pass.normals_C.row(y);
    const int x_step = pass.parity < 0 ? 1 : 2;
    const int x_begin = pass.parity < 0 ? 0
                        : quarter       ? (pass.parity - 2) & 1
                                        : (y + pass.parity) & 1;
    for (int x = x_begin; x < width; x += x_step) {
      const Eigen::Vector3f& n_C = n_row[x];
      if (is_invalid_normal(n_C)) continue;
      const Lanes4 p_W_lanes = pass.T_W_C.apply(v_row[x]);
      const Lanes4 p_Cref_lanes = pass.T_Cref_W.apply(p_W_lanes);
      const Eigen::Vector3f p_W(p_W_lanes[0], p_W_lanes[1], p_W_lanes[2]);
      const Eigen::Vector3f p_Cref(p_Cref_lanes[0], p_Cref_lanes[1], p_Cref_lanes[2]);
      if (!(p_Cref.z() > 0.0f)) continue;
      const Eigen::Vector2f px = pass.camera.project(p_Cref);
      if (!pass.camera.in_image(px)) continue;  // also rejects NaN
      // In the image px + 0.5 is non-negative, where truncation is floor (no libm call). A model
      // cast at half resolution is read at the nearest cast pixel: its copies lie to one side
      // of their source, and pairing through them would pull every frame the same way.
      int u = 0;
      int v = 0;
      if (pass.model_W.pixel_stride == 2) {
        // A live pixel that projects halfway between two cast ones (the odd pixels, while the
        // camera barely moves) goes to either side in turns, so the ties cancel as well.
        const float tie = (((x >> 1) + y) & 1) != 0 ? 0.125f : -0.125f;
        u = 2 * static_cast<int>(0.5f * px.x() + 0.5f + tie);
        v = 2 * static_cast<int>(0.5f * px.y() + 0.5f + tie);
      } else {
        u = static_cast<int>(px.x() + 0.5f);
        v = static_cast<int>(px.y() + 0.5f);
      }
      // Unsigned: negative u or v wrap past the bounds, two tests instead of four.
      if (static_cast<unsigned>(u) >= model_w_u || static_cast<unsigned>(v) >= model_h_u) continue;
      if (!pass.model_W.valid(u, v)) continue;
      const Eigen::Vector3f& n_model_W = pass.model_W.normals(u, v);
      const Eigen::Vector3f diff_W = p_W - pass.model_W.vertices(u, v);
      if (!(diff_W.squaredNorm() <= pass.max_distance_sq_m2)) continue;
      const Lanes4 n_live_W_lanes = pass.T_W_C.rotate(n_C);
      const Eigen::Vector3f n_live_W(n_live_W_lanes[0], n_live_W_lanes[1], n_live_W_lanes[2]);
      if (!(n_live_W.dot(n_model_W) >= pass.min_normal_dot)) continue;

      const float r = n_model_W.dot(diff_W);
      float w = 1.0f;
      if constexpr (kWeighted) {
        const double z_rel = static_cast<double>(v_row[x].z()) * pass.inv_knee_m;
        const double z_rel_sq = z_rel * z_rel;
        w = static_cast<float>(1.0 / (1.0 + z_rel_sq * z_rel_sq));
      }
      const Eigen::Vector3f p_cross_n = p_W.cross(n_model_W);
      const float j[6] = {n_model_W.x(), n_model_W.y(), n_model_W.z(),
                          p_cross_n.x(), p_cross_n.y(), p_cross_n.z()};
      batch.add(j, w, r);
      if (batch.full()) batch.flush(sums);
      const double r_d = static_cast<double>(r);
      sums.residual_sq += r_d * r_d;
      ++sums.count;
    }
  }
  batch.flush(sums);
  out = sums;
}

// Sums the task partials in task order.
IcpTracker::Partial reduce(const IcpTracker::Partial* partials) {
  IcpTracker::Partial total = partials[0];
  for (int t = 1; t < kTrackTasks; ++t) {
    const IcpTracker::Partial& p = partials[t];
    for (int k = 0; k < 21; ++k) total.jtj[k] += p.jtj[k];
    for (int k = 0; k < 6; ++k) total.jtr[k] += p.jtr[k];
    total.residual_sq += p.residual_sq;
    total.count += p.count;
  }
  return total;
}

// The prior's information in the units of the pass's normal equations `A` (see IcpPrior).
Matrix6d prior_information(const IcpPrior& prior, const IcpTracker::Partial& total,
                           const Matrix6d& A) {
  Matrix6d L = Matrix6d::Zero();
  if (prior.fixed_information) {
    for (int a = 0; a < 3; ++a) {
      L(a, a) = prior.information_t;
      L(a + 3, a + 3) = prior.information_r;
    }
    return L;
  }
  // The per-pair residual variance (given, else the pass's own), floored, per independent sample.
  const double floor_sq = prior.icp_noise_floor_m * prior.icp_noise_floor_m;
  double mean_sq = prior.icp_sigma_m * prior.icp_sigma_m;
  if (!(prior.icp_sigma_m > 0.0)) mean_sq = total.count > 0 ? total.residual_sq / total.count : 0.0;
  const double var_icp = (mean_sq > floor_sq ? mean_sq : floor_sq) * prior.icp_pixels_per_sample;
  // Ad maps a world-frame left twist (v, w) to the camera-frame one: v_C = R^T (v + w x t),
  // w_C = R^T w. Its inverse Ad_inv (v = R v_C + t x R w_C, w = R w_C) takes A to the camera's
  // twist: A_C = Ad_inv^T A Ad_inv.
  const Eigen::Matrix3d R_W_C = prior.T_W_C.linear();
  const Eigen::Vector3d t = prior.T_W_C.translation();
  Eigen::Matrix3d t_cross;
  t_cross << 0.0, -t.z(), t.y(), t.z(), 0.0, -t.x(), -t.y(), t.x(), 0.0;
  Matrix6d Ad = Matrix6d::Zero();
  Ad.topLeftCorner<3, 3>() = R_W_C.transpose();
  Ad.topRightCorner<3, 3>() = -R_W_C.transpose() * t_cross;  // w x t = -t x w
  Ad.bottomRightCorner<3, 3>() = R_W_C.transpose();
  Matrix6d Ad_inv = Matrix6d::Zero();
  Ad_inv.topLeftCorner<3, 3>() = R_W_C;
  Ad_inv.topRightCorner<3, 3>() = t_cross * R_W_C;
  Ad_inv.bottomRightCorner<3, 3>() = R_W_C;
  for (int a = 0; a < 6; ++a) {
    const double sigma = a < 3 ? prior.sigma_t_m : prior.sigma_rad;
    double var = var_icp;
    if (prior.icp_error_var_C[a] > 0.0) {
      // For the prior-to-ICP information ratio on this axis to be var_C / sigma^2, L(a, a) must
      // be A_C(a, a) var_C / sigma^2. The larger of the two variances wins.
      const double a_C = Ad_inv.col(a).dot(A * Ad_inv.col(a));
      const double seen = a_C * prior.icp_error_var_C[a];
      if (seen > var) var = seen;
    }
    L(a, a) = var / (sigma * sigma);
  }
  const Matrix6d L_W = Ad.transpose() * L * Ad;
  // Exactly symmetric, so the solve does not depend on rounding in the product's two halves.
  return 0.5 * (L_W + L_W.transpose());
}

// The Gauss-Newton step, or false when the system is singular or the pairs too few.
bool solve_step(const IcpTracker::Partial& total, const IcpPrior* prior, const Se3d& estimate,
                Vector6d& twist) {
  if (total.count < 6) return false;
  Matrix6d A;
  int k = 0;
  for (int a = 0; a < 6; ++a) {
    for (int b = a; b < 6; ++b) {
      A(a, b) = total.jtj[k];
      A(b, a) = total.jtj[k];
      ++k;
    }
  }
  Vector6d g;
  for (int a = 0; a < 6; ++a) g(a) = total.jtr[a];
  if (prior != nullptr) {
    const Vector6d e = se3_log(estimate * prior->T_W_C.inverse());
    const Matrix6d L = prior_information(*prior, total, A);
    A += L;
    g.noalias() += L * e;
  }
  const Eigen::LDLT<Matrix6d> ldlt(A);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return false;
  // A pivot many orders below the largest means an unconstrained direction (one plane in view).
  const Vector6d pivots = ldlt.vectorD();
  if (!(pivots.minCoeff() > 1e-9 * pivots.maxCoeff())) return false;
  twist = ldlt.solve(-g);
  return twist.allFinite();
}

}  // namespace

bool TrackConfig::valid() const {
  for (int it : iterations) {
    if (it < 0) return false;
  }
  return std::isfinite(max_distance_m) && max_distance_m >= 0.0f && std::isfinite(min_normal_dot) &&
         min_normal_dot >= -1.0f && min_normal_dot <= 1.0f && std::isfinite(convergence_norm) &&
         convergence_norm >= 0.0 && std::isfinite(lost_max_rms_m) && lost_max_rms_m >= 0.0f &&
         std::isfinite(lost_min_inlier_fraction) && lost_min_inlier_fraction >= 0.0f &&
         lost_min_inlier_fraction <= 1.0f && std::isfinite(lost_min_image_fraction) &&
         lost_min_image_fraction >= 0.0f && lost_min_image_fraction <= 1.0f &&
         std::isfinite(depth_weight_knee_m) && depth_weight_knee_m >= 0.0f;
}

bool IcpPrior::valid() const {
  auto in = [](double value, double low, double high) { return value >= low && value <= high; };
  // Bounds that keep every information finite: 1 / (1e-9)^2 and 1e6 * 1^2 are far from overflow.
  return in(sigma_t_m, 1e-9, 1e3) && in(sigma_rad, 1e-9, 1e3) && in(icp_noise_floor_m, 0.0, 1.0) &&
         in(icp_pixels_per_sample, 1.0, 1e6) && in(icp_sigma_m, 0.0, 1.0) &&
         in(information_t, 0.0, 1e300) && in(information_r, 0.0, 1e300) && in(gate_m, 0.0, 1e300) &&
         in(gate_rad, 0.0, 1e300) && in(icp_error_var_C[0], 0.0, 1.0) &&
         in(icp_error_var_C[1], 0.0, 1.0) && in(icp_error_var_C[2], 0.0, 1.0) &&
         in(icp_error_var_C[3], 0.0, 1.0) && in(icp_error_var_C[4], 0.0, 1.0) &&
         in(icp_error_var_C[5], 0.0, 1.0);
}

const char* track_outcome_name(TrackOutcome outcome) {
  switch (outcome) {
    case TrackOutcome::tracked:
      return "tracked";
    case TrackOutcome::lost_residual:
      return "lost_residual";
    case TrackOutcome::lost_inliers:
      return "lost_inliers";
    case TrackOutcome::lost_singular:
      return "lost_singular";
    case TrackOutcome::failed:
      return "failed";
  }
  return "unknown";
}

Status IcpTracker::set_config(const TrackConfig& config) {
  if (!config.valid()) return StatusCode::invalid_argument;
  config_ = config;
  return ok_status();
}

TrackReport IcpTracker::track(const DepthPyramid& live, ConstSurfaceMap model_W,
                              const PinholeCamera& camera_level0, const Se3d& T_W_Cref, Se3d& T_W_C,
                              const WorkerTeam& team, const IcpPrior* prior) {
  TrackReport report;
  if (!reserved_) {
    report.status = StatusCode::failed_precondition;
    return report;
  }
  bool args_ok = camera_level0.valid() && !model_W.vertices.empty() && !model_W.normals.empty() &&
                 model_W.vertices.width == camera_level0.width &&
                 model_W.vertices.height == camera_level0.height &&
                 model_W.normals.width == camera_level0.width &&
                 model_W.normals.height == camera_level0.height && is_rigid(T_W_Cref.matrix()) &&
                 is_rigid(T_W_C.matrix());
  if (prior != nullptr) args_ok = args_ok && prior->valid() && is_rigid(prior->T_W_C.matrix());
  for (int level = 0; level < kPyramidLevels && args_ok; ++level) {
    const int w = width_ >> level;
    const int h = height_ >> level;
    const ImageView<Eigen::Vector3f>& v = live.vertices_C[level];
    const ImageView<Eigen::Vector3f>& n = live.normals_C[level];
    args_ok =
        !v.empty() && !n.empty() && v.width == w && v.height == h && n.width == w && n.height == h;
  }
  if (!args_ok) {
    report.status = StatusCode::invalid_argument;
    return report;
  }

  Pass pass;
  pass.model_W = model_W;
  pass.camera = camera_level0;
  const Se3d T_Cref_W = T_W_Cref.inverse();
  pass.T_Cref_W =
      RigidLanes::from(T_Cref_W.linear().cast<float>(), T_Cref_W.translation().cast<float>());
  pass.max_distance_sq_m2 = config_.max_distance_m * config_.max_distance_m;
  pass.min_normal_dot = config_.min_normal_dot;

  Partial* partials = partials_;
  auto run_pass = [&](int level, const Se3d& T_W_C_estimate, int parity) {
    pass.parity = parity;
    pass.vertices_C = live.vertices_C[level];
    pass.normals_C = live.normals_C[level];
    pass.inv_knee_m = level == 0 && config_.depth_weight_knee_m > 0.0f
                          ? 1.0 / static_cast<double>(config_.depth_weight_knee_m)
                          : 0.0;
    pass.T_W_C = RigidLanes::from(T_W_C_estimate.linear().cast<float>(),
                                  T_W_C_estimate.translation().cast<float>());
    auto task_fn = [&](std::size_t task) {
      if (pass.inv_knee_m > 0.0) {
        accumulate_rows<true>(pass, task, partials[task]);
      } else {
        accumulate_rows<false>(pass, task, partials[task]);
      }
    };
    team.for_each_task(kTrackTasks, task_fn);
    Partial total = reduce(partials);
    if (parity >= 0) {
      // Half (a quarter of) the pixels stand for all of them: doubled (quadrupled, exactly), the
      // sums weigh against the prior, and count against the gates, as a full pass's would; the
      // step is the same.
      const std::uint32_t pixels_per_sample = parity >= 2 ? 4u : 2u;
      const double scale = static_cast<double>(pixels_per_sample);
      for (double& v : total.jtj) v *= scale;
      for (double& v : total.jtr) v *= scale;
      total.residual_sq *= scale;
      total.count *= pixels_per_sample;
    }
    return total;
  };

  // Serial integer count: the same for any worker count, and a few tens of microseconds.
  const std::uint32_t model_pixels = valid_pixel_count(model_W);
  // A model covering little of the view (a full block pool, the first frames of a new area)
  // leaves too few pairs to halve: the checkerboard then lets the estimate slide.
  const bool checkerboard =
      config_.finest_level_checkerboard &&
      static_cast<double>(model_pixels) >= kCheckerboardMinModelFraction *
                                               static_cast<double>(model_W.width()) *
                                               static_cast<double>(model_W.height());

  // A model cast at half resolution has a marched point for every 2 x 2 live pixels.
  const bool quarter = checkerboard && config_.finest_level_quarter(model_W.pixel_stride);

  const bool middle_halved = config_.middle_level_halved(width_, height_);

  Se3d estimate = T_W_C;
  bool singular = false;
  // Residual statistics for the report: from the last level-0 pass, taken at the estimate before
  // its step (as KinectFusion does: the step usually shrinks them, and one more pass over the
  // finest level would cost a fifth of the tracking); from a pass at the final estimate only when
  // the finest level took no step.
  Partial final_total;
  Se3d final_pass_estimate = Se3d::Identity();
  bool have_final = false;
  const IcpPrior* pull = nullptr;
  for (int level = kPyramidLevels - 1; level >= 0; --level) {
    if (level == 0 && prior != nullptr) {
      const Se3d gap = prior->T_W_C.inverse() * estimate;
      const bool agrees = gap.translation().norm() <= prior->gate_m &&
                          Eigen::AngleAxisd(gap.linear()).angle() <= prior->gate_rad;
      pull = agrees ? prior : nullptr;
    }
    for (int it = 0; it < config_.iterations[level]; ++it) {
      // The finest level's passes take every other pixel, alternating between iterations; one
      // pixel of each 2 x 2 against a model cast at half resolution, the four in turn.
      // The middle level's take every other pixel too, alternating the same way.
      const bool halved = checkerboard && (level == 0 || (level == 1 && middle_halved));
      const int parity = !halved ? -1 : level == 0 && quarter ? 2 + kQuarterOrder[it & 3] : it & 1;
      const Partial total = run_pass(level, estimate, parity);
      Vector6d twist;
      if (!solve_step(total, level == 0 ? pull : nullptr, estimate, twist)) {
        singular = level == 0;
        break;
      }
      const Se3d step_from = estimate;
      estimate = se3_exp(twist) * estimate;
      ++report.iterations[level];
      if (level == 0) {
        final_total = total;
        final_pass_estimate = step_from;
        have_final = true;
      }
      if (twist.norm() < config_.convergence_norm) break;
    }
  }
  if (!have_final) final_total = run_pass(0, estimate, !checkerboard ? -1 : quarter ? 2 : 0);
  Vector6d data_twist;
  if (pull != nullptr && have_final &&
      solve_step(final_total, nullptr, final_pass_estimate, data_twist)) {
    report.has_data_estimate = true;
    report.T_W_C_data = se3_exp(data_twist) * final_pass_estimate;
  }

  const double pixels = static_cast<double>(width_) * static_cast<double>(height_);
  report.status = ok_status();
  report.inliers = final_total.count;
  report.model_pixels = model_pixels;
  report.inlier_fraction =
      model_pixels > 0 ? static_cast<float>(final_total.count / static_cast<double>(model_pixels))
                       : 0.0f;
  const bool too_few_in_image =
      static_cast<double>(final_total.count) < config_.lost_min_image_fraction * pixels;
  report.rms_residual_m =
      final_total.count > 0
          ? static_cast<float>(std::sqrt(final_total.residual_sq / final_total.count))
          : 0.0f;
  if (report.inlier_fraction < config_.lost_min_inlier_fraction || too_few_in_image ||
      final_total.count == 0) {
    report.outcome = TrackOutcome::lost_inliers;
  } else if (singular) {
    report.outcome = TrackOutcome::lost_singular;
  } else if (report.rms_residual_m > config_.lost_max_rms_m) {
    report.outcome = TrackOutcome::lost_residual;
  } else {
    report.outcome = TrackOutcome::tracked;
    T_W_C = estimate;
  }
  return report;
}

}  // namespace octofuse
