#pragma once
// The per-frame loop: validate -> pre-process -> pose -> integrate -> carve free space ->
// ray-cast, over one caller-provided buffer of bytes_required(config) bytes. After init(),
// process() performs no heap allocation and its work is bounded by the budgets in the config.
// lib/README.md describes the loop, the pose sources, the degradation order, eviction and the
// frame deadline.
//
//   PipelineConfig config = ...;
//   std::size_t bytes = bytes_required(config);
//   void* buffer = aligned_alloc(kArenaAlignment, bytes);     // or a static array on a board
//   Pipeline<MultiresVoxel> pipeline;
//   OCTOFUSE_TRY(pipeline.init(buffer, bytes, config, clock));
//   while (source.next(frame) ...) pipeline.process(frame, &stats);
//
// Threading: query() may run on any thread while process() runs on another.

#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/error_text.hpp"
#include "octofuse/core/parallel.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/fusion/fusion_config.hpp"
#include "octofuse/fusion/integrator.hpp"
#include "octofuse/image/depth_pyramid.hpp"
#include "octofuse/map/block_store.hpp"
#include "octofuse/map/octree.hpp"
#include "octofuse/math/camera.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/pipeline/clock.hpp"
#include "octofuse/pipeline/cost_model.hpp"
#include "octofuse/query/esdf.hpp"
#include "octofuse/query/free_space.hpp"
#include "octofuse/query/map_guard.hpp"
#include "octofuse/query/map_query.hpp"
#include "octofuse/render/raycaster.hpp"
#include "octofuse/sensor/depth_frame.hpp"
#include "octofuse/sensor/frame_validator.hpp"
#include "octofuse/track/icp.hpp"

