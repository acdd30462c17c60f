#pragma once
// Point-to-plane ICP of a live depth pyramid against a ray-cast model, coarse to fine.
//
// Each iteration transforms the live vertices by the current estimate T_W_C, projects them into
// the reference camera (the pose T_W_Cref the model was ray-cast from, level-0 intrinsics; coarse
// levels associate into the same level-0 model), rejects pairs farther apart than
// max_distance_m or whose normals disagree (dot < min_normal_dot), and accumulates the 6x6 normal
// equations of r = n_W . (T_W_C p_C - q_W), level-0 pairs weighted down with their depth (far
// depth is noisier, see depth_weight_knee_m): batches of 64 pairs summed in float lanes, the
// batches in double (a batch's float sums round by at most about 64 x 2^-24, 4e-6 of their size).
// The rows are split into kTrackTasks fixed chunks whose partial sums are added in task order, so
// the pose is bit-identical for any worker count. The increment (left-multiplied, twist (v, w))
// comes from an LDLT solve and is applied with se3_exp; a level stops when the increment's norm
// drops below convergence_norm.
//
// The reported residual and inliers are those of the last level-0 pass when it converged, else
// of one more pass at the final estimate. Tracking is lost when the RMS residual exceeds
// lost_max_rms_m, or the inliers are fewer than lost_min_inlier_fraction of the model's valid
// pixels or fewer than lost_min_image_fraction of all level-0 pixels; T_W_C then keeps the value
// passed in. Counting inliers against the model, not the image, keeps a map that covers part of
// the view (a full block pool) trackable.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/parallel.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/image/depth_pyramid.hpp"
#include "octofuse/image/surface_map.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"

namespace octofuse {

// Row chunks of one association pass, independent of the worker count.
inline constexpr int kTrackTasks = 16;

struct TrackConfig {
  // Per level, index 0 = finest; 0 skips a level. Two finest passes (both checkerboard halves):
  // a third and fourth moved the estimate by ~0.2 mm back and forth between the halves' optima and
  // did not lower the 7-Scenes or sim ATE; four coarse and eight coarsest keep the basin for fast
  // motion (lib/README.md, "Tracking").
  int iterations[kPyramidLevels] = {2, 4, 8};
  float max_distance_m = 0.1f;             // association gate on |p_W - q_W|
  float min_normal_dot = 0.8f;             // association gate on n_live_W . n_model_W
  double convergence_norm = 1e-5;          // stop a level when |twist| falls below this
  float lost_max_rms_m = 0.02f;            // RMS point-to-plane residual
  float lost_min_inlier_fraction = 0.15f;  // of the model's valid pixels
  // Also of all level-0 pixels: a sliver of model (a small block pool's map) lets ICP slide.
  float lost_min_image_fraction = 0.05f;
  // Level-0 pairs are weighted by the inverse of their expected residual variance, the model's
  // own error plus depth noise growing as z^2 (structured light, stereo): 1 / (1 + (z / knee)^4)
  // with z the live point's depth and knee where the two are equal (Kinect-class noise reaches
  // a 1 cm model's few millimetres near 1 m). 0 weighs all pairs alike, as KinectFusion does.
  // Coarser levels stay unweighted: they only find the basin.
  float depth_weight_knee_m = 1.0f;
  // Level-0 passes take every other pixel in a checkerboard, the two halves alternating between
  // iterations: half the work of the costliest level; the reported inliers are then the half's
  // count doubled. Only while the model covers at least half of the image: a smaller one leaves
  // too few pairs to halve.
  bool finest_level_checkerboard = true;
  // With the checkerboard on, the middle level's passes take every other pixel the same way
  // where that level has at least kMiddleCheckerboardMinPixels (a 640 x 480 camera at the
  // default working resolution): ICP's work per frame falls by a quarter; the 7-Scenes and sim
  // ATE stayed within 0.5 % (the sim:desk path squeezed into 30-40 frames 2-3 % worse:
  // lib/README.md, "Tracking"). At 80 x 60 the halves' 2 400 pixels left a resumed small-sim
  // run 1 cm off.
  bool middle_level_checkerboard = true;
  static constexpr int kMiddleCheckerboardMinPixels = 160 * 120;
  // Whether the middle level's passes take the checkerboard at this working (level-0)
  // resolution (the finest level's coverage condition aside); the deadline's cost model asks
  // the same.
  bool middle_level_halved(int width, int height) const {
    return finest_level_checkerboard && middle_level_checkerboard &&
           (width >> 1) * (height >> 1) >= kMiddleCheckerboardMinPixels;
  }
  // With the checkerboard, against a model cast at half resolution (SurfaceMap::pixel_stride 2,
  // one marched point per 2 x 2 pixels) the passes take one pixel of each 2 x 2 instead, the four
  // in turn between iterations: as many live points as the model has, half the checkerboard's
  // work. Off by default: on sim:desk it tracked 1-2 % worse (lib/README.md, "Tracking").
  bool finest_level_quarter_on_half_model = false;
  // Whether the finest passes take the quarter against a model cast with this pixel stride (the
  // checkerboard's coverage condition aside); the deadline's cost model asks the same.
  bool finest_level_quarter(int model_pixel_stride) const {
    return finest_level_checkerboard && finest_level_quarter_on_half_model &&
           model_pixel_stride == 2;
  }

