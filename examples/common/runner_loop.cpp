// The frame loop of a run (runner_steps.hpp).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>

#include "esdf_slice.hpp"
#include "octofuse/render/shade.hpp"
#include "runner_steps.hpp"

#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
#include "octofuse/ports/replay/mcap_writer.hpp"
#include "octofuse/ports/replay/ros_messages.hpp"
#endif

namespace octofuse::examples::detail {
namespace {

// Warnings about frames that did not do their part, each kind said once with what to change
// (a long run would otherwise print thousands); the counts are in stats.json and the summary.
struct FrameWarnings {
  static constexpr int kLostReports = 5;
  int lost_reported = 0;
  bool pool_full = false;
  bool finest_full = false;
  bool fusion_budget = false;
  bool raycast_budget = false;
  bool evict_budget = false;
  bool unfused = false;
  bool nodes_full = false;
  bool mid_full = false;
  bool free_space_full = false;
  bool icp_budget_set = false;  // --budget-icp given: the default iterations are no budget

  void after(const FrameStats& s) {
    const unsigned long index = static_cast<unsigned long>(s.frame_index);
    if (s.integration.finest_refusals > 0 && !finest_full) {
      finest_full = true;
      std::fprintf(stderr,
                   "warning: frame %lu: the finest-level pool is full (%u levels): blocks beyond "
                   "it integrate at scale 1 (raise --map-memory for finer detail)\n",
                   index, s.memory.finest_capacity);
    }
    if (s.integration.mid_refusals > 0 && !mid_full) {
      mid_full = true;
      std::fprintf(stderr,
                   "warning: frame %lu: the mid-level pool is full (%u levels): blocks beyond it "
                   "integrate at scale 2 (raise --map-memory for finer detail)\n",
                   index, s.memory.mid_capacity);
    }
    if (s.memory.node_refusals > 0 && !nodes_full) {
      nodes_full = true;
      std::fprintf(stderr,
                   "warning: frame %lu: the inner-node pool is full (%u nodes): blocks that need a "
                   "new node are not mapped (raise --map-memory; node_refusals in stats.json)\n",
                   index, s.memory.node_capacity);
    }
    if (s.free_space.pool_refused > 0 && !free_space_full) {
      free_space_full = true;
      std::fprintf(stderr,
                   "warning: frame %lu: one frame's carving needs more than the whole free-space "
                   "pool: air beyond it is not recorded (free_space_refused in stats.json)\n",
                   index);
    }
    const bool blocks_refused = s.integration.pool_refusals > s.integration.finest_refusals +
                                                                  s.integration.mid_refusals +
                                                                  s.integration.node_refusals;
    if (blocks_refused && !pool_full) {
      pool_full = true;
      std::fprintf(stderr,
                   "warning: frame %lu: the block pool is full (%u blocks): surface it has no room "
                   "for is not mapped (raise --map-memory)\n",
                   index, s.memory.block_capacity);
    }
    if (s.integration.budget_hit && !fusion_budget) {
      fusion_budget = true;
      std::fprintf(stderr,
                   "warning: frame %lu: an integration budget bound (blocks coarsened, skipped or "
                   "not allocated; see budget_hits in stats.json)\n",
                   index);
    }
    if (s.eviction.budget_hit && !evict_budget) {
      evict_budget = true;
      std::fprintf(stderr,
                   "warning: frame %lu: the eviction budget bound (%u blocks evicted, a pool is "
                   "still above its low-water mark)\n",
                   index, s.eviction.evicted);
    }
    if (s.raycast.budget_hit() && !raycast_budget) {
      raycast_budget = true;
      std::fprintf(stderr,
                   "warning: frame %lu: the ray-cast step budget bound (pixels left invalid)\n",
                   index);
    }
    if (s.result == FrameResult::lost && lost_reported <= kLostReports) {
      if (lost_reported++ == kLostReports) {
        std::fprintf(stderr, "warning: more frames lost; counted in the summary and stats.json\n");
        return;
      }
      std::fprintf(
          stderr, "warning: frame %lu lost (%s: %u pixels matched, %.0f%% of the model)%s%s\n",
          index, track_outcome_name(s.track.outcome), s.track.inliers,
          100.0 * static_cast<double>(s.track.inlier_fraction),
          icp_budget_set && s.budget_icp_hit ? "; ICP stopped at its iteration budget" : "",
          s.memory.block_capacity > 0 && s.memory.blocks_used == s.memory.block_capacity
              ? "; the block pool is full"
              : "");
    }
    const bool fused_nothing =
        (s.result == FrameResult::tracked || s.result == FrameResult::first) &&
        s.integration.blocks_integrated == 0;
    if (fused_nothing && !unfused) {
      unfused = true;
      std::fprintf(
          stderr, "warning: frame %lu fused nothing%s\n", index,
          s.integration.rays_outside_cube > 0 ? " (its view lies outside the map's cube)" : "");
    }
  }
};

// Fills the live view's snapshot from the run so far; `rgb` is the reused shading buffer.
template <typename VoxelT>
void fill_snapshot(Pipeline<VoxelT>& pipeline, const RunSummary& summary, long processed,
                   double fps, bool refresh_view, std::vector<Rgb8>* rgb, LiveSnapshot* snapshot) {
  const FrameStats& last = summary.frames.back();
  snapshot->frame = processed;
  snapshot->fps = fps;
  snapshot->tracking = frame_result_name(last.result);
  snapshot->map_bytes_used = last.memory.bytes_used;
  snapshot->map_bytes_reserved = last.memory.bytes_reserved;
  snapshot->blocks_used = last.memory.blocks_used;
  snapshot->block_capacity = last.memory.block_capacity;
  snapshot->stage_ms.clear();
  const std::size_t frames = summary.frames.size();
  const std::size_t first = frames > kLiveHistoryFrames ? frames - kLiveHistoryFrames : 0;
  for (std::size_t i = first; i < frames; ++i) {
    const StageTimes& t = summary.frames[i].times;
    snapshot->stage_ms.push_back(static_cast<float>(t.validate_ms + t.preprocess_ms));
    snapshot->stage_ms.push_back(static_cast<float>(t.track_ms));
    snapshot->stage_ms.push_back(static_cast<float>(t.integrate_ms));
    snapshot->stage_ms.push_back(static_cast<float>(t.raycast_ms));
  }
  snapshot->trajectory_p_W.clear();
  const std::size_t poses = summary.trajectory.size();
  const std::size_t stride = (poses + kLiveTrajectoryPoints - 1) / kLiveTrajectoryPoints;
  for (std::size_t i = 0; i < poses; i += std::max<std::size_t>(stride, 1)) {
    const Eigen::Vector3d p_W = summary.trajectory[i].T_W_C.translation();
    for (int k = 0; k < 3; ++k) snapshot->trajectory_p_W.push_back(static_cast<float>(p_W[k]));
  }
  // The view is cast at every pixel (about what a guided reference cast at every pixel costs),
  // so the image is refreshed less often than the figures.
  if (!refresh_view) return;
  const PinholeCamera& camera = pipeline.working_camera();
  rgb->resize(static_cast<std::size_t>(camera.width) * camera.height);
  ImageView<Rgb8> view(rgb->data(), camera.width, camera.height);
  const Eigen::Vector3f light_W = pipeline.reference_T_W_C().translation().template cast<float>();
  snapshot->width = 0;
  snapshot->height = 0;
  snapshot->rgb.clear();
  if (pipeline.cast_view().ok() &&
      shade_by_scale(pipeline.view_surface_W(), pipeline.view_scale_image(), light_W, view).ok()) {
    snapshot->width = camera.width;
    snapshot->height = camera.height;
    const auto* bytes = reinterpret_cast<const std::uint8_t*>(rgb->data());
    snapshot->rgb.assign(bytes, bytes + rgb->size() * sizeof(Rgb8));
  }
}

// The odometry's pose for this frame as the pipeline's prior (--odometry); the first frame's
// anchors the odometry in the world.
// A pose of the odometry at the frame's time (within half a microsecond, the frames' resolution)
// is taken as it is rather than interpolated, so that an odometry recorded per frame (--record)
// gives back the very poses of the run that recorded it.
bool odometry_at(const std::vector<host::TimedPose>& poses, double t_s, Se3d* T_O_C) {
  constexpr double kSameTime_s = 0.5e-6;
  const auto at =
      std::lower_bound(poses.begin(), poses.end(), t_s - kSameTime_s,
                       [](const host::TimedPose& pose, double t) { return pose.timestamp_s < t; });
  if (at != poses.end() && std::fabs(at->timestamp_s - t_s) <= kSameTime_s) {
    *T_O_C = at->T_W_C;
    return true;
  }
  return host::interpolate_pose(poses, t_s, kOdometryEndTolerance_s, T_O_C);
}

// `as_replayed`: the odometry is being recorded, so the run uses its poses as the recording will
// give them back (through a quaternion). `T_O_C_out`: the odometry's pose of the camera, when it
// has one for this frame.
int odometry_prior(const RunOptions& options, const DepthFrame& frame, long processed,
                   bool as_replayed, RunInputs* inputs, RunSummary* summary, PosePrior* prior,
                   Eigen::Matrix4d* T_O_C_out, bool* have_T_O_C) {
  *have_T_O_C = false;
  const bool odometry_sim = inputs->odometry_sim;
  const std::vector<host::TimedPose>& odometry_O = inputs->odometry_O;
#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
  sim::DriftingOdometry& drifting_odometry = inputs->drifting_odometry;
#endif
  Se3d& T_W_O = inputs->T_W_O;
  if (!options.odometry.empty()) {
    const double t_s = static_cast<double>(frame.timestamp_us) * 1e-6;
    Se3d T_O_C = Se3d::Identity();
    bool have_odometry = false;
    if (odometry_sim) {
      if (!frame.has_ground_truth) {
        return error_exit("--odometry sim needs a source with ground truth");
      }
      Se3d truth = Se3d::Identity();
      truth.matrix() = frame.T_W_C_ground_truth;
#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
      T_O_C = drifting_odometry.next(truth);
      have_odometry = true;
#endif
    } else {
      have_odometry = odometry_at(odometry_O, t_s, &T_O_C);
    }
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
    if (have_odometry && as_replayed) T_O_C.matrix() = replay::pose_as_replayed(T_O_C.matrix());
#else
    (void)as_replayed;
#endif
    if (processed == 0) {
      if (!have_odometry) {
        char text[160];
        std::snprintf(text, sizeof(text),
                      ": does not cover the first frame (t = %.6f s; poses span %.6f to %.6f s)",
                      t_s, odometry_O.front().timestamp_s, odometry_O.back().timestamp_s);
        return error_exit(options.odometry + text);
      }
      Se3d T_W_C0 = options.initial_T_W_C;
      if (!options.have_initial_pose && frame.has_ground_truth) {
        T_W_C0.matrix() = frame.T_W_C_ground_truth;
      }
      T_W_O = T_W_C0 * T_O_C.inverse();
    }
    if (have_odometry) {
      *T_O_C_out = T_O_C.matrix();
      *have_T_O_C = true;
      prior->valid = true;
      prior->T_W_C = (T_W_O * T_O_C).matrix();
      host::TimedPose pose;
      pose.timestamp_s = t_s;
      pose.T_W_C.matrix() = prior->T_W_C;
      summary->odometry.push_back(pose);
    } else {
      ++summary->frames_without_odometry;
    }
  }
  return 0;
}

// What the loop shows as it runs: the live view (snapshots at most 10 times a second, the mesh
// when a browser asks), the status line (RunOptions::live_status) and the progress line.
struct FrameDisplay {
  LiveSnapshot snapshot;
  std::vector<Rgb8> snapshot_rgb;
  std::chrono::steady_clock::time_point last_publish = std::chrono::steady_clock::now();
  long frames_since_publish = 0;
  long frames_since_status = 0;
  std::chrono::steady_clock::time_point last_status = std::chrono::steady_clock::now();
  bool show_progress = false;
  std::chrono::steady_clock::time_point last_slice;  // the distance field's slice, once a second
  std::chrono::steady_clock::time_point last_view;   // the shaded view, twice a second
  EsdfSliceImage slice;
};

// After a frame, a store (--map-file or its FILE.free): what the frame wrote survives a power cut
// from here on, and old versions are reclaimed a little per frame (at most twice what the frame
// wrote plus 256 KiB of copying, so a compaction always catches up with the writes). Each failure
// is warned about once.
void keep_store(host::BlockStoreFile& store, bool wrote, std::uint64_t bytes_written,
                const char* path, const char* what, bool* sync_warned, bool* compact_warned) {
  if (wrote && !store.sync().ok() && !*sync_warned) {
    *sync_warned = true;
    std::fprintf(stderr, "warning: %s: sync failed; the store may lose recent %s\n", path, what);
  }
  ErrorText compact_error;
  const std::size_t compact_budget =
      static_cast<std::size_t>(2 * bytes_written) + (std::size_t{256} << 10);
  if (!store.compact_step(compact_budget, &compact_error).ok() && !*compact_warned) {
    *compact_warned = true;
    std::fprintf(stderr, "warning: %s (the store keeps growing until one succeeds)\n",
                 compact_error.c_str());
  }
}

// The distance field's slice at the camera's height into the snapshot (with --esdf).
template <typename VoxelT>
void fill_slice(const Pipeline<VoxelT>& pipeline, EsdfSliceImage* slice, LiveSnapshot* snapshot) {
  constexpr float kSliceMax_m = 1.0f;
  const MapQuery<VoxelT> query = pipeline.query();
  auto observed = [&](const Eigen::Vector3f& p_W) {
    const Result<PointAnswer> a = query.point(p_W);
    return a.ok() && a.value().state != PointState::unknown &&
           a.value().state != PointState::outside;
  };
  const float z_W = static_cast<float>(pipeline.reference_T_W_C().translation().z());
  esdf_slice(pipeline.esdf(), z_W, kSliceMax_m, observed, slice);
  snapshot->slice_width = slice->width;
  snapshot->slice_height = slice->height;
  snapshot->slice_z_m = slice->z_W;
  snapshot->slice_max_m = kSliceMax_m;
  snapshot->slice_version = pipeline.esdf().published_version();
  snapshot->slice_rgb = slice->rgb;
}

template <typename VoxelT>
int show_frame(const RunOptions& options, Pipeline<VoxelT>& pipeline, const RunSummary& summary,
               long processed, const FrameStats& stats, LiveServer* server, FrameDisplay* display) {
  LiveSnapshot& snapshot = display->snapshot;
  std::vector<Rgb8>& snapshot_rgb = display->snapshot_rgb;
  auto& last_publish = display->last_publish;
  long& frames_since_publish = display->frames_since_publish;
  long& frames_since_status = display->frames_since_status;
  auto& last_status = display->last_status;
  const bool show_progress = display->show_progress;
  if (server != nullptr && server->mesh_requested()) {
    VectorMeshSink sink;
    if (!extract_mesh(pipeline, options, &sink)) return error_exit("cannot reserve the mesher");
    server->publish_mesh(mesh_ply_bytes(sink.positions.empty() ? nullptr : sink.positions[0].data(),
                                        sink.scales.data(), sink.positions.size(),
                                        sink.indices.data(), sink.indices.size() / 3));
  }
  if (server != nullptr) {
    // At most 10 snapshots a second, and a new view (a cast at every pixel) in at most two.
    ++frames_since_publish;
    const auto now = std::chrono::steady_clock::now();
    const double since_s = std::chrono::duration<double>(now - last_publish).count();
    if (since_s >= 0.1) {
      const bool refresh_view =
          std::chrono::duration<double>(now - display->last_view).count() >= 0.5;
      if (refresh_view) display->last_view = now;
      fill_snapshot(pipeline, summary, processed,
                    static_cast<double>(frames_since_publish) / since_s, refresh_view,
                    &snapshot_rgb, &snapshot);
      // A slice costs a point query and a field query a cell (tens of milliseconds).
      if (pipeline.esdf().reserved() &&
          std::chrono::duration<double>(now - display->last_slice).count() >= 1.0) {
        fill_slice(pipeline, &display->slice, &snapshot);
        display->last_slice = now;
      }
      server->publish(snapshot);
      frames_since_publish = 0;
      last_publish = now;
    }
  }
  if (options.live_status) {
    ++frames_since_status;
    const auto now = std::chrono::steady_clock::now();
    const double since_s = std::chrono::duration<double>(now - last_status).count();
    if (since_s >= 1.0) {
      std::printf("%.1f fps  frame %ld  %s  pipeline %.1f ms  blocks %u\n",
                  static_cast<double>(frames_since_status) / since_s, processed,
                  frame_result_name(stats.result), stats.times.total_ms, stats.memory.blocks_used);
      std::fflush(stdout);
      frames_since_status = 0;
      last_status = now;
    }
  }
  if (show_progress) {
    std::fprintf(stderr, "\rframe %5ld  %-8s  pose %-10s  %6.1f ms  blocks %u/%u  ", processed,
                 frame_result_name(stats.result), pose_origin_name(stats.pose_origin),
                 stats.times.total_ms, stats.memory.blocks_used, stats.memory.block_capacity);
  }
  return 0;
}

}  // namespace

template <typename VoxelT>
int run_frames(const RunOptions& options, RunInputs* inputs, PipelineRun<VoxelT>* run,
               RunSummary* summary, LoopResult* loop) {
  std::string error;
  const std::unique_ptr<DepthSource>& source = inputs->source;
  LoopingSource* looping = inputs->looping;
  const bool load_map = inputs->load_map;
  Pipeline<VoxelT>& pipeline = run->pipeline;
  const std::unique_ptr<AlignedBuffer>& buffer = run->buffer;
  std::unique_ptr<host::TumTrajectoryWriter>& trajectory_file = loop->trajectory_file;
  std::unique_ptr<LiveServer>& server = loop->server;
  if (!options.serve.empty()) {
    server = LiveServer::start(options.serve, LiveServerLimits(), &error);
    if (server == nullptr) return error_exit(error);
    std::fprintf(stderr, "live view at %s\n", server->url().c_str());
  }

#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
  replay::McapWriter recorder;
  bool recording = false;
#else
  if (!options.record.empty()) return error_exit("--record needs the replay port in this build");
#endif
  FrameDisplay display;
  display.show_progress = options.progress && ::isatty(STDERR_FILENO);
  DepthFrame frame;
  FrameWarnings warnings;
  bool store_sync_warned = false;
  bool store_compact_warned = false;
  bool store_write_warned = false;
  bool free_store_sync_warned = false;
  bool free_store_compact_warned = false;
  bool free_store_failed_warned = false;
  bool finest_store_sync_warned = false;
  bool finest_store_compact_warned = false;
  bool finest_store_write_warned = false;
  const PipelineBudget default_budget;
  for (int level = 0; level < kPyramidLevels; ++level) {
    warnings.icp_budget_set = warnings.icp_budget_set || options.budget.icp_iterations[level] !=
                                                             default_budget.icp_iterations[level];
  }
  std::uint64_t& fused_after_first = loop->fused_after_first;
  long processed = 0;
  bool have_first_pose = false;
  Se3d first_T_W_C = Se3d::Identity();  // the pose the first frame was given (loop_source)
  int consecutive_failures = 0;
  for (;;) {
    if (options.stop != nullptr && options.stop->load()) break;
    if (options.max_frames >= 0 && processed >= options.max_frames) break;
    const NextFrame next = source->next(frame);
    if (next.outcome == FrameOutcome::end_of_stream) {
      // A recording cut short ends with the cause in last_error().
      if (next.status.code() != StatusCode::end_of_stream) {
        std::fprintf(stderr, "warning: %s\n", source->last_error());
      }
      break;
    }
    if (next.outcome == FrameOutcome::error) {
      return error_exit(options.source_spec + ": " + source->last_error());
    }
    if (next.outcome == FrameOutcome::skip) {
      ++summary->frames_skipped_by_source;
      std::fprintf(stderr, "warning: skipped a frame: %s\n", source->last_error());
      continue;
    }
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
    if (!options.record.empty()) {
      if (!recording) {
        PinholeCamera camera = inputs->input_camera;
        camera.width = frame.depth_raw.width;
        camera.height = frame.depth_raw.height;
        if (!recorder.open(options.record.c_str(), camera, !options.odometry.empty()).ok()) {
          return error_exit(recorder.last_error());
        }
        recording = true;
      }
      // The run uses the ground truth as the recording will give it back (through a quaternion),
      // so that replaying the recording is this run, bit for bit.
      if (frame.has_ground_truth) {
        frame.T_W_C_ground_truth = replay::pose_as_replayed(frame.T_W_C_ground_truth);
      }
    }
#endif
    PosePrior prior;
    Eigen::Matrix4d T_O_C = Eigen::Matrix4d::Identity();
    bool have_T_O_C = false;
    if (const int rc = odometry_prior(options, frame, processed, !options.record.empty(), inputs,
                                      summary, &prior, &T_O_C, &have_T_O_C);
        rc != 0) {
      return rc;
    }
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
    if (recording) {
      if (!recorder.write(frame, have_T_O_C ? &T_O_C : nullptr).ok()) {
        return error_exit(recorder.last_error());
      }
    }
#endif
    if (looping != nullptr && looping->loop_started()) {
      if (options.on_loop_start) options.on_loop_start(looping->loop());
      // The camera is back where the first frame was: without this, tracking would have to
      // bridge the jump from the end of the recording to its start.
      if (have_first_pose && !pipeline.set_pose(first_T_W_C).ok()) {
        return error_exit("cannot relocalise at the start of pass " +
                          std::to_string(looping->loop()) + ": " + pipeline.last_error());
      }
    }
    if (buffer == nullptr) {
      Se3d T_W_C0 = options.initial_T_W_C;
      if (!options.have_initial_pose && frame.has_ground_truth) {
        T_W_C0.matrix() = frame.T_W_C_ground_truth;
      }
      const int rc = init_pipeline(options, *inputs, T_W_C0, run, summary);
      if (rc != 0) return rc;
    }
    if (load_map && processed == 0 && !options.have_initial_pose && !frame.has_ground_truth) {
      return error_exit(options.source_spec +
                        ": no ground truth to place the first frame in the loaded map; give "
                        "--initial-pose tx,ty,tz,qx,qy,qz,qw");
    }

    FrameStats stats;
    if (run->store_probe != nullptr)
      run->store_probe->begin_frame(static_cast<std::uint64_t>(processed));
    const Status status = pipeline.process(frame, prior, &stats);
    if (run->store_probe != nullptr) run->store_probe->end_frame();
    ++processed;
    if (options.on_frame) options.on_frame(stats);
    if (stats.result == FrameResult::rejected) {
      ++summary->frames_rejected;
      std::fprintf(stderr, "warning: frame %lu rejected: %s\n",
                   static_cast<unsigned long>(stats.frame_index), pipeline.last_error());
      if (++consecutive_failures > 100) return error_exit("100 bad frames in a row, giving up");
      continue;
    }
    consecutive_failures = 0;
    if (stats.deadline.over) ++summary->frames_over_deadline;
    if (stats.deadline.fusion_skipped) ++summary->frames_fusion_skipped;
    if (stats.deadline.fusion_skipped && stats.deadline.raycast_skipped) {
      ++summary->frames_track_only;
    }
    if (stats.result == FrameResult::lost) ++summary->frames_lost;
    if (stats.result == FrameResult::nearly_empty) ++summary->frames_nearly_empty;
    if (stats.pose_origin == PoseOrigin::prior_gate) ++summary->frames_prior_gate;
    if (stats.pose_origin == PoseOrigin::prior_lost) ++summary->frames_prior_lost;
    if (stats.prior_dropped && ++summary->priors_dropped <= 5) {
      std::fprintf(stderr,
                   "warning: frame %lu: the odometry's pose is implausibly far or fast; not "
                   "used%s\n",
                   static_cast<unsigned long>(stats.frame_index),
                   summary->priors_dropped == 5 ? " (further such frames are not reported)" : "");
    }
    if (!status.ok() && status.code() != StatusCode::resource_exhausted &&
        status.code() != StatusCode::data_loss && stats.result != FrameResult::lost) {
      return error_exit(std::string("frame processing failed: ") + status.name());
    }
    summary->free_space_refusals += stats.free_space.pool_refused;
    if (run->store != nullptr) {
      StoreReport& t = summary->store_total;
      t.written += stats.store.written;
      t.unchanged += stats.store.unchanged;
      t.write_failed += stats.store.write_failed;
      t.read += stats.store.read;
      t.read_failed += stats.store.read_failed;
      t.remapped += stats.store.remapped;
      t.read_in_place += stats.store.read_in_place;
      t.deferred += stats.store.deferred;
      t.bytes_written += stats.store.bytes_written;
      t.bytes_read += stats.store.bytes_read;
      t.finest_written += stats.store.finest_written;
      t.finest_write_failed += stats.store.finest_write_failed;
      t.finest_bytes_written += stats.store.finest_bytes_written;
      t.finest_read += stats.store.finest_read;
      t.finest_read_failed += stats.store.finest_read_failed;
      t.finest_waiting += stats.store.finest_waiting;
      t.finest_bytes_read += stats.store.finest_bytes_read;
      keep_store(*run->store, stats.store.written > 0, stats.store.bytes_written,
                 options.map_file_path.c_str(), "blocks", &store_sync_warned,
                 &store_compact_warned);
      if (run->finest_store != nullptr) {
        keep_store(*run->finest_store, stats.store.finest_written > 0,
                   stats.store.finest_bytes_written, (options.map_file_path + ".fine").c_str(),
                   "finest levels", &finest_store_sync_warned, &finest_store_compact_warned);
      }
      if (stats.store.finest_write_failed > 0 && !finest_store_write_warned) {
        finest_store_write_warned = true;
        std::fprintf(stderr,
                     "warning: frame %lu: the finest-level store refused %u records (that detail "
                     "is lost; store_finest_write_failed in stats.json)\n",
                     static_cast<unsigned long>(stats.frame_index),
                     stats.store.finest_write_failed);
      }
      if (stats.store.write_failed > 0 && !store_write_warned) {
        store_write_warned = true;
        std::fprintf(stderr,
                     "warning: frame %lu: the block store refused %u blocks (their state is "
                     "lost; store_write_failed in stats.json)\n",
                     static_cast<unsigned long>(stats.frame_index), stats.store.write_failed);
      }
    }
    if (run->free_store != nullptr) {
      FreeStoreReport& t = summary->free_store_total;
      const FreeStoreReport& f = stats.free_store;
      t.written += f.written;
      t.write_failed += f.write_failed;
      t.read += f.read;
      t.read_failed += f.read_failed;
      t.waiting += f.waiting;
      t.merged += f.merged;
      t.bytes_written += f.bytes_written;
      t.bytes_read += f.bytes_read;
      keep_store(*run->free_store, f.written > 0, f.bytes_written,
                 (options.map_file_path + ".free").c_str(), "regions", &free_store_sync_warned,
                 &free_store_compact_warned);
      if ((f.write_failed > 0 || f.read_failed > 0) && !free_store_failed_warned) {
        free_store_failed_warned = true;
        std::fprintf(stderr,
                     "warning: frame %lu: the free-space store failed %u writes and %u reads "
                     "(that air reads unknown; free_store_write_failed and free_store_read_failed "
                     "in stats.json)\n",
                     static_cast<unsigned long>(stats.frame_index), f.write_failed, f.read_failed);
      }
    }
    warnings.after(stats);
    const bool fused = stats.integration.blocks_integrated > 0;
    if ((stats.result == FrameResult::tracked || stats.result == FrameResult::first) && !fused) {
      ++summary->frames_unfused;
    }
    if (stats.result == FrameResult::tracked && fused) ++fused_after_first;
    if (stats.result == FrameResult::first && !have_first_pose) {
      have_first_pose = true;
      first_T_W_C = pipeline.T_W_C();
    }
    ++summary->frames_processed;
    if (options.keep_frame_records) summary->frames.push_back(stats);
    host::TimedPose pose;
    pose.timestamp_s = static_cast<double>(frame.timestamp_us) * 1e-6;
    pose.T_W_C = pipeline.T_W_C();
    if (options.keep_frame_records) summary->trajectory.push_back(pose);
    if (!options.out_dir.empty() && trajectory_file == nullptr) {
      if (!make_dir(options.out_dir)) {
        return error_exit("cannot create output folder " + options.out_dir);
      }
      trajectory_file = std::make_unique<host::TumTrajectoryWriter>();
      const std::string path = join(options.out_dir, "trajectory.txt");
      if (!trajectory_file->open(path.c_str()).ok()) {
        return error_exit(trajectory_file->last_error());
      }
    }
    if (trajectory_file != nullptr && !trajectory_file->append(pose).ok()) {
      return error_exit(trajectory_file->last_error());
    }
    if (options.save_every > 0 && !options.save_map_path.empty() &&
        processed % options.save_every == 0) {
      std::string save_error;
      if (!save_map_now(options, pipeline, summary, &save_error, run->store.get(),
                        run->free_store.get(), run->finest_store.get())) {
        std::fprintf(stderr, "warning: map not saved: %s\n", save_error.c_str());
      }
    }
    if (frame.has_ground_truth && options.keep_frame_records) {
      host::TimedPose truth;
      truth.timestamp_s = pose.timestamp_s;
      truth.T_W_C.matrix() = frame.T_W_C_ground_truth;
      summary->ground_truth.push_back(truth);
    }
    if (options.write_frames && !options.out_dir.empty()) {
      char name[64];
      std::snprintf(name, sizeof(name), "frames/render_%06ld.png", processed - 1);
      ErrorText png_error;
      if ((processed == 1 && !make_dir(join(options.out_dir, "frames"))) ||
          !write_render(pipeline, join(options.out_dir, name), &png_error)) {
        return error_exit("cannot write " + join(options.out_dir, name));
      }
    }
    if (const int rc =
            show_frame(options, pipeline, *summary, processed, stats, server.get(), &display);
        rc != 0) {
      return rc;
    }
  }
  if (display.show_progress) std::fprintf(stderr, "\n");
  if (server != nullptr) {
    std::fprintf(stderr,
                 "live view: %llu answers, %llu connections refused over the cap, %llu timed "
                 "out\n",
                 static_cast<unsigned long long>(server->responses()),
                 static_cast<unsigned long long>(server->refused()),
                 static_cast<unsigned long long>(server->timed_out()));
  }
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
  if (recording) {
    const std::uint64_t recorded = recorder.frames_written();
    if (!recorder.close().ok()) return error_exit(recorder.last_error());
    std::fprintf(stderr, "recorded %llu frames to %s\n", static_cast<unsigned long long>(recorded),
                 options.record.c_str());
  }
#endif
  return 0;
}

template int run_frames<MultiresVoxel>(const RunOptions&, RunInputs*, PipelineRun<MultiresVoxel>*,
                                       RunSummary*, LoopResult*);
template int run_frames<Multires16Voxel>(const RunOptions&, RunInputs*,
                                         PipelineRun<Multires16Voxel>*, RunSummary*, LoopResult*);
template int run_frames<TsdfVoxel>(const RunOptions&, RunInputs*, PipelineRun<TsdfVoxel>*,
                                   RunSummary*, LoopResult*);

}  // namespace octofuse::examples::detail
