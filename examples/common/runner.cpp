#include "runner.hpp"

#include <unistd.h>

#include <sys/stat.h>
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <thread>
#include <utility>

#include "deadline_calibration.hpp"
#include "host_memory.hpp"
#include "live_server.hpp"
#include "looping_source.hpp"
#include "octofuse/mesh/mesher.hpp"
#include "octofuse/pipeline/steady_clock.hpp"
#include "octofuse/ports/host/atomic_file.hpp"
#include "octofuse/ports/host/json_writer.hpp"
#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/ply.hpp"
#include "octofuse/ports/host/png_writer.hpp"
#include "octofuse/ports/host/trajectory_eval.hpp"
#include "octofuse/render/shade.hpp"
#include "query_points.hpp"
#include "stage_plot.hpp"

#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
#include "octofuse/ports/sim/odometry.hpp"
#endif

namespace octofuse::examples {
namespace {

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

// Whether --odometry names the simulated odometry rather than a file.
bool odometry_is_sim(const RunOptions& options) {
  return options.odometry == "sim" || options.odometry.rfind("sim:", 0) == 0;
}

// The files the run writes into out_dir.
std::vector<std::string> out_dir_files(const RunOptions& options) {
  std::vector<std::string> names = {"trajectory.txt", "render.png", "stats.json",
                                    "stage_times.svg"};
  if (options.write_mesh) names.emplace_back("mesh.ply");
  if (!options.query_points_path.empty()) names.emplace_back("queries.txt");
  if (!options.odometry.empty()) names.emplace_back("odometry.txt");
  return names;
}

// `path` with its folder resolved (and the file, when it exists or is a link), so that two
// spellings of one file compare equal; `path` itself when its folder does not resolve.
std::string resolved_path(const std::string& path) {
  char resolved[PATH_MAX];
  if (::realpath(path.c_str(), resolved) != nullptr) return resolved;
  const std::size_t slash = path.rfind('/');
  const std::string folder = slash == std::string::npos ? "." : path.substr(0, slash + 1);
  if (::realpath(folder.c_str(), resolved) == nullptr) return path;
  std::string out = resolved;
  if (out.empty() || out.back() != '/') out += '/';
  return out + (slash == std::string::npos ? path : path.substr(slash + 1));
}

// Checks, before the first frame, every file the run will write: each can be created where it
// goes (AtomicFile's rules: absent or a regular file, in a folder that takes files), and no two
// outputs, nor an output and an input, are one file. Leaves nothing behind (an output folder it
// had to create for the check is removed again). False with the reason in *error.
bool check_outputs(const RunOptions& options, std::string* error) {
  struct Output {
    std::string path;
    std::string what;
  };
  std::vector<Output> outputs;
  bool created_out_dir = false;
  if (!options.out_dir.empty()) {
    struct stat st;
    if (::stat(options.out_dir.c_str(), &st) == 0) {
      if (!S_ISDIR(st.st_mode)) {
        *error = options.out_dir + ": --out names something that is not a folder";
        return false;
      }
    } else if (::mkdir(options.out_dir.c_str(), 0755) == 0) {
      created_out_dir = true;
    } else {
      *error = "cannot create output folder " + options.out_dir + " (" + std::strerror(errno) + ")";
      return false;
    }
    for (const std::string& name : out_dir_files(options)) {
      outputs.push_back({join(options.out_dir, name.c_str()), "--out's " + name});
    }
    const std::string frames_dir = join(options.out_dir, "frames");
    if (options.write_frames && ::stat(frames_dir.c_str(), &st) == 0 && !S_ISDIR(st.st_mode)) {
      *error = frames_dir + ": not a folder (--write-frames writes into it)";
      if (created_out_dir) ::rmdir(options.out_dir.c_str());
      return false;
    }
  }
  if (!options.save_map_path.empty()) outputs.push_back({options.save_map_path, "--save-map"});
  if (options.deadline_ms > 0.0 && !options.deadline_calibration.empty() &&
      !options.deadline_freeze) {
    outputs.push_back({options.deadline_calibration, "--deadline-calibration"});
  }
  std::vector<Output> inputs;
  if (!options.odometry.empty() && !odometry_is_sim(options)) {
    inputs.push_back({options.odometry, "--odometry"});
  }
  if (!options.query_points_path.empty()) {
    inputs.push_back({options.query_points_path, "--query-points"});
  }
  // Each output against the outputs before it and every input.
  auto first_problem = [&]() -> std::string {
    for (std::size_t i = 0; i < outputs.size(); ++i) {
      ErrorText why;
      if (!host::check_writable(outputs[i].path.c_str(), &why).ok()) {
        return outputs[i].what + ": " + why.c_str();
      }
      const std::string resolved = resolved_path(outputs[i].path);
      for (std::size_t k = 0; k < i + inputs.size(); ++k) {
        const Output& other = k < i ? outputs[k] : inputs[k - i];
        if (resolved_path(other.path) == resolved) {
          return outputs[i].what + " " + outputs[i].path + " is the file of " + other.what +
                 "; refusing to overwrite it";
        }
      }
    }
    return std::string();
  };
  *error = first_problem();
  // Made again when the first frame's pose is written: a run that fails before leaves nothing.
  if (created_out_dir) ::rmdir(options.out_dir.c_str());
  return error->empty();
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
  json.key("pool_refusals").value(static_cast<std::uint64_t>(s.integration.pool_refusals));
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
    json.end_object();
  }
  json.end_object();
}

// Intrinsics a depth camera can have: the principal point in the middle half of the image and a
// field of view between 10 and 170 degrees on each axis. Anything else is a mix-up (intrinsics for
// another image size, a typo) that would lose every frame after the first.
bool plausible_intrinsics(const PinholeCamera& camera, std::string* why) {
  constexpr double kMinFov_deg = 10.0;
  constexpr double kMaxFov_deg = 170.0;
  constexpr double kRadToDeg = 57.29577951308232;
  char text[256];
  const double w = camera.width, h = camera.height;
  std::snprintf(text, sizeof(text), "intrinsics fx %g fy %g cx %g cy %g for %dx%d images: ",
                static_cast<double>(camera.fx), static_cast<double>(camera.fy),
                static_cast<double>(camera.cx), static_cast<double>(camera.cy), camera.width,
                camera.height);
  *why = text;
  if (!camera.valid()) {
    *why += "not finite and positive";
    return false;
  }
  if (!(camera.cx >= 0.25 * w && camera.cx <= 0.75 * w && camera.cy >= 0.25 * h &&
        camera.cy <= 0.75 * h)) {
    *why += "the principal point is far from the image centre (intrinsics for another size?)";
    return false;
  }
  const double fov_x_deg = 2.0 * std::atan(0.5 * w / camera.fx) * kRadToDeg;
  const double fov_y_deg = 2.0 * std::atan(0.5 * h / camera.fy) * kRadToDeg;
  if (!(fov_x_deg >= kMinFov_deg && fov_x_deg <= kMaxFov_deg && fov_y_deg >= kMinFov_deg &&
        fov_y_deg <= kMaxFov_deg)) {
    std::snprintf(text, sizeof(text), "a field of view of %.1f x %.1f degrees (10 to 170 accepted)",
                  fov_x_deg, fov_y_deg);
    *why += text;
    return false;
  }
  return true;
}

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
  bool icp_budget_set = false;  // --budget-icp given: the default iterations are no budget

