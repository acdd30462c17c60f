#pragma once
// The per-frame loop of the paper's section 3: validate -> pre-process -> track -> integrate ->
// carve free space -> ray-cast, over one caller-provided buffer of bytes_required(config) bytes.
// After init(), process() performs no heap allocation and its work is bounded by the budgets in the
// config.
//
//   PipelineConfig config = ...;
//   std::size_t bytes = bytes_required(config);
//   void* buffer = aligned_alloc(kArenaAlignment, bytes);     // or a static array on a board
//   Pipeline<MultiresVoxel> pipeline;
//   OCTOFUSE_TRY(pipeline.init(buffer, bytes, config, clock));
//   while (source.next(frame) ...) pipeline.process(frame, &stats);
//
// Tracking: the first frame fixes the pose (config.initial_T_W_C, or the frame's ground truth when
// config.initial_pose_from_ground_truth); later frames are tracked by ICP against the ray-cast of
// the previous tracked pose, or take the ground truth (PoseSource::ground_truth). When tracking is
// lost the pose stays, nothing is integrated, the reference view is kept, and the next frames try
// again against it (recovery when the view matches again).
//
// Degradation when a budget binds, in this fixed order: (1) ICP does at most the budgeted
// iterations per level; (2) fusion stops allocating new blocks beyond max_new_blocks (farthest
// first); (3) over max_voxel_updates, far blocks integrate one scale coarser, then are skipped;
// (4) beyond max_integrated_blocks the farthest blocks are skipped; (5) ray-casting leaves
// pixels invalid when its step budget runs out; (6) free-space carving stops at its node visit
// and allocation budgets (FreeSpaceConfig), leaving octants it did not reach as they were. Each
// hit is reported in FrameStats.
//
// Queries while mapping: query() answers from any thread while process() runs on another.
// process() holds the map's guard (query/map_guard.hpp) exclusively over integration and carving
// only, and every query holds it shared, so an answer always reflects the map after a whole frame
// (PointAnswer::map_version counts the frames fused), and process() waits for readers at most the
// longest query in flight (bounded by QueryLimits::max_visits, see query/map_query.hpp).

#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/parallel.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/fusion/fusion_config.hpp"
#include "octofuse/fusion/integrator.hpp"
#include "octofuse/image/depth_pyramid.hpp"
#include "octofuse/map/octree.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/pipeline/clock.hpp"
#include "octofuse/query/free_space.hpp"
#include "octofuse/query/map_guard.hpp"
#include "octofuse/query/map_query.hpp"
#include "octofuse/render/raycaster.hpp"
#include "octofuse/sensor/depth_frame.hpp"
#include "octofuse/sensor/frame_validator.hpp"
#include "octofuse/track/icp.hpp"

namespace octofuse {

enum class MapKind : std::uint8_t { multires, single_res };
enum class PoseSource : std::uint8_t { track, ground_truth };

struct PipelineBudget {
  std::uint32_t max_new_blocks = 0xFFFFFFFFu;         // per frame
  std::uint32_t max_integrated_blocks = 0xFFFFFFFFu;  // per frame
  std::uint64_t max_voxel_updates = ~std::uint64_t{0};
  std::uint64_t raycast_steps = 0;                  // 0 = unbounded
  int icp_iterations[kPyramidLevels] = {4, 5, 10};  // index 0 = finest level
};

struct PipelineConfig {
  PinholeCamera input_camera;  // the source's native intrinsics and size
  MapKind map_kind = MapKind::multires;
  MapConfig map;
  FrameValidatorConfig validator;  // near/far also bound fusion and ray-casting
  PreprocessConfig preprocess;
  FusionConfig fusion;
  TrackConfig track;
  PipelineBudget budget;
  // Free space carved after integration (query/free_space.hpp); its budgets are step (6).
  // node_capacity 0 takes max(map node capacity, block capacity) nodes (40 bytes each);
  // clearance_m 0 takes mu / 2 and occlusion_clear_m 0 takes 4 mu.
  FreeSpaceConfig free_space;
  int workers = 1;
  PoseSource pose_source = PoseSource::track;
  bool initial_pose_from_ground_truth = true;
  // ICP starts from the pose extrapolated with the last tracked motion (constant velocity)
  // instead of the last pose.
  bool constant_velocity_prediction = true;
  Se3d initial_T_W_C = Se3d::Identity();
};

// The defaults DESIGN.md section 4 gives for a camera: QVGA working resolution from VGA, mu = 8
// voxels, near/far 0.4/4 m, a cube of 2^voxel_depth voxels centred on `centre_W`, pools sized for
// `block_capacity` blocks, room for 2^17 blocks touched per frame (2^18 below 5 mm voxels).
PipelineConfig default_pipeline_config(const PinholeCamera& input_camera, float voxel_size_m,
                                       int voxel_depth, std::uint32_t block_capacity,
                                       const Eigen::Vector3f& centre_W);

// ok, or invalid_argument naming nothing (see validate() of each part) when a part is invalid.
Status validate(const PipelineConfig& config);

// Bytes init() carves from its buffer for this config (0 if the config is invalid).
std::size_t bytes_required(const PipelineConfig& config);

struct StageTimes {
  double validate_ms = 0.0;
  double preprocess_ms = 0.0;
  double track_ms = 0.0;
  double integrate_ms = 0.0;
  double free_space_ms = 0.0;
  double raycast_ms = 0.0;
  double total_ms = 0.0;
};

enum class FrameResult : std::uint8_t {
  tracked,       // pose estimated (or taken from ground truth) and the frame integrated
  first,         // first frame: pose fixed, integrated
  lost,          // tracking lost: pose kept, nothing integrated
  rejected,      // the frame failed validation: nothing changed
  nearly_empty,  // too few valid pixels: not tracked, not integrated
};
const char* frame_result_name(FrameResult result);

struct FrameStats {
  std::uint64_t frame_index = 0;  // frames given to process(), from 0
  std::int64_t timestamp_us = 0;
  FrameResult result = FrameResult::rejected;
  StageTimes times;
  FrameReport input;  // validator's pixel counts
  TrackReport track;  // meaningful when a track was attempted
  bool track_attempted = false;
  IntegrationReport integration;  // meaningful when integrated
  FreeSpaceReport free_space;     // meaningful when integrated with free space enabled
  RaycastStats raycast;
  bool budget_icp_hit = false;  // ICP stopped by its iteration budget on some level
  MapMemory memory;
  Se3d T_W_C = Se3d::Identity();
  bool any_budget_hit() const {
    return budget_icp_hit || integration.budget_hit || raycast.budget_hit() ||
           free_space.budget_hit;
  }
};

template <typename VoxelT>
class Pipeline {
 public:
  using Map = Octree<VoxelT>;

