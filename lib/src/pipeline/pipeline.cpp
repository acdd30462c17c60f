#include "octofuse/pipeline/pipeline.hpp"

#include <algorithm>
#include <cmath>
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

namespace {
constexpr float kSmallVoxel_m = 0.005f;
}  // namespace

PipelineConfig default_pipeline_config(const PinholeCamera& input_camera, float voxel_size_m,
                                       int voxel_depth, std::uint32_t block_capacity,
                                       const Eigen::Vector3f& centre_W) {
  PipelineConfig c;
  c.input_camera = input_camera;
  // Nodes: at most one per 2 blocks in practice (8 children, shared upper levels); keep slack.
  const std::uint32_t node_capacity = block_capacity / 2 + 1024;
  c.map = MapConfig::centred(centre_W, voxel_size_m, voxel_depth, block_capacity, node_capacity);
  // Recorded poses are often printed with few digits (7-Scenes: R^T R off by 4e-4); 1e-3 still
  // rejects anything that is not a rotation.
  c.validator.rigid_tolerance = 1e-3;
  c.fusion.mu_m = 8.0f * voxel_size_m;
  // Below 5 mm a far view touches more than 2^17 distinct blocks (2 mm sim:desk: up to 146k);
  // each extra 2^17 of per-frame capacity costs the integrator about 14 MB.
  if (voxel_size_m < kSmallVoxel_m) c.fusion.max_blocks_per_frame = 1u << 18;
  c.fusion.near_m = c.validator.near_m;
  c.fusion.far_m = c.validator.far_m;
  return c;
}

