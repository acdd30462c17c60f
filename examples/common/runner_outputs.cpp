// The outputs of a run (runner_steps.hpp): trajectory, queries, map file, odometry, mesh, render
// and stats.
#include <sys/stat.h>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <string>
#include <utility>

#include "deadline_calibration.hpp"
#include "octofuse/ports/host/json_writer.hpp"
#include "octofuse/ports/host/ply.hpp"
#include "octofuse/ports/host/png_writer.hpp"
#include "octofuse/ports/host/trajectory_eval.hpp"
#include "octofuse/render/shade.hpp"
#include "query_points.hpp"
#include "runner_steps.hpp"
#include "stage_plot.hpp"

namespace octofuse::examples::detail {
namespace {

// The finest-level store's figures of a frame or of the run (the same keys in both).
void write_finest_store_keys(host::JsonWriter& json, const StoreReport& r) {
  json.key("store_finest_written").value(static_cast<std::uint64_t>(r.finest_written));
  json.key("store_finest_write_failed").value(static_cast<std::uint64_t>(r.finest_write_failed));
  json.key("store_finest_bytes_written").value(r.finest_bytes_written);
  json.key("store_finest_read").value(static_cast<std::uint64_t>(r.finest_read));
  json.key("store_finest_read_failed").value(static_cast<std::uint64_t>(r.finest_read_failed));
  json.key("store_finest_waiting").value(static_cast<std::uint64_t>(r.finest_waiting));
  json.key("store_finest_bytes_read").value(r.finest_bytes_read);
}

void write_frame_json(host::JsonWriter& json, const FrameStats& s) {
  json.begin_object();
  json.key("index").value(s.frame_index);
  json.key("timestamp_us").value(s.timestamp_us);
  json.key("result").value(frame_result_name(s.result));
  json.key("tracked").value(s.result == FrameResult::tracked || s.result == FrameResult::first);
  json.key("pose").value(pose_origin_name(s.pose_origin));
  json.key("prior").value(s.has_prior);
  if (s.prior_dropped) json.key("prior_dropped").value(true);
  if (s.has_prediction && s.track_attempted) {
    json.key("prior_gap_m").value(s.prior_gap_m);
    json.key("prior_gap_rad").value(s.prior_gap_rad);
  }
  json.key("ms").begin_object();
  json.key("validate").value(s.times.validate_ms);
  json.key("preprocess").value(s.times.preprocess_ms);
  json.key("track").value(s.times.track_ms);
  json.key("integrate").value(s.times.integrate_ms);
  json.key("free_space").value(s.times.free_space_ms);
  json.key("raycast").value(s.times.raycast_ms);
  json.key("total").value(s.times.total_ms);
  json.key("helper_wait").value(s.times.helper_wait_ms);
  json.end_object();
  json.key("valid_pixels").value(static_cast<std::uint64_t>(s.input.valid_pixels));
  if (s.track_attempted) {
    json.key("icp").begin_object();
    json.key("outcome").value(track_outcome_name(s.track.outcome));
    json.key("iterations").begin_array();
    for (int level = 0; level < kPyramidLevels; ++level) json.value(s.track.iterations[level]);
    json.end_array();
    json.key("rms_m").value(static_cast<double>(s.track.rms_residual_m));
    json.key("inlier_fraction").value(static_cast<double>(s.track.inlier_fraction));
    json.end_object();
  }
  json.key("blocks_allocated").value(static_cast<std::uint64_t>(s.integration.blocks_allocated));
  json.key("blocks_integrated").value(static_cast<std::uint64_t>(s.integration.blocks_integrated));
  json.key("blocks_per_scale").begin_array();
  for (int i = 0; i < 4; ++i) {
    json.value(static_cast<std::uint64_t>(s.integration.blocks_per_scale[i]));
  }
  json.end_array();
  json.key("voxels_updated").value(s.integration.voxels_updated);
  json.key("blocks_evicted").value(static_cast<std::uint64_t>(s.eviction.evicted));
  json.key("blocks_demoted").value(static_cast<std::uint64_t>(s.eviction.demoted));
  json.key("blocks_demoted_mid").value(static_cast<std::uint64_t>(s.eviction.demoted_mid));
  json.key("pool_refusals").value(static_cast<std::uint64_t>(s.integration.pool_refusals));
  json.key("node_refusals").value(static_cast<std::uint64_t>(s.integration.node_refusals));
  json.key("mid_refusals").value(static_cast<std::uint64_t>(s.integration.mid_refusals));
  json.key("free_space_refused").value(static_cast<std::uint64_t>(s.free_space.pool_refused));
  json.key("store_written").value(static_cast<std::uint64_t>(s.store.written));
  json.key("store_unchanged").value(static_cast<std::uint64_t>(s.store.unchanged));
  json.key("store_write_failed").value(static_cast<std::uint64_t>(s.store.write_failed));
  json.key("store_read").value(static_cast<std::uint64_t>(s.store.read));
  json.key("store_read_in_place").value(static_cast<std::uint64_t>(s.store.read_in_place));
  json.key("store_read_failed").value(static_cast<std::uint64_t>(s.store.read_failed));
  json.key("store_remapped").value(static_cast<std::uint64_t>(s.store.remapped));
  json.key("store_waiting").value(static_cast<std::uint64_t>(s.store.waiting));
  json.key("store_deferred").value(static_cast<std::uint64_t>(s.store.deferred));
  json.key("store_bytes_written").value(s.store.bytes_written);
  json.key("store_bytes_read").value(s.store.bytes_read);
  write_finest_store_keys(json, s.store);
  json.key("free_store_written").value(static_cast<std::uint64_t>(s.free_store.written));
  json.key("free_store_merged").value(static_cast<std::uint64_t>(s.free_store.merged));
  json.key("free_store_write_failed").value(static_cast<std::uint64_t>(s.free_store.write_failed));
  json.key("free_store_read").value(static_cast<std::uint64_t>(s.free_store.read));
  json.key("free_store_read_failed").value(static_cast<std::uint64_t>(s.free_store.read_failed));
  json.key("free_store_waiting").value(static_cast<std::uint64_t>(s.free_store.waiting));
  json.key("free_store_bytes_written").value(s.free_store.bytes_written);
  json.key("free_store_bytes_read").value(s.free_store.bytes_read);
  json.key("keys_dropped").value(static_cast<std::uint64_t>(s.integration.keys_dropped));
  json.key("raycast_steps").value(s.raycast.steps);
  json.key("raycast_valid_pixels").value(static_cast<std::uint64_t>(s.raycast.valid_pixels));
  json.key("raycast_guided_pixels").value(static_cast<std::uint64_t>(s.raycast.guided_pixels));
  json.key("raycast_guide_fallbacks")
      .value(static_cast<std::uint64_t>(s.raycast.guide_fallback_pixels));
  json.key("raycast_miss_skipped").value(static_cast<std::uint64_t>(s.raycast.miss_skipped_pixels));
  json.key("raycast_guided_misses").value(static_cast<std::uint64_t>(s.raycast.guided_misses));
  json.key("budget_hits").begin_object();
  json.key("icp").value(s.budget_icp_hit);
  json.key("evict").value(s.eviction.budget_hit);
  json.key("fusion").value(s.integration.budget_hit);
  json.key("raycast").value(s.raycast.budget_hit());
  json.key("free_space").value(s.free_space.budget_hit);
  json.end_object();
  json.key("free_space_visits").value(static_cast<std::uint64_t>(s.free_space.node_visits));
  json.key("free_space_nodes").value(static_cast<std::uint64_t>(s.free_space.nodes_used));
  json.key("free_space_pruned").value(static_cast<std::uint64_t>(s.free_space.pruned));
  json.key("free_space_far_dropped").value(static_cast<std::uint64_t>(s.free_space.far_dropped));
  json.key("blocks_used").value(static_cast<std::uint64_t>(s.memory.blocks_used));
  if (s.deadline.active) {
    // What the frame deadline derived and what the frame gave up for it (budgets 0: configured).
    const DeadlineReport& d = s.deadline;
    json.key("deadline").begin_object();
    json.key("over").value(d.over);
    json.key("planned").value(d.planned);
    json.key("infeasible").value(d.infeasible);
    json.key("cut_to").value(deadline_step_name(d.deepest));
    json.key("predicted_ms").value(d.predicted_ms);
    json.key("icp_iterations").begin_array();
    for (const int iterations : d.icp_iterations) json.value(iterations);
    json.end_array();
    json.key("icp_iterations_given_up").value(d.icp_iterations_given_up);
    json.key("max_voxel_updates").value(d.max_voxel_updates);
    json.key("raycast_steps").value(d.raycast_steps);
    json.key("raycast_half_resolution").value(d.raycast_half);
    json.key("allocation_half").value(d.allocation_half);
    json.key("allocation_rays").value(static_cast<std::uint64_t>(s.integration.allocation_rays));
    json.key("free_space_visits").value(static_cast<std::uint64_t>(d.free_space_visits));
    json.key("blocks_coarsened")
        .value(static_cast<std::uint64_t>(s.integration.budget_blocks_coarsened));
    json.key("blocks_skipped")
        .value(static_cast<std::uint64_t>(s.integration.budget_blocks_skipped));
    json.key("raycast_pixels_cut").value(static_cast<std::uint64_t>(s.raycast.budget_cut_pixels));
    json.key("fusion_skipped").value(d.fusion_skipped);
    json.key("raycast_skipped").value(d.raycast_skipped);
    json.end_object();
  }
  json.end_object();
}

std::uint64_t file_size(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 ? static_cast<std::uint64_t>(st.st_size) : 0;
}

// Reports a write that failed after the frame loop; the run goes on to write every other output.
struct LateFailures {
  int count = 0;
  void operator()(const std::string& message) {
    std::fprintf(stderr, "error: %s\n", message.c_str());
    ++count;
  }
};

// The ATE of the trajectory and of the odometry against the ground truth, where there is enough.
void evaluate_trajectories(RunSummary* summary) {
  if (summary->ground_truth.size() >= 3 &&
      summary->ground_truth.size() == summary->trajectory.size()) {
    ErrorText ate_error;
    const Result<host::AteResult> ate =
        host::compute_ate(summary->trajectory, summary->ground_truth, 1e-3, &ate_error);
    if (ate.ok()) {
      summary->have_ate = true;
      summary->ate_rmse_m = ate.value().translation_m.rmse;
      summary->ate_max_m = ate.value().translation_m.max;
    }
  }

  if (summary->odometry.size() >= 3 && !summary->ground_truth.empty()) {
    ErrorText ate_error;
    const Result<host::AteResult> ate =
        host::compute_ate(summary->odometry, summary->ground_truth, 1e-3, &ate_error);
    if (ate.ok()) {
      summary->have_odometry_ate = true;
      summary->odometry_ate_rmse_m = ate.value().translation_m.rmse;
    }
  }
}

// What the run claims: most frames gave a pose from tracking, and tracking fused new views.
void judge_run(std::uint64_t fused_after_first, RunSummary* summary) {
  const std::uint64_t frames_read =
      summary->frames_processed + summary->frames_rejected + summary->frames_skipped_by_source;
  const std::uint64_t frames_failed =
      summary->frames_lost + summary->frames_rejected + summary->frames_skipped_by_source;
  if (frames_read >= 2 && 2 * frames_failed > frames_read) {
    summary->failure = std::to_string(frames_failed) + " of " + std::to_string(frames_read) +
                       " frames lost, rejected or unreadable (" +
                       std::to_string(summary->frames_lost) + " lost, " +
                       std::to_string(summary->frames_rejected) + " rejected, " +
                       std::to_string(summary->frames_skipped_by_source) + " unreadable)";
  } else if (summary->frames_processed >= 2 && fused_after_first == 0) {
    summary->failure = "nothing was fused after the first frame (" +
                       std::to_string(summary->frames_processed) + " frames)";
  }
}

// stats.json (every frame, the summary, the deadline's model) and stage_times.svg.
void write_stats(const RunOptions& options, MapKind map_kind, RunSummary* summary,
                 LateFailures& late_failure) {
  host::JsonWriter json;
  json.begin_object();
  json.key("frames").begin_array();
  for (const FrameStats& s : summary->frames) write_frame_json(json, s);
  json.end_array();
  std::vector<double> totals, track, integrate, raycast, preprocess, free_space;
  for (const FrameStats& s : summary->frames) {
    totals.push_back(s.times.total_ms);
    free_space.push_back(s.times.free_space_ms);
    track.push_back(s.times.track_ms);
    integrate.push_back(s.times.integrate_ms);
    raycast.push_back(s.times.raycast_ms);
    preprocess.push_back(s.times.validate_ms + s.times.preprocess_ms);
  }
  const Percentiles total = percentiles(totals);
  json.key("summary").begin_object();
  json.key("source").value(options.source_spec.c_str());
  json.key("map").value(map_option_name(map_kind));
  json.key("voxel_size_m").value(static_cast<double>(options.voxel_size_m));
  json.key("threads").value(options.threads);
  json.key("frames").value(static_cast<std::uint64_t>(summary->frames.size()));
  json.key("frames_lost").value(summary->frames_lost);
  json.key("frames_rejected").value(summary->frames_rejected);
  json.key("frames_skipped_by_source").value(summary->frames_skipped_by_source);
  json.key("frames_dropped_by_source").value(summary->frames_dropped_by_source);
  json.key("frames_nearly_empty").value(summary->frames_nearly_empty);
  json.key("frames_unfused").value(summary->frames_unfused);
  if (!options.odometry.empty()) {
    json.key("pose_source").value(options.odometry_only ? "external" : "external_prior");
    json.key("frames_without_odometry").value(summary->frames_without_odometry);
    json.key("frames_prior_gate").value(summary->frames_prior_gate);
    json.key("frames_prior_lost").value(summary->frames_prior_lost);
    json.key("priors_dropped").value(summary->priors_dropped);
    json.key("odometry_noise_m").value(summary->odometry_noise_m);
    json.key("odometry_noise_rad").value(summary->odometry_noise_rad);
    if (summary->have_odometry_ate) {
      json.key("odometry_ate_rmse_m").value(summary->odometry_ate_rmse_m);
    }
  }
  json.key("total_ms").begin_object();
  json.key("median").value(total.median);
  json.key("p90").value(total.p90);
  json.key("p99").value(total.p99);
  json.key("max").value(total.max);
  json.end_object();
  json.key("median_ms").begin_object();
  json.key("preprocess").value(percentiles(preprocess).median);
  json.key("track").value(percentiles(track).median);
  json.key("integrate").value(percentiles(integrate).median);
  json.key("raycast").value(percentiles(raycast).median);
  json.key("free_space").value(percentiles(free_space).median);
  json.end_object();
  json.key("arena_bytes").value(static_cast<std::uint64_t>(summary->arena_bytes));
  json.key("map_bytes_reserved")
      .value(static_cast<std::uint64_t>(summary->map_memory.bytes_reserved));
  json.key("map_bytes_used").value(static_cast<std::uint64_t>(summary->map_memory.bytes_used));
  json.key("pool_blocks_used").value(static_cast<std::uint64_t>(summary->map_memory.blocks_used));
  json.key("pool_block_capacity")
      .value(static_cast<std::uint64_t>(summary->map_memory.block_capacity));
  json.key("pool_finest_used").value(static_cast<std::uint64_t>(summary->map_memory.finest_used));
  json.key("pool_finest_capacity")
      .value(static_cast<std::uint64_t>(summary->map_memory.finest_capacity));
  json.key("pool_mid_used").value(static_cast<std::uint64_t>(summary->map_memory.mid_used));
  json.key("pool_mid_capacity").value(static_cast<std::uint64_t>(summary->map_memory.mid_capacity));
  json.key("blocks_evicted").value(summary->map_memory.evicted);
  json.key("pool_refusals").value(summary->map_memory.refusals);
  json.key("node_refusals").value(summary->map_memory.node_refusals);
  json.key("mid_refusals").value(summary->map_memory.mid_refusals);
  json.key("nodes_evicted").value(summary->map_memory.nodes_evicted);
  json.key("free_space_refusals").value(summary->free_space_refusals);
  json.key("store_written").value(static_cast<std::uint64_t>(summary->store_total.written));
  json.key("store_unchanged").value(static_cast<std::uint64_t>(summary->store_total.unchanged));
  json.key("store_write_failed")
      .value(static_cast<std::uint64_t>(summary->store_total.write_failed));
  json.key("store_read").value(static_cast<std::uint64_t>(summary->store_total.read));
  json.key("store_read_in_place")
      .value(static_cast<std::uint64_t>(summary->store_total.read_in_place));
  json.key("store_read_failed").value(static_cast<std::uint64_t>(summary->store_total.read_failed));
  json.key("store_remapped").value(static_cast<std::uint64_t>(summary->store_total.remapped));
  json.key("store_deferred").value(static_cast<std::uint64_t>(summary->store_total.deferred));
  json.key("store_bytes_written").value(summary->store_total.bytes_written);
  json.key("store_bytes_read").value(summary->store_total.bytes_read);
  write_finest_store_keys(json, summary->store_total);
  json.key("store_finest_file_bytes").value(summary->finest_store_file_bytes);
  json.key("store_finest_keys").value(summary->finest_store_keys);
  json.key("store_file_bytes").value(summary->store_file_bytes);
  json.key("store_keys").value(summary->store_keys);
  json.key("store_live_bytes").value(summary->store_live_bytes);
  json.key("store_compactions").value(summary->store_compactions);
  json.key("store_reload_latency");
  write_reload_latency_json(json, summary->store_reload_latency);
  const FreeStoreReport& free_total = summary->free_store_total;
  json.key("free_store_written").value(static_cast<std::uint64_t>(free_total.written));
  json.key("free_store_merged").value(static_cast<std::uint64_t>(free_total.merged));
  json.key("free_store_write_failed").value(static_cast<std::uint64_t>(free_total.write_failed));
  json.key("free_store_read").value(static_cast<std::uint64_t>(free_total.read));
  json.key("free_store_read_failed").value(static_cast<std::uint64_t>(free_total.read_failed));
  json.key("free_store_bytes_written").value(free_total.bytes_written);
  json.key("free_store_bytes_read").value(free_total.bytes_read);
  json.key("free_store_file_bytes").value(summary->free_store_file_bytes);
  json.key("free_store_keys").value(summary->free_store_keys);
  json.key("free_space_bytes_used").value(static_cast<std::uint64_t>(summary->free_space_bytes));
  json.key("mesh_vertices").value(static_cast<std::uint64_t>(summary->mesh_vertices));
  json.key("mesh_triangles").value(static_cast<std::uint64_t>(summary->mesh_triangles));
  json.key("failure").value(summary->failure.c_str());
  if (summary->have_ate) {
    json.key("ate_rmse_m").value(summary->ate_rmse_m);
    json.key("ate_max_m").value(summary->ate_max_m);
  }
  json.key("wall_s").value(summary->wall_s);
  if (options.deadline_ms > 0.0) {
    const CostModel& m = summary->deadline_model;
    json.key("deadline").begin_object();
    json.key("deadline_ms").value(options.deadline_ms);
    json.key("frozen").value(options.deadline_freeze);
    json.key("calibration_loaded").value(summary->deadline_calibration_loaded);
    json.key("frames_over").value(summary->frames_over_deadline);
    json.key("frames_fusion_skipped").value(summary->frames_fusion_skipped);
    json.key("frames_track_only").value(summary->frames_track_only);
    json.key("share_over")
        .value(summary->frames_processed > 0 ? static_cast<double>(summary->frames_over_deadline) /
                                                   static_cast<double>(summary->frames_processed)
                                             : 0.0);
    json.key("model").begin_object();
    json.key("fixed_ms").value(m.fixed_ms);
    json.key("icp_fixed_ms").value(m.icp.fixed_ms);
    json.key("icp_ms_per_mpixel_iteration").value(m.icp.ms_per_munit);
    json.key("integrate_fixed_ms").value(m.integrate.fixed_ms);
    json.key("integrate_ms_per_mvoxel").value(m.integrate.ms_per_munit);
    json.key("raycast_fixed_ms").value(m.raycast.fixed_ms);
    json.key("raycast_ms_per_mstep").value(m.raycast.ms_per_munit);
    json.key("free_space_fixed_ms").value(m.free_space.fixed_ms);
    json.key("free_space_ms_per_mvisit").value(m.free_space.ms_per_munit);
    json.key("safety").value(m.safety);
    json.end_object();
    json.end_object();
  }
  json.end_object();
  json.end_object();
  ErrorText json_error;
  const std::string path = join(options.out_dir, "stats.json");
  if (json.write_file(path.c_str(), &json_error).ok()) {
    summary->files_written.push_back("stats.json");
  } else {
    late_failure(json_error.c_str());
  }

  const std::vector<plot::StageSeries> series = {
      {"pre-process", "#7f7f7f", preprocess},
      {"track", "#1f77b4", track},
      {"integrate", "#2ca02c", integrate},
      {"ray-cast", "#d62728", raycast},
  };
  const std::string plot_path = join(options.out_dir, "stage_times.svg");
  if (plot::write_stacked_svg(plot_path, options.source_spec + " stage times", series)) {
    summary->files_written.push_back("stage_times.svg");
  } else {
    late_failure("cannot write " + plot_path);
  }
}

// Meshes `map` into `sink`; false when the mesher cannot reserve its memory.
template <typename VoxelT>
bool extract_map_mesh(const Octree<VoxelT>& map, const RunOptions& options, VectorMeshSink* sink) {
  MeshConfig mesh_config;
  mesh_config.read_scale = options.mesh_read_scale;
  // Dual marching cubes yields a few dozen vertices per surface block: size the
  // de-duplication table (48-96 bytes per vertex) from the map, capped at 8 M vertices.
  mesh_config.vertex_capacity = static_cast<std::uint32_t>(
      std::clamp<std::uint64_t>(std::uint64_t{96} * map.memory().blocks_used, 1u << 16, 1u << 23));
  const std::size_t bytes = Mesher<VoxelT>::bytes_required(mesh_config);
  AlignedBuffer mesh_buffer(bytes);
  LinearArena arena(mesh_buffer.data, bytes);
  Mesher<VoxelT> mesher;
  if (!mesher.reserve(arena, mesh_config).ok()) return false;
  const Result<MeshStats> meshed = mesher.extract(map, *sink);
  if (!meshed.ok()) {
    std::fprintf(stderr, "warning: meshing stopped early (%s)\n", meshed.status().name());
  }
  return true;
}

// mesh.ply, and the mesh kept in the summary with keep_mesh.
// With --map-file the mesh is the whole map's, as --save-map's file is: the blocks in memory and
// those the store holds.
template <typename VoxelT>
void write_mesh(const RunOptions& options, const Pipeline<VoxelT>& pipeline,
                host::BlockStoreFile* store, host::BlockStoreFile* finest_store,
                RunSummary* summary, LateFailures& late_failure) {
  const bool write_mesh_file = options.write_mesh && !options.out_dir.empty();
  if (!write_mesh_file && !options.keep_mesh) return;
  std::unique_ptr<host::HeapMap<VoxelT>> merged;
  if (store != nullptr) {
    ErrorText merge_error;
    const host::FinestMerge finest{finest_store, pipeline.config().fusion.y_max};
    if (!host::merge_map_with_store(&pipeline.map(), pipeline.map().config(), *store,
                                    options.map_file_path.c_str(), &merged, &merge_error, finest)
             .ok()) {
      late_failure(std::string("mesh.ply not written: ") + merge_error.c_str());
      return;
    }
  }
  VectorMeshSink sink;
  const bool meshed =
      extract_map_mesh(merged != nullptr ? merged->map : pipeline.map(), options, &sink);
  if (!meshed) late_failure("mesh.ply not written: cannot reserve the mesher");
  if (meshed) {
    host::MeshView mesh;
    mesh.vertices = sink.positions.data();
    mesh.vertex_count = sink.positions.size();
    mesh.indices = sink.indices.data();
    mesh.triangle_count = sink.indices.size() / 3;
    mesh.vertex_scale = sink.scales.data();
    if (write_mesh_file) {
      ErrorText ply_error;
      const std::string path = join(options.out_dir, "mesh.ply");
      if (host::write_ply(path.c_str(), mesh, &ply_error).ok()) {
        summary->files_written.push_back("mesh.ply");
      } else {
        late_failure(ply_error.c_str());
      }
    }
    summary->mesh_vertices = mesh.vertex_count;
    summary->mesh_triangles = mesh.triangle_count;
    if (options.keep_mesh) {
      summary->mesh_positions = std::move(sink.positions);
      summary->mesh_indices = std::move(sink.indices);
    }
  }
}

}  // namespace

template <typename VoxelT>
bool write_render(Pipeline<VoxelT>& pipeline, const std::string& path, ErrorText* error) {
  const PinholeCamera& camera = pipeline.working_camera();
  std::vector<Rgb8> rgb(static_cast<std::size_t>(camera.width) * camera.height);
  ImageView<Rgb8> view(rgb.data(), camera.width, camera.height);
  const Eigen::Vector3f light_W = pipeline.reference_T_W_C().translation().template cast<float>();
  if (!pipeline.cast_view().ok()) {
    error->set("cannot ray-cast the view");
    return false;
  }
  if (!shade_by_scale(pipeline.view_surface_W(), pipeline.view_scale_image(), light_W, view).ok()) {
    error->set("cannot shade the ray-cast");
    return false;
  }
  return host::write_png_rgb8(path.c_str(), reinterpret_cast<const std::uint8_t*>(rgb.data()),
                              camera.width, camera.height,
                              static_cast<std::ptrdiff_t>(camera.width * sizeof(Rgb8)), error)
      .ok();
}

// Writes --save-map's file; false (with the reason in *error) when it could not.
template <typename VoxelT>
bool save_map_now(const RunOptions& options, const Pipeline<VoxelT>& pipeline, RunSummary* summary,
                  std::string* error, host::BlockStoreFile* store, host::BlockStoreFile* free_store,
                  host::BlockStoreFile* finest_store) {
  const auto start = std::chrono::steady_clock::now();
  ErrorText text;
  MapSaveInfo info;
  info.frames = pipeline.frame_count();
  info.mu_m = pipeline.config().fusion.mu_m;
  const FreeSpace* free_space =
      pipeline.config().free_space.enabled ? &pipeline.free_space() : nullptr;
  // With --map-file the file holds the whole map: memory and store.
  const Status saved =
      store != nullptr
          ? host::save_map_file_with_store(options.save_map_path.c_str(), pipeline.map(),
                                           free_space, *store, info, &text, free_store,
                                           {finest_store, pipeline.config().fusion.y_max})
          : host::save_map_file(options.save_map_path.c_str(), pipeline.map(), free_space, info,
                                &text);
  if (!saved.ok()) {
    *error = text.c_str();
    return false;
  }
  summary->map_last_save_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  summary->map_file_bytes = file_size(options.save_map_path);
  ++summary->map_saves;
  return true;
}

template <typename VoxelT>
bool extract_mesh(const Pipeline<VoxelT>& pipeline, const RunOptions& options,
                  VectorMeshSink* sink) {
  return extract_map_mesh(pipeline.map(), options, sink);
}

// Ends the run: closes the trajectory file and the source, and takes the pipeline's figures
// into the summary (writing the learnt deadline calibration). Non-zero when no frame was usable.
template <typename VoxelT>
int close_run(const RunOptions& options, RunInputs* inputs, PipelineRun<VoxelT>* run,
              LoopResult* loop, RunSummary* summary, LateFailures& late_failure) {
  std::string error;
  const std::unique_ptr<DepthSource>& source = inputs->source;
  const auto start_time = inputs->start_time;
  Pipeline<VoxelT>& pipeline = run->pipeline;
  const std::unique_ptr<AlignedBuffer>& buffer = run->buffer;
  std::unique_ptr<host::TumTrajectoryWriter>& trajectory_file = loop->trajectory_file;
  if (trajectory_file != nullptr) {
    if (trajectory_file->close().ok()) {
      summary->files_written.push_back("trajectory.txt");
    } else {
      late_failure(trajectory_file->last_error());
    }
  }
  summary->frames_dropped_by_source = source->frames_dropped();
  source->close();
  summary->wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start_time).count();
  if (buffer == nullptr) return error_exit(options.source_spec + ": no usable frame");
  summary->frames_lost = pipeline.frames_lost();
  summary->odometry_noise_m = pipeline.prior_noise_m();
  summary->odometry_noise_rad = pipeline.prior_noise_rad();
  summary->map_memory = pipeline.map().memory();
  if (run->store != nullptr) {
    const host::BlockStoreFileStats store = run->store->stats();
    summary->store_file_bytes = store.file_bytes;
    summary->store_keys = store.keys;
    summary->store_live_bytes = store.live_bytes;
    summary->store_compactions = store.compactions;
  }
  if (run->finest_store != nullptr) {
    const host::BlockStoreFileStats finest_store = run->finest_store->stats();
    summary->finest_store_file_bytes = finest_store.file_bytes;
    summary->finest_store_keys = finest_store.keys;
  }
  if (run->free_store != nullptr) {
    const host::BlockStoreFileStats free_store = run->free_store->stats();
    summary->free_store_file_bytes = free_store.file_bytes;
    summary->free_store_keys = free_store.keys;
  }
  if (options.deadline_ms > 0.0) {
    summary->deadline_model = pipeline.cost_model();
    if (!options.deadline_calibration.empty() && !options.deadline_freeze &&
        !write_deadline_calibration(options.deadline_calibration, summary->deadline_model,
                                    &error)) {
      late_failure(error);
    }
  }
  if (options.free_space) summary->free_space_bytes = pipeline.free_space().bytes_used();
  if constexpr (std::is_same_v<VoxelT, MultiresVoxel>) {
    if (options.inspect_final_map) options.inspect_final_map(pipeline.query());
  }
  return 0;
}