  // True when every field is finite and in range (iterations >= 0, gates and knee >= 0, dot in
  // [-1, 1]).
  bool valid() const;
};

enum class TrackOutcome : std::uint8_t {
  tracked = 0,
  lost_residual,  // RMS residual above lost_max_rms_m
  lost_inliers,   // too few associated pixels (view does not match the model)
  lost_singular,  // the normal equations could not be solved (degenerate geometry)
  failed,         // bad arguments: see status
};

// Stable lower-case name ("tracked", "lost_inliers", ...); never null.
const char* track_outcome_name(TrackOutcome outcome);

struct TrackReport {
  Status status;  // ok, or why nothing was attempted
  TrackOutcome outcome = TrackOutcome::failed;
  int iterations[kPyramidLevels] = {0, 0, 0};  // Gauss-Newton steps taken per level
  float rms_residual_m = 0.0f;                 // at the estimate, level 0
  float inlier_fraction = 0.0f;                // inliers / model_pixels
  std::uint32_t inliers = 0;                   // level-0 pairs that passed the gates
  std::uint32_t model_pixels = 0;              // valid pixels of the model (ray-cast)
  // When a prior pulled the finest level: the pose the data alone gives (the last finest pass's
  // step solved without the prior), to compare with the prior unbiased by the pull. Otherwise
  // (no pull, or that step singular) has_data_estimate is false.
  bool has_data_estimate = false;
  Se3d T_W_C_data = Se3d::Identity();