Status validate(const PipelineConfig& config) {
  if (!config.input_camera.valid()) return StatusCode::invalid_argument;
  OCTOFUSE_TRY(validate(config.map));
  OCTOFUSE_TRY(validate(config.fusion));
  OCTOFUSE_TRY(validate(config.free_space));
  if (!config.preprocess.valid() || !config.track.valid()) return StatusCode::invalid_argument;
  if (config.workers < 1 || config.workers > 64) return StatusCode::invalid_argument;
  for (int level = 0; level < kPyramidLevels; ++level) {
    if (config.budget.icp_iterations[level] < 0) return StatusCode::invalid_argument;
  }
  if (!is_rigid(config.initial_T_W_C.matrix(), config.validator.rigid_tolerance)) {
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

namespace {
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
  OCTOFUSE_TRY(raycaster_.reserve(arena, raycast));
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
  OCTOFUSE_TRY(validate(config));
  const MapKind expected =
      std::is_same_v<VoxelT, MultiresVoxel> ? MapKind::multires : MapKind::single_res;
  if (config.map_kind != expected) return StatusCode::invalid_argument;
  if (buffer == nullptr || reinterpret_cast<std::uintptr_t>(buffer) % kArenaAlignment != 0) {
    return StatusCode::invalid_argument;
  }
  arena_ = LinearArena(buffer, bytes);
  OCTOFUSE_TRY(reserve(arena_, config));
  OCTOFUSE_TRY(validator_.init(config.input_camera, config.validator));
  config_ = config;
  clock_ = clock;
  team_ = WorkerTeam(config.workers);
  working_camera_ = config.input_camera.downsampled(config.preprocess.downsample_factor);
  T_W_C_ = rigid_from(config.initial_T_W_C.matrix());
  T_W_Cref_ = T_W_C_;
  T_Cprev_C_ = Se3d::Identity();
  have_reference_ = false;
  frame_index_ = 0;
  frames_lost_ = 0;
  map_version_ = 0;
  initialised_ = true;
  return ok_status();
}

template <typename VoxelT>
Status Pipeline<VoxelT>::process(const DepthFrame& frame, FrameStats* stats_out) {
  FrameStats stats;
  stats.frame_index = frame_index_;
  stats.timestamp_us = frame.timestamp_us;
  if (!initialised_) {
    if (stats_out != nullptr) *stats_out = stats;
    return StatusCode::failed_precondition;
  }
  ++frame_index_;
  const std::int64_t t_start = clock_.now();

  // 1. Validate and convert to metres.
  const Status valid = validator_.validate(frame, input_depth_m_, &stats.input);
  const std::int64_t t_validated = clock_.now();
  stats.times.validate_ms = elapsed_ms(t_start, t_validated);
  auto finish = [&](FrameResult result, Status status) {
    stats.result = result;
    stats.T_W_C = T_W_C_;
    stats.memory = map_.memory();
    stats.times.total_ms = elapsed_ms(t_start, clock_.now());
    if (stats_out != nullptr) *stats_out = stats;
    return status;
  };
  if (valid.code() == StatusCode::data_loss) return finish(FrameResult::nearly_empty, valid);
  if (!valid.ok()) return finish(FrameResult::rejected, valid);

  // 2. Pre-process: working resolution, pyramid of depth, vertices, normals.
  OCTOFUSE_TRY(preprocessor_.process(input_depth_m_, config_.input_camera, team_));
  const std::int64_t t_preprocessed = clock_.now();
  stats.times.preprocess_ms = elapsed_ms(t_validated, t_preprocessed);

  // 3. Pose.
  Se3d ground_truth = Se3d::Identity();
  if (frame.has_ground_truth) ground_truth = rigid_from(frame.T_W_C_ground_truth);
  FrameResult result = FrameResult::tracked;
  if (!have_reference_) {
    result = FrameResult::first;
    if (config_.initial_pose_from_ground_truth && frame.has_ground_truth) T_W_C_ = ground_truth;
  } else if (config_.pose_source == PoseSource::ground_truth && frame.has_ground_truth) {
    T_Cprev_C_ = rigid_from((T_W_C_.inverse() * ground_truth).matrix());
    T_W_C_ = ground_truth;
  } else {
    Se3d estimate = T_W_C_;
    if (config_.constant_velocity_prediction) {
      // Compositions drift off SO(3); keep the guess exactly rigid for ICP's checks.
      estimate = rigid_from((T_W_C_ * T_Cprev_C_).matrix());
    }
    stats.track_attempted = true;
    stats.track = tracker_.track(preprocessor_.pyramid(), raycaster_.surface_W(), working_camera_,
                                 T_W_Cref_, estimate, team_);
    for (int level = 0; level < kPyramidLevels; ++level) {
      const int budget = config_.budget.icp_iterations[level];
      if (budget > 0 && stats.track.iterations[level] >= budget) stats.budget_icp_hit = true;
    }
    if (stats.track.tracked()) {
      estimate = rigid_from(estimate.matrix());
      T_Cprev_C_ = rigid_from((T_W_C_.inverse() * estimate).matrix());
      T_W_C_ = estimate;
    } else {
      T_Cprev_C_ = Se3d::Identity();  // the motion is unknown again
      ++frames_lost_;
      stats.times.track_ms = elapsed_ms(t_preprocessed, clock_.now());
      return finish(FrameResult::lost, stats.track.status);
    }
  }
  const std::int64_t t_tracked = clock_.now();
  stats.times.track_ms = elapsed_ms(t_preprocessed, t_tracked);

  // 4. Integrate at the working resolution.
  FusionBudget budget;
  budget.max_new_blocks = config_.budget.max_new_blocks;
  budget.max_integrated_blocks = config_.budget.max_integrated_blocks;
  budget.max_voxel_updates = config_.budget.max_voxel_updates;
  std::int64_t t_integrated = 0;
  std::int64_t t_carved = 0;
  {
    // Queries from other threads wait here, and see the map before or after this frame.
    ExclusiveHold hold(guard_);
    stats.integration =
        integrator_.integrate(map_, preprocessor_.pyramid().depth_m[0], working_camera_, T_W_C_,
                              static_cast<std::uint32_t>(stats.frame_index), budget, team_);
    t_integrated = clock_.now();
    const Status fused = stats.integration.status;
    // 4b. Free space seen by this frame (after the TSDF, which takes precedence in its band).
    if (config_.free_space.enabled &&
        (fused.ok() || fused.code() == StatusCode::resource_exhausted)) {
      stats.free_space = free_space_.carve(preprocessor_.pyramid().depth_m[0], working_camera_,
                                           T_W_C_, static_cast<std::uint32_t>(stats.frame_index));
    }
    ++map_version_;
    t_carved = clock_.now();
  }
  stats.times.integrate_ms = elapsed_ms(t_tracked, t_integrated);
  stats.times.free_space_ms = elapsed_ms(t_integrated, t_carved);
  const Status integration_status = stats.integration.status;
  if (!integration_status.ok() && integration_status.code() != StatusCode::resource_exhausted) {
    return finish(result, integration_status);
  }

  // 5. Ray-cast the reference view for the next frame.
  // Guided by the depth just fused from this pose: most rays start in the band in front of it.
  const Result<RaycastStats> raycast =
      raycaster_.raycast(map_, working_camera_, T_W_C_, team_, preprocessor_.pyramid().depth_m[0]);
  stats.times.raycast_ms = elapsed_ms(t_carved, clock_.now());
  if (!raycast.ok()) return finish(result, raycast.status());
  stats.raycast = raycast.value();
  T_W_Cref_ = T_W_C_;
  have_reference_ = true;
  return finish(result, integration_status);
}

template class Pipeline<TsdfVoxel>;
template class Pipeline<MultiresVoxel>;

}  // namespace octofuse