namespace octofuse {

// The voxel type of a pipeline: Pipeline<MultiresVoxel>, Pipeline<TsdfVoxel> and
// Pipeline<Multires16Voxel> (quantised, half the memory; fusion.y_max <= kMultires16MaxWeight).
enum class MapKind : std::uint8_t { multires, single_res, multires16 };

template <typename VoxelT>
constexpr MapKind map_kind_of() {
  if constexpr (std::is_same_v<VoxelT, MultiresVoxel>) return MapKind::multires;
  if constexpr (std::is_same_v<VoxelT, Multires16Voxel>) return MapKind::multires16;
  return MapKind::single_res;
}
// "multires", "single_res" or "multires16".
inline const char* map_kind_name(MapKind kind) {
  return kind == MapKind::multires     ? "multires"
         : kind == MapKind::multires16 ? "multires16"
                                       : "single_res";
}
enum class PoseSource : std::uint8_t { track, ground_truth, external, external_prior };
const char* pose_source_name(PoseSource source);

// A camera-to-world pose for one frame from outside the pipeline (odometry); `valid` false: none.
// It must be finite and rigid within FrameValidatorConfig::rigid_tolerance, as the ground truth.
struct PosePrior {
  bool valid = false;
  Eigen::Matrix4d T_W_C = Eigen::Matrix4d::Identity();
};

struct PipelineBudget {
  std::uint32_t max_new_blocks = 0xFFFFFFFFu;         // per frame
  std::uint32_t max_integrated_blocks = 0xFFFFFFFFu;  // per frame
  std::uint64_t max_voxel_updates = ~std::uint64_t{0};
  std::uint64_t raycast_steps = 0;  // 0 = unbounded
  // The reference ray-cast marches every other pixel in x and y and copies it to the other three
  // (RaycastConfig::pixel_stride 2): a quarter of its work, the model ICP tracks against coarser.
  // On by default: tracking pairs with the marched pixels only, and its accuracy holds on real
  // and synthetic data (lib/README.md, "Half resolution"). A display casts its own view at every
  // pixel (PipelineConfig::view_cast). false: every pixel (the frame deadline may still halve it).
  bool raycast_half = true;
  std::uint32_t max_evictions = 0xFFFFFFFFu;  // blocks evicted per frame (EvictionConfig)
  // With a BlockStore (Pipeline::set_block_store()): records written (evictions beyond wait for
  // the next frame) and read back per frame, step (2) of the degradation order.
  std::uint32_t max_store_writes = 2048;
  std::uint32_t max_store_reads = 512;
  // The share of max_store_reads the view's read-ahead (before tracking) leaves to the stored
  // blocks this frame's integration is about to allocate: a block it needs and the budget leaves
  // unread misses the frame's data (deferred), one the read-ahead does not reach is read when
  // needed. In [0, 1]; 0: the read-ahead may spend it all. Half: on 7-Scenes under 16 MB it left
  // out 3 % of the block-frames the read-ahead spending it all did, and read 22 % less (a
  // quarter: 7 %, 5 % less), with the same tracking (docs/memory.md).
  float store_read_share_integration = 0.5f;
  // Index 0 = finest level. When tracking, at least one level must iterate (init() returns
  // invalid_argument otherwise): no iteration would report every frame tracked, unchecked.
  // The defaults are TrackConfig's (lib/README.md, "Tracking", says why two at the finest level).
  int icp_iterations[kPyramidLevels] = {2, 4, 8};
};

// When to evict blocks (lib/README.md, "Bounded memory"). Marks are fractions of each pool's
// capacity, 0 < low_water < high_water <= 1.
struct EvictionConfig {
  bool enabled = false;
  float high_water = 0.9f;
  float low_water = 0.8f;
  // A view that wants more finest levels than the pool holds takes turns at scale 0: a block in
  // view that fuses at scale 0 keeps a level it got at least this many frames before eviction may
  // take it back for another block (each turn given up is a record written with a finest store).
  // 30 (a second at camera rate): on 7-Scenes under 16 MB half the disk work of 0 for the same
  // surface; 0: turns as short as the marks make them.
  std::uint32_t finest_turn_frames = 30;
};

// What eviction did in one frame.
struct EvictionReport {
  std::uint32_t evicted = 0;      // blocks removed before this frame's integration
  std::uint32_t demoted = 0;      // blocks that gave their finest (and mid) level back
  std::uint32_t demoted_mid = 0;  // of those, blocks kept at scale 2 that gave their mid level back
  bool triggered = false;   // a pool (blocks, finest or mid levels, inner nodes) was above its mark
  bool budget_hit = false;  // max_evictions stopped it above the low-water mark
};

// What the block store did in one frame (Pipeline::set_block_store()).
struct StoreReport {
  std::uint32_t written = 0;        // evicted blocks handed to the store
  std::uint32_t unchanged = 0;      // evicted blocks unchanged since read back: no write needed
  std::uint32_t write_failed = 0;   // ... that it refused (their state is lost)
  std::uint32_t read = 0;           // stored blocks in view read back before integration
  std::uint32_t read_in_place = 0;  // of those, ones the frame would have mapped afresh
  std::uint32_t read_failed = 0;    // damaged records (those blocks are mapped afresh)
  std::uint32_t remapped = 0;       // stored blocks in view already mapped afresh (record dropped)
  std::uint32_t waiting = 0;        // stored blocks in view left for a later frame (budget, room)
  // Stored blocks the frame would have fused, left out of it because the read budget was spent:
  // they are read back and fused from a later frame on instead of mapped afresh (remapped).
  std::uint32_t deferred = 0;
  std::uint64_t bytes_written = 0;
  std::uint64_t bytes_read = 0;
  bool budget_hit = false;  // max_store_reads or max_store_writes bound
  // With a finest-level store (Pipeline::set_finest_store()): records of blocks whose finest
  // level was given up (demoted, or read back demoted into a full pool) handed to it.
  std::uint32_t finest_written = 0;
  std::uint32_t finest_write_failed = 0;  // ... that it refused (that detail is lost)
  std::uint64_t finest_bytes_written = 0;
  // Blocks about to integrate at scale 0 that took their finest level back from it, instead of
  // a fresh interpolated one; damaged or unusable records (a fresh level then); blocks whose
  // record waits for a later frame (the read budget: they integrate at scale 1). With the finest
  // pool full nothing is read (the level would be refused, as a fresh one is).
  std::uint32_t finest_read = 0;
  std::uint32_t finest_read_failed = 0;
  std::uint32_t finest_waiting = 0;
  std::uint64_t finest_bytes_read = 0;
};

// Where a pose prior may plausibly be, and how far it may move between two frames
// (PipelineConfig::prior_motion): no coordinate's magnitude above max_coordinate_m; since the last
// frame's prior at most max_speed_mps times the time between the two frames plus slack_m, and a
// turn of at most max_rate_radps times it plus slack_rad. The defaults are far beyond any robot a
// depth camera maps from (360 km/h, 1700 degrees/s) and catch corrupt or unit-confused odometry:
// a jump of kilometres, coordinates of 1e300.
struct PriorMotionLimits {
  double max_coordinate_m = 1e6;
  double max_speed_mps = 100.0;
  double max_rate_radps = 30.0;
  double slack_m = 0.1;
  double slack_rad = 0.2;
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
  // Free space carved after integration (query/free_space.hpp); its budgets are step (7).
  // node_capacity 0 takes max(map node capacity, block capacity) nodes (40 bytes each);
  // clearance_m 0 takes mu / 2 and occlusion_clear_m 0 takes 4 mu.
  FreeSpaceConfig free_space;
  // Distance field for planners (query/esdf.hpp), updated after carving; its budget is step (8).
  EsdfConfig esdf;
  EvictionConfig eviction;
  // A per-frame time limit the budgets are derived from (0 = off: the budgets above as they are).
  DeadlineConfig deadline;
  int workers = 1;
  // Reserves a second ray-cast at the working resolution (about 25 bytes a pixel) for
  // Pipeline::cast_view(): a display at every pixel while the reference is cast at half.
  bool view_cast = false;
  PoseSource pose_source = PoseSource::track;
  bool initial_pose_from_ground_truth = true;
  // ICP starts from the pose extrapolated with the last tracked motion (constant velocity)
  // instead of the last pose.
  bool constant_velocity_prediction = true;
  Se3d initial_T_W_C = Se3d::Identity();
  // external_prior: ICP's pose loses to the prior's prediction beyond this gap. A camera moved by
  // hand or on a small robot covers at most ~5 cm per frame at 30 Hz; over one frame 1 %/m
  // odometry drift is under a millimetre and converged ICP is within a few millimetres, while ICP
  // that slid along a plane or into another minimum is off by centimetres to its 0.1 m pairing
  // gate. 3 cm and 2 degrees sit between the two.
  double prior_gate_m = 0.03;
  double prior_gate_rad = 0.035;
  // external_prior: how strongly ICP is pulled towards the prediction at its finest level
  // (IcpPrior). By default by the two estimates' uncertainties. The odometry's: its stated error
  // per axis of its relative motion over one frame (camera frame; the sim odometry's 1 mm / 1 mrad
  // white noise per pose is 1.4 mm / 1.4 mrad on a difference of two). ICP's: its normal
  // equations over the last tracked frame's residual variance (at least prior_icp_noise_floor_m
  // squared, times prior_icp_pixels_per_sample pairs per independent sample), or, along a camera
  // axis where the frames so far show it worse than that, what they show: the running mean
  // square of the gap between ICP's pose on the data alone (TrackReport::T_W_C_data, so the pull
  // does not hide the gap it acts on) and the prediction, weight prior_gap_rate per frame, frames
  // within the gate only, less the odometry's stated variance. A view that fixes every direction
  // (the desk: gaps as large as the odometry's noise) then barely moves, while a direction it
  // leaves loose (a plane-only view) or along which ICP slides (the room's walls: gaps across
  // the view twice the odometry's noise) follows the odometry. prior_fixed_information pulls with
  // prior_information_t/_r in the normal equations' units instead, the same every frame (0, 0: not
  // at all; the prediction is then only ICP's starting point and the gate's reference).
  double prior_noise_m = 0.0015;
  double prior_noise_rad = 0.0015;
  // The odometry's noise as it shows, estimated online: a path a camera follows is smooth over
  // four frames, so the third difference of successive priors' positions (and the second of
  // their rotation increments) is their white noise (20 times its variance). Once
  // prior_noise_estimate_frames frames have been seen, the larger of the stated and the seen noise
  // weighs the prior: an odometry noisier than stated cannot outweigh ICP. 0: off.
  int prior_noise_estimate_frames = 20;
  double prior_icp_noise_floor_m = 0.0005;
  double prior_icp_pixels_per_sample = 1.0;
  double prior_gap_rate = 0.1;  // in [0, 1]; 0: ICP's normal equations only
  // A prior beyond these is implausible and dropped for its frame (FrameStats::prior_dropped;
  // the frame is tracked as if it had none).
  PriorMotionLimits prior_motion;
  bool prior_fixed_information = false;
  double prior_information_t = 300.0;  // per m^2, with prior_fixed_information
  double prior_information_r = 300.0;  // per rad^2, with prior_fixed_information
};

// The reference defaults for a camera: QVGA working resolution from VGA, mu = 8
// voxels, near/far 0.4/4 m, a cube of 2^voxel_depth voxels centred on `centre_W`, pools sized for
// `block_capacity` blocks, room for 2^17 blocks touched per frame (2^18 below 5 mm voxels).
PipelineConfig default_pipeline_config(const PinholeCamera& input_camera, float voxel_size_m,
                                       int voxel_depth, std::uint32_t block_capacity,
                                       const Eigen::Vector3f& centre_W);

// ok, or invalid_argument when a part is invalid; `error`, when given, names the setting.
Status validate(const PipelineConfig& config, ErrorText* error = nullptr);

// Bytes init() carves from its buffer for this config (0 if the config is invalid).
std::size_t bytes_required(const PipelineConfig& config);

struct StageTimes {
  double validate_ms = 0.0;
  double preprocess_ms = 0.0;
  double track_ms = 0.0;
  double integrate_ms = 0.0;
  double free_space_ms = 0.0;
  double esdf_ms = 0.0;
  double raycast_ms = 0.0;
  double total_ms = 0.0;
  // Of the above, the calling thread's wait for helpers still on claimed tasks after it ran out of
  // tasks (a helper preempted on a core another program holds); 0 with one worker.
  double helper_wait_ms = 0.0;
};

enum class FrameResult : std::uint8_t {
  tracked,       // pose estimated (or taken from ground truth) and the frame integrated (unless
                 // the deadline gave that up: FrameStats::deadline.fusion_skipped)
  first,         // first frame: pose fixed, integrated
  lost,          // tracking lost: pose kept, nothing integrated
  rejected,      // the frame failed validation: nothing changed
  nearly_empty,  // too few valid pixels: not tracked, not integrated
};
const char* frame_result_name(FrameResult result);

// Where a frame's pose came from.
enum class PoseOrigin : std::uint8_t {
  none,          // no new pose (lost, rejected, nearly empty): the previous one stays
  initial,       // the first frame (or the first after reset())
  icp,           // ICP (in external_prior: within the gate of the prior's prediction)
  ground_truth,  // PoseSource::ground_truth
  prior,         // PoseSource::external: the frame's prior
  prior_gate,    // external_prior: ICP differed from the prediction by more than the gate
  prior_lost,    // external_prior: ICP was lost; fused at the prediction
};
const char* pose_origin_name(PoseOrigin origin);

struct FrameStats {
  std::uint64_t frame_index = 0;  // frames given to process(), from 0
  std::int64_t timestamp_us = 0;
  FrameResult result = FrameResult::rejected;
  StageTimes times;
  FrameReport input;  // validator's pixel counts
  TrackReport track;  // meaningful when a track was attempted
  bool track_attempted = false;
  EvictionReport eviction;        // before integration
  StoreReport store;              // with a block store: reads before eviction, writes in it
  IntegrationReport integration;  // meaningful when integrated
  FreeSpaceReport free_space;     // meaningful when integrated with free space enabled
  FreeStoreReport free_store;     // with a free-space store: regions read before carving, spilled
  EsdfReport esdf;                // meaningful when integrated with the distance field enabled
  RaycastStats raycast;
  bool budget_icp_hit = false;  // ICP stopped by its iteration budget on some level
  DeadlineReport deadline;      // the budgets a frame deadline derived, and what it gave up
  MapMemory memory;
  Se3d T_W_C = Se3d::Identity();
  PoseOrigin pose_origin = PoseOrigin::none;
  bool has_prior = false;       // the frame came with a valid PosePrior
  bool prior_dropped = false;   // ... which was implausible (PipelineConfig::prior_motion), unused
  bool has_prediction = false;  // external_prior: a prediction from the prior was formed
  double prior_gap_m = 0.0;     // |ICP - prediction| translation, when both exist
  double prior_gap_rad = 0.0;   // and rotation angle
  bool any_budget_hit() const {
    return budget_icp_hit || eviction.budget_hit || store.budget_hit || integration.budget_hit ||
           raycast.budget_hit() || free_space.budget_hit || esdf.budget_hit;
  }
};

// Whether a coordinate of `T_W_C`'s position is beyond the limit (false for a NaN: is_rigid()
// catches those).
bool prior_position_implausible(const Se3d& T_W_C, const PriorMotionLimits& limits);
// Whether going from `from` to `to` in `dt_s` seconds (< 0 counts as 0) moves or turns faster
// than the limits allow; *moved_m and *turned_rad (optional) get the motion.
bool prior_motion_implausible(const Se3d& from, const Se3d& to, double dt_s,
                              const PriorMotionLimits& limits, double* moved_m = nullptr,
                              double* turned_rad = nullptr);

template <typename VoxelT>
class Pipeline {
 public:
  using Map = Octree<VoxelT>;

