#pragma once
// Runs the pipeline over a source and writes the main program's outputs into a folder:
// trajectory.txt (TUM), mesh.ply, render.png, stats.json, stage_times.svg. Shared by
// octofuse-replay, octofuse-live and octofuse-bench.

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "octofuse/mesh/mesher.hpp"
#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"
#include "sources.hpp"

namespace octofuse::examples {

struct RunOptions {
  std::string source_spec = "sim:desk";
  SourceOptions source;
  std::string out_dir;  // empty: write nothing
  MapKind map_kind = MapKind::multires;
  float voxel_size_m = 0.01f;
  float mu_m = 0.0f;        // 0: 8 voxels
  float map_size_m = 8.0f;  // cube side (rounded up to a power of two of voxels)
  long max_frames = -1;     // stop after this many frames; -1 = the whole source
  int threads = 1;
  PoseSource pose_source = PoseSource::track;
  std::uint32_t max_blocks = 0;   // block pool capacity; 0 = from voxel size and map memory
  float map_memory_mb = 1024.0f;  // used when max_blocks is 0
  PipelineBudget budget;
  bool bilateral = false;
  float icp_depth_knee_m = -1.0f;  // < 0: the library's default
  bool write_mesh = true;
  MeshReadScale mesh_read_scale = MeshReadScale::current;
  bool write_frames = false;  // frames/render_NNNNNN.png after every frame
  bool keep_mesh = false;     // keep the mesh in RunSummary (for evaluation)
  bool progress = true;       // a progress line on stderr when it is a terminal
  bool live_status = false;   // once a second on stdout: frame rate and tracking state
  std::string serve;          // "ADDR:PORT": live view in a browser (live_server.hpp); empty: off
  const std::atomic<bool>* stop = nullptr;  // set from a signal handler to end early
};

struct RunSummary {
  std::vector<FrameStats> frames;
  std::vector<host::TimedPose> trajectory;     // one per processed frame
  std::vector<host::TimedPose> ground_truth;   // where the source had it
  std::uint64_t frames_skipped_by_source = 0;  // FrameOutcome::skip
  std::uint64_t frames_rejected = 0;
  std::uint64_t frames_lost = 0;
  std::uint64_t frames_nearly_empty = 0;
  bool have_ate = false;
  double ate_rmse_m = 0.0;
  double ate_max_m = 0.0;
  std::size_t arena_bytes = 0;
  MapMemory map_memory;
  std::size_t mesh_vertices = 0;
  std::size_t mesh_triangles = 0;
  std::vector<Eigen::Vector3f> mesh_positions;  // with keep_mesh
  std::vector<std::uint32_t> mesh_indices;
  double wall_s = 0.0;
};

// 0 on success; otherwise prints "error: ..." and returns the exit code.
int run_pipeline(const RunOptions& options, RunSummary* summary);

// Median, p90, p99, max and mean of a sample (sorted copy); zeros for an empty one.
struct Percentiles {
  double median = 0.0, p90 = 0.0, p99 = 0.0, max = 0.0;
  double mean = 0.0;  // sets the sustained frame rate, where the median shows a typical frame
};
Percentiles percentiles(std::vector<double> values);

// "current" or "finest" (the --mesh-scale values); false for anything else.
bool parse_mesh_read_scale(const std::string& text, MeshReadScale* scale);

}  // namespace octofuse::examples