  // Carves everything from `buffer` (kArenaAlignment-aligned, `bytes` >= bytes_required(config))
  // and starts the worker team. invalid_argument: bad config or map kind not matching VoxelT;
  // resource_exhausted: buffer too small.
  Status init(void* buffer, std::size_t bytes, const PipelineConfig& config, Clock clock = {});

  // Processes one frame. Returns ok (see stats->result: tracked, first, lost, nearly_empty),
  // invalid_argument (the frame failed validation: last_error() says why; the pipeline is
  // unchanged), resource_exhausted (the map's pool is full: the frame was integrated into what
  // exists; the map is intact), failed_precondition before init(). Never allocates.
  Status process(const DepthFrame& frame, FrameStats* stats);

  const Se3d& T_W_C() const { return T_W_C_; }
  const Map& map() const { return map_; }
  Map& map() { return map_; }
  // The free space carved so far (reserved only when config.free_space.enabled).
  const FreeSpace& free_space() const { return free_space_; }
  // Point and region queries over the map and its free space, safe to call from other threads
  // while process() runs (see the top of this file). Valid while the pipeline lives.
  MapQuery<VoxelT> query() const {
    return MapQuery<VoxelT>(map_, config_.free_space.enabled ? &free_space_ : nullptr,
                            config_.fusion.mu_m, &guard_, &map_version_);
  }
  const MapGuard& guard() const { return guard_; }
  const PipelineConfig& config() const { return config_; }
  const WorkerTeam& team() const { return team_; }
  // The last ray-cast (world frame) and its scale image, at the working resolution.
  ConstSurfaceMap surface_W() const { return raycaster_.surface_W(); }
  ImageView<const std::uint8_t> scale_image() const { return raycaster_.scale_image(); }
  const PinholeCamera& working_camera() const { return working_camera_; }
  const Se3d& reference_T_W_C() const { return T_W_Cref_; }
  const char* last_error() const { return validator_.last_error(); }
  std::uint64_t frames_lost() const { return frames_lost_; }
  std::uint64_t frames_rejected() const { return validator_.frames_rejected(); }
  std::size_t bytes_used() const { return arena_.bytes_used(); }

 private:
  template <typename Arena>
  Status reserve(Arena& arena, const PipelineConfig& config);
  friend std::size_t bytes_required(const PipelineConfig& config);

  PipelineConfig config_;
  Clock clock_;
  WorkerTeam team_;
  LinearArena arena_;
  FrameValidator validator_;
  ImageView<float> input_depth_m_;
  DepthPreprocessor preprocessor_;
  IcpTracker tracker_;
  Map map_;
  Integrator<VoxelT> integrator_;
  Raycaster<VoxelT> raycaster_;
  FreeSpace free_space_;
  MapGuard guard_;
  std::uint64_t map_version_ = 0;  // frames fused; written under guard_
  PinholeCamera working_camera_;
  Se3d T_W_C_ = Se3d::Identity();
  Se3d T_W_Cref_ = Se3d::Identity();   // pose of the current ray-cast reference
  Se3d T_Cprev_C_ = Se3d::Identity();  // last tracked frame-to-frame motion
  bool have_reference_ = false;
  std::uint64_t frame_index_ = 0;
  std::uint64_t frames_lost_ = 0;
  bool initialised_ = false;
};

extern template class Pipeline<TsdfVoxel>;
extern template class Pipeline<MultiresVoxel>;

}  // namespace octofuse