  // Carves everything from `buffer` (kArenaAlignment-aligned, `bytes` >= bytes_required(config))
  // and starts the worker team. invalid_argument: bad config or map kind not matching VoxelT;
  // resource_exhausted: buffer too small. last_error() names what was wrong.
  Status init(void* buffer, std::size_t bytes, const PipelineConfig& config, Clock clock = {});

  // Processes one frame. Returns ok (see stats->result: tracked, first, lost, nearly_empty),
  // invalid_argument (the frame failed validation: last_error() says why; the pipeline is
  // unchanged), resource_exhausted (the map's pool is full: the frame was integrated into what
  // exists; the map is intact), failed_precondition before init(). Never allocates.
  Status process(const DepthFrame& frame, FrameStats* stats) {
    return process(frame, PosePrior{}, stats);
  }
  // The same with the vehicle's pose for this frame (used by the external pose sources; ignored
  // by track and ground_truth). A prior that is not finite and rigid rejects the frame
  // (invalid_argument, nothing changes); one that is implausibly far or fast is dropped (the
  // frame goes on without it, stats->prior_dropped).
  Status process(const DepthFrame& frame, const PosePrior& prior, FrameStats* stats);

  // Writes the pages of the next `blocks` blocks the map's pools hand out (with their finest and
  // mid levels, and as many octree and free-space nodes), so the frames that take them pay no
  // first-touch page faults: the first frame allocates a whole view at once (3 100 blocks at 1 cm
  // on 7-Scenes). Those pages become resident now; the rest of the pools stays untouched. From the
  // thread that calls process(), between frames; allocates nothing, changes no result.
  // failed_precondition before init().
  Status prefault(std::uint32_t blocks);