  void after(const FrameStats& s) {
    const unsigned long index = static_cast<unsigned long>(s.frame_index);
    const bool finest_only = s.integration.pool_refusals == s.integration.finest_refusals;
    if (s.integration.pool_refusals > 0 && finest_only && !finest_full) {
      finest_full = true;
      std::fprintf(stderr,
                   "warning: frame %lu: the finest-level pool is full (%u levels): blocks beyond "
                   "it integrate at scale 1 (raise --map-memory for finer detail)\n",
                   index, s.memory.finest_capacity);
    }
    if (s.integration.pool_refusals > 0 && !finest_only && !pool_full) {
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
  // With eviction a small cap must still hold a whole view: blocks are cheap and a finest level
  // costs 7x one, so the split below applies at any voxel size (blocks past the finest pool
  // integrate at scale 1, the farthest give theirs back).
  if (!Map::kSplitFinest ||
      (!options.eviction.enabled && scale0_max_depth_m >= 0.5 * defaults.fusion.far_m)) {
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

std::uint64_t file_size(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 ? static_cast<std::uint64_t>(st.st_size) : 0;
}

// Writes --save-map's file; false (with the reason in *error) when it could not.
template <typename VoxelT>
bool save_map_now(const RunOptions& options, const Pipeline<VoxelT>& pipeline, RunSummary* summary,
                  std::string* error) {
  const auto start = std::chrono::steady_clock::now();
  ErrorText text;
  MapSaveInfo info;
  info.frames = pipeline.frame_count();
  info.mu_m = pipeline.config().fusion.mu_m;
  const FreeSpace* free_space =
      pipeline.config().free_space.enabled ? &pipeline.free_space() : nullptr;
  if (!host::save_map_file(options.save_map_path.c_str(), pipeline.map(), free_space, info, &text)
           .ok()) {
    *error = text.c_str();
    return false;
  }
  summary->map_last_save_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  summary->map_file_bytes = file_size(options.save_map_path);
  ++summary->map_saves;
  return true;
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
  // Every output path checked first: one found wrong after the last frame loses the whole run.
  if (!check_outputs(options, &error)) return error_exit(error);
  // The deadline's starting model: the calibration file when there is one (frozen: it must be).
  CostModel deadline_model;
  if (!options.deadline_calibration.empty()) {
    std::FILE* probe = std::fopen(options.deadline_calibration.c_str(), "rb");
    const bool absent = probe == nullptr && errno == ENOENT;
    if (probe != nullptr) std::fclose(probe);
    if (!absent || options.deadline_freeze) {
      if (!read_deadline_calibration(options.deadline_calibration, &deadline_model, &error)) {
        return error_exit(error);
      }
      summary->deadline_calibration_loaded = true;
    }
  }
  summary->deadline_model = deadline_model;
  std::vector<Eigen::Vector3f> query_points;
  if (!options.query_points_path.empty() &&
      !load_query_points(options.query_points_path, &query_points, &error)) {
    return error_exit(error);
  }
  std::unique_ptr<DepthSource> source = make_source(options.source_spec, options.source, &error);
  if (source == nullptr) return error_exit(error);
  LoopingSource* looping = nullptr;
  if (options.loop_source) {
    auto wrapper = std::make_unique<LoopingSource>(std::move(source));
    looping = wrapper.get();
    source = std::move(wrapper);
  }
  if (!source->open().ok()) {
    return error_exit(options.source_spec + ": " + source->last_error());
  }
  PinholeCamera input_camera = source->intrinsics();
  if (options.source.have_intrinsics) {
    // Live sources learn their size only when opened; the override keeps it.
    input_camera.fx = static_cast<float>(options.source.intrinsics[0]);
    input_camera.fy = static_cast<float>(options.source.intrinsics[1]);
    input_camera.cx = static_cast<float>(options.source.intrinsics[2]);
    input_camera.cy = static_cast<float>(options.source.intrinsics[3]);
  }
  // Before any output exists: a run that cannot work leaves nothing behind.
  std::string implausible;
  if (!plausible_intrinsics(input_camera, &implausible)) {
    return error_exit(options.source_spec + ": " + implausible);
  }
  const auto start_time = std::chrono::steady_clock::now();

  Pipeline<VoxelT> pipeline;
  std::unique_ptr<AlignedBuffer> buffer;
  const Clock clock = steady_clock();
  // With --load-map: the saved map's header (its geometry replaces the one around the first
  // camera).
  const bool load_map = !options.load_map_path.empty();
  MapFileHeader loaded;
  if (load_map) {
    ErrorText header_error;
    const Result<MapFileHeader> header =
        host::read_map_file_header(options.load_map_path.c_str(), &header_error);
    if (!header.ok()) return error_exit(header_error.c_str());
    loaded = header.value();
  }
  auto init_pipeline = [&](const Se3d& T_W_C0) {
    // Without a loaded map the first frame fixes where the map's cube sits: around the first
    // camera, shifted along its view direction so what it sees is inside.
    const int depth =
        load_map ? loaded.voxel_depth : voxel_depth_for(options.map_size_m, options.voxel_size_m);
    const float side_m = options.voxel_size_m * static_cast<float>(1 << depth);
    const Eigen::Vector3f centre_W =
        (T_W_C0.translation() + T_W_C0.linear().col(2) * (0.25 * side_m)).cast<float>();
    const PoolSizes pools = pool_sizes<VoxelT>(options, input_camera);
    PipelineConfig config =
        default_pipeline_config(input_camera, options.voxel_size_m, depth, pools.blocks, centre_W);
    config.map.finest_capacity = pools.finest;
    if (load_map) {
      config.map.origin_W = loaded.origin_W;
      config.map.voxel_size_m = loaded.voxel_size_m;
      config.map.node_capacity = std::max(config.map.node_capacity, loaded.node_count);
      if (pools.blocks < loaded.block_count) {
        return error_exit(options.load_map_path + ": needs " + std::to_string(loaded.block_count) +
                          " blocks, the map memory holds " + std::to_string(pools.blocks) +
                          " (raise --map-memory or --max-blocks)");
      }
    }
    config.map_kind = map_kind_of<VoxelT>();
    if (options.mu_m > 0.0f) config.fusion.mu_m = options.mu_m;
    config.fusion.behind_mu = options.band_behind_mu;
    if (load_map) config.fusion.mu_m = loaded.mu_m;  // the TSDF is normalised by it
    config.workers = options.threads;
    config.pose_source = options.pose_source;
    if (options.odometry_noise[0] > 0.0) {
      config.prior_noise_m = options.odometry_noise[0];
      config.prior_noise_rad = options.odometry_noise[1];
    }
    if (options.odometry_information[0] >= 0.0) {  // an explicit fixed pull wins
      config.prior_fixed_information = true;
      config.prior_information_t = options.odometry_information[0];
      config.prior_information_r = options.odometry_information[1];
    }
    if (!options.odometry.empty()) {
      config.pose_source =
          options.odometry_only ? PoseSource::external : PoseSource::external_prior;
    }
    config.budget = options.budget;
    config.deadline.deadline_ms = options.deadline_ms;
    config.deadline.model = deadline_model;
    config.deadline.adapt = !options.deadline_freeze;
    config.eviction = options.eviction;
    config.free_space.enabled = options.free_space;
    config.free_space.exact_silhouettes = options.free_space_exact;
    if (load_map && loaded.free_node_count > 0) {
      // The saved free space is read with the settings it was carved with (its distance bounds
      // depend on the margin), in a pool that holds it.
      config.free_space.margin_m = loaded.free_margin_m;
      config.free_space.finest_octant_voxels = loaded.free_octant_voxels;
      config.free_space.max_free_count = static_cast<std::uint8_t>(loaded.free_max_count);
      const std::uint32_t pool =
          config.free_space.node_capacity != 0
              ? config.free_space.node_capacity
              : std::max(config.map.node_capacity, config.map.block_capacity);
      config.free_space.node_capacity = std::max(pool, loaded.free_node_count);
    }
    config.preprocess.bilateral = options.bilateral;
    if (options.icp_depth_knee_m >= 0.0f)
      config.track.depth_weight_knee_m = options.icp_depth_knee_m;
    config.initial_T_W_C = T_W_C0;
    config.initial_pose_from_ground_truth = !options.have_initial_pose;
    if (options.adjust_config) options.adjust_config(&config);
    ErrorText config_error;
    if (!validate(config, &config_error).ok()) return error_exit(config_error.c_str());
    const std::size_t bytes = bytes_required(config);
    if (bytes == 0) return error_exit("invalid configuration (check voxel size, mu, threads)");
    buffer = std::make_unique<AlignedBuffer>(bytes);
    if (buffer->data == nullptr) return error_exit("cannot reserve the map memory");
    const Status init = pipeline.init(buffer->data, bytes, config, clock);
    if (!init.ok()) {
      return error_exit(std::string("pipeline init failed (") + init.name() +
                        "): " + pipeline.last_error());
    }
    summary->arena_bytes = bytes;
    return 0;
  };
  if (load_map) {
    const int rc = init_pipeline(options.initial_T_W_C);
    if (rc != 0) return rc;
    const auto start = std::chrono::steady_clock::now();
    ErrorText load_error;
    MapFileHeader header;
    FreeSpace* free_space = pipeline.config().free_space.enabled ? &pipeline.free_space() : nullptr;
    if (!host::load_map_file(options.load_map_path.c_str(), pipeline.map(), free_space, &header,
                             &load_error)
             .ok()) {
      return error_exit(load_error.c_str());
    }
    if (!pipeline.resume_frame_count(header.frames).ok()) {
      return error_exit("cannot continue the map's frame count");
    }
    summary->map_loaded = true;
    summary->map_loaded_blocks = header.block_count;
    summary->map_loaded_free_nodes = free_space != nullptr ? header.free_node_count : 0;
    summary->map_load_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }

  // The vehicle's odometry, mapped so the first frame's pose anchors the world:
  // T_W_C(t) = T_W_C0 * inverse(T_O_C0) * T_O_C(t).
  const bool odometry_sim = odometry_is_sim(options);
  std::vector<host::TimedPose> odometry_O;
#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
  sim::OdometryDriftConfig drift_config;
  if (odometry_sim) {
    ErrorText odometry_error;
    const char* spec = options.odometry.size() > 4 ? options.odometry.c_str() + 4 : "";
    if (!sim::odometry_config_from_spec(spec, &drift_config, &odometry_error).ok()) {
      return error_exit(std::string("--odometry: ") + odometry_error.c_str());
    }
  }
  sim::DriftingOdometry drifting_odometry(drift_config);
#else
  if (odometry_sim) return error_exit("--odometry sim: built without the sim port");
#endif
  if (!odometry_sim && !options.odometry.empty()) {
    ErrorText odometry_error;
    if (!host::read_tum_trajectory(options.odometry.c_str(), &odometry_O, &odometry_error).ok()) {
      return error_exit(odometry_error.c_str());
    }
    if (odometry_O.empty()) return error_exit(options.odometry + ": no poses");
    // The same bounds the pipeline holds each prior to, checked over the whole file first.
    const PriorMotionLimits limits = PipelineConfig().prior_motion;
    for (std::size_t i = 0; i < odometry_O.size(); ++i) {
      const host::TimedPose& pose = odometry_O[i];
      double moved_m = 0.0;
      double turned_rad = 0.0;
      const bool far = prior_position_implausible(pose.T_W_C, limits);
      if (far ||
          (i > 0 && prior_motion_implausible(odometry_O[i - 1].T_W_C, pose.T_W_C,
                                             pose.timestamp_s - odometry_O[i - 1].timestamp_s,
                                             limits, &moved_m, &turned_rad))) {
        char text[320];
        if (far) {
          std::snprintf(
              text, sizeof(text), ": pose %zu (t = %.6f s): position (%g, %g, %g) m is beyond %g m",
              i + 1, pose.timestamp_s, pose.T_W_C.translation().x(), pose.T_W_C.translation().y(),
              pose.T_W_C.translation().z(), limits.max_coordinate_m);
        } else {
          std::snprintf(text, sizeof(text),
                        ": pose %zu (t = %.6f s): moves %g m and turns %g rad in %g s since the "
                        "one before (at most %g m/s and %g rad/s, plus %g m and %g rad)",
                        i + 1, pose.timestamp_s, moved_m, turned_rad,
                        pose.timestamp_s - odometry_O[i - 1].timestamp_s, limits.max_speed_mps,
                        limits.max_rate_radps, limits.slack_m, limits.slack_rad);
        }
        return error_exit(options.odometry + text);
      }
    }
  }
  Se3d T_W_O = Se3d::Identity();

  // Opened with the first frame's pose: a run that fails before it (a port in use, an odometry
  // that starts late, no memory for the map) leaves no output.
  std::unique_ptr<host::TumTrajectoryWriter> trajectory_file;

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

  const bool show_progress = options.progress && ::isatty(STDERR_FILENO);
  DepthFrame frame;
  FrameWarnings warnings;
  const PipelineBudget default_budget;
  for (int level = 0; level < kPyramidLevels; ++level) {
    warnings.icp_budget_set = warnings.icp_budget_set || options.budget.icp_iterations[level] !=
                                                             default_budget.icp_iterations[level];
  }
  std::uint64_t fused_after_first = 0;
  long processed = 0;
  bool have_first_pose = false;
  Se3d first_T_W_C = Se3d::Identity();  // the pose the first frame was given (loop_source)
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
    PosePrior prior;
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
        have_odometry = host::interpolate_pose(odometry_O, t_s, kOdometryEndTolerance_s, &T_O_C);
      }
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
        prior.valid = true;
        prior.T_W_C = (T_W_O * T_O_C).matrix();
        host::TimedPose pose;
        pose.timestamp_s = t_s;
        pose.T_W_C.matrix() = prior.T_W_C;
        summary->odometry.push_back(pose);
      } else {
        ++summary->frames_without_odometry;
      }
    }
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
      const int rc = init_pipeline(T_W_C0);
      if (rc != 0) return rc;
    }
    if (load_map && processed == 0 && !options.have_initial_pose && !frame.has_ground_truth) {
      return error_exit(options.source_spec +
                        ": no ground truth to place the first frame in the loaded map; give "
                        "--initial-pose tx,ty,tz,qx,qy,qz,qw");
    }