  bool tracked() const { return outcome == TrackOutcome::tracked; }
};

// A pose the estimate is pulled towards (the vehicle's odometry). Each Gauss-Newton step at the
// finest level solves (A + L) dx = -(g + L e): A and g the weighted point-to-plane normal equations
// (each pair adds up to n n^T to the translation block), e the twist from the prior to the
// estimate (world frame, translation first, as the steps), L the prior's information in A's
// units. Directions the view constrains poorly (a wall, a floor) follow the prior; others ICP.
//
// By default L comes from the two estimates' uncertainties, per axis of the camera's twist:
//   L = Ad^T diag(var_a / sigma_a^2) Ad,
// sigma_a the prior's error (sigma_t_m, sigma_rad) and Ad the adjoint taking the world twist to
// the camera's (a world rotation also moves the camera by omega x t). var_a is ICP's variance on
// axis a in A's units: A / var_icp is ICP's information, var_icp the per-pair residual variance
// (icp_sigma_m squared, else the pass's mean squared residual; at least icp_noise_floor_m
// squared) times icp_pixels_per_sample, so var_a = var_icp; dividing both informations by
// 1 / var_icp keeps A in its units. Where icp_error_var_C says ICP errs more on an axis than that
// (the normal equations assume independent pixels, but a model error spans many, so ICP can slide
// along a wall by millimetres that they put at micrometres), var_a = A_C(a, a) *
// icp_error_var_C[a], A_C = A in the camera's twist: that axis is then shared as the two
// variances say. A view that fixes every direction barely moves; a direction it leaves loose
// (unconstrained: A_C(a, a) = 0) or that ICP is seen to get wrong follows the prior.
//
// With fixed_information, L = diag(information_t x3, information_r x3) in A's units instead, the
// same for every frame (an explicit override).
//
// Applied at the finest level only, and only when the coarser levels, which find the basin from
// the data alone, land within the gate of the prior: a prior that disagrees more is not pulled
// towards (the caller decides which to trust).
struct IcpPrior {
  Se3d T_W_C = Se3d::Identity();
  double sigma_t_m = 0.0015;           // prior's error per axis (camera frame), metres
  double sigma_rad = 0.0015;           // and radians
  double icp_noise_floor_m = 0.0005;   // lower bound of ICP's per-pair residual sigma
  double icp_pixels_per_sample = 1.0;  // pairs per independent residual (>= 1)
  // ICP's per-pair residual sigma; 0: the pass's own RMS. A caller passes the last converged
  // frame's, which a poor starting pose (a prior that is off) cannot inflate.
  double icp_sigma_m = 0.0;
  // ICP's error variance per camera axis (m^2 x3, rad^2 x3) as seen from outside: how far its
  // poses and the prior's disagree beyond the prior's own noise. Along an axis where it exceeds
  // what the normal equations claim, L_C there is A_C * icp_error_var_C / sigma^2 (A_C: A in the
  // camera's twist), so that axis is shared as the two variances say. 0: none.
  double icp_error_var_C[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  bool fixed_information = false;
  double information_t = 0.0;  // per m^2, with fixed_information
  double information_r = 0.0;  // per rad^2, with fixed_information
  double gate_m = 0.03;
  double gate_rad = 0.035;

  // True when every field is finite and in range: sigmas in [1e-9, 1e3], floor and icp_sigma_m
  // in [0, 1] m, pixels per sample in [1, 1e6], error variances in [0, 1], information and gates
  // >= 0 (NaN fails).
  bool valid() const;
};

class IcpTracker {
 public:
  // Carves the per-task reduction buffers from `arena` (LinearArena or ArenaSizer) for a live
  // pyramid whose level 0 is `width` x `height`. Returns invalid_argument for a bad config or
  // size, resource_exhausted when the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, const TrackConfig& config, int width, int height);

  // Estimates T_W_C (in: initial guess, out: estimate; unchanged unless tracked). `model_W` holds
  // world-frame vertices and normals ray-cast at T_W_Cref with `camera_level0` (same size).
  // report.status: ok; invalid_argument when sizes do not match reserve(), the camera is not
  // valid or a pose is not rigid/finite (outcome failed); failed_precondition before reserve().
  // `prior` (optional, must be rigid) adds a pull towards a pose; see IcpPrior.
  TrackReport track(const DepthPyramid& live, ConstSurfaceMap model_W,
                    const PinholeCamera& camera_level0, const Se3d& T_W_Cref, Se3d& T_W_C,
                    const WorkerTeam& team, const IcpPrior* prior = nullptr);

  const TrackConfig& config() const { return config_; }
  // Changes iteration counts etc. between frames (a per-frame budget); invalid_argument if bad.
  Status set_config(const TrackConfig& config);

  // One task's share of the weighted normal equations: upper triangle of J^T W J (row-major),
  // J^T W r, the unweighted sum of r^2 and the pair count.
  struct alignas(64) Partial {  // one cache line set per task: no false sharing
    double jtj[21];
    double jtr[6];
    double residual_sq;
    std::uint32_t count;
  };

 private:
  TrackConfig config_;
  Partial* partials_ = nullptr;  // kTrackTasks entries
  int width_ = 0;
  int height_ = 0;
  bool reserved_ = false;
};

template <typename Arena>
Status IcpTracker::reserve(Arena& arena, const TrackConfig& config, int width, int height) {
  reserved_ = false;
  if (!config.valid() || width <= 0 || height <= 0) return StatusCode::invalid_argument;
  Result<Partial*> partials = arena.template allocate_array<Partial>(kTrackTasks, kArenaAlignment);
  if (!partials.ok()) return partials.status();
  config_ = config;
  partials_ = partials.value();
  width_ = width;
  height_ = height;
  reserved_ = partials_ != nullptr;  // an ArenaSizer hands out no memory
  return ok_status();
}

}  // namespace octofuse
