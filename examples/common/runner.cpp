#include "runner.hpp"

#include <unistd.h>

#include <sys/stat.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <utility>

#include "live_server.hpp"
#include "octofuse/mesh/mesher.hpp"
#include "octofuse/ports/host/json_writer.hpp"
#include "octofuse/ports/host/ply.hpp"
#include "octofuse/ports/host/png_writer.hpp"
#include "octofuse/ports/host/trajectory_eval.hpp"
#include "octofuse/render/shade.hpp"
#include "stage_plot.hpp"

namespace octofuse::examples {
namespace {

std::int64_t steady_now_us(void*) {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

struct AlignedBuffer {
  void* data = nullptr;
  // Plain pages on purpose: with transparent huge pages advised, each first touch of 2 MiB waits
  // for the kernel to compact memory, which made 1 cm integration 40% slower (6.9-7.1 ms vs
  // 10.3-11.5 ms per frame, 2 threads); at 2 mm the TLB gain did not show in integration.
  explicit AlignedBuffer(std::size_t bytes) {
    data = std::aligned_alloc(kArenaAlignment,
                              align_up(std::max<std::size_t>(bytes, 1), kArenaAlignment));
  }
  ~AlignedBuffer() { std::free(data); }
  AlignedBuffer(const AlignedBuffer&) = delete;
  AlignedBuffer& operator=(const AlignedBuffer&) = delete;
};

// Collects the streamed mesh into vectors for the PLY writer (host side may allocate).
class VectorMeshSink final : public MeshSink {
 public:
  Status add_vertices(const MeshVertex* vertices, std::size_t count) override {
    for (std::size_t i = 0; i < count; ++i) {
      positions.push_back(vertices[i].p_W);
      scales.push_back(vertices[i].scale);
    }
    return ok_status();
  }
  Status add_triangles(const MeshTriangle* triangles, std::size_t count) override {
    for (std::size_t i = 0; i < count; ++i) {
      for (int k = 0; k < 3; ++k) indices.push_back(triangles[i].v[k]);
    }
    return ok_status();
  }
  std::vector<Eigen::Vector3f> positions;
  std::vector<std::uint8_t> scales;
  std::vector<std::uint32_t> indices;
};

int voxel_depth_for(float map_size_m, float voxel_size_m) {
  int depth = kMinVoxelDepth;
  while (depth < kMaxVoxelDepth &&
         voxel_size_m * static_cast<float>(1 << depth) < map_size_m * 0.999f) {
    ++depth;
  }
  return depth;
}

std::string join(const std::string& dir, const char* name) {
  return dir + "/" + name;
}

bool make_dir(const std::string& path) {
  if (::mkdir(path.c_str(), 0755) == 0) return true;
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}

int error_exit(const std::string& message) {
  std::fprintf(stderr, "error: %s\n", message.c_str());
  return 1;
}

void write_frame_json(host::JsonWriter& json, const FrameStats& s) {
  json.begin_object();
  json.key("index").value(s.frame_index);
  json.key("timestamp_us").value(s.timestamp_us);
  json.key("result").value(frame_result_name(s.result));
  json.key("tracked").value(s.result == FrameResult::tracked || s.result == FrameResult::first);
  json.key("ms").begin_object();
  json.key("validate").value(s.times.validate_ms);
  json.key("preprocess").value(s.times.preprocess_ms);
  json.key("track").value(s.times.track_ms);
  json.key("integrate").value(s.times.integrate_ms);
  json.key("raycast").value(s.times.raycast_ms);
  json.key("total").value(s.times.total_ms);
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
  json.key("pool_refusals").value(static_cast<std::uint64_t>(s.integration.pool_refusals));
  json.key("keys_dropped").value(static_cast<std::uint64_t>(s.integration.keys_dropped));
  json.key("raycast_steps").value(s.raycast.steps);
  json.key("raycast_valid_pixels").value(static_cast<std::uint64_t>(s.raycast.valid_pixels));
  json.key("raycast_guided_pixels").value(static_cast<std::uint64_t>(s.raycast.guided_pixels));
  json.key("raycast_guide_fallbacks")
      .value(static_cast<std::uint64_t>(s.raycast.guide_fallback_pixels));
  json.key("budget_hits").begin_object();
  json.key("icp").value(s.budget_icp_hit);
  json.key("fusion").value(s.integration.budget_hit);
  json.key("raycast").value(s.raycast.budget_hit());
  json.end_object();
  json.key("blocks_used").value(static_cast<std::uint64_t>(s.memory.blocks_used));
  json.end_object();
}

struct PoolSizes {
  std::uint32_t blocks = 0;
  std::uint32_t finest = 0;  // 0: one per block
};

// Pool capacities from --max-blocks, or from --map-memory. A multires block takes its finest level
// (8^3 voxels) only when it integrates at scale 0, i.e. closer than kScale0MaxRatio * fx * voxel:
// when that covers most of the depth range (1 cm at QVGA: 3.9 m of 4) any block may need one;
// otherwise (2 mm: 0.8 m) half the memory goes to blocks and half to finest levels, so far, coarse
// blocks do not pay for a finest level they never use.
template <typename VoxelT>
PoolSizes pool_sizes(const RunOptions& options, const PinholeCamera& input_camera) {
  PoolSizes sizes;
  if (options.max_blocks != 0) {
    sizes.blocks = options.max_blocks;
    return sizes;
  }
  constexpr double kMaxBlocks = 4.0e6;
  const double bytes = options.map_memory_mb * 1048576.0;
  const PipelineConfig defaults = default_pipeline_config(
      input_camera, options.voxel_size_m, kMinVoxelDepth, 1, Eigen::Vector3f::Zero());
  const double working_fx = input_camera.fx / defaults.preprocess.downsample_factor;
  const double scale0_max_depth_m = kScale0MaxRatio * working_fx * options.voxel_size_m;
  using Map = Octree<VoxelT>;
  if (!Map::kSplitFinest || scale0_max_depth_m >= 0.5 * defaults.fusion.far_m) {
    sizes.blocks = static_cast<std::uint32_t>(
        std::min(kMaxBlocks, bytes / static_cast<double>(Map::kBytesPerBlockWorstCase)));
    return sizes;
  }
  sizes.blocks = static_cast<std::uint32_t>(
      std::min(kMaxBlocks, 0.5 * bytes / static_cast<double>(sizeof(typename Map::Block))));
  sizes.finest = static_cast<std::uint32_t>(
      std::min(static_cast<double>(sizes.blocks),
               0.5 * bytes / static_cast<double>(sizeof(typename Map::Finest))));
  return sizes;
}

template <typename VoxelT>
bool write_render(const Pipeline<VoxelT>& pipeline, const std::string& path, ErrorText* error) {
  const PinholeCamera& camera = pipeline.working_camera();
  std::vector<Rgb8> rgb(static_cast<std::size_t>(camera.width) * camera.height);
  ImageView<Rgb8> view(rgb.data(), camera.width, camera.height);
  const Eigen::Vector3f light_W = pipeline.reference_T_W_C().translation().template cast<float>();
  if (!shade_by_scale(pipeline.surface_W(), pipeline.scale_image(), light_W, view).ok()) {
    error->set("cannot shade the ray-cast");
    return false;
  }
  return host::write_png_rgb8(path.c_str(), reinterpret_cast<const std::uint8_t*>(rgb.data()),
                              camera.width, camera.height,
                              static_cast<std::ptrdiff_t>(camera.width * sizeof(Rgb8)), error)
      .ok();
}

// Meshes the map into `sink`; false when the mesher cannot reserve its memory.
template <typename VoxelT>
bool extract_mesh(const Pipeline<VoxelT>& pipeline, const RunOptions& options,
                  VectorMeshSink* sink) {
  MeshConfig mesh_config;
  mesh_config.read_scale = options.mesh_read_scale;
  // Dual marching cubes yields a few dozen vertices per surface block: size the
  // de-duplication table (48-96 bytes per vertex) from the map, capped at 8 M vertices.
  mesh_config.vertex_capacity = static_cast<std::uint32_t>(std::clamp<std::uint64_t>(
      std::uint64_t{96} * pipeline.map().memory().blocks_used, 1u << 16, 1u << 23));
  const std::size_t bytes = Mesher<VoxelT>::bytes_required(mesh_config);
  AlignedBuffer mesh_buffer(bytes);
  LinearArena arena(mesh_buffer.data, bytes);
  Mesher<VoxelT> mesher;
  if (!mesher.reserve(arena, mesh_config).ok()) return false;
  const Result<MeshStats> meshed = mesher.extract(pipeline.map(), *sink);
  if (!meshed.ok()) {
    std::fprintf(stderr, "warning: meshing stopped early (%s)\n", meshed.status().name());
  }
  return true;
}

// Fills the live view's snapshot from the run so far; `rgb` is the reused shading buffer.
template <typename VoxelT>
void fill_snapshot(const Pipeline<VoxelT>& pipeline, const RunSummary& summary, long processed,
                   double fps, std::vector<Rgb8>* rgb, LiveSnapshot* snapshot) {
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
  const PinholeCamera& camera = pipeline.working_camera();
  rgb->resize(static_cast<std::size_t>(camera.width) * camera.height);
  ImageView<Rgb8> view(rgb->data(), camera.width, camera.height);
  const Eigen::Vector3f light_W = pipeline.reference_T_W_C().translation().template cast<float>();
  snapshot->width = 0;
  snapshot->height = 0;
  snapshot->rgb.clear();
  if (shade_by_scale(pipeline.surface_W(), pipeline.scale_image(), light_W, view).ok()) {
    snapshot->width = camera.width;
    snapshot->height = camera.height;
    const auto* bytes = reinterpret_cast<const std::uint8_t*>(rgb->data());
    snapshot->rgb.assign(bytes, bytes + rgb->size() * sizeof(Rgb8));
  }
}

template <typename VoxelT>
int run_typed(const RunOptions& options, RunSummary* summary) {
  std::string error;
  std::unique_ptr<DepthSource> source = make_source(options.source_spec, options.source, &error);
  if (source == nullptr) return error_exit(error);
  if (!source->open().ok()) {
    return error_exit(options.source_spec + ": " + source->last_error());
  }
  if (!options.out_dir.empty() && !make_dir(options.out_dir)) {
    return error_exit("cannot create output folder " + options.out_dir);
  }
  PinholeCamera input_camera = source->intrinsics();
  if (options.source.have_intrinsics) {
    // Live sources learn their size only when opened; the override keeps it.
    input_camera.fx = static_cast<float>(options.source.intrinsics[0]);
    input_camera.fy = static_cast<float>(options.source.intrinsics[1]);
    input_camera.cx = static_cast<float>(options.source.intrinsics[2]);
    input_camera.cy = static_cast<float>(options.source.intrinsics[3]);
  }
  const auto start_time = std::chrono::steady_clock::now();

  std::unique_ptr<host::TumTrajectoryWriter> trajectory_file;
  if (!options.out_dir.empty()) {
    trajectory_file = std::make_unique<host::TumTrajectoryWriter>();
    const std::string path = join(options.out_dir, "trajectory.txt");
    if (!trajectory_file->open(path.c_str()).ok()) return error_exit(trajectory_file->last_error());
  }

  std::unique_ptr<LiveServer> server;
  LiveSnapshot snapshot;
  std::vector<Rgb8> snapshot_rgb;
  auto last_publish = std::chrono::steady_clock::now();
  long frames_since_publish = 0;
  if (!options.serve.empty()) {
    server = LiveServer::start(options.serve, LiveServerLimits(), &error);
    if (server == nullptr) return error_exit(error);
    std::fprintf(stderr, "live view at %s\n", server->url().c_str());
  }

  Pipeline<VoxelT> pipeline;
  std::unique_ptr<AlignedBuffer> buffer;
  const Clock clock{&steady_now_us, nullptr};
  const bool show_progress = options.progress && ::isatty(STDERR_FILENO);
  DepthFrame frame;
  long processed = 0;
  int consecutive_failures = 0;
  long frames_since_status = 0;
  auto last_status = std::chrono::steady_clock::now();
  for (;;) {
    if (options.stop != nullptr && options.stop->load()) break;
    if (options.max_frames >= 0 && processed >= options.max_frames) break;
    const NextFrame next = source->next(frame);
    if (next.outcome == FrameOutcome::end_of_stream) break;
    if (next.outcome == FrameOutcome::error) {
      return error_exit(options.source_spec + ": " + source->last_error());
    }
    if (next.outcome == FrameOutcome::skip) {
      ++summary->frames_skipped_by_source;
      std::fprintf(stderr, "warning: skipped a frame: %s\n", source->last_error());
      continue;
    }
    if (buffer == nullptr) {
      // The first frame fixes where the map's cube sits: around the first camera, shifted along
      // its view direction so what it sees is inside.
      Se3d T_W_C0 = Se3d::Identity();
      if (frame.has_ground_truth) T_W_C0.matrix() = frame.T_W_C_ground_truth;
      const int depth = voxel_depth_for(options.map_size_m, options.voxel_size_m);
      const float side_m = options.voxel_size_m * static_cast<float>(1 << depth);
      const Eigen::Vector3f centre_W =
          (T_W_C0.translation() + T_W_C0.linear().col(2) * (0.25 * side_m)).cast<float>();
      const PoolSizes pools = pool_sizes<VoxelT>(options, input_camera);
      PipelineConfig config = default_pipeline_config(input_camera, options.voxel_size_m, depth,
                                                      pools.blocks, centre_W);
      config.map.finest_capacity = pools.finest;
      config.map_kind =
          std::is_same_v<VoxelT, MultiresVoxel> ? MapKind::multires : MapKind::single_res;
      if (options.mu_m > 0.0f) config.fusion.mu_m = options.mu_m;
      config.workers = options.threads;
      config.pose_source = options.pose_source;
      config.budget = options.budget;
      config.preprocess.bilateral = options.bilateral;
      if (options.icp_depth_knee_m >= 0.0f)
        config.track.depth_weight_knee_m = options.icp_depth_knee_m;
      config.initial_T_W_C = T_W_C0;
      const std::size_t bytes = bytes_required(config);
      if (bytes == 0) return error_exit("invalid configuration (check voxel size, mu, threads)");
      buffer = std::make_unique<AlignedBuffer>(bytes);
      if (buffer->data == nullptr) return error_exit("cannot reserve the map memory");
      const Status init = pipeline.init(buffer->data, bytes, config, clock);
      if (!init.ok()) return error_exit(std::string("pipeline init failed: ") + init.name());
      summary->arena_bytes = bytes;
    }

    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    ++processed;
    if (stats.result == FrameResult::rejected) {
      ++summary->frames_rejected;
      std::fprintf(stderr, "warning: frame %lu rejected: %s\n",
                   static_cast<unsigned long>(stats.frame_index), pipeline.last_error());
      if (++consecutive_failures > 100) return error_exit("100 bad frames in a row, giving up");
      continue;
    }
    consecutive_failures = 0;
    if (stats.result == FrameResult::lost) ++summary->frames_lost;
    if (stats.result == FrameResult::nearly_empty) ++summary->frames_nearly_empty;
    if (!status.ok() && status.code() != StatusCode::resource_exhausted &&
        status.code() != StatusCode::data_loss && stats.result != FrameResult::lost) {
      return error_exit(std::string("frame processing failed: ") + status.name());
    }
    summary->frames.push_back(stats);
    host::TimedPose pose;
    pose.timestamp_s = static_cast<double>(frame.timestamp_us) * 1e-6;
    pose.T_W_C = pipeline.T_W_C();
    summary->trajectory.push_back(pose);
    if (trajectory_file != nullptr && !trajectory_file->append(pose).ok()) {
      return error_exit(trajectory_file->last_error());
    }
    if (frame.has_ground_truth) {
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
    if (server != nullptr && server->mesh_requested()) {
      VectorMeshSink sink;
      if (!extract_mesh(pipeline, options, &sink)) return error_exit("cannot reserve the mesher");
      server->publish_mesh(mesh_ply_bytes(
          sink.positions.empty() ? nullptr : sink.positions[0].data(), sink.scales.data(),
          sink.positions.size(), sink.indices.data(), sink.indices.size() / 3));
    }
    if (server != nullptr) {
      // At most 10 snapshots a second: shading and copying cost the loop about a millisecond.
      ++frames_since_publish;
      const auto now = std::chrono::steady_clock::now();
      const double since_s = std::chrono::duration<double>(now - last_publish).count();
      if (since_s >= 0.1) {
        fill_snapshot(pipeline, *summary, processed,
                      static_cast<double>(frames_since_publish) / since_s, &snapshot_rgb,
                      &snapshot);
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
                    frame_result_name(stats.result), stats.times.total_ms,
                    stats.memory.blocks_used);
        std::fflush(stdout);
        frames_since_status = 0;
        last_status = now;
      }
    }
    if (show_progress) {
      std::fprintf(stderr, "\rframe %5ld  %-8s  %6.1f ms  blocks %u/%u  ", processed,
                   frame_result_name(stats.result), stats.times.total_ms, stats.memory.blocks_used,
                   stats.memory.block_capacity);
    }
  }
  if (show_progress) std::fprintf(stderr, "\n");
  if (server != nullptr) {
    std::fprintf(stderr,
                 "live view: %llu answers, %llu connections refused over the cap, %llu timed "
                 "out\n",
                 static_cast<unsigned long long>(server->responses()),
                 static_cast<unsigned long long>(server->refused()),
                 static_cast<unsigned long long>(server->timed_out()));
  }
  if (trajectory_file != nullptr && !trajectory_file->close().ok()) {
    return error_exit(trajectory_file->last_error());
  }
  source->close();
  summary->wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start_time).count();
  if (buffer == nullptr) return error_exit(options.source_spec + ": no usable frame");
  summary->frames_lost = pipeline.frames_lost();
  summary->map_memory = pipeline.map().memory();

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

  // mesh.ply
  const bool write_mesh_file = options.write_mesh && !options.out_dir.empty();
  if (write_mesh_file || options.keep_mesh) {
    VectorMeshSink sink;
    if (!extract_mesh(pipeline, options, &sink)) return error_exit("cannot reserve the mesher");
    host::MeshView mesh;
    mesh.vertices = sink.positions.data();
    mesh.vertex_count = sink.positions.size();
    mesh.indices = sink.indices.data();
    mesh.triangle_count = sink.indices.size() / 3;
    mesh.vertex_scale = sink.scales.data();
    if (write_mesh_file) {
      ErrorText ply_error;
      const std::string path = join(options.out_dir, "mesh.ply");
      if (!host::write_ply(path.c_str(), mesh, &ply_error).ok()) {
        return error_exit(ply_error.c_str());
      }
    }
    summary->mesh_vertices = mesh.vertex_count;
    summary->mesh_triangles = mesh.triangle_count;
    if (options.keep_mesh) {
      summary->mesh_positions = std::move(sink.positions);
      summary->mesh_indices = std::move(sink.indices);
    }
  }

  if (options.out_dir.empty()) return 0;

  // render.png: the last ray-cast, shaded and coloured by interpolation scale.
  {
    ErrorText png_error;
    if (!write_render(pipeline, join(options.out_dir, "render.png"), &png_error)) {
      return error_exit(png_error.c_str());
    }
  }

  // stats.json
  {
    host::JsonWriter json;
    json.begin_object();
    json.key("frames").begin_array();
    for (const FrameStats& s : summary->frames) write_frame_json(json, s);
    json.end_array();
    std::vector<double> totals, track, integrate, raycast, preprocess;
    for (const FrameStats& s : summary->frames) {
      totals.push_back(s.times.total_ms);
      track.push_back(s.times.track_ms);
      integrate.push_back(s.times.integrate_ms);
      raycast.push_back(s.times.raycast_ms);
      preprocess.push_back(s.times.validate_ms + s.times.preprocess_ms);
    }
    const Percentiles total = percentiles(totals);
    json.key("summary").begin_object();
    json.key("source").value(options.source_spec.c_str());
    json.key("map").value(std::is_same_v<VoxelT, MultiresVoxel> ? "multires" : "single");
    json.key("voxel_size_m").value(static_cast<double>(options.voxel_size_m));
    json.key("threads").value(options.threads);
    json.key("frames").value(static_cast<std::uint64_t>(summary->frames.size()));
    json.key("frames_lost").value(summary->frames_lost);
    json.key("frames_rejected").value(summary->frames_rejected);
    json.key("frames_skipped_by_source").value(summary->frames_skipped_by_source);
    json.key("frames_nearly_empty").value(summary->frames_nearly_empty);
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
    json.end_object();
    json.key("arena_bytes").value(static_cast<std::uint64_t>(summary->arena_bytes));
    json.key("map_bytes_reserved")
        .value(static_cast<std::uint64_t>(summary->map_memory.bytes_reserved));
    json.key("map_bytes_used").value(static_cast<std::uint64_t>(summary->map_memory.bytes_used));
    json.key("pool_blocks_used").value(static_cast<std::uint64_t>(summary->map_memory.blocks_used));
    json.key("pool_block_capacity")
        .value(static_cast<std::uint64_t>(summary->map_memory.block_capacity));
    json.key("pool_refusals").value(summary->map_memory.refusals);
    json.key("mesh_vertices").value(static_cast<std::uint64_t>(summary->mesh_vertices));
    json.key("mesh_triangles").value(static_cast<std::uint64_t>(summary->mesh_triangles));
    if (summary->have_ate) {
      json.key("ate_rmse_m").value(summary->ate_rmse_m);
      json.key("ate_max_m").value(summary->ate_max_m);
    }
    json.key("wall_s").value(summary->wall_s);
    json.end_object();
    json.end_object();
    ErrorText json_error;
    const std::string path = join(options.out_dir, "stats.json");
    if (!json.write_file(path.c_str(), &json_error).ok()) return error_exit(json_error.c_str());

    const std::vector<plot::StageSeries> series = {
        {"pre-process", "#7f7f7f", preprocess},
        {"track", "#1f77b4", track},
        {"integrate", "#2ca02c", integrate},
        {"ray-cast", "#d62728", raycast},
    };
    const std::string plot_path = join(options.out_dir, "stage_times.svg");
    if (!plot::write_stacked_svg(plot_path, options.source_spec + " stage times", series)) {
      return error_exit("cannot write " + plot_path);
    }
  }
  return 0;
}

}  // namespace

Percentiles percentiles(std::vector<double> values) {
  Percentiles p;
  if (values.empty()) return p;
  std::sort(values.begin(), values.end());
  auto at = [&](double q) {
    const std::size_t i = static_cast<std::size_t>(std::ceil(q * values.size())) - 1;
    return values[std::min(values.size() - 1, std::max<std::size_t>(i, 0))];
  };
  const std::size_t n = values.size();
  p.median = n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
  p.p90 = at(0.90);
  p.p99 = at(0.99);
  p.max = values.back();
  double sum = 0.0;
  for (double v : values) sum += v;
  p.mean = sum / static_cast<double>(n);
  return p;
}

bool parse_mesh_read_scale(const std::string& text, MeshReadScale* scale) {
  if (text == "current") {
    *scale = MeshReadScale::current;
  } else if (text == "finest") {
    *scale = MeshReadScale::finest_fused;
  } else {
    return false;
  }
  return true;
}

int run_pipeline(const RunOptions& options, RunSummary* summary) {
  *summary = RunSummary();
  if (options.map_kind == MapKind::multires) return run_typed<MultiresVoxel>(options, summary);
  return run_typed<TsdfVoxel>(options, summary);
}

}  // namespace octofuse::examples
