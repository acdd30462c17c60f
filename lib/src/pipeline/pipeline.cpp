#include "octofuse/pipeline/pipeline.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <type_traits>

namespace octofuse {

const char* frame_result_name(FrameResult result) {
  switch (result) {
    case FrameResult::tracked:
      return "tracked";
    case FrameResult::first:
      return "first";
    case FrameResult::lost:
      return "lost";
    case FrameResult::rejected:
      return "rejected";
    case FrameResult::nearly_empty:
      return "nearly_empty";
  }
  return "unknown";
}

const char* pose_source_name(PoseSource source) {
  switch (source) {
    case PoseSource::track:
      return "track";
    case PoseSource::ground_truth:
      return "ground_truth";
    case PoseSource::external:
      return "external";
    case PoseSource::external_prior:
      return "external_prior";
  }
  return "unknown";
}

const char* pose_origin_name(PoseOrigin origin) {
  switch (origin) {
    case PoseOrigin::none:
      return "none";
    case PoseOrigin::initial:
      return "initial";
    case PoseOrigin::icp:
      return "icp";
    case PoseOrigin::ground_truth:
      return "ground_truth";
    case PoseOrigin::prior:
      return "prior";
    case PoseOrigin::prior_gate:
      return "prior_gate";
    case PoseOrigin::prior_lost:
      return "prior_lost";
  }
  return "unknown";
}

namespace {
constexpr float kSmallVoxel_m = 0.005f;

bool positive_finite(double v) {
  return std::isfinite(v) && v > 0.0;
}
}  // namespace

PipelineConfig default_pipeline_config(const PinholeCamera& input_camera, float voxel_size_m,
                                       int voxel_depth, std::uint32_t block_capacity,
                                       const Eigen::Vector3f& centre_W) {
  PipelineConfig c;
  c.input_camera = input_camera;
  // Nodes: at most one per 2 blocks in practice (8 children, shared upper levels); keep slack.
  const std::uint32_t node_capacity = block_capacity / 2 + 1024;
  c.map = MapConfig::centred(centre_W, voxel_size_m, voxel_depth, block_capacity, node_capacity);
  // Recorded poses are often printed with few digits (7-Scenes' are visibly off SO(3)); 1e-3 still
  // rejects anything that is not a rotation.
  c.validator.rigid_tolerance = 1e-3;
  c.fusion.mu_m = 8.0f * voxel_size_m;
  // Below 5 mm a far view can touch more than 2^17 distinct blocks; per-frame capacity costs the
  // integrator memory, so only small voxels get more.
  if (voxel_size_m < kSmallVoxel_m) c.fusion.max_blocks_per_frame = 1u << 18;
  c.fusion.near_m = c.validator.near_m;
  c.fusion.far_m = c.validator.far_m;
  return c;
}

// Names the first setting that is wrong; each part's own validate() stays the authority.
Status validate(const PipelineConfig& config, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  auto bad = [&](const char* what) {
    err.set("invalid configuration: %s", what);
    return Status(StatusCode::invalid_argument);
  };
  if (!config.input_camera.valid()) {
    return bad("input_camera (size > 0, finite fx, fy > 0 and cx, cy)");
  }
  const MapConfig& m = config.map;
  if (!positive_finite(m.voxel_size_m)) return bad("map.voxel_size_m must be finite and > 0");
  if (m.voxel_depth < kMinVoxelDepth || m.voxel_depth > kMaxVoxelDepth) {
    return bad("map.voxel_depth out of range");
  }
  if (!m.origin_W.allFinite()) return bad("map.origin_W must be finite");
  if (m.block_capacity == 0 || m.block_capacity > (1u << 30)) {
    return bad("map.block_capacity must be in [1, 2^30]");
  }
  if (m.finest_capacity > (1u << 30)) return bad("map.finest_capacity must be <= 2^30");
  if (m.mid_capacity > (1u << 30)) return bad("map.mid_capacity must be <= 2^30");
  if (m.node_capacity == 0 || m.node_capacity > (1u << 31)) {
    return bad("map.node_capacity must be in [1, 2^31]");
  }
  if (!validate(config.map).ok()) return bad("map");
  const FusionConfig& f = config.fusion;
  if (!positive_finite(f.mu_m)) return bad("fusion.mu_m must be finite and > 0");
  if (!positive_finite(f.near_m) || !std::isfinite(f.far_m) || !(f.near_m < f.far_m)) {
    return bad("fusion.near_m/far_m must be finite with 0 < near < far");
  }
  if (!validate(config.fusion).ok()) {
    return bad(
        "fusion (y_max >= 1, allocation_pixel_step >= 1, max_blocks_per_frame > 0, "
        "scale_hysteresis in [0, 1), fixed_scale <= 3, task_count >= 1)");
  }
  if (config.map_kind == MapKind::multires16 && !(f.y_max <= kMultires16MaxWeight)) {
    return bad("fusion.y_max must be <= 1023.98 for the multires16 map (its largest weight)");
  }
  if (!validate(config.free_space).ok()) {
    return bad("free_space (finite margins >= 0, max_free_count >= 1, visit budget > 0)");
  }
  if (config.esdf.enabled && !validate(config.esdf, config.map).ok()) {
    return bad(
        "esdf (cells_per_side a multiple of 8 in [8, 1016], cell_voxels 1/2/4/8, window "
        "within the map's cube, centre finite or NaN)");
  }
  const EvictionConfig& e = config.eviction;
  if (e.enabled && !(e.low_water > 0.0f && e.low_water < e.high_water && e.high_water <= 1.0f)) {
    return bad("eviction marks must satisfy 0 < low_water < high_water <= 1");
  }
  const float share = config.budget.store_read_share_integration;
  if (!(share >= 0.0f && share <= 1.0f)) {
    return bad("budget.store_read_share_integration must be in [0, 1]");
  }
  if (e.enabled && config.budget.max_evictions == 0) {
    return bad("budget.max_evictions must be >= 1 when eviction is enabled");
  }
  {
    ErrorText deadline_error;
    if (!validate(config.deadline, &deadline_error).ok()) return bad(deadline_error.c_str());
  }
  if (!config.preprocess.valid()) return bad("preprocess");
  if (!config.track.valid()) return bad("track");
  if (config.workers < 1 || config.workers > 64) return bad("workers must be in [1, 64]");
  int icp_iterations = 0;
  for (int level = 0; level < kPyramidLevels; ++level) {
    if (config.budget.icp_iterations[level] < 0) return bad("budget.icp_iterations must be >= 0");
    icp_iterations += config.budget.icp_iterations[level];
  }
  // No iteration at all would report every frame tracked at the predicted pose.
  if (config.pose_source == PoseSource::track && icp_iterations == 0) {
    return bad("budget.icp_iterations must allow at least one iteration when tracking");
  }
  if (!is_rigid(config.initial_T_W_C.matrix(), config.validator.rigid_tolerance)) {
    return bad("initial_T_W_C must be finite and rigid");
  }
  if (!positive_finite(config.prior_gate_m) || !positive_finite(config.prior_gate_rad)) {
    return bad("prior_gate_m and prior_gate_rad must be finite and > 0");
  }
  if (!std::isfinite(config.prior_information_t) || !(config.prior_information_t >= 0.0) ||
      !std::isfinite(config.prior_information_r) || !(config.prior_information_r >= 0.0)) {
    return bad("prior_information_t and prior_information_r must be finite and >= 0");
  }
  IcpPrior prior;
  prior.sigma_t_m = config.prior_noise_m;
  prior.sigma_rad = config.prior_noise_rad;
  if (!prior.valid()) return bad("prior_noise_m and prior_noise_rad must be in [1e-9, 1e3]");
  prior.icp_noise_floor_m = config.prior_icp_noise_floor_m;
  if (!prior.valid()) return bad("prior_icp_noise_floor_m must be in [0, 1]");
  prior.icp_pixels_per_sample = config.prior_icp_pixels_per_sample;
  if (!prior.valid()) return bad("prior_icp_pixels_per_sample must be in [1, 1e6]");
  if (!(config.prior_gap_rate >= 0.0 && config.prior_gap_rate <= 1.0)) {
    return bad("prior_gap_rate must be in [0, 1]");
  }
  if (config.prior_noise_estimate_frames < 0 || config.prior_noise_estimate_frames > 100000) {
    return bad("prior_noise_estimate_frames must be in [0, 100000]");
  }
  const PriorMotionLimits& motion = config.prior_motion;
  if (!positive_finite(motion.max_coordinate_m) || !positive_finite(motion.max_speed_mps) ||
      !positive_finite(motion.max_rate_radps) ||
      !(motion.slack_m >= 0.0 && std::isfinite(motion.slack_m)) ||
      !(motion.slack_rad >= 0.0 && std::isfinite(motion.slack_rad))) {
    return bad("prior_motion.max_* must be finite and > 0, prior_motion.slack_* finite and >= 0");
  }
  return ok_status();
}

bool prior_position_implausible(const Se3d& T_W_C, const PriorMotionLimits& limits) {
  return T_W_C.translation().cwiseAbs().maxCoeff() > limits.max_coordinate_m;
}

bool prior_motion_implausible(const Se3d& from, const Se3d& to, double dt_s,
                              const PriorMotionLimits& limits, double* moved_m,
                              double* turned_rad) {
  const double dt = dt_s > 0.0 ? dt_s : 0.0;
  const double moved = (to.translation() - from.translation()).norm();
  const double turned =
      Eigen::AngleAxisd(Eigen::Matrix3d(from.linear().transpose() * to.linear())).angle();
  if (moved_m != nullptr) *moved_m = moved;
  if (turned_rad != nullptr) *turned_rad = turned;
  return !(moved <= limits.max_speed_mps * dt + limits.slack_m) ||
         !(turned <= limits.max_rate_radps * dt + limits.slack_rad);
}

namespace {
// Squared distance in voxels from `camera_voxel` to the centre of the block at `coords`: exact in
// integers, so the rankings built on it are the same on every architecture.
std::uint64_t block_distance2(const Eigen::Vector3i& coords, const Eigen::Vector3i& camera_voxel) {
  const Eigen::Vector3i d =
      coords * kBlockSide + Eigen::Vector3i::Constant(kBlockSide / 2) - camera_voxel;
  return static_cast<std::uint64_t>(static_cast<std::int64_t>(d.x()) * d.x() +
                                    static_cast<std::int64_t>(d.y()) * d.y() +
                                    static_cast<std::int64_t>(d.z()) * d.z());
}

double elapsed_ms(std::int64_t from_us, std::int64_t to_us) {
  return static_cast<double>(to_us - from_us) * 1e-3;
}

// A validated (near-)rigid matrix as an exact rigid transform, so small errors in recorded
// poses do not accumulate in the map.
Se3d rigid_from(const Eigen::Matrix4d& T) {
  Se3d out = Se3d::Identity();
  out.linear() = orthonormalize(T.topLeftCorner<3, 3>());
  out.translation() = T.topRightCorner<3, 1>();
  return out;
}
}  // namespace

template <typename VoxelT>
template <typename Arena>
Status Pipeline<VoxelT>::reserve(Arena& arena, const PipelineConfig& config) {
  const int width = config.input_camera.width;
  const int height = config.input_camera.height;
  const int factor = config.preprocess.downsample_factor;
  OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
  Result<float*> depth = arena.template allocate_array<float>(
      static_cast<std::size_t>(width) * static_cast<std::size_t>(height), kArenaAlignment);
  OCTOFUSE_TRY(depth);
  input_depth_m_ = ImageView<float>(depth.value(), width, height);
  OCTOFUSE_TRY(preprocessor_.reserve(arena, config.preprocess, width, height));
  const int working_width = width / factor;
  const int working_height = height / factor;
  TrackConfig track = config.track;
  for (int level = 0; level < kPyramidLevels; ++level) {
    track.iterations[level] = config.budget.icp_iterations[level];
  }
  OCTOFUSE_TRY(tracker_.reserve(arena, track, working_width, working_height));
  OCTOFUSE_TRY(map_.reserve(arena, config.map));
  OCTOFUSE_TRY(integrator_.reserve(arena, config.fusion, working_width, working_height));
  RaycastConfig raycast;
  raycast.width = working_width;
  raycast.height = working_height;
  raycast.near_m = config.validator.near_m;
  raycast.far_m = config.validator.far_m;
  raycast.mu_m = config.fusion.mu_m;
  raycast.step_budget = config.budget.raycast_steps;
  raycast.pixel_stride = config.budget.raycast_half ? 2 : 1;
  OCTOFUSE_TRY(raycaster_.reserve(arena, raycast));
  if (config.view_cast) {
    raycast.step_budget = 0;
    raycast.pixel_stride = 1;
    OCTOFUSE_TRY(view_raycaster_.reserve(arena, raycast));
  }
  if (config.free_space.enabled) {
    FreeSpaceConfig free_space = config.free_space;
    if (!(free_space.clearance_m > 0.0f)) free_space.clearance_m = 0.5f * config.fusion.mu_m;
    // A free-space node is 40 bytes: room for one per block costs little beside the blocks.
    if (free_space.node_capacity == 0) {
      free_space.node_capacity = std::max(config.map.node_capacity, config.map.block_capacity);
    }
    if (!(free_space.occlusion_clear_m > 0.0f)) {
      free_space.occlusion_clear_m = 4.0f * config.fusion.mu_m;
    }
    OCTOFUSE_TRY(free_space_.reserve(arena, free_space, config.map, working_width, working_height));
    Result<std::uint8_t*> input_beyond = arena.template allocate_array<std::uint8_t>(
        static_cast<std::size_t>(width) * static_cast<std::size_t>(height), kArenaAlignment);
    OCTOFUSE_TRY(input_beyond);
    input_beyond_far_ = ImageView<std::uint8_t>(input_beyond.value(), width, height);
    Result<std::uint8_t*> working_beyond = arena.template allocate_array<std::uint8_t>(
        static_cast<std::size_t>(working_width) * static_cast<std::size_t>(working_height),
        kArenaAlignment);
    OCTOFUSE_TRY(working_beyond);
    working_beyond_far_ =
        ImageView<std::uint8_t>(working_beyond.value(), working_width, working_height);
  }
  if (config.esdf.enabled) {
    OCTOFUSE_TRY(esdf_.reserve(arena, config.esdf, config.map));
    esdf_.set_guard(&guard_);
  }
  if (config.eviction.enabled) {
    const std::uint32_t blocks = config.map.block_capacity;
    Result<EvictionCandidate*> candidates =
        arena.template allocate_array<EvictionCandidate>(blocks, kArenaAlignment);
    OCTOFUSE_TRY(candidates);
    Result<std::uint32_t*> indices = arena.template allocate_array<std::uint32_t>(blocks);
    OCTOFUSE_TRY(indices);
    Result<std::uint8_t*> in_frame = arena.template allocate_array<std::uint8_t>(blocks);
    OCTOFUSE_TRY(in_frame);
    eviction_candidates_ = candidates.value();
    eviction_indices_ = indices.value();
    in_frame_ = in_frame.value();
    if (in_frame_ != nullptr) std::memset(in_frame_, 0, blocks);
    Result<std::uint8_t*> record =
        arena.template allocate_array<std::uint8_t>(block_record_max_bytes<VoxelT>());
    OCTOFUSE_TRY(record);
    Result<std::uint64_t*> keys = arena.template allocate_array<std::uint64_t>(kStoreKeyCapacity);
    OCTOFUSE_TRY(keys);
    store_record_ = record.value();
    store_keys_ = keys.value();
  }
  OCTOFUSE_TRY(arena.allocate_bytes(0, kArenaAlignment));
  return ok_status();
}

std::size_t bytes_required(const PipelineConfig& config) {
  if (!validate(config).ok()) return 0;
  ArenaSizer sizer;
  Status status;
  if (config.map_kind == MapKind::multires) {
    Pipeline<MultiresVoxel> probe;
    status = probe.reserve(sizer, config);
  } else if (config.map_kind == MapKind::multires16) {
    Pipeline<Multires16Voxel> probe;
    status = probe.reserve(sizer, config);
  } else {
    Pipeline<TsdfVoxel> probe;
    status = probe.reserve(sizer, config);
  }
  return status.ok() ? sizer.bytes_used() : 0;
}

template <typename VoxelT>
Status Pipeline<VoxelT>::init(void* buffer, std::size_t bytes, const PipelineConfig& config,
                              Clock clock) {
  initialised_ = false;
  own_error_ = true;
  OCTOFUSE_TRY(validate(config, &error_));
  const MapKind expected = map_kind_of<VoxelT>();
  if (config.map_kind != expected) {
    error_.set("invalid configuration: map_kind is %s but the pipeline's voxel type is %s",
               map_kind_name(config.map_kind), map_kind_name(expected));
    return StatusCode::invalid_argument;
  }
  if (buffer == nullptr || reinterpret_cast<std::uintptr_t>(buffer) % kArenaAlignment != 0) {
    error_.set("buffer is null or not aligned to %zu bytes", kArenaAlignment);
    return StatusCode::invalid_argument;
  }
  arena_ = LinearArena(buffer, bytes);
  const Status reserved = reserve(arena_, config);
  if (!reserved.ok()) {
    error_.set("buffer of %zu bytes is too small: bytes_required() gives %zu (%s)", bytes,
               bytes_required(config), reserved.name());
    return reserved;
  }
  const Status validator = validator_.init(config.input_camera, config.validator);
  if (!validator.ok()) {
    error_.set("invalid configuration: validator (%s)", validator_.last_error());
    return validator;
  }
  own_error_ = false;
  config_ = config;
  clock_ = clock;
  {
    // floor, so a mark never exceeds the pool; the low mark is at least one below the high one.
    auto mark = [](std::uint32_t capacity, float fraction) {
      return static_cast<std::uint32_t>(static_cast<double>(capacity) *
                                        static_cast<double>(fraction));
    };
    const MapMemory memory = map_.memory();
    evict_high_blocks_ = mark(memory.block_capacity, config.eviction.high_water);
    evict_low_blocks_ = mark(memory.block_capacity, config.eviction.low_water);
    evict_high_finest_ = mark(memory.finest_capacity, config.eviction.high_water);
    evict_low_finest_ = mark(memory.finest_capacity, config.eviction.low_water);
    evict_high_mid_ = mark(memory.mid_capacity, config.eviction.high_water);
    evict_low_mid_ = mark(memory.mid_capacity, config.eviction.low_water);
    evict_high_nodes_ = mark(memory.node_capacity, config.eviction.high_water);
    evict_low_nodes_ = mark(memory.node_capacity, config.eviction.low_water);
  }
  team_ = WorkerTeam(config.workers);
  team_.set_clock(clock_);  // FrameStats::times.helper_wait_ms
  working_camera_ = config.input_camera.downsampled(config.preprocess.downsample_factor);
  // A reference cast already at half resolution leaves the deadline's half step nothing to give.
  DeadlineConfig deadline = config.deadline;
  if (config.budget.raycast_half) deadline.raycast_half_resolution = false;
  deadline_.reset(
      deadline, config.budget.icp_iterations, working_camera_.width, working_camera_.height,
      config.pose_source == PoseSource::track || config.pose_source == PoseSource::external_prior,
      config.free_space.enabled,
      config.track.finest_level_quarter(config.budget.raycast_half ? 2 : 1) ? 0.5 : 1.0,
      config.track.middle_level_halved(working_camera_.width, working_camera_.height) ? 0.5 : 1.0);
  current_ = FrameStats{};
  T_W_C_ = rigid_from(config.initial_T_W_C.matrix());
  T_W_Cref_ = T_W_C_;
  T_Cprev_C_ = Se3d::Identity();
  prior_prev_ = Se3d::Identity();
  have_prior_prev_ = false;
  restart_prior_statistics();
  have_reference_ = false;
  view_cast_done_ = false;
  reference_guided_ = false;
  pose_set_ = false;
  frame_index_ = 0;
  frames_lost_ = 0;
  priors_rejected_ = 0;
  priors_dropped_ = 0;
  have_last_prior_ = false;
  map_version_ = 0;
  initialised_ = true;
  return ok_status();
}

template <typename VoxelT>
void Pipeline<VoxelT>::restart_prior_statistics() {
  // Gaps as large as the odometry's own noise: nothing seen against ICP yet.
  for (int a = 0; a < 6; ++a) {
    const double sigma = a < 3 ? config_.prior_noise_m : config_.prior_noise_rad;
    prior_gap_sq_C_[a] = sigma * sigma;
  }
  last_icp_rms_m_ = 0.0;
  prior_history_size_ = 0;
  prior_jitter_t_m_ = 0.0;
  prior_jitter_rad_ = 0.0;
  prior_jitter_samples_ = 0;
}

namespace {
// From the mean norm of a third difference of white noise to one frame's relative error per
// axis: a 3-D Gaussian's mean norm is 1.5958 sigma per axis, a third difference has 20 times a
// pose's variance, a difference of two poses twice it: sqrt(2) / (1.5958 * sqrt(20)).
constexpr double kJitterToFrameNoise = 0.19816;
constexpr int kJitterMeanFrames = 100;
// The running mean square of ICP's gaps (rate 0.1: about 10 frames) scatters by a third of its
// value when the gaps are the odometry's noise alone, and ICP's own error (on the desk 1.2-1.6 mm
// per axis, correlated from frame to frame through the map) adds to it; taking such an excess for a
// per-frame error pulled ICP towards a white-noise odometry and raised the trajectory error (the
// desk, odometry noisier than stated: 1.68 mm against 1.49 mm for ICP alone at a threshold of
// three). Only a mean square ten times the odometry's variance (ICP erring three times the
// odometry's sigma on the axis: sliding along a wall or a corridor) is taken as ICP's own error.
constexpr double kGapSignificance = 10.0;
}  // namespace

template <typename VoxelT>
void Pipeline<VoxelT>::observe_prior_noise(const Se3d& prior_T_W_C, std::int64_t time_us) {
  const int window = config_.prior_noise_estimate_frames;
  if (window <= 0) return;
  if (prior_history_size_ == 4) {
    for (int i = 0; i < 3; ++i) {
      prior_history_[i] = prior_history_[i + 1];
      prior_history_us_[i] = prior_history_us_[i + 1];
    }
    prior_history_size_ = 3;
  }
  prior_history_[prior_history_size_] = prior_T_W_C;
  prior_history_us_[prior_history_size_] = time_us;
  ++prior_history_size_;
  if (prior_history_size_ < 4) return;
  // Evenly spaced frames only: a gap (a frame without a prior, a dropped one) is not jitter.
  const double d0 = static_cast<double>(prior_history_us_[1] - prior_history_us_[0]);
  const double d1 = static_cast<double>(prior_history_us_[2] - prior_history_us_[1]);
  const double d2 = static_cast<double>(prior_history_us_[3] - prior_history_us_[2]);
  const double mean_us = (d0 + d1 + d2) / 3.0;
  if (!(mean_us > 0.0) || std::abs(d0 - mean_us) > 0.25 * mean_us ||
      std::abs(d1 - mean_us) > 0.25 * mean_us || std::abs(d2 - mean_us) > 0.25 * mean_us) {
    return;
  }
  const Se3d* p = prior_history_;
  const Eigen::Vector3d d3 =
      p[3].translation() - 3.0 * p[2].translation() + 3.0 * p[1].translation() - p[0].translation();
  Eigen::Vector3d turn[3];
  for (int i = 0; i < 3; ++i) {
    const Eigen::AngleAxisd aa(Eigen::Matrix3d(p[i].linear().transpose() * p[i + 1].linear()));
    turn[i] = aa.angle() * aa.axis();
  }
  const Eigen::Vector3d dr = turn[2] - 2.0 * turn[1] + turn[0];
  double jitter_t = d3.norm();
  double jitter_r = dr.norm();
  if (prior_jitter_samples_ >= window) {
    // A real jolt of the camera is not noise: at most four times the mean so far.
    jitter_t = std::min(jitter_t, 4.0 * prior_jitter_t_m_);
    jitter_r = std::min(jitter_r, 4.0 * prior_jitter_rad_);
  }
  // The plain mean over the first samples, then a running mean over about kJitterMeanFrames: a
  // third difference's norm scatters widely, and over a few tens of frames the estimate was off
  // by enough at times to cost trajectory error.
  const double rate =
      1.0 / static_cast<double>(std::min(prior_jitter_samples_ + 1, kJitterMeanFrames));
  prior_jitter_t_m_ += rate * (jitter_t - prior_jitter_t_m_);
  prior_jitter_rad_ += rate * (jitter_r - prior_jitter_rad_);
  if (prior_jitter_samples_ < std::max(window, kJitterMeanFrames)) ++prior_jitter_samples_;
}

template <typename VoxelT>
double Pipeline<VoxelT>::prior_noise_m() const {
  const int window = config_.prior_noise_estimate_frames;
  if (window <= 0 || prior_jitter_samples_ < window) return config_.prior_noise_m;
  return std::max(config_.prior_noise_m, kJitterToFrameNoise * prior_jitter_t_m_);
}

template <typename VoxelT>
double Pipeline<VoxelT>::prior_noise_rad() const {
  const int window = config_.prior_noise_estimate_frames;
  if (window <= 0 || prior_jitter_samples_ < window) return config_.prior_noise_rad;
  return std::max(config_.prior_noise_rad, kJitterToFrameNoise * prior_jitter_rad_);
}

template <typename VoxelT>
Status Pipeline<VoxelT>::resume_frame_count(std::uint64_t frames) {
  if (!initialised_ || frame_index_ != 0) return StatusCode::failed_precondition;
  frame_index_ = frames;
  return ok_status();
}

template <typename VoxelT>
Status Pipeline<VoxelT>::prefault(std::uint32_t blocks) {
  if (!initialised_) return StatusCode::failed_precondition;
  map_.prefault(blocks);
  if (free_space_.reserved()) free_space_.prefault(blocks);
  return ok_status();
}

template <typename VoxelT>
Status Pipeline<VoxelT>::reset() {
  if (!initialised_) return StatusCode::failed_precondition;
  {
    // Readers see the map before the reset or after it, never half cleared.
    ExclusiveHold hold(guard_);
    if (store_ != nullptr) {
      // Blocks taken from the store are stored again: a later frame may read them back.
      for (std::uint32_t i = 0; i < map_.block_count(); ++i) {
        store_->release(morton_encode(map_.block(i).coords));
      }
    }
    if (finest_store_ != nullptr) {
      // So are finest levels taken back: the store's record is the level again.
      for (std::uint32_t i = 0; i < map_.block_count(); ++i) {
        finest_store_->release(morton_encode(map_.block(i).coords));
      }
    }
    map_.clear();
    if (free_store_ != nullptr) {
      // Every region goes to the store (merged with what it held): a later frame reads it back.
      FreeStoreReport spilled;
      free_space_.spill_and_prune(T_W_C_.translation().cast<float>(), -1.0f, free_store_, &spilled);
    }
    if (free_space_.reserved()) free_space_.clear();
    if (esdf_.reserved()) esdf_.clear();
    ++map_version_;
  }
  validator_.restart_stream();
  T_W_C_ = rigid_from(config_.initial_T_W_C.matrix());
  T_W_Cref_ = T_W_C_;
  T_Cprev_C_ = Se3d::Identity();
  have_prior_prev_ = false;
  have_last_prior_ = false;
  restart_prior_statistics();
  have_reference_ = false;
  view_cast_done_ = false;
  reference_guided_ = false;
  pose_set_ = false;
  raycaster_.forget_previous_cast();
  // frame_index_ keeps counting: the integrator's per-frame stamps must not repeat.
  return ok_status();
}

template <typename VoxelT>
Status Pipeline<VoxelT>::set_pose(const Se3d& T_W_C) {
  if (!initialised_) return StatusCode::failed_precondition;
  if (!is_rigid(T_W_C.matrix(), config_.validator.rigid_tolerance)) {
    return StatusCode::invalid_argument;
  }
  T_W_C_ = rigid_from(T_W_C.matrix());
  T_Cprev_C_ = Se3d::Identity();  // the motion into the new pose is unknown
  have_prior_prev_ = false;       // and so is the prior that goes with it
  if (!have_reference_) {
    pose_set_ = true;
    T_W_Cref_ = T_W_C_;
    return ok_status();
  }
  if (store_ != nullptr) {
    // Stored blocks in the new view come back first (within the frame budgets), so the ray-cast
    // shows the old map there.
    ExclusiveHold hold(guard_);
    StoreReport reloaded;
    reload_stored(reloaded);
  }
  // The old reference was seen from elsewhere: ray-cast what the map shows from here, whole.
  if (deadline_.active()) {
    raycaster_.set_step_budget(config_.budget.raycast_steps);
    raycaster_.set_pixel_stride(1);
  }
  view_cast_done_ = false;
  reference_guided_ = false;
  const Result<RaycastStats> raycast = raycaster_.raycast(map_, working_camera_, T_W_C_, team_);
  if (!raycast.ok()) return raycast.status();
  T_W_Cref_ = T_W_C_;
  return ok_status();
}

template <typename VoxelT>
typename Pipeline<VoxelT>::RoomShort Pipeline<VoxelT>::room_short(
    const FusionBudget& budget) const {
  RoomShort short_of;
  if (!config_.eviction.enabled) return short_of;
  const MapMemory memory = map_.memory();
  // A frame allocates at most its list of touched blocks: with that much room, nothing to do.
  const std::uint32_t most =
      std::min(budget.max_new_blocks, integrator_.config().max_blocks_per_frame);
  short_of.blocks = memory.block_capacity - memory.blocks_used < most;
  short_of.nodes = memory.node_capacity - memory.nodes_used <
                   std::uint64_t{most} * static_cast<std::uint64_t>(map_.block_level() - 1);
  return short_of;
}

template <typename VoxelT>
std::uint32_t Pipeline<VoxelT>::count_new_nodes() {
  const std::uint32_t capacity = map_.memory().block_capacity;
  std::uint32_t missing = 0;
  integrator_.for_each_listed_block([this, capacity, &missing](std::uint64_t morton,
                                                               const Eigen::Vector3i&,
                                                               std::uint32_t index, int) {
    if (index == kNoIndex && missing < capacity) eviction_candidates_[missing++].morton = morton;
  });
  // In Morton order the blocks under one octant are consecutive: an ancestor is new once, for the
  // first of them.
  std::sort(eviction_candidates_, eviction_candidates_ + missing, EvictionCandidate::key_less);
  const int block_level = map_.block_level();
  std::uint32_t nodes = 0;
  for (std::uint32_t i = 0; i < missing; ++i) {
    const std::uint64_t morton = eviction_candidates_[i].morton;
    // The nodes below the deepest one that exists above the block are new...
    int first_new = map_.lookup(block_to_voxel(morton_decode(morton))).level + 1;
    // ... but those above the previous block too were counted with it (ancestors `up` levels above
    // the blocks share their Morton code without its low 3 * up bits).
    if (i > 0) {
      const std::uint64_t previous = eviction_candidates_[i - 1].morton;
      int up = 1;
      while (up < block_level && (morton >> (3 * up)) != (previous >> (3 * up))) ++up;
      first_new = std::max(first_new, block_level - up + 1);
    }
    if (first_new < block_level) nodes += static_cast<std::uint32_t>(block_level - first_new);
  }
  return nodes;
}

template <typename VoxelT>
EvictionReport Pipeline<VoxelT>::evict(std::uint32_t frame_index, std::uint32_t new_blocks,
                                       std::uint32_t new_nodes) {
  EvictionReport report;
  if (!config_.eviction.enabled) return report;
  const MapMemory memory = map_.memory();
  const bool finest_pool = Map::kSplitFinest && memory.finest_capacity > 0;
  std::uint32_t over_blocks = 0;
  std::uint32_t over_finest = 0;
  std::uint32_t over_mid = 0;
  if (memory.blocks_used > evict_high_blocks_) {
    over_blocks = memory.blocks_used - evict_low_blocks_;
  }
  // What must go for the frame's new blocks to fit at all (within max_evictions, whatever the
  // write budget).
  const std::uint64_t after = std::uint64_t{memory.blocks_used} + new_blocks;
  std::uint32_t must_go = after > memory.block_capacity
                              ? static_cast<std::uint32_t>(std::min<std::uint64_t>(
                                    after - memory.block_capacity, memory.blocks_used))
                              : 0;
  // Then down to the low-water mark after the allocation, as when the pool passes its high mark:
  // the blocks evicted may include some this frame touches, which then count as new too.
  if (must_go > 0) {
    over_blocks = std::max(over_blocks, static_cast<std::uint32_t>(std::min<std::uint64_t>(
                                            after - evict_low_blocks_, memory.blocks_used)));
  }
  if (finest_pool && memory.finest_used > evict_high_finest_) {
    over_finest = memory.finest_used - evict_low_finest_;
  }
  if (finest_pool && memory.mid_used > evict_high_mid_) {
    over_mid = memory.mid_used - evict_low_mid_;
  }
  // The node pool: over its high mark, or short of the nodes the frame's new blocks need.
  const std::uint64_t nodes_after = std::uint64_t{memory.nodes_used} + new_nodes;
  std::uint32_t must_go_nodes = 0;
  if ((memory.nodes_used > evict_high_nodes_ || nodes_after > memory.node_capacity) &&
      memory.blocks_used > 0) {
    // Inner nodes go with their last block: evict the share of the blocks that the nodes are over
    // their low mark (the farthest blocks take whole octants with them; a next frame evicts more
    // if that was not enough).
    const auto share = [&memory](std::uint64_t nodes) {
      const std::uint64_t blocks =
          (nodes * memory.blocks_used + memory.nodes_used - 1) / memory.nodes_used;
      return static_cast<std::uint32_t>(std::min<std::uint64_t>(blocks, memory.blocks_used));
    };
    over_blocks = std::max(over_blocks, share(nodes_after - evict_low_nodes_));
    if (nodes_after > memory.node_capacity) {
      must_go_nodes = share(nodes_after - memory.node_capacity);
    }
  }
  must_go = std::max(must_go, must_go_nodes);
  if (over_blocks == 0 && over_finest == 0 && over_mid == 0) return report;
  report.triggered = true;
  // Rank every block: not updated by the previous frame, not read back by this one and not in
  // this frame's list first, then read back by this one (in view), then the previous frame's
  // and this frame's (evicting one would lose what it holds, or with a store write it and map it
  // afresh at once, its record dropped when next read); within each, farthest first (squared
  // distance in voxels from the camera's voxel to the block's centre, exact in integers), then by
  // Morton code, a total order. When only the fine levels are over their marks, the last tier
  // gives up first the levels of blocks this frame does not fuse at scale 0 (farthest first),
  // then those of the blocks that hold no surface, then of those that do, each by who has held
  // theirs longest (finest_turn): a view larger than the pool takes turns at scale 0, the surface
  // first, instead of some blocks never getting one.
  const Eigen::Vector3i camera_voxel =
      map_.point_to_voxel(T_W_C_.translation().template cast<float>());
  const std::uint32_t count = map_.block_count();
  const std::uint32_t recent_frame = frame_index > 0 ? frame_index - 1 : 0;
  constexpr std::uint8_t kListed = 1;
  constexpr std::uint8_t kListedAtFinest = 2;
  integrator_.for_each_listed_block(
      [this](std::uint64_t, const Eigen::Vector3i&, std::uint32_t index, int scale) {
        if (index != kNoIndex) in_frame_[index] = scale == 0 ? kListedAtFinest : kListed;
      });
  const bool levels_only = over_blocks == 0;
  for (std::uint32_t i = 0; i < count; ++i) {
    const typename Map::Block& block = map_.block(i);
    const bool recent =
        (block.last_updated_frame >= recent_frame && block.integrated()) || in_frame_[i] != 0;
    const std::uint64_t tier = recent ? 0 : i >= read_back_from_ ? 1 : 2;
    std::uint64_t order = block_distance2(block.coords, camera_voxel);  // below 2^60
    bool turn_kept = false;
    if (tier == 0 && levels_only && in_frame_[i] == kListedAtFinest) {
      order = std::uint64_t{0xFFFFFFFFu - block.finest_turn};
      if (!block.may_hold_surface()) order |= std::uint64_t{1} << 59;
      turn_kept = block.has_finest() &&
                  frame_index - block.finest_turn < config_.eviction.finest_turn_frames;
    } else if (tier == 0 && levels_only) {
      order |= std::uint64_t{1} << 60;
    }
    in_frame_[i] = 0;
    EvictionCandidate& c = eviction_candidates_[i];
    c.rank = (tier << 61) | order;
    c.turn_kept = turn_kept;
    c.morton = block.morton;
    c.index = i;
    c.has_finest = block.has_finest() && Map::kSplitFinest;
    c.has_mid = block.has_mid() && Map::kSplitFinest;
    c.clean = block.stored_clean != 0;
  }
  std::sort(eviction_candidates_, eviction_candidates_ + count,
            [](const EvictionCandidate& a, const EvictionCandidate& b) {
              if (a.rank != b.rank) return a.rank > b.rank;
              return a.morton < b.morton;
            });
  // Evicted blocks fill eviction_indices_ from the front, demoted ones from the back (those that
  // give their mid level back too marked by kDemoteMid). The budget bounds evictions and
  // demotions together, and, with a store, the records written (a block read back and unchanged
  // writes none). Room for the frame's new blocks (must_go) is made whatever the write budget: a
  // refused block is a hole in the map, a write more is a little disk time.
  constexpr std::uint32_t kDemoteMid = 0x80000000u;  // pool indices are below 2^30
  std::uint32_t evicted = 0;
  std::uint32_t demoted = 0;
  std::uint32_t demoted_mid = 0;
  std::uint32_t writes = 0;
  for (std::uint32_t i = 0; i < count && (over_blocks > 0 || over_finest > 0 || over_mid > 0);
       ++i) {
    const EvictionCandidate& c = eviction_candidates_[i];
    const bool demote_mid = c.has_mid && over_mid > 0;
    if (over_blocks == 0 && !(c.has_finest && over_finest > 0) && !demote_mid) continue;
    if (c.turn_kept) continue;
    const bool write = over_blocks > 0 && store_ != nullptr && !c.clean;
    const bool writes_spent = write && writes == config_.budget.max_store_writes;
    if (evicted + demoted == config_.budget.max_evictions || (writes_spent && evicted >= must_go)) {
      report.budget_hit = true;
      if (writes_spent) current_.store.budget_hit = true;
      break;
    }
    if (over_blocks > 0) {
      eviction_indices_[evicted++] = c.index;
      writes += write ? 1 : 0;
      --over_blocks;
    } else if (demote_mid) {
      eviction_indices_[count - 1 - demoted++] = c.index | kDemoteMid;
      ++demoted_mid;
    } else {
      eviction_indices_[count - 1 - demoted++] = c.index;
    }
    if (c.has_finest && over_finest > 0) --over_finest;
    if (c.has_mid && over_mid > 0) --over_mid;
  }
  if (store_ != nullptr) spill(evicted);
  // Demote first (eviction moves blocks to other pool indices): the blocks that keep scale 2,
  // gathered at the front of the demoted range, then those that keep scale 1.
  std::uint32_t* demoted_begin = eviction_indices_ + (count - demoted);
  std::uint32_t* demoted_end = eviction_indices_ + count;
  std::uint32_t* keep_1 = std::partition(demoted_begin, demoted_end,
                                         [](std::uint32_t v) { return (v & kDemoteMid) != 0; });
  for (std::uint32_t* v = demoted_begin; v != keep_1; ++v) *v &= ~kDemoteMid;
  for (const std::uint32_t* v = demoted_begin; v != demoted_end; ++v) {
    typename Map::Block& block = map_.block(*v);
    if (finest_store_ != nullptr && block.has_finest()) keep_finest(*v);
    block.finest_turn = frame_index;
  }
  map_.release_mid(demoted_begin, static_cast<std::size_t>(keep_1 - demoted_begin));
  map_.release_finest(keep_1, static_cast<std::size_t>(demoted_end - keep_1));
  map_.evict_blocks(eviction_indices_, evicted);
  report.evicted = evicted;
  report.demoted = demoted;
  report.demoted_mid = demoted_mid;
  return report;
}

template <typename VoxelT>
typename FinestLevelSource<VoxelT>::Answer Pipeline<VoxelT>::FinestReader::restore(
    Octree<VoxelT>& map, std::uint32_t index) {
  Pipeline& p = *pipeline_;
  StoreReport& report = p.current_.store;
  const std::uint64_t key = morton_encode(map.block(index).coords);
  if (!p.finest_store_->holds(key)) return FinestLevelSource<VoxelT>::Answer::none;
  // No room for the level: no read; a fresh level is refused as well, and counted as usual.
  const MapMemory memory = map.memory();
  if (memory.finest_used >= memory.finest_capacity ||
      (!map.block(index).has_mid() && memory.mid_used >= memory.mid_capacity)) {
    return FinestLevelSource<VoxelT>::Answer::none;
  }
  if (report.finest_read + report.finest_read_failed == p.config_.budget.max_store_reads) {
    ++report.finest_waiting;
    report.budget_hit = true;
    return FinestLevelSource<VoxelT>::Answer::wait;
  }
  const Result<std::size_t> size =
      p.finest_store_->take(key, p.store_record_, block_record_max_bytes<VoxelT>());
  if (!size.ok()) {
    ++report.finest_read_failed;
    return FinestLevelSource<VoxelT>::Answer::none;
  }
  report.finest_bytes_read += size.value();
  const Status restored =
      restore_finest_from_record(map, index, p.store_record_, size.value(), p.config_.fusion.y_max);
  if (restored.ok()) {
    ++report.finest_read;
    return FinestLevelSource<VoxelT>::Answer::restored;
  }
  p.finest_store_->release(key);  // still the block's newest finest record
  ++report.finest_read_failed;
  return FinestLevelSource<VoxelT>::Answer::none;
}

template <typename VoxelT>
void Pipeline<VoxelT>::keep_finest(std::uint32_t index) {
  const Result<std::size_t> size =
      encode_block_record(map_.block(index), store_record_, block_record_max_bytes<VoxelT>());
  if (!size.ok()) {
    ++current_.store.finest_write_failed;
    return;
  }
  put_finest(morton_encode(map_.block(index).coords), size.value());
}

template <typename VoxelT>
void Pipeline<VoxelT>::keep_finest_read_back(std::uint32_t index, std::uint64_t key,
                                             std::size_t record_size) {
  if (finest_store_ == nullptr || map_.block(index).has_finest() ||
      !block_record_holds_finest<VoxelT>(store_record_, record_size)) {
    return;
  }
  put_finest(key, record_size);
}

template <typename VoxelT>
void Pipeline<VoxelT>::put_finest(std::uint64_t key, std::size_t record_size) {
  StoreReport& report = current_.store;
  if (finest_store_->put(key, store_record_, record_size).ok()) {
    ++report.finest_written;
    report.finest_bytes_written += record_size;
  } else {
    ++report.finest_write_failed;
  }
}

// Hands the blocks about to be evicted (the first `count` of eviction_indices_) to the store.
template <typename VoxelT>
void Pipeline<VoxelT>::spill(std::uint32_t count) {
  StoreReport& report = current_.store;
  for (std::uint32_t i = 0; i < count; ++i) {
    const typename Map::Block& block = map_.block(eviction_indices_[i]);
    if (block.stored_clean != 0) {
      // Read back and not integrated since: the store's record is still its state.
      store_->release(morton_encode(block.coords));
      ++report.unchanged;
      continue;
    }
    const Result<std::size_t> size =
        encode_block_record(block, store_record_, block_record_max_bytes<VoxelT>());
    const Status put = size.ok()
                           ? store_->put(morton_encode(block.coords), store_record_, size.value())
                           : size.status();
    if (!put.ok()) {
      ++report.write_failed;
      continue;
    }
    ++report.written;
    report.bytes_written += size.value();
  }
}

// Stored blocks whose centre projects into the view (within two blocks of its edges, in front of
// the camera, nearer than the depth range plus a block) come back nearest first, before this
// frame's integration would map their space afresh, while the pool is below its high-water mark.
template <typename VoxelT>
void Pipeline<VoxelT>::reload_stored(StoreReport& report) {
  const float far_m = config_.fusion.far_m;
  const float block_m = static_cast<float>(kBlockSide) * map_.voxel_size_m();
  const Se3f T_W_C = T_W_C_.template cast<float>();
  const Se3f T_C_W = T_W_C.inverse();
  const PinholeCamera& cam = working_camera_;
  // The view's bounding box in block coordinates (camera centre and the far plane's corners).
  Eigen::Vector3f lo = T_W_C.translation();
  Eigen::Vector3f hi = lo;
  const float us[2] = {-0.5f, static_cast<float>(cam.width) - 0.5f};
  const float vs[2] = {-0.5f, static_cast<float>(cam.height) - 0.5f};
  for (float u : us) {
    for (float v : vs) {
      const Eigen::Vector3f p_W = T_W_C * cam.back_project(u, v, far_m + block_m);
      lo = lo.cwiseMin(p_W);
      hi = hi.cwiseMax(p_W);
    }
  }
  const Eigen::Vector3i lo_block = voxel_to_block(map_.point_to_voxel(lo));
  const Eigen::Vector3i hi_block = voxel_to_block(map_.point_to_voxel(hi));
  const std::size_t found = store_->find_in_box(lo_block, hi_block, store_keys_, kStoreKeyCapacity);
  store_keys_found_ = found;
  // In view: rank by squared distance (voxels), nearest first, ties by key.
  const Eigen::Vector3i camera_voxel = map_.point_to_voxel(T_W_C.translation());
  std::uint32_t candidates = 0;
  const std::uint32_t memory_capacity = map_.memory().block_capacity;
  for (std::size_t i = 0; i < found; ++i) {
    const Eigen::Vector3i coords = morton_decode(store_keys_[i]);
    const Eigen::Vector3f p_C = T_C_W * map_.block_centre_W(coords);
    if (!(p_C.z() > 0.0f) || p_C.z() > far_m + block_m) continue;
    const Eigen::Vector2f px = cam.project(p_C);
    // Two blocks' width in pixels: integration's bands reach blocks whose centres lie outside.
    const float m = 2.0f * cam.fx * block_m / std::max(p_C.z(), block_m);
    if (px.x() < -m || px.y() < -m || px.x() > static_cast<float>(cam.width) + m ||
        px.y() > static_cast<float>(cam.height) + m) {
      continue;
    }
    EvictionCandidate& c = eviction_candidates_[candidates++];
    c.rank = block_distance2(coords, camera_voxel);
    c.morton = store_keys_[i];
    if (candidates == memory_capacity) break;
  }
  sort_nearest_first(candidates);
  // Up to the pool's high-water mark only: filling it further would make this frame's eviction
  // send blocks just read back (in view, but not yet updated) out again, frame after frame.
  const std::uint32_t used = map_.memory().blocks_used;
  const std::uint32_t room = evict_high_blocks_ > used ? evict_high_blocks_ - used : 0;
  // What integration may need is kept back: the rest is the read-ahead's.
  const std::uint32_t kept =
      static_cast<std::uint32_t>(static_cast<double>(config_.budget.max_store_reads) *
                                 static_cast<double>(config_.budget.store_read_share_integration));
  const std::uint32_t ahead = config_.budget.max_store_reads - kept;
  const std::uint32_t budget = std::min(room, ahead);
  std::uint32_t restored = 0;
  for (std::uint32_t i = 0; i < candidates; ++i) {
    if (report.read + report.read_failed + report.remapped == budget) {
      report.waiting = candidates - i;
      if (budget == ahead) report.budget_hit = true;
      break;
    }
    const std::uint64_t key = eviction_candidates_[i].morton;
    const Result<std::size_t> size =
        store_->take(key, store_record_, block_record_max_bytes<VoxelT>());
    if (!size.ok()) {
      ++report.read_failed;
      continue;
    }
    report.bytes_read += size.value();
    const Result<std::uint32_t> index = restore_block_record(map_, store_record_, size.value());
    if (index.ok()) {
      ++report.read;
      eviction_indices_[restored++] = index.value();
      keep_finest_read_back(index.value(), key, size.value());
    } else if (index.status().code() == StatusCode::failed_precondition) {
      ++report.remapped;
    } else if (index.status().code() == StatusCode::resource_exhausted) {
      // A pool is full: it stays stored for a later frame.
      store_->release(key);
      report.waiting = candidates - i;
      break;
    } else {
      ++report.read_failed;
    }
  }
  if (restored > 0) map_.propagate_summaries(eviction_indices_, restored);
}

// The first `count` eviction candidates by rank, lowest (nearest) first, ties by key.
template <typename VoxelT>
void Pipeline<VoxelT>::sort_nearest_first(std::uint32_t count) {
  std::sort(eviction_candidates_, eviction_candidates_ + count,
            [](const EvictionCandidate& a, const EvictionCandidate& b) {
              if (a.rank != b.rank) return a.rank < b.rank;
              return a.morton < b.morton;
            });
}

// Stored blocks that this frame's integration is about to allocate (in its list, not in memory:
// they waited after reload_stored(), for room or for their turn, or lay beyond the keys it was
// given) are read back instead, nearest first, within what is left of the frame's read budget. Room
// is no reason to wait here: each takes the slot the new block would have taken, which eviction has
// made. Without this the block would be mapped afresh and its record dropped when its turn came
// (remapped).
template <typename VoxelT>
void Pipeline<VoxelT>::read_back_missing(StoreReport& report) {
  // The budget may be spent already: then the stored blocks among them are only left out.
  const std::uint32_t spent = report.read + report.read_failed + report.remapped;
  const std::uint32_t budget =
      config_.budget.max_store_reads > spent ? config_.budget.max_store_reads - spent : 0;
  const Eigen::Vector3i camera_voxel =
      map_.point_to_voxel(T_W_C_.translation().template cast<float>());
  const std::uint32_t capacity = map_.memory().block_capacity;
  // Every missing block is asked for (a miss costs the store a look-up, not a read): the keys
  // found in view are capped at kStoreKeyCapacity, which a large view's box can exceed.
  std::uint32_t candidates = 0;
  integrator_.for_each_listed_block(
      [&](std::uint64_t morton, const Eigen::Vector3i& coords, std::uint32_t index, int) {
        if (index != kNoIndex || candidates == capacity) return;
        EvictionCandidate& c = eviction_candidates_[candidates++];
        c.rank = block_distance2(coords, camera_voxel);
        c.morton = morton;
      });
  // The same order for any list order (and thread count).
  sort_nearest_first(candidates);
  std::uint32_t restored = 0;
  std::uint32_t reads = 0;
  std::uint32_t tried = 0;
  for (; tried < candidates && reads < budget; ++tried) {
    const std::uint64_t key = eviction_candidates_[tried].morton;
    const Result<std::size_t> size =
        store_->take(key, store_record_, block_record_max_bytes<VoxelT>());
    if (!size.ok()) {
      // Not stored (a new block indeed), or the store failed: mapped afresh.
      if (size.status().code() != StatusCode::out_of_range) {
        ++report.read_failed;
        ++reads;
      }
      continue;
    }
    ++reads;
    report.bytes_read += size.value();
    const Result<std::uint32_t> index = restore_block_record(map_, store_record_, size.value());
    if (index.ok()) {
      ++report.read;
      ++report.read_in_place;
      eviction_indices_[restored++] = index.value();
      keep_finest_read_back(index.value(), key, size.value());
    } else if (index.status().code() == StatusCode::resource_exhausted) {
      store_->release(key);  // a pool is full: the block is mapped afresh, as before
      break;
    } else {
      ++report.read_failed;
    }
  }
  if (restored > 0) map_.propagate_summaries(eviction_indices_, restored);
  report.waiting = report.waiting > restored ? report.waiting - restored : 0;
  if (tried == candidates || reads < budget) return;
  report.budget_hit = true;
  // The stored ones among the rest are left out of this frame: mapped afresh now, their records
  // would be dropped when next read (remapped); left out, they come back in a later frame.
  EvictionCandidate* rest = eviction_candidates_ + tried;
  std::uint32_t held = 0;
  for (std::uint32_t i = tried; i < candidates; ++i) {
    if (store_->holds(eviction_candidates_[i].morton)) rest[held++] = eviction_candidates_[i];
  }
  if (held == 0) return;
  std::sort(rest, rest + held, EvictionCandidate::key_less);
  report.deferred =
      integrator_.leave_out_listed_blocks([rest, held](std::uint64_t morton, std::uint32_t index) {
        EvictionCandidate probe;
        probe.morton = morton;
        return index == kNoIndex &&
               std::binary_search(rest, rest + held, probe, EvictionCandidate::key_less);
      });
}

template <typename VoxelT>
void Pipeline<VoxelT>::apply_deadline(const DeadlineReport& plan) {
  TrackConfig track = tracker_.config();
  for (int level = 0; level < kPyramidLevels; ++level) {
    track.iterations[level] = plan.icp_iterations[level];
  }
  // The plan keeps each level within [floor, configured budget], which the config validated.
  (void)tracker_.set_config(track);
  // Planned budgets never exceed the configured ones (0 = unbounded there).
  auto bounded = [](std::uint64_t configured, std::uint64_t planned) {
    if (planned == 0) return configured;
    return configured == 0 ? planned : std::min(configured, planned);
  };
  raycaster_.set_step_budget(bounded(config_.budget.raycast_steps, plan.raycast_steps));
  raycaster_.set_pixel_stride(plan.raycast_half || config_.budget.raycast_half ? 2 : 1);
  const int allocation_step = config_.fusion.allocation_pixel_step;
  integrator_.set_allocation_pixel_step(plan.allocation_half ? 2 * allocation_step
                                                             : allocation_step);
  if (free_space_.reserved()) {
    free_space_.set_visit_budget(static_cast<std::uint32_t>(
        bounded(config_.free_space.max_node_visits, plan.free_space_visits)));
  }
}

template <typename VoxelT>
FrameObservation Pipeline<VoxelT>::observe_frame(const FrameStats& stats, bool integrated,
                                                 bool carved, bool raycast_done) const {
  FrameObservation o;
  o.timed = clock_.now_us != nullptr;
  o.total_ms = stats.times.total_ms;
  if (stats.track_attempted) {
    o.icp.ran = true;
    o.icp.budget_hit = stats.budget_icp_hit;
    for (int level = 0; level < kPyramidLevels; ++level) {
      o.icp.units += static_cast<double>(stats.track.iterations[level]) *
                     static_cast<double>(working_camera_.width >> level) *
                     static_cast<double>(working_camera_.height >> level);
    }
    o.icp.ms = stats.times.track_ms;
  }
  if (integrated) {
    o.integrate.ran = true;
    o.integrate.budget_hit = stats.integration.budget_hit;
    for (int scale = 0; scale < 4; ++scale) {
      o.integrate.units += static_cast<double>(stats.integration.blocks_per_scale[scale]) *
                           static_cast<double>(block_scale_count(scale));
    }
    o.integrate.ms = stats.times.integrate_ms;
    // A coarsened block saved at most a scale-0 block less a scale-1 one; a skipped one at most
    // a whole block.
    o.integrate.demand = o.integrate.units +
                         static_cast<double>(stats.integration.budget_blocks_coarsened) *
                             static_cast<double>(block_scale_count(0) - block_scale_count(1)) +
                         static_cast<double>(stats.integration.budget_blocks_skipped) *
                             static_cast<double>(block_scale_count(0));
  }
  if (carved) {
    o.free_space.ran = true;
    o.free_space.budget_hit = stats.free_space.budget_hit;
    o.free_space.units = static_cast<double>(stats.free_space.node_visits);
    o.free_space.ms = stats.times.free_space_ms;
  }
  if (raycast_done) {
    o.raycast.ran = true;
    const double pixels =
        static_cast<double>(working_camera_.width) * static_cast<double>(working_camera_.height);
    const double marched = static_cast<double>(stats.raycast.marched_pixels);
    // At half resolution the full cast's demand is not known either.
    o.raycast.budget_hit = stats.raycast.budget_hit() || marched < pixels;
    o.raycast.units = static_cast<double>(stats.raycast.steps);
    o.raycast.ms = stats.times.raycast_ms;
    // The pixels left invalid would have marched as the others did, and at half resolution
    // each unmarched pixel as the marched ones.
    const double reached = pixels - static_cast<double>(stats.raycast.budget_cut_pixels);
    if (reached > 0.0 && marched > 0.0) {
      o.raycast.demand = o.raycast.units * (pixels / reached) * (pixels / marched);
    }
  }
  return o;
}

// A working pixel is beyond the range when every input pixel it covers was measured beyond it.
template <typename VoxelT>
void Pipeline<VoxelT>::downsample_beyond_far() {
  const int factor = config_.preprocess.downsample_factor;
  for (int y = 0; y < working_beyond_far_.height; ++y) {
    std::uint8_t* out = working_beyond_far_.row(y);
    if (factor == 2) {
      // The common case, in a loop the compiler vectorises.
      const std::uint8_t* in0 = input_beyond_far_.row(2 * y);
      const std::uint8_t* in1 = input_beyond_far_.row(2 * y + 1);
      for (int x = 0; x < working_beyond_far_.width; ++x) {
        out[x] =
            static_cast<std::uint8_t>(in0[2 * x] & in0[2 * x + 1] & in1[2 * x] & in1[2 * x + 1]);
      }
      continue;
    }
    for (int x = 0; x < working_beyond_far_.width; ++x) {
      std::uint8_t all = 1;
      for (int dy = 0; dy < factor; ++dy) {
        const std::uint8_t* in = input_beyond_far_.row(factor * y + dy) + factor * x;
        for (int dx = 0; dx < factor; ++dx) all = static_cast<std::uint8_t>(all & in[dx]);
      }
      out[x] = all;
    }
  }
}

// process()'s state between its steps.
template <typename VoxelT>
struct Pipeline<VoxelT>::FrameProgress {
  std::int64_t t_start = 0;
  std::int64_t t_last = 0;          // the clock at the end of the last step
  const int* icp_budget = nullptr;  // this frame's ICP iterations per pyramid level
  bool prior_valid = false;         // a prior was given and kept as plausible
  PoseOrigin origin = PoseOrigin::none;
  FrameResult result = FrameResult::tracked;  // lost: the pose step ended the frame
  bool integrated = false;
  bool carved = false;
  bool raycast_done = false;
};

namespace {
// The integrator's budgets: the configured ones, the deadline's voxel updates where lower.
FusionBudget fusion_budget(const PipelineBudget& configured, const DeadlineReport& plan) {
  FusionBudget budget;
  budget.max_new_blocks = configured.max_new_blocks;
  budget.max_integrated_blocks = configured.max_integrated_blocks;
  budget.max_voxel_updates = configured.max_voxel_updates;
  if (plan.max_voxel_updates > 0) {
    budget.max_voxel_updates = std::min(budget.max_voxel_updates, plan.max_voxel_updates);
  }
  return budget;
}
}  // namespace

template <typename VoxelT>
typename Pipeline<VoxelT>::FrameProgress Pipeline<VoxelT>::start_frame(const DepthFrame& frame) {
  FrameStats& stats = current_;
  stats = FrameStats{};
  stats.frame_index = frame_index_;
  stats.timestamp_us = frame.timestamp_us;
  ++frame_index_;
  FrameProgress progress;
  // The frame deadline's budgets for this frame (the configured ones when it is off).
  stats.deadline = deadline_.plan();
  progress.icp_budget = config_.budget.icp_iterations;
  if (deadline_.active()) apply_deadline(stats.deadline);
  // Without a reference view (the first frame, after reset()) the frame fuses and casts whatever
  // the plan says: a later frame has nothing to track against otherwise.
  if (!have_reference_) {
    stats.deadline.fusion_skipped = false;
    stats.deadline.raycast_skipped = false;
  }
  if (stats.deadline.planned) progress.icp_budget = stats.deadline.icp_iterations;
  (void)team_.take_helper_wait_us();  // waits outside process() are no frame's
  progress.t_start = clock_.now();
  own_error_ = false;
  return progress;
}

template <typename VoxelT>
Status Pipeline<VoxelT>::validate_frame(const DepthFrame& frame, const PosePrior& prior) {
  if (prior.valid && !is_rigid(prior.T_W_C, config_.validator.rigid_tolerance)) {
    own_error_ = true;
    error_.set("pose prior is not finite and rigid (tolerance %g)",
               config_.validator.rigid_tolerance);
    ++priors_rejected_;
    return StatusCode::invalid_argument;
  }
  return validator_.validate(frame, input_depth_m_, &current_.input, input_beyond_far_);
}

// An implausible prior (far away, or too fast since the last one) is dropped, not trusted: the
// frame goes on as if it had none. The next prior is judged against the last kept one.
template <typename VoxelT>
bool Pipeline<VoxelT>::keep_plausible_prior(const DepthFrame& frame, const PosePrior& prior) {
  const Se3d candidate = rigid_from(prior.T_W_C);
  const PriorMotionLimits& limits = config_.prior_motion;
  const double dt_s = static_cast<double>(frame.timestamp_us - last_prior_time_us_) * 1e-6;
  if (prior_position_implausible(candidate, limits) ||
      (have_last_prior_ && prior_motion_implausible(last_prior_T_W_C_, candidate, dt_s, limits))) {
    current_.prior_dropped = true;
    ++priors_dropped_;
    return false;
  }
  last_prior_T_W_C_ = candidate;
  last_prior_time_us_ = frame.timestamp_us;
  have_last_prior_ = true;
  observe_prior_noise(candidate, frame.timestamp_us);
  return true;
}

template <typename VoxelT>
Status Pipeline<VoxelT>::estimate_pose(const DepthFrame& frame, const PosePrior& prior,
                                       FrameProgress& progress) {
  Se3d ground_truth = Se3d::Identity();
  if (frame.has_ground_truth) ground_truth = rigid_from(frame.T_W_C_ground_truth);
  Se3d prior_T_W_C = Se3d::Identity();
  if (progress.prior_valid) prior_T_W_C = rigid_from(prior.T_W_C);
  const bool use_prior =
      progress.prior_valid && (config_.pose_source == PoseSource::external ||
                               config_.pose_source == PoseSource::external_prior);
  current_.has_prior = progress.prior_valid;
  if (!have_reference_) {
    progress.result = FrameResult::first;
    progress.origin = PoseOrigin::initial;
    if (pose_set_) {
      // set_pose() chose it.
    } else if (use_prior) {
      T_W_C_ = prior_T_W_C;
    } else if (config_.initial_pose_from_ground_truth && frame.has_ground_truth) {
      T_W_C_ = ground_truth;
    }
  } else if (config_.pose_source == PoseSource::ground_truth && frame.has_ground_truth) {
    progress.origin = PoseOrigin::ground_truth;
    T_Cprev_C_ = rigid_from((T_W_C_.inverse() * ground_truth).matrix());
    T_W_C_ = ground_truth;
  } else if (config_.pose_source == PoseSource::external) {
    if (!progress.prior_valid) {
      // Nothing to fuse at: lost until a prior comes.
      T_Cprev_C_ = Se3d::Identity();
      ++frames_lost_;
      progress.result = FrameResult::lost;
      return ok_status();
    }
    progress.origin = PoseOrigin::prior;
    T_Cprev_C_ = rigid_from((T_W_C_.inverse() * prior_T_W_C).matrix());
    T_W_C_ = prior_T_W_C;
  } else if (!track_pose(prior_T_W_C, use_prior, progress)) {
    progress.result = FrameResult::lost;
    return current_.track.status;
  }
  // T_W_C_ was set by this frame: its prior is the one the next prediction starts from.
  pose_set_ = false;
  have_prior_prev_ = use_prior;
  if (use_prior) prior_prev_ = prior_T_W_C;
  return ok_status();
}

// track, or external_prior: ICP from a prediction, the prior's own motion when there is one.
template <typename VoxelT>
bool Pipeline<VoxelT>::track_pose(const Se3d& prior_T_W_C, bool use_prior,
                                  FrameProgress& progress) {
  FrameStats& stats = current_;
  const bool predict = use_prior && have_prior_prev_;
  Se3d prediction = Se3d::Identity();
  Se3d estimate = T_W_C_;
  if (predict) {
    prediction = rigid_from((T_W_C_ * prior_prev_.inverse() * prior_T_W_C).matrix());
    estimate = prediction;
  } else if (config_.constant_velocity_prediction) {
    // Compositions drift off SO(3); keep the guess exactly rigid for ICP's checks.
    estimate = rigid_from((T_W_C_ * T_Cprev_C_).matrix());
  }
  stats.has_prediction = predict;
  stats.track_attempted = true;
  const IcpPrior icp_prior = icp_prior_at(prediction);
  const bool pull = predict && (!icp_prior.fixed_information || icp_prior.information_t > 0.0 ||
                                icp_prior.information_r > 0.0);
  stats.track = tracker_.track(preprocessor_.pyramid(), raycaster_.surface_W(), working_camera_,
                               T_W_Cref_, estimate, team_, pull ? &icp_prior : nullptr);
  for (int level = 0; level < kPyramidLevels; ++level) {
    const int budget = progress.icp_budget[level];
    if (budget > 0 && stats.track.iterations[level] >= budget) stats.budget_icp_hit = true;
  }
  if (stats.track.tracked()) {
    last_icp_rms_m_ = stats.track.rms_residual_m;
    estimate = rigid_from(estimate.matrix());
    progress.origin = PoseOrigin::icp;
    if (predict) gate_on_prediction(prediction, estimate, progress.origin);
  } else if (predict) {
    estimate = prediction;  // lost with a prior: fused at the prior, not lost
    progress.origin = PoseOrigin::prior_lost;
  } else {
    T_Cprev_C_ = Se3d::Identity();  // the motion is unknown again
    ++frames_lost_;
    stats.times.track_ms = elapsed_ms(progress.t_last, clock_.now());
    return false;
  }
  T_Cprev_C_ = rigid_from((T_W_C_.inverse() * estimate).matrix());
  T_W_C_ = estimate;
  return true;
}

// What ICP is told about the prediction: the odometry's noise, and ICP's own error as it shows.
template <typename VoxelT>
IcpPrior Pipeline<VoxelT>::icp_prior_at(const Se3d& prediction) const {
  IcpPrior icp_prior;
  icp_prior.T_W_C = prediction;
  const double noise_m = prior_noise_m();
  const double noise_rad = prior_noise_rad();
  icp_prior.sigma_t_m = noise_m;
  icp_prior.sigma_rad = noise_rad;
  icp_prior.icp_noise_floor_m = config_.prior_icp_noise_floor_m;
  icp_prior.icp_pixels_per_sample = config_.prior_icp_pixels_per_sample;
  icp_prior.icp_sigma_m = last_icp_rms_m_;
  for (int a = 0; a < 6; ++a) {
    const double sigma = a < 3 ? noise_m : noise_rad;
    const double excess = prior_gap_sq_C_[a] - kGapSignificance * sigma * sigma;
    icp_prior.icp_error_var_C[a] = excess > 0.0 && excess <= 1.0 ? excess : 0.0;
  }
  icp_prior.fixed_information = config_.prior_fixed_information;
  icp_prior.information_t = config_.prior_information_t;
  icp_prior.information_r = config_.prior_information_r;
  icp_prior.gate_m = config_.prior_gate_m;
  icp_prior.gate_rad = config_.prior_gate_rad;
  return icp_prior;
}

// A tracked pose outside the gate around the prediction is replaced by the prediction; one
// inside it updates the running gaps between ICP and the odometry.
template <typename VoxelT>
void Pipeline<VoxelT>::gate_on_prediction(const Se3d& prediction, Se3d& estimate,
                                          PoseOrigin& origin) {
  FrameStats& stats = current_;
  const Se3d gap = prediction.inverse() * estimate;
  stats.prior_gap_m = gap.translation().norm();
  stats.prior_gap_rad = Eigen::AngleAxisd(gap.linear()).angle();
  if (!(stats.prior_gap_m <= config_.prior_gate_m) ||
      !(stats.prior_gap_rad <= config_.prior_gate_rad)) {
    estimate = prediction;
    origin = PoseOrigin::prior_gate;
    return;
  }
  // How far ICP, on the data alone, and the odometry disagree per camera axis (gated frames
  // excluded; the pulled pose would hide the disagreement it acts on).
  const Se3d data = stats.track.has_data_estimate ? stats.track.T_W_C_data : estimate;
  const Vector6d gap_C = se3_log(rigid_from((prediction.inverse() * data).matrix()));
  const double rate = config_.prior_gap_rate;
  for (int a = 0; a < 6; ++a) {
    prior_gap_sq_C_[a] += rate * (gap_C(a) * gap_C(a) - prior_gap_sq_C_[a]);
  }
}

// Evicts, integrates at the working resolution and carves free space, under the map's guard;
// returns the integration's status.
template <typename VoxelT>
Status Pipeline<VoxelT>::fuse_frame(FrameProgress& progress) {
  FrameStats& stats = current_;
  const FusionBudget budget = fusion_budget(config_.budget, stats.deadline);
  std::int64_t t_integrated = 0;
  std::int64_t t_carved = 0;
  {
    // Queries from other threads wait here, and see the map before or after this frame.
    ExclusiveHold hold(guard_);
    // Stored blocks in view first (they are then not new), then room for exactly the blocks this
    // frame will allocate, then integration.
    read_back_from_ = map_.memory().blocks_used;
    store_keys_found_ = 0;
    if (store_ != nullptr) reload_stored(stats.store);
    // When the room is short, or a store may hold blocks the frame would otherwise map afresh,
    // the integration is done in two parts: the frame's blocks are collected and counted once,
    // and the blocks not allocated yet (after the reads) are what eviction makes room for and
    // what the store is asked for again.
    const ImageView<const float> depth_m = preprocessor_.pyramid().depth_m[0];
    const RoomShort short_of = room_short(budget);
    // Stored blocks in view that reload_stored() left unread (room, budget, its key cap).
    const bool stored_left = store_keys_found_ > stats.store.read;
    const bool two_parts = short_of.blocks || short_of.nodes || stored_left;
    std::uint32_t new_blocks = 0;
    std::uint32_t new_nodes = 0;
    if (two_parts) {
      const IntegrationReport begun =
          integrator_.begin_frame(map_, depth_m, working_camera_, T_W_C_, team_);
      if (short_of.blocks) new_blocks = std::min(begun.blocks_requested, budget.max_new_blocks);
      if (short_of.nodes) new_nodes = count_new_nodes();
    }
    stats.eviction = evict(static_cast<std::uint32_t>(stats.frame_index), new_blocks, new_nodes);
    if (stored_left) read_back_missing(stats.store);
    read_back_from_ = 0xFFFFFFFFu;
    const std::uint64_t node_refusals_before = map_.memory().node_refusals;
    const auto frame_index = static_cast<std::uint32_t>(stats.frame_index);
    stats.integration = two_parts ? integrator_.finish_frame(map_, depth_m, working_camera_, T_W_C_,
                                                             frame_index, budget, team_)
                                  : integrator_.integrate(map_, depth_m, working_camera_, T_W_C_,
                                                          frame_index, budget, team_);
    stats.integration.node_refusals =
        static_cast<std::uint32_t>(map_.memory().node_refusals - node_refusals_before);
    progress.integrated = true;
    t_integrated = clock_.now();
    const Status fused = stats.integration.status;
    // Free space after the TSDF, which takes precedence in its band.
    if (config_.free_space.enabled &&
        (fused.ok() || fused.code() == StatusCode::resource_exhausted)) {
      carve_free_space();
      progress.carved = true;
    }
    ++map_version_;
    t_carved = clock_.now();
  }
  stats.times.integrate_ms = elapsed_ms(progress.t_last, t_integrated);
  stats.times.free_space_ms = elapsed_ms(t_integrated, t_carved);
  progress.t_last = t_carved;
  update_esdf(progress);
  return stats.integration.status;
}

// Step (8): the distance field follows the changed map within its cell budget, outside the
// guard (only this thread writes the map); it publishes under the guard.
template <typename VoxelT>
void Pipeline<VoxelT>::update_esdf(FrameProgress& progress) {
  if (!esdf_.reserved()) return;
  FrameStats& stats = current_;
  if (stats.eviction.evicted > 0 || stats.eviction.demoted > 0) esdf_.mark_all_dirty();
  if (config_.esdf.follow_m > 0.0f) {
    const Eigen::Vector3f camera_W = T_W_C_.translation().cast<float>();
    if ((camera_W - esdf_.target_centre_W()).norm() > config_.esdf.follow_m) {
      esdf_.centre_on(camera_W);
    }
  }
  stats.esdf =
      esdf_.update(map_, free_space_.reserved() ? &free_space_ : nullptr, config_.fusion.mu_m,
                   static_cast<std::uint32_t>(stats.frame_index), map_version_);
  const std::int64_t t_done = clock_.now();
  stats.times.esdf_ms = elapsed_ms(progress.t_last, t_done);
  progress.t_last = t_done;
}

// The free space this frame saw; when its pool runs full, the free space farthest from the camera
// is forgotten to make room for the next frames.
template <typename VoxelT>
void Pipeline<VoxelT>::carve_free_space() {
  FrameStats& stats = current_;
  ImageView<const std::uint8_t> beyond;
  if (stats.input.beyond_far_pixels > 0) {
    downsample_beyond_far();
    beyond = working_beyond_far_;
  }
  const std::uint32_t capacity = free_space_.node_capacity();
  const float min_radius_m = config_.free_space.prune_radius_m > 0.0f
                                 ? config_.free_space.prune_radius_m
                                 : 0.25f * config_.fusion.far_m;
  if (free_store_ != nullptr) {
    // Stored air near the camera or in its view comes back before this frame carves (so the
    // frame clears what it now sees occupied), nearest first, while the pool stays under 7/8
    // full (pruning starts at 15/16).
    RegionReach reach;
    reach.camera_W = T_W_C_.translation().cast<float>();
    reach.R_C_W = T_W_C_.linear().transpose().cast<float>();
    reach.camera = working_camera_;
    reach.radius_m = min_radius_m;
    reach.far_m = config_.validator.far_m;
    free_space_.reload_regions(reach, *free_store_, config_.budget.max_store_reads,
                               capacity - capacity / 8, &stats.free_store);
  }
  stats.free_space = free_space_.carve(preprocessor_.pyramid().depth_m[0], working_camera_, T_W_C_,
                                       static_cast<std::uint32_t>(stats.frame_index), beyond,
                                       config_.validator.far_m);
  const FreeSpaceReport& carved = stats.free_space;
  // The next frame is likely to ask for about what this one did (twice what was refused: a
  // refused node hides the refinement below it). When that does not fit, or the pool is more than
  // 15/16 full, the farthest air goes until the pool has room for it with a quarter to spare:
  // room for at least a quarter of the pool, at most half (a frame's carving is mostly air the
  // pool already holds; a first view alone may ask for most of the pool).
  const std::uint64_t demand =
      std::uint64_t{carved.new_nodes} + carved.far_dropped + 2 * std::uint64_t{carved.pool_refused};
  const std::uint64_t room = std::min<std::uint64_t>(
      capacity / 2, std::max<std::uint64_t>(capacity / 4, demand + demand / 4));
  const std::uint64_t used = free_space_.node_count();
  if (used > capacity - capacity / 16 || used + demand > capacity) {
    const std::uint32_t keep = static_cast<std::uint32_t>(capacity - room);
    stats.free_space.pruned = free_space_.spill_and_prune_to(
        T_W_C_.translation().cast<float>(), keep, min_radius_m, free_store_, &stats.free_store);
    stats.free_space.nodes_used = free_space_.node_count();
    stats.free_space.bytes_used = free_space_.bytes_used();
  }
}

// The reference view the next frame tracks against, guided by the depth just fused from this
// pose: most rays start in the band in front of it.
template <typename VoxelT>
Status Pipeline<VoxelT>::cast_reference_view(FrameProgress& progress) {
  const Result<RaycastStats> raycast =
      raycaster_.raycast(map_, working_camera_, T_W_C_, team_, preprocessor_.pyramid().depth_m[0]);
  if (raycast.ok()) {
    current_.raycast = raycast.value();
    progress.raycast_done = true;
  }
  current_.times.raycast_ms = elapsed_ms(progress.t_last, clock_.now());
  if (!raycast.ok()) return raycast.status();
  T_W_Cref_ = T_W_C_;
  have_reference_ = true;
  view_cast_done_ = false;
  reference_guided_ = true;
  return ok_status();
}

template <typename VoxelT>
Status Pipeline<VoxelT>::cast_view() {
  if (!initialised_) return StatusCode::failed_precondition;
  if (!config_.view_cast) return ok_status();
  view_cast_done_ = false;
  const Result<RaycastStats> view =
      view_raycaster_.raycast(map_, working_camera_, T_W_Cref_, team_, reference_guide_depth_m());
  if (!view.ok()) return view.status();
  view_cast_done_ = true;
  return ok_status();
}

template <typename VoxelT>
Status Pipeline<VoxelT>::finish_frame(const FrameProgress& progress, FrameResult result,
                                      Status status, FrameStats* stats_out) {
  FrameStats& stats = current_;
  stats.result = result;
  stats.pose_origin = progress.origin;
  stats.T_W_C = T_W_C_;
  stats.memory = map_.memory();
  stats.times.total_ms = elapsed_ms(progress.t_start, clock_.now());
  stats.times.helper_wait_ms = static_cast<double>(team_.take_helper_wait_us()) * 1e-3;
  if (deadline_.active()) {
    stats.deadline.over = stats.times.total_ms > stats.deadline.deadline_ms;
    deadline_.observe(
        observe_frame(stats, progress.integrated, progress.carved, progress.raycast_done),
        stats.deadline);
  }
  if (stats_out != nullptr) *stats_out = stats;
  return status;
}

template <typename VoxelT>
Status Pipeline<VoxelT>::process(const DepthFrame& frame, const PosePrior& prior,
                                 FrameStats* stats_out) {
  if (!initialised_) {
    FrameStats stats;
    stats.frame_index = frame_index_;
    stats.timestamp_us = frame.timestamp_us;
    if (stats_out != nullptr) *stats_out = stats;
    return StatusCode::failed_precondition;
  }
  FrameProgress progress = start_frame(frame);
  reference_guided_ = false;

  // 1. Validate and convert to metres; a bad prior rejects the frame before anything changes.
  const Status valid = validate_frame(frame, prior);
  const std::int64_t t_validated = clock_.now();
  current_.times.validate_ms = elapsed_ms(progress.t_start, t_validated);
  if (valid.code() == StatusCode::data_loss) {
    return finish_frame(progress, FrameResult::nearly_empty, valid, stats_out);
  }
  if (!valid.ok()) return finish_frame(progress, FrameResult::rejected, valid, stats_out);
  progress.prior_valid = prior.valid && keep_plausible_prior(frame, prior);

  // 2. Pre-process: working resolution, pyramid of depth, vertices, normals.
  OCTOFUSE_TRY(preprocessor_.process(input_depth_m_, config_.input_camera, team_));
  progress.t_last = clock_.now();
  current_.times.preprocess_ms = elapsed_ms(t_validated, progress.t_last);

  // 3. Pose.
  const Status posed = estimate_pose(frame, prior, progress);
  if (progress.result == FrameResult::lost) {
    return finish_frame(progress, FrameResult::lost, posed, stats_out);
  }
  const std::int64_t t_tracked = clock_.now();
  current_.times.track_ms = elapsed_ms(progress.t_last, t_tracked);
  progress.t_last = t_tracked;

  // 4. Integrate, and carve free space (not on a frame the deadline gave them up on).
  Status integration_status = ok_status();
  if (!current_.deadline.fusion_skipped) integration_status = fuse_frame(progress);
  if (!integration_status.ok() && integration_status.code() != StatusCode::resource_exhausted) {
    return finish_frame(progress, progress.result, integration_status, stats_out);
  }

  // 5. Ray-cast the reference view for the next frame (or track it against the last one).
  if (current_.deadline.raycast_skipped) {
    return finish_frame(progress, progress.result, integration_status, stats_out);
  }
  const Status cast = cast_reference_view(progress);
  if (!cast.ok()) return finish_frame(progress, progress.result, cast, stats_out);
  return finish_frame(progress, progress.result, integration_status, stats_out);
}

template class Pipeline<TsdfVoxel>;
template class Pipeline<MultiresVoxel>;
template class Pipeline<Multires16Voxel>;

}  // namespace octofuse
