#pragma once
// The steps of run_pipeline (runner.cpp), internal to the programs: setup (runner_setup.cpp: the
// output checks, the inputs, the pipeline and its map), the frame loop (runner_loop.cpp) and the
// outputs (runner_outputs.cpp). Each returns 0 or the exit code after printing "error: ...".

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "host_memory.hpp"
#include "live_server.hpp"
#include "looping_source.hpp"
#include "octofuse/pipeline/steady_clock.hpp"
#include "octofuse/ports/host/block_store_file.hpp"
#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"
#include "reload_latency.hpp"
#include "runner.hpp"

#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
#include "octofuse/ports/sim/odometry.hpp"
#endif

namespace octofuse::examples::detail {

std::string join(const std::string& dir, const char* name);
// Creates the folder, or finds it there; false when neither.
bool make_dir(const std::string& path);
// Prints "error: <message>" to stderr; returns 1.
int error_exit(const std::string& message);

// What the run reads before the pipeline exists (setup).
struct RunInputs {
  CostModel deadline_model;  // the deadline's starting model
  std::vector<Eigen::Vector3f> query_points;
  std::unique_ptr<DepthSource> source;
  LoopingSource* looping = nullptr;  // `source`, with RunOptions::loop_source
  PinholeCamera input_camera;        // the source's, or --intrinsics
  std::chrono::steady_clock::time_point start_time;
  bool load_map = false;
  MapFileHeader loaded;  // with --load-map: the saved map's header
  // The vehicle's odometry, mapped so the first frame's pose anchors the world:
  // T_W_C(t) = T_W_C0 * inverse(T_O_C0) * T_O_C(t).
  bool odometry_sim = false;
  std::vector<host::TimedPose> odometry_O;
#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
  sim::DriftingOdometry drifting_odometry;
#endif
  Se3d T_W_O = Se3d::Identity();
};

// The pipeline and its arena; no arena until init_pipeline places the map.
template <typename VoxelT>
struct PipelineRun {
  Pipeline<VoxelT> pipeline;
  std::unique_ptr<AlignedBuffer> buffer;
  const Clock clock = steady_clock();
  std::unique_ptr<host::BlockStoreFile> store;         // --map-file
  std::unique_ptr<host::BlockStoreFile> free_store;    // --map-file's FILE.free (free space on)
  std::unique_ptr<host::BlockStoreFile> finest_store;  // --map-file's FILE.fine (multires)
  // Between the pipeline and `store`: how long blocks wait to be read back.
  std::unique_ptr<ReloadLatencyProbe> store_probe;
};

// What the frame loop leaves for the outputs.
struct LoopResult {
  // Opened with the first frame's pose: a run that fails before it (a port in use, an odometry
  // that starts late, no memory for the map) leaves no output.
  std::unique_ptr<host::TumTrajectoryWriter> trajectory_file;
  std::unique_ptr<LiveServer> server;
  std::uint64_t fused_after_first = 0;
};

// Setup (runner_setup.cpp). Checks every output path, reads the deadline calibration and the
// query points, opens the source, checks its intrinsics and reads --load-map's header.
int open_inputs(const RunOptions& options, RunSummary* summary, RunInputs* inputs);
// Configures the pipeline with its map placed for the first camera pose T_W_C0 (or the loaded
// map's geometry), reserves its arena and initialises it.
template <typename VoxelT>
int init_pipeline(const RunOptions& options, const RunInputs& inputs, const Se3d& T_W_C0,
                  PipelineRun<VoxelT>* run, RunSummary* summary);
// --load-map: initialises the pipeline and reads the saved map (and its free space) into it.
template <typename VoxelT>
int load_saved_map(const RunOptions& options, const RunInputs& inputs, PipelineRun<VoxelT>* run,
                   RunSummary* summary);
// --odometry: the simulated odometry's settings, or the file's poses, checked as the pipeline
// checks each prior.
int read_odometry(const RunOptions& options, RunInputs* inputs);

// The frame loop (runner_loop.cpp): starts the live view, then reads, tracks and fuses frames
// until the source ends, max_frames or a stop; records each frame in the summary.
template <typename VoxelT>
int run_frames(const RunOptions& options, RunInputs* inputs, PipelineRun<VoxelT>* run,
               RunSummary* summary, LoopResult* loop);

// The outputs (runner_outputs.cpp): closes the run and writes what it made (trajectory, queries,
// the map file, odometry, mesh, render, stats); 1 when a write failed.
template <typename VoxelT>
int write_outputs(const RunOptions& options, RunInputs* inputs, PipelineRun<VoxelT>* run,
                  LoopResult* loop, RunSummary* summary);
// Writes --save-map's file; false (with the reason in *error) when it could not.
template <typename VoxelT>
bool save_map_now(const RunOptions& options, const Pipeline<VoxelT>& pipeline, RunSummary* summary,
                  std::string* error, host::BlockStoreFile* store = nullptr,
                  host::BlockStoreFile* free_store = nullptr,
                  host::BlockStoreFile* finest_store = nullptr);
// Meshes the map into `sink`; false when the mesher cannot reserve its memory.
template <typename VoxelT>
bool extract_mesh(const Pipeline<VoxelT>& pipeline, const RunOptions& options,
                  VectorMeshSink* sink);
// The map cast at every pixel from the reference pose (Pipeline::cast_view()), shaded and
// coloured by interpolation scale, as a PNG.
template <typename VoxelT>
bool write_render(Pipeline<VoxelT>& pipeline, const std::string& path, ErrorText* error);

}  // namespace octofuse::examples::detail