template <typename VoxelT>
int write_outputs(const RunOptions& options, RunInputs* inputs, PipelineRun<VoxelT>* run,
                  LoopResult* loop, RunSummary* summary) {
  std::string error;
  const std::vector<Eigen::Vector3f>& query_points = inputs->query_points;
  Pipeline<VoxelT>& pipeline = run->pipeline;
  // From here on a write that fails is reported and the run goes on to write every other
  // output; the exit status is then 1.
  LateFailures late_failure;
  if (const int rc = close_run(options, inputs, run, loop, summary, late_failure); rc != 0) {
    return rc;
  }
  if (!options.query_points_path.empty() && !options.out_dir.empty()) {
    if (pipeline.esdf().reserved()) pipeline.flush_esdf();
    if (write_query_answers(pipeline.query(), query_points, join(options.out_dir, "queries.txt"),
                            &error, &pipeline.esdf())) {
      summary->files_written.push_back("queries.txt");
    } else {
      late_failure(error);
    }
  }
  if (!options.save_map_path.empty()) {
    std::string save_error;
    if (!save_map_now(options, pipeline, summary, &save_error, run->store.get(),
                      run->free_store.get(), run->finest_store.get())) {
      late_failure(save_error);
    }
  }

  evaluate_trajectories(summary);
  if (!options.odometry.empty() && !options.out_dir.empty()) {
    ErrorText odometry_error;
    const std::string path = join(options.out_dir, "odometry.txt");
    if (!host::write_tum_trajectory(path.c_str(), summary->odometry, &odometry_error).ok()) {
      late_failure(odometry_error.c_str());
    }
  }

  write_mesh(options, pipeline, run->store.get(), run->finest_store.get(), summary, late_failure);

  judge_run(loop->fused_after_first, summary);

  if (options.out_dir.empty()) return late_failure.count == 0 ? 0 : 1;

  // render.png: the map ray-cast at every pixel from the last reference pose, shaded and coloured
  // by interpolation scale.
  {
    ErrorText png_error;
    if (write_render(pipeline, join(options.out_dir, "render.png"), &png_error)) {
      summary->files_written.push_back("render.png");
    } else {
      late_failure(png_error.c_str());
    }
  }

  write_stats(options, map_kind_of<VoxelT>(), summary, late_failure);
  return late_failure.count == 0 ? 0 : 1;
}