  // Forgets the map and starts over: the next frame is a first frame. Memory stays reserved,
  // nothing is allocated; the counters (frames given, lost, rejected) keep running and the
  // frame timestamps may start again. failed_precondition before init().
  Status reset();
  // Relocalises: the camera is now at T_W_C. With a map, the reference view is ray-cast again from
  // there, so the next frame tracks against what the map shows from the new pose; before the
  // first frame, the first frame takes this pose. invalid_argument: not finite and rigid;
  // failed_precondition before init().
  Status set_pose(const Se3d& T_W_C);

  const Se3d& T_W_C() const { return T_W_C_; }
  // Evicted blocks go to `store` and come back from it when the camera returns (block_store.hpp);
  // null: evicted blocks are forgotten. failed_precondition without eviction enabled. The store
  // must outlive its use; set it between frames.
  Status set_block_store(BlockStore* store) {
    if (store != nullptr && eviction_candidates_ == nullptr) return StatusCode::failed_precondition;
    store_ = store;
    return ok_status();
  }
  // Finest levels given up to make room (a demoted block, a block read back into a full pool)
  // go to `store` as the block's record at that moment, keyed like the block store's, the newest
  // winning; the block stays in memory at a coarser scale. When such a block is next to
  // integrate at scale 0 it takes its level back from the store (restore_finest_from_record(),
  // then down-propagation of what its coarse levels learned since) instead of a fresh interpolated
  // one, within max_store_reads records a frame (beyond, it waits at scale 1; with the finest
  // pool full it is refused a level as any block is). A map merged with the store (the host port's
  // merge_map_with_store()) does the same for every block, so the map kept on disk holds the detail
  // memory could not. A store of its own, not the block store's. Records written are bounded by
  // max_evictions (demotions count there). null: given-up finest levels are gone.
  // failed_precondition without eviction enabled or for a single-res map. Set it between frames.
  Status set_finest_store(BlockStore* store) {
    if (store != nullptr && (eviction_candidates_ == nullptr || !Map::kSplitFinest)) {
      return StatusCode::failed_precondition;
    }
    finest_store_ = store;
    integrator_.set_finest_source(store != nullptr ? &finest_reader_ : nullptr);
    return ok_status();
  }
  // Free space forgotten to make room goes to `store` by region and comes back from it when the
  // camera returns (FreeOctree::spill_and_prune()); a store of its own, not the block store's.
  // null: forgotten air is gone. failed_precondition without free space. Set it between frames.
  Status set_free_space_store(BlockStore* store) {
    if (store != nullptr && !free_space_.reserved()) return StatusCode::failed_precondition;
    free_store_ = store;
    return ok_status();
  }
  const Map& map() const { return map_; }
  Map& map() { return map_; }
  // The free space carved so far (reserved only when config.free_space.enabled).
  const FreeSpace& free_space() const { return free_space_; }
  // For loading a saved map's free space before the first frame (map/map_io.hpp).
  FreeSpace& free_space() { return free_space_; }
  // Point and region queries over the map and its free space, safe to call from other threads
  // while process() runs (lib/README.md, "Queries"). Valid while the pipeline lives.
  MapQuery<VoxelT> query() const {
    return MapQuery<VoxelT>(map_, config_.free_space.enabled ? &free_space_ : nullptr,
                            config_.fusion.mu_m, &guard_, &map_version_);
  }
  const MapGuard& guard() const { return guard_; }
  // The distance field (reserved only when config.esdf.enabled; answers nothing otherwise), safe
  // to query from other threads while process() runs.
  const EsdfField& esdf() const { return esdf_; }
  // Brings the distance field up to the map now, without its budget (after the last frame).
  EsdfReport flush_esdf() {
    return esdf_.flush(map_, free_space_.reserved() ? &free_space_ : nullptr, config_.fusion.mu_m,
                       static_cast<std::uint32_t>(frame_index_ > 0 ? frame_index_ - 1 : 0),
                       map_version_);
  }
  const PipelineConfig& config() const { return config_; }
  const WorkerTeam& team() const { return team_; }
  // The last reference ray-cast (world frame) and its scale image, at the working resolution;
  // at half resolution (PipelineBudget::raycast_half) each marched pixel fills its 2 x 2.
  ConstSurfaceMap surface_W() const { return raycaster_.surface_W(); }
  ImageView<const std::uint8_t> scale_image() const { return raycaster_.scale_image(); }
  // For display: ray-casts the map from the reference pose at every pixel, without a step budget,
  // into the view cast (PipelineConfig::view_cast), so the reference cast ICP tracks against is
  // left as it was. Guided by the depth the reference was cast with when the last frame cast it
  // (reference_guide_depth_m()), unguided otherwise: a guided view costs about half. Call between
  // frames (it uses the workers); allocates nothing. Without view_cast it casts nothing and the
  // view is the reference cast.
  Status cast_view();
  // The working-resolution depth the last frame fused and cast the reference with; empty when the
  // last frame did not cast it (lost, rejected, a deadline's turn) or after set_pose()/reset().
  ImageView<const float> reference_guide_depth_m() const {
    if (!reference_guided_) return ImageView<const float>();
    return preprocessor_.pyramid().depth_m[0];
  }
  // The view cast_view() made (the reference cast before any, or without view_cast).
  ConstSurfaceMap view_surface_W() const {
    return view_cast_done_ ? view_raycaster_.surface_W() : raycaster_.surface_W();
  }
  ImageView<const std::uint8_t> view_scale_image() const {
    return view_cast_done_ ? view_raycaster_.scale_image() : raycaster_.scale_image();
  }
  const PinholeCamera& working_camera() const { return working_camera_; }
  const Se3d& reference_T_W_C() const { return T_W_Cref_; }
  // The frame deadline's cost model as learnt so far (config().deadline.model before any frame);
  // give it as DeadlineConfig::model to start a later run from it.
  const CostModel& cost_model() const { return deadline_.model(); }
  // The stats of the frame process() is working on, filled stage by stage (each stage's report
  // before the clock is read after it): a clock that models time from work reads them.
  const FrameStats& frame_in_progress() const { return current_; }
  const char* last_error() const { return own_error_ ? error_.c_str() : validator_.last_error(); }
  std::uint64_t frames_lost() const { return frames_lost_; }
  // Frames given to process() (the index the next frame gets).
  std::uint64_t frame_count() const { return frame_index_; }
  // Continues the frame numbering of a loaded map (blocks record the index of the frame that last
  // updated them): the next frame gets index `frames`. failed_precondition before init() or once
  // a frame was processed.
  Status resume_frame_count(std::uint64_t frames);
  std::uint64_t frames_rejected() const { return validator_.frames_rejected() + priors_rejected_; }
  // Priors dropped as implausible (PipelineConfig::prior_motion); their frames were processed.
  std::uint64_t priors_dropped() const { return priors_dropped_; }
  // The odometry's error per axis over one frame of relative motion that weighs the prior now:
  // the stated prior_noise_m / prior_noise_rad, or what the priors' own jitter shows when that is
  // larger (PipelineConfig::prior_noise_estimate_frames).
  double prior_noise_m() const;
  double prior_noise_rad() const;
  std::size_t bytes_used() const { return arena_.bytes_used(); }