    FrameStats stats;
    const Status status = pipeline.process(frame, prior, &stats);
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
      if (!save_map_now(options, pipeline, summary, &save_error)) {
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
      std::fprintf(stderr, "\rframe %5ld  %-8s  pose %-10s  %6.1f ms  blocks %u/%u  ", processed,
                   frame_result_name(stats.result), pose_origin_name(stats.pose_origin),
                   stats.times.total_ms, stats.memory.blocks_used, stats.memory.block_capacity);
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
  // From here on a write that fails is reported and the run goes on to write every other
  // output; the exit status is then 1.
  int late_failures = 0;
  auto late_failure = [&late_failures](const std::string& message) {
    std::fprintf(stderr, "error: %s\n", message.c_str());
    ++late_failures;
  };
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
  if (!options.query_points_path.empty() && !options.out_dir.empty()) {
    if (write_query_answers(pipeline.query(), query_points, join(options.out_dir, "queries.txt"),
                            &error)) {
      summary->files_written.push_back("queries.txt");
    } else {
      late_failure(error);
    }
  }
  if (!options.save_map_path.empty()) {
    std::string save_error;
    if (!save_map_now(options, pipeline, summary, &save_error)) late_failure(save_error);
  }

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
  if (!options.odometry.empty() && !options.out_dir.empty()) {
    ErrorText odometry_error;
    const std::string path = join(options.out_dir, "odometry.txt");
    if (!host::write_tum_trajectory(path.c_str(), summary->odometry, &odometry_error).ok()) {
      late_failure(odometry_error.c_str());
    }
  }

  // mesh.ply
  const bool write_mesh_file = options.write_mesh && !options.out_dir.empty();
  VectorMeshSink sink;
  const bool meshed =
      (write_mesh_file || options.keep_mesh) && extract_mesh(pipeline, options, &sink);
  if ((write_mesh_file || options.keep_mesh) && !meshed) {
    late_failure("mesh.ply not written: cannot reserve the mesher");
  }
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

  // What the run claims: most frames gave a pose from tracking, and tracking fused new views.
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

  if (options.out_dir.empty()) return late_failures == 0 ? 0 : 1;

  // render.png: the last ray-cast, shaded and coloured by interpolation scale.
  {
    ErrorText png_error;
    if (write_render(pipeline, join(options.out_dir, "render.png"), &png_error)) {
      summary->files_written.push_back("render.png");
    } else {
      late_failure(png_error.c_str());
    }
  }

  // stats.json
  {
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
    json.key("map").value(map_option_name(map_kind_of<VoxelT>()));
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
    json.key("blocks_evicted").value(summary->map_memory.evicted);
    json.key("pool_refusals").value(summary->map_memory.refusals);
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
      json.key("share_over")
          .value(summary->frames_processed > 0
                     ? static_cast<double>(summary->frames_over_deadline) /
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
  return late_failures == 0 ? 0 : 1;
}

}  // namespace

int default_thread_count() {
  const unsigned cores = std::thread::hardware_concurrency();
  return static_cast<int>(std::clamp(cores, 1u, 64u));
}

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

const char* map_option_name(MapKind kind) {
  return kind == MapKind::single_res   ? "single"
         : kind == MapKind::multires16 ? "multires16"
                                       : "multires";
}

bool parse_map_option(const std::string& text, MapKind* kind) {
  for (MapKind k : {MapKind::multires, MapKind::single_res, MapKind::multires16}) {
    if (text == map_option_name(k)) {
      *kind = k;
      return true;
    }
  }
  return false;
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

int run_pipeline(const RunOptions& options_in, RunSummary* summary) {
  *summary = RunSummary();
  RunOptions options = options_in;
  if (!options.keep_frame_records && (!options.out_dir.empty() || !options.serve.empty())) {
    return error_exit("a run that keeps no per-frame record writes no files and serves no view");
  }
  if (!options.load_map_path.empty()) {
    // The saved map decides the voxel type and size (its header is checked again, with the rest
    // of the file, before the first frame).
    ErrorText error;
    const Result<MapFileHeader> header =
        host::read_map_file_header(options.load_map_path.c_str(), &error);
    if (!header.ok()) return error_exit(error.c_str());
    const MapVoxelType type = header.value().voxel_type;
    options.map_kind = type == MapVoxelType::multires     ? MapKind::multires
                       : type == MapVoxelType::multires16 ? MapKind::multires16
                                                          : MapKind::single_res;
    options.voxel_size_m = header.value().voxel_size_m;
  }
  if (options.map_kind == MapKind::multires) return run_typed<MultiresVoxel>(options, summary);
  if (options.map_kind == MapKind::multires16) return run_typed<Multires16Voxel>(options, summary);
  return run_typed<TsdfVoxel>(options, summary);
}

}  // namespace octofuse::examples
