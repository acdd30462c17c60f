#pragma once
// Runs the pipeline over a source and writes the files octofuse-replay documents into a folder:
// trajectory.txt (TUM), mesh.ply, render.png, stats.json, stage_times.svg (and odometry.txt with
// --odometry). Shared by octofuse-replay, octofuse-live and octofuse-bench.

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "octofuse/mesh/mesher.hpp"
#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"
#include "reload_latency.hpp"
#include "sources.hpp"

namespace octofuse::examples {

// --threads' default: the machine's cores (std::thread::hardware_concurrency()), in [1, 64] (the
// pipeline's range). The results are the same for any count.
int default_thread_count();

struct RunOptions {
  std::string source_spec = "sim:desk";
  SourceOptions source;
  std::string out_dir;  // empty: write nothing
  MapKind map_kind = MapKind::multires;
  float voxel_size_m = 0.01f;
  float mu_m = 0.0f;                                           // 0: 8 voxels
  float band_behind_mu = 1.0f;                                 // FusionConfig::behind_mu
  int allocation_step = FusionConfig{}.allocation_pixel_step;  // --allocation-step
  float allocation_group_block_px =
      FusionConfig{}.allocation_group_block_px;  // --allocation-group-px
  float map_size_m = 8.0f;  // cube side (rounded up to a power of two of voxels)
  long max_frames = -1;     // stop after this many frames; -1 = the whole source
  int threads = default_thread_count();
  PoseSource pose_source = PoseSource::track;
  // --odometry: a TUM trajectory file, or "sim[:drift=..,noise=..,seed=..]" for a drifting noisy
  // odometry of the source's ground truth; empty: none. Used as the pose prior.
  std::string odometry;
  // --record FILE.mcap: the frames the pipeline receives, written as a ROS 2 bag; empty: none.
  std::string record;
  bool odometry_only = false;        // --odometry-mode only: fuse at the odometry, no ICP
  bool odometry_mode_given = false;  // --odometry-mode was given (it needs --odometry)
  double odometry_information[2] = {-1.0, -1.0};  // --odometry-weight T,R; < 0: not given
  double odometry_noise[2] = {-1.0, -1.0};        // --odometry-noise M,R; <= 0: the defaults
  std::uint32_t max_blocks = 0;   // block pool capacity; 0 = from voxel size and map memory
  float map_memory_mb = 1024.0f;  // used when max_blocks is 0
  // Blocks whose pool pages are written before the first frame (Pipeline::prefault): a view's
  // worth at 1 cm, so the first frame pays no first-touch page faults. 0: none.
  std::uint32_t prefault_blocks = 8192;
  PipelineBudget budget;
  // --deadline-ms: a per-frame time limit the budgets are derived from (0 = off); the cost model
  // starts from --deadline-calibration FILE when it exists and is written back to it after the
  // run, unless --deadline-freeze keeps it fixed (then FILE must exist, and results repeat).
  double deadline_ms = 0.0;
  std::string deadline_calibration;
  bool deadline_freeze = false;
  // --evict: on by default in the programs, so a memory cap bounds the map instead of tracking.
  EvictionConfig eviction = {true, 0.9f, 0.8f, 30};
  bool bilateral = false;
  float icp_depth_knee_m = -1.0f;  // < 0: the library's default
  bool icp_quarter = false;        // TrackConfig::finest_level_quarter_on_half_model
  bool icp_full_middle = false;    // !TrackConfig::middle_level_checkerboard
  bool write_mesh = true;
  MeshReadScale mesh_read_scale = MeshReadScale::current;
  bool write_frames = false;      // frames/render_NNNNNN.png after every frame
  bool free_space = true;         // carve free space (PipelineConfig::free_space.enabled)
  bool free_space_exact = false;  // FreeSpaceConfig::exact_silhouettes
  bool esdf = false;              // PipelineConfig::esdf.enabled (--query-points answers use it)
  float esdf_follow_m = 0.0f;     // PipelineConfig::esdf.follow_m (--esdf-follow)
  // --query-points FILE: answered against the final map into DIR/queries.txt (empty: none).
  std::string query_points_path;
  // Called with the final multires map's queries before the run returns (benchmarks).
  std::function<void(const MapQuery<MultiresVoxel>&)> inspect_final_map;
  // Called with the pipeline's config before init (benchmarks that vary a setting).
  std::function<void(PipelineConfig*)> adjust_config;
  // Replays the source pass after pass (LoopingSource) until max_frames. Each pass after the first
  // starts where the first did, so the pipeline is relocalised (Pipeline::set_pose) to the pose
  // it gave the first frame before that pass's first frame: the camera is back on its dock.
  bool loop_source = false;
  // Called after every frame given to the pipeline (rejected ones too: see stats.result), and,
  // with loop_source, before the first frame of each pass after the first (benchmarks: soak).
  std::function<void(const FrameStats&)> on_frame;
  std::function<void(int loop)> on_loop_start;
  // false: RunSummary keeps no per-frame record (frames, trajectory, ground truth, so no ATE), and
  // a long run's memory does not grow with its length. Needs out_dir empty (stats.json is made
  // from those records).
  bool keep_frame_records = true;
  bool keep_mesh = false;    // keep the mesh in RunSummary (for evaluation)
  bool progress = true;      // a progress line on stderr when it is a terminal
  bool live_status = false;  // once a second on stdout: frame rate and tracking state
  std::string serve;         // "ADDR:PORT": live view in a browser (live_server.hpp); empty: off
  const std::atomic<bool>* stop = nullptr;  // set from a signal handler to end early
  // Maps: --save-map writes the map at the end (also when stopped) and, with --save-every N,
  // after every N processed frames; --load-map starts from a saved map (its voxel type, voxel
  // size, mu and cube replace --map, --voxel-size, --mu and --map-size).
  std::string save_map_path;
  long save_every = 0;
  std::string load_map_path;
  // --map-file: evicted blocks go to this store and come back when the camera returns.
  std::string map_file_path;
  bool map_file_finest = true;  // --map-file-finest: FILE.fine beside it (multires maps)
  // --initial-pose: the first frame's pose (camera to world) instead of the source's ground truth.
  bool have_initial_pose = false;
  Se3d initial_T_W_C = Se3d::Identity();
};

struct RunSummary {
  std::uint64_t frames_processed = 0;  // processed, not rejected (frames.size() when kept)
  std::vector<FrameStats> frames;
  std::vector<host::TimedPose> trajectory;     // one per processed frame
  std::vector<host::TimedPose> ground_truth;   // where the source had it
  std::uint64_t frames_skipped_by_source = 0;  // FrameOutcome::skip
  std::uint64_t frames_dropped_by_source = 0;  // DepthSource::frames_dropped(): never delivered
  std::uint64_t frames_rejected = 0;
  std::uint64_t frames_lost = 0;
  std::uint64_t frames_nearly_empty = 0;
  std::vector<host::TimedPose> odometry;      // the prior given to each frame (world frame)
  std::uint64_t frames_without_odometry = 0;  // outside the odometry's time span
  std::uint64_t frames_prior_gate = 0;        // PoseOrigin::prior_gate
  std::uint64_t frames_prior_lost = 0;        // PoseOrigin::prior_lost
  std::uint64_t priors_dropped = 0;           // implausible priors the pipeline did not use
  // The odometry's noise per frame that weighed the prior at the end: the stated one or, when
  // larger, what the odometry's jitter showed (Pipeline::prior_noise_m/_rad).
  double odometry_noise_m = 0.0;
  double odometry_noise_rad = 0.0;
  bool have_odometry_ate = false;
  double odometry_ate_rmse_m = 0.0;
  bool have_ate = false;
  double ate_rmse_m = 0.0;
  double ate_max_m = 0.0;
  std::size_t arena_bytes = 0;
  MapMemory map_memory;
  std::size_t free_space_bytes = 0;       // free-space nodes in use at the end
  std::uint64_t free_space_refusals = 0;  // free-space nodes refused, the pool full
  // With --map-file: the store's totals (StoreReport summed) and its file at the end.
  StoreReport store_total;
  std::uint64_t store_file_bytes = 0;
  std::uint64_t store_keys = 0;
  std::uint64_t store_live_bytes = 0;   // the newest record of every block
  std::uint64_t store_compactions = 0;  // finished in this run
  ReloadLatency store_reload_latency;   // frames stored blocks waited to be read back
  // With --map-file and free space: the free-space store (FILE.free), as above.
  FreeStoreReport free_store_total;
  std::uint64_t finest_store_file_bytes = 0;  // --map-file's FILE.fine
  std::uint64_t finest_store_keys = 0;
  std::uint64_t free_store_file_bytes = 0;
  std::uint64_t free_store_keys = 0;
  std::size_t mesh_vertices = 0;
  std::size_t mesh_triangles = 0;
  std::vector<Eigen::Vector3f> mesh_positions;  // with keep_mesh
  std::vector<std::uint32_t> mesh_indices;
  double wall_s = 0.0;
  std::uint64_t frames_unfused = 0;        // tracked (or ground truth) but nothing integrated
  std::vector<std::string> files_written;  // names in out_dir, once each is complete on disk
  // Why the run did not produce what it claims (most frames lost or rejected, nothing fused after
  // the first frame); empty when it did. The outputs are still written, for diagnosis.
  std::string failure;
  bool map_loaded = false;  // with --load-map: its blocks and save time
  std::uint32_t map_loaded_blocks = 0;
  std::uint32_t map_loaded_free_nodes = 0;  // 0: none in the file, or free space off
  double map_load_s = 0.0;
  std::uint32_t map_saves = 0;  // files written by --save-map (periodic and final)
  double map_last_save_s = 0.0;
  std::uint64_t map_file_bytes = 0;  // size of the last map file written
  // With --deadline-ms: the cost model at the end of the run (what --deadline-calibration saves),
  // and the frames whose process() time exceeded the deadline.
  CostModel deadline_model;
  std::uint64_t frames_over_deadline = 0;
  std::uint64_t frames_fusion_skipped = 0;  // the deadline's depth not fused (incl. track-only)
  std::uint64_t frames_track_only = 0;      // neither fused nor cast
  bool deadline_calibration_loaded = false;
};

// 0 when the outputs were written (check summary->failure too); otherwise prints "error: ..."
// and returns the exit code.
int run_pipeline(const RunOptions& options, RunSummary* summary);

// Median, p90, p99, max and mean of a sample (sorted copy); zeros for an empty one.
struct Percentiles {
  double median = 0.0, p90 = 0.0, p99 = 0.0, max = 0.0;
  double mean = 0.0;  // sets the sustained frame rate, where the median shows a typical frame
};
Percentiles percentiles(std::vector<double> values);

// Frames up to this far before the first or after the last odometry pose take that end pose;
// further out they get no prior (no extrapolation).
inline constexpr double kOdometryEndTolerance_s = 0.02;

// "current" or "finest" (the --mesh-scale values); false for anything else.
bool parse_mesh_read_scale(const std::string& text, MeshReadScale* scale);

// --map's values: "multires", "single" and "multires16" (also stats.json's summary "map").
const char* map_option_name(MapKind kind);
// False for any other text.
bool parse_map_option(const std::string& text, MapKind* kind);

}  // namespace octofuse::examples