 private:
  template <typename Arena>
  Status reserve(Arena& arena, const PipelineConfig& config);
  // Step (2): evicts blocks when a pool is above its high-water mark (see EvictionConfig), or
  // when the frame's `new_blocks` (not yet allocated) or the inner nodes they need (`new_nodes`)
  // would not fit in their pools.
  EvictionReport evict(std::uint32_t frame_index, std::uint32_t new_blocks,
                       std::uint32_t new_nodes);
  // Whether the block pool's room, or the node pool's (each new block can need block_level - 1
  // new inner nodes), could be short of what this frame allocates: then the frame's blocks are
  // collected and counted before eviction (Integrator::begin_frame()).
  struct RoomShort {
    bool blocks = false;
    bool nodes = false;
  };
  RoomShort room_short(const FusionBudget& budget) const;
  // Between Integrator::begin_frame() and finish_frame(): the inner nodes the listed blocks not
  // allocated yet would create, each once (an upper bound when the frame's new-block budget
  // allocates only some of them). Uses eviction_candidates_ as scratch.
  std::uint32_t count_new_nodes();
  // Before step (2): reads back stored blocks in the camera's view (set_block_store()).
  void reload_stored(StoreReport& report);
  // Between Integrator::begin_frame() and finish_frame(): reads back, in their place, the stored
  // blocks the frame would map afresh.
  void read_back_missing(StoreReport& report);
  void sort_nearest_first(std::uint32_t count);
  // With a finest-level store (set_finest_store()): hands it block `index`'s record, its finest
  // level about to be given up (store_record_ is the scratch).
  void keep_finest(std::uint32_t index);
  // ... or the record just read back into store_record_ (`key`, `record_size` bytes) when it
  // held a finest level that block `index` came back without.
  void keep_finest_read_back(std::uint32_t index, std::uint64_t key, std::size_t record_size);
  void put_finest(std::uint64_t key, std::size_t record_size);
  // In step (2): hands the first `count` blocks of eviction_indices_ to the store.
  void spill(std::uint32_t count);
  // Sets the tracker's, ray-caster's and free space's budgets from a deadline plan.
  void apply_deadline(const DeadlineReport& plan);
  // What the finished frame did and took, for the deadline's model.
  FrameObservation observe_frame(const FrameStats& stats, bool integrated, bool carved,
                                 bool raycast_done) const;
  void restart_prior_statistics();
  // process()'s steps, in order, and the state passed between them.
  struct FrameProgress;
  FrameProgress start_frame(const DepthFrame& frame);
  Status validate_frame(const DepthFrame& frame, const PosePrior& prior);
  bool keep_plausible_prior(const DepthFrame& frame, const PosePrior& prior);
  // progress.result lost: the frame ends here with the status returned.
  Status estimate_pose(const DepthFrame& frame, const PosePrior& prior, FrameProgress& progress);
  bool track_pose(const Se3d& prior_T_W_C, bool use_prior, FrameProgress& progress);
  IcpPrior icp_prior_at(const Se3d& prediction) const;
  void gate_on_prediction(const Se3d& prediction, Se3d& estimate, PoseOrigin& origin);
  Status fuse_frame(FrameProgress& progress);
  void carve_free_space();
  void update_esdf(FrameProgress& progress);
  Status cast_reference_view(FrameProgress& progress);
  Status finish_frame(const FrameProgress& progress, FrameResult result, Status status,
                      FrameStats* stats_out);
  friend std::size_t bytes_required(const PipelineConfig& config);