template int write_outputs<MultiresVoxel>(const RunOptions&, RunInputs*,
                                          PipelineRun<MultiresVoxel>*, LoopResult*, RunSummary*);
template int write_outputs<Multires16Voxel>(const RunOptions&, RunInputs*,
                                            PipelineRun<Multires16Voxel>*, LoopResult*,
                                            RunSummary*);
template int write_outputs<TsdfVoxel>(const RunOptions&, RunInputs*, PipelineRun<TsdfVoxel>*,
                                      LoopResult*, RunSummary*);
template bool save_map_now<MultiresVoxel>(const RunOptions&, const Pipeline<MultiresVoxel>&,
                                          RunSummary*, std::string*, host::BlockStoreFile*,
                                          host::BlockStoreFile*, host::BlockStoreFile*);
template bool save_map_now<Multires16Voxel>(const RunOptions&, const Pipeline<Multires16Voxel>&,
                                            RunSummary*, std::string*, host::BlockStoreFile*,
                                            host::BlockStoreFile*, host::BlockStoreFile*);
template bool save_map_now<TsdfVoxel>(const RunOptions&, const Pipeline<TsdfVoxel>&, RunSummary*,
                                      std::string*, host::BlockStoreFile*, host::BlockStoreFile*,
                                      host::BlockStoreFile*);
template bool extract_mesh<MultiresVoxel>(const Pipeline<MultiresVoxel>&, const RunOptions&,
                                          VectorMeshSink*);
template bool extract_mesh<Multires16Voxel>(const Pipeline<Multires16Voxel>&, const RunOptions&,
                                            VectorMeshSink*);
template bool extract_mesh<TsdfVoxel>(const Pipeline<TsdfVoxel>&, const RunOptions&,
                                      VectorMeshSink*);
template bool write_render<MultiresVoxel>(Pipeline<MultiresVoxel>&, const std::string&, ErrorText*);
template bool write_render<Multires16Voxel>(Pipeline<Multires16Voxel>&, const std::string&,
                                            ErrorText*);
template bool write_render<TsdfVoxel>(Pipeline<TsdfVoxel>&, const std::string&, ErrorText*);

}  // namespace octofuse::examples::detail