  PipelineConfig config_;
  Clock clock_;
  WorkerTeam team_;
  LinearArena arena_;
  FrameValidator validator_;
  ImageView<float> input_depth_m_;
  // Pixels measured beyond the depth range, at the input and the working resolution (free
  // space's evidence; reserved only with free space on).
  ImageView<std::uint8_t> input_beyond_far_;
  ImageView<std::uint8_t> working_beyond_far_;
  void downsample_beyond_far();
  DepthPreprocessor preprocessor_;
  IcpTracker tracker_;
  Map map_;
  Integrator<VoxelT> integrator_;
  Raycaster<VoxelT> raycaster_;
  Raycaster<VoxelT> view_raycaster_;  // reserved with config.view_cast only
  bool view_cast_done_ = false;       // view_raycaster_ holds the view (cast_view())
  bool reference_guided_ = false;     // this frame cast the reference guided by its own depth
  FreeSpace free_space_;
  EsdfField esdf_;
  DeadlineController deadline_;
  FrameStats current_;
  // Eviction ranking scratch, one entry per block slot (only when eviction is enabled).
  struct EvictionCandidate {
    std::uint64_t rank = 0;  // higher goes first: not recently updated, then squared distance
    std::uint64_t morton = 0;
    std::uint32_t index = 0;
    bool has_finest = false;
    bool has_mid = false;
    bool clean = false;      // read back and unchanged: evicting it writes nothing
    bool turn_kept = false;  // its finest level is within its turn (finest_turn_frames)
    static bool key_less(const EvictionCandidate& a, const EvictionCandidate& b) {
      return a.morton < b.morton;
    }
  };
  EvictionCandidate* eviction_candidates_ = nullptr;
  std::uint32_t* eviction_indices_ = nullptr;
  std::uint8_t* in_frame_ = nullptr;  // per pool index: nonzero while evict() ranks a listed block
  std::uint32_t evict_high_blocks_ = 0;  // marks as block / finest-level counts
  std::uint32_t evict_low_blocks_ = 0;
  std::uint32_t evict_high_finest_ = 0;
  std::uint32_t evict_low_finest_ = 0;
  std::uint32_t evict_high_mid_ = 0;
  std::uint32_t evict_low_mid_ = 0;
  BlockStore* store_ = nullptr;
  BlockStore* free_store_ = nullptr;
  BlockStore* finest_store_ = nullptr;
  // Reads finest levels back from finest_store_ for the integrator.
  class FinestReader final : public FinestLevelSource<VoxelT> {
   public:
    explicit FinestReader(Pipeline* pipeline) : pipeline_(pipeline) {}
    typename FinestLevelSource<VoxelT>::Answer restore(Octree<VoxelT>& map,
                                                       std::uint32_t index) override;

   private:
    Pipeline* pipeline_;
  };
  FinestReader finest_reader_{this};
  std::uint8_t* store_record_ = nullptr;  // one block record (with eviction)
  std::uint64_t* store_keys_ = nullptr;   // kStoreKeyCapacity keys found in view
  std::size_t store_keys_found_ = 0;      // by this frame's reload_stored(), in key order
  // Blocks at this pool index and above were read back by this frame (restored blocks are
  // appended): they are in view, so eviction takes them only after the older ones.
  std::uint32_t read_back_from_ = 0xFFFFFFFFu;
  static constexpr std::size_t kStoreKeyCapacity = 8192;
  std::uint32_t evict_high_nodes_ = 0;  // inner-node marks (nodes go with their last block)
  std::uint32_t evict_low_nodes_ = 0;
  MapGuard guard_;
  std::uint64_t map_version_ = 0;  // frames fused; written under guard_
  PinholeCamera working_camera_;
  Se3d T_W_C_ = Se3d::Identity();
  Se3d T_W_Cref_ = Se3d::Identity();    // pose of the current ray-cast reference
  Se3d T_Cprev_C_ = Se3d::Identity();   // last tracked frame-to-frame motion
  Se3d prior_prev_ = Se3d::Identity();  // the prior of the frame that last set T_W_C_
  bool have_prior_prev_ = false;
  // external_prior: running mean square of ICP's gap to the prediction per camera axis, and the
  // last tracked frame's RMS residual (0: none yet).
  double prior_gap_sq_C_[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  // The odometry's white noise as it shows (PipelineConfig::prior_noise_estimate_frames): the last
  // kept priors and their times (newest last), the running mean of their third differences' norm.
  Se3d prior_history_[4];
  std::int64_t prior_history_us_[4] = {0, 0, 0, 0};
  int prior_history_size_ = 0;
  double prior_jitter_t_m_ = 0.0;
  double prior_jitter_rad_ = 0.0;
  int prior_jitter_samples_ = 0;
  void observe_prior_noise(const Se3d& prior_T_W_C, std::int64_t time_us);
  double last_icp_rms_m_ = 0.0;
  bool have_reference_ = false;
  bool pose_set_ = false;  // set_pose() before the first frame: the first frame keeps it
  std::uint64_t frame_index_ = 0;
  std::uint64_t frames_lost_ = 0;
  std::uint64_t priors_rejected_ = 0;
  std::uint64_t priors_dropped_ = 0;
  // The last frame's prior and timestamp, for the plausibility of the next one's motion.
  Se3d last_prior_T_W_C_ = Se3d::Identity();
  std::int64_t last_prior_time_us_ = 0;
  bool have_last_prior_ = false;
  ErrorText error_;
  bool own_error_ = false;  // last_error() is error_ rather than the validator's
  bool initialised_ = false;
};

extern template class Pipeline<TsdfVoxel>;
extern template class Pipeline<MultiresVoxel>;
extern template class Pipeline<Multires16Voxel>;

}  // namespace octofuse
