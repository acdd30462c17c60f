// Setup of a run (runner_steps.hpp): the output checks, the inputs, the pipeline and its map.
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
#include <utility>

#include "deadline_calibration.hpp"
#include "octofuse/ports/host/atomic_file.hpp"
#include "query_points.hpp"
#include "runner_steps.hpp"

#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
#include "octofuse/ports/replay/bag_source.hpp"
#endif

namespace octofuse::examples::detail {
namespace {

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
  if (!options.record.empty()) outputs.push_back({options.record, "--record"});
  if (!options.map_file_path.empty()) {
    outputs.push_back({options.map_file_path, "--map-file"});
    if (options.free_space) outputs.push_back({options.map_file_path + ".free", "--map-file"});
    if (options.map_kind != MapKind::single_res && options.map_file_finest) {
      outputs.push_back({options.map_file_path + ".fine", "--map-file"});
    }
  }
  if (options.deadline_ms > 0.0 && !options.deadline_calibration.empty() &&
      !options.deadline_freeze) {
    outputs.push_back({options.deadline_calibration, "--deadline-calibration"});
  }
  std::vector<Output> inputs;
  // A bag given as a source or odometry is a file behind its "mcap:" or "rosbag:" prefix and
  // "?" options.
  auto is_bag = [](const std::string& spec) {
    return spec.rfind("mcap:", 0) == 0 || spec.rfind("rosbag:", 0) == 0;
  };
  auto bag_file = [](const std::string& spec) {
    const std::size_t start = spec.find(':') + 1;
    const std::size_t query = spec.find('?');
    return spec.substr(start, query == std::string::npos ? std::string::npos : query - start);
  };
  if (is_bag(options.source_spec)) {
    inputs.push_back({bag_file(options.source_spec), "--source"});
  }
  if (!options.odometry.empty() && !odometry_is_sim(options)) {
    inputs.push_back(
        {is_bag(options.odometry) ? bag_file(options.odometry) : options.odometry, "--odometry"});
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

struct PoolSizes {
  std::uint32_t blocks = 0;
  std::uint32_t finest = 0;  // 0: one per block
  std::uint32_t mid = 0;     // 0: one per block
};

// Pool capacities that split `bytes` of blocks and levels. A multires block takes its finest level
// (8^3 voxels) only when it integrates at scale 0, i.e. closer than kScale0MaxRatio * fx * voxel:
// when that covers most of the depth range (1 cm at QVGA: 3.9 m of 4) any block may need one;
// otherwise (2 mm: 0.8 m) half the memory goes to blocks (with their mid levels; as many as
// 32-bit voxels would take) and the rest to finest levels, so far, coarse blocks do not pay for a
// finest level they never use.
template <typename VoxelT>
PoolSizes split_pools(const RunOptions& options, const PinholeCamera& input_camera, double bytes) {
  PoolSizes sizes;
  constexpr double kMaxBlocks = 4.0e6;
  const PipelineConfig defaults = default_pipeline_config(
      input_camera, options.voxel_size_m, kMinVoxelDepth, 1, Eigen::Vector3f::Zero());
  const double working_fx = input_camera.fx / defaults.preprocess.downsample_factor;
  const double scale0_max_depth_m = kScale0MaxRatio * working_fx * options.voxel_size_m;
  using Map = Octree<VoxelT>;
  // With eviction a small cap must still hold a whole view: blocks are cheap and a finest level
  // costs 3x one with its mid level, so the split below applies at any voxel size (blocks past
  // the finest pool integrate at scale 1, the farthest give theirs back).
  if (!Map::kSplitFinest ||
      (!options.eviction.enabled && scale0_max_depth_m >= 0.5 * defaults.fusion.far_m)) {
    sizes.blocks = static_cast<std::uint32_t>(std::max(
        1.0, std::min(kMaxBlocks, bytes / static_cast<double>(Map::kBytesPerBlockWorstCase))));
    return sizes;
  }
  // Mid levels (scale 1) for the share of blocks that may integrate that fine: with eviction,
  // the share of the depth range where scale 1 reaches (twice scale 0's depth, scale_for_ratio();
  // 2 mm at QVGA: 1.75 m of 4, where 7-Scenes has a quarter of its blocks), since blocks past the
  // pool integrate at scale 2 until eviction gives the farthest blocks' mid levels back. Without
  // eviction nothing would give them back: one per block.
  const double mid_share =
      options.eviction.enabled
          ? std::min(1.0, 2.0 * scale0_max_depth_m / static_cast<double>(defaults.fusion.far_m))
          : 1.0;
  // The blocks a view needs depend on the scene and the voxel size, not on the voxel's width: the
  // block pool is sized as for 32-bit voxels, and what narrower voxels save on those blocks goes
  // to finest levels (a 16-bit map under 16 MB at 1 cm: 6 477 blocks and 5 769 finest levels,
  // where a 7-Scenes view fuses up to 3 700 blocks at scale 0).
  using Wide = Octree<MultiresVoxel>;
  const auto block_bytes = [mid_share](double block, double mid) {
    return block + mid_share * mid;
  };
  const double wide_block_bytes = block_bytes(static_cast<double>(sizeof(typename Wide::Block)),
                                              static_cast<double>(sizeof(typename Wide::Mid)));
  const double own_block_bytes = block_bytes(static_cast<double>(sizeof(typename Map::Block)),
                                             static_cast<double>(sizeof(typename Map::Mid)));
  sizes.blocks = static_cast<std::uint32_t>(
      std::max(1.0, std::min(kMaxBlocks, 0.5 * bytes / wide_block_bytes)));
  sizes.mid = mid_share >= 1.0 ? 0
                               : std::max<std::uint32_t>(
                                     1, static_cast<std::uint32_t>(mid_share * sizes.blocks));
  const double saved = static_cast<double>(sizes.blocks) * (wide_block_bytes - own_block_bytes);
  // At least one: 0 would mean one per block.
  sizes.finest = static_cast<std::uint32_t>(std::max(
      1.0, std::min(static_cast<double>(sizes.blocks),
                    (0.5 * bytes + saved) / static_cast<double>(sizeof(typename Map::Finest)))));
  return sizes;
}

// What the octree reserves for `sizes` (MapMemory::bytes_reserved): the pools, the inner nodes,
// the hash and the scratch, the last three growing with the block capacity.
template <typename VoxelT>
std::size_t map_bytes_for(const RunOptions& options, const PinholeCamera& input_camera,
                          const PoolSizes& sizes) {
  MapConfig map = default_pipeline_config(input_camera, options.voxel_size_m, kMinVoxelDepth,
                                          sizes.blocks, Eigen::Vector3f::Zero())
                      .map;
  map.finest_capacity = sizes.finest;
  map.mid_capacity = sizes.mid;
  return Octree<VoxelT>::bytes_required(map);
}

// The bytes to split between blocks and levels so that all the octree of VoxelT reserves fits
// in `cap`; 0 when not even one block does.
template <typename VoxelT>
double fitted_split_bytes(const RunOptions& options, const PinholeCamera& input_camera,
                          double cap) {
  using Map = Octree<VoxelT>;
  double bytes = cap;
  for (int step = 0; step < 100; ++step) {
    const PoolSizes sizes = split_pools<VoxelT>(options, input_camera, bytes);
    const double reserved =
        static_cast<double>(map_bytes_for<VoxelT>(options, input_camera, sizes));
    if (reserved > 0.0 && reserved <= cap) return bytes;
    if (reserved <= 0.0 || sizes.blocks <= 1) break;
    MapConfig pools;
    pools.block_capacity = sizes.blocks;
    pools.finest_capacity = sizes.finest;
    pools.mid_capacity = sizes.mid;
    double pool_bytes = static_cast<double>(pools.block_capacity) * sizeof(typename Map::Block);
    if constexpr (Map::kSplitFinest) {
      pool_bytes +=
          static_cast<double>(pools.effective_finest_capacity()) * sizeof(typename Map::Finest) +
          static_cast<double>(pools.effective_mid_capacity()) * sizeof(typename Map::Mid);
    }
    // The cap less the octree's own part at this capacity (which only shrinks with the blocks);
    // where rounding leaves the pools a little over, less that too.
    const double next = cap - (reserved - pool_bytes);
    bytes = next < bytes ? next : bytes - (reserved - cap);
  }
  return 0.0;
}

// Pool capacities from --max-blocks, or from --map-memory, which bounds everything the octree
// reserves (stats.json's map_bytes_reserved), not only its blocks and levels: what it takes
// beside them (inner nodes, hash, scratch, the pools' free lists: 4.5 % of 16 MB at 1 cm) grows
// with the capacities and comes off the split's bytes first. A 16-bit map gets the float map's
// blocks and mid levels and as many finest levels as then fit. False with `error` when the cap
// cannot hold a map.
template <typename VoxelT>
bool pool_sizes(const RunOptions& options, const PinholeCamera& input_camera, PoolSizes* sizes,
                std::string* error) {
  using Map = Octree<VoxelT>;
  if (options.max_blocks != 0) {
    *sizes = PoolSizes();
    sizes->blocks = options.max_blocks;
    return true;
  }
  const double cap = static_cast<double>(options.map_memory_mb) * 1048576.0;
  using Sized = std::conditional_t<Map::kSplitFinest, MultiresVoxel, VoxelT>;
  const double bytes = fitted_split_bytes<Sized>(options, input_camera, cap);
  *sizes = split_pools<VoxelT>(options, input_camera, bytes > 0.0 ? bytes : 1.0);
  double reserved = static_cast<double>(map_bytes_for<VoxelT>(options, input_camera, *sizes));
  while (bytes > 0.0 && reserved > cap && sizes->finest > 1) {
    const double over_levels = std::ceil((reserved - cap) / sizeof(typename Map::Finest));
    sizes->finest -=
        static_cast<std::uint32_t>(std::min(over_levels, static_cast<double>(sizes->finest - 1)));
    reserved = static_cast<double>(map_bytes_for<VoxelT>(options, input_camera, *sizes));
  }
  if (bytes > 0.0 && reserved <= cap) return true;
  char text[160];
  std::snprintf(text, sizeof(text),
                "--map-memory %g MB cannot hold the map's fixed part (%.2f MB with one block)",
                static_cast<double>(options.map_memory_mb), reserved / 1048576.0);
  *error = text;
  return false;
}

// Opens (or creates) the store at `path` for a map of `geometry`: the store, or null with a
// one-line `error`; a dropped torn tail is warned about.
std::unique_ptr<host::BlockStoreFile> open_store(const std::string& path,
                                                 const std::uint8_t* geometry,
                                                 std::size_t geometry_size, std::string* error) {
  auto store = std::make_unique<host::BlockStoreFile>();
  ErrorText store_error;
  ErrorText warning;
  if (!store->open(path.c_str(), geometry, geometry_size, &store_error, &warning).ok()) {
    *error = store_error.c_str();
    return nullptr;
  }
  if (!warning.empty()) std::fprintf(stderr, "warning: %s\n", warning.c_str());
  return store;
}

}  // namespace

int open_inputs(const RunOptions& options, RunSummary* summary, RunInputs* inputs) {
  std::string error;
  // Every output path checked first: one found wrong after the last frame loses the whole run.
  if (!check_outputs(options, &error)) return error_exit(error);
  // The deadline's starting model: the calibration file when there is one (frozen: it must be).
  CostModel& deadline_model = inputs->deadline_model;
  if (!options.deadline_calibration.empty()) {
    struct stat probe;
    const bool absent =
        ::stat(options.deadline_calibration.c_str(), &probe) != 0 && errno == ENOENT;
    if (!absent || options.deadline_freeze) {
      if (!read_deadline_calibration(options.deadline_calibration, &deadline_model, &error)) {
        return error_exit(error);
      }
      summary->deadline_calibration_loaded = true;
    }
  }
  summary->deadline_model = deadline_model;
  std::vector<Eigen::Vector3f>& query_points = inputs->query_points;
  if (!options.query_points_path.empty() &&
      !load_query_points(options.query_points_path, &query_points, &error)) {
    return error_exit(error);
  }
  std::unique_ptr<DepthSource>& source = inputs->source;
  source = make_source(options.source_spec, options.source, &error);
  if (source == nullptr) return error_exit(error);
  LoopingSource*& looping = inputs->looping;
  if (options.loop_source) {
    auto wrapper = std::make_unique<LoopingSource>(std::move(source));
    looping = wrapper.get();
    source = std::move(wrapper);
  }
  if (!source->open().ok()) {
    return error_exit(options.source_spec + ": " + source->last_error());
  }
  PinholeCamera& input_camera = inputs->input_camera;
  input_camera = source->intrinsics();
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
  inputs->start_time = std::chrono::steady_clock::now();

  // With --load-map: the saved map's header (its geometry replaces the one around the first
  // camera).
  const bool load_map = inputs->load_map = !options.load_map_path.empty();
  MapFileHeader& loaded = inputs->loaded;
  if (load_map) {
    ErrorText header_error;
    const Result<MapFileHeader> header =
        host::read_map_file_header(options.load_map_path.c_str(), &header_error);
    if (!header.ok()) return error_exit(header_error.c_str());
    loaded = header.value();
  }
  return 0;
}

template <typename VoxelT>
int init_pipeline(const RunOptions& options, const RunInputs& inputs, const Se3d& T_W_C0,
                  PipelineRun<VoxelT>* run, RunSummary* summary) {
  const bool load_map = inputs.load_map;
  const MapFileHeader& loaded = inputs.loaded;
  const PinholeCamera& input_camera = inputs.input_camera;
  const CostModel& deadline_model = inputs.deadline_model;
  Pipeline<VoxelT>& pipeline = run->pipeline;
  std::unique_ptr<AlignedBuffer>& buffer = run->buffer;
  const Clock& clock = run->clock;
  // Without a loaded map the first frame fixes where the map's cube sits: around the first
  // camera, shifted along its view direction so what it sees is inside.
  const int depth =
      load_map ? loaded.voxel_depth : voxel_depth_for(options.map_size_m, options.voxel_size_m);
  const float side_m = options.voxel_size_m * static_cast<float>(1 << depth);
  const Eigen::Vector3f centre_W =
      (T_W_C0.translation() + T_W_C0.linear().col(2) * (0.25 * side_m)).cast<float>();
  PoolSizes pools;
  std::string pool_error;
  if (!pool_sizes<VoxelT>(options, input_camera, &pools, &pool_error)) {
    return error_exit(pool_error);
  }
  PipelineConfig config =
      default_pipeline_config(input_camera, options.voxel_size_m, depth, pools.blocks, centre_W);
  config.map.finest_capacity = pools.finest;
  config.map.mid_capacity = pools.mid;
  // A loaded map's blocks may each hold a mid level (the header does not count them).
  if (load_map && pools.mid != 0) {
    config.map.mid_capacity = std::min(pools.blocks, std::max(pools.mid, loaded.block_count));
  }
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
  config.fusion.allocation_pixel_step = options.allocation_step;
  config.fusion.allocation_group_block_px = options.allocation_group_block_px;
  if (load_map) config.fusion.mu_m = loaded.mu_m;  // the TSDF is normalised by it
  config.workers = options.threads;
  // render.png, frames/ and the live view show the map at every pixel whatever the reference.
  config.view_cast = !options.out_dir.empty() || !options.serve.empty();
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
    config.pose_source = options.odometry_only ? PoseSource::external : PoseSource::external_prior;
  }
  config.budget = options.budget;
  config.deadline.deadline_ms = options.deadline_ms;
  config.deadline.model = deadline_model;
  config.deadline.adapt = !options.deadline_freeze;
  config.eviction = options.eviction;
  config.free_space.enabled = options.free_space;
  config.free_space.exact_silhouettes = options.free_space_exact;
  if (options.esdf) {
    // The window over the middle of the cube, at most 128 cells of 2 voxels a side; unknown
    // space counts as obstacle, so a free point's distance bounds unseen surfaces too.
    config.esdf.enabled = true;
    config.esdf.unknown_is_obstacle = true;
    config.esdf.cell_voxels = 2;
    config.esdf.cells_per_side = std::min(128, config.map.voxels_per_side() / 2);
    config.esdf.follow_m = options.esdf_follow_m;
  }
  if (load_map && loaded.free_node_count > 0) {
    // The saved free space is read with the settings it was carved with (its distance bounds
    // depend on the margin), in a pool that holds it.
    config.free_space.margin_m = loaded.free_margin_m;
    config.free_space.finest_octant_voxels = loaded.free_octant_voxels;
    config.free_space.max_free_count = static_cast<std::uint8_t>(loaded.free_max_count);
    const std::uint32_t pool = config.free_space.node_capacity != 0
                                   ? config.free_space.node_capacity
                                   : std::max(config.map.node_capacity, config.map.block_capacity);
    config.free_space.node_capacity = std::max(pool, loaded.free_node_count);
  }
  config.preprocess.bilateral = options.bilateral;
  if (options.icp_depth_knee_m >= 0.0f) config.track.depth_weight_knee_m = options.icp_depth_knee_m;
  config.track.finest_level_quarter_on_half_model = options.icp_quarter;
  config.track.middle_level_checkerboard = !options.icp_full_middle;
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
  // A map to be loaded takes the first slots itself: load_saved_map() prefaults after it.
  if (!inputs.load_map) (void)pipeline.prefault(options.prefault_blocks);  // ok after init()
  if (!options.map_file_path.empty()) {
    // The store belongs to one map geometry: voxel type, size, depth and origin.
    const MapConfig& map = pipeline.map().config();
    host::StoreGeometry store_geometry;
    store_geometry.voxel_type = map_voxel_type<VoxelT>();
    store_geometry.voxel_size_m = map.voxel_size_m;
    store_geometry.voxel_depth = map.voxel_depth;
    store_geometry.origin_W = map.origin_W;
    std::uint8_t geometry[host::kStoreGeometryBytes];
    host::encode_store_geometry(store_geometry, geometry);
    std::string store_error;
    run->store = open_store(options.map_file_path, geometry, sizeof(geometry), &store_error);
    if (run->store == nullptr) return error_exit(store_error);
    run->store_probe =
        std::make_unique<ReloadLatencyProbe>(run->store.get(), &summary->store_reload_latency);
    if (!pipeline.set_block_store(run->store_probe.get()).ok()) {
      return error_exit("--map-file needs eviction (--evict HIGH,LOW)");
    }
    if (Pipeline<VoxelT>::Map::kSplitFinest && options.map_file_finest) {
      // Finest levels given up for room go to FILE.fine, the block's record at that moment.
      std::uint8_t finest_geometry[host::kFinestStoreGeometryBytes];
      host::encode_finest_store_geometry(store_geometry, finest_geometry);
      run->finest_store = open_store(options.map_file_path + ".fine", finest_geometry,
                                     sizeof(finest_geometry), &store_error);
      if (run->finest_store == nullptr) return error_exit(store_error);
      if (!pipeline.set_finest_store(run->finest_store.get()).ok()) {
        return error_exit("cannot attach the finest-level store");
      }
    }
    if (pipeline.config().free_space.enabled) {
      // Free space the pool forgets goes to FILE.free, by region.
      std::uint8_t free_geometry[host::kFreeStoreGeometryBytes];
      host::encode_free_store_geometry(store_geometry, free_geometry);
      run->free_store = open_store(options.map_file_path + ".free", free_geometry,
                                   sizeof(free_geometry), &store_error);
      if (run->free_store == nullptr) return error_exit(store_error);
      if (!pipeline.set_free_space_store(run->free_store.get()).ok()) {
        return error_exit("cannot attach the free-space store");
      }
    }
  }
  return 0;
}

template <typename VoxelT>
int load_saved_map(const RunOptions& options, const RunInputs& inputs, PipelineRun<VoxelT>* run,
                   RunSummary* summary) {
  Pipeline<VoxelT>& pipeline = run->pipeline;
  const int rc = init_pipeline(options, inputs, options.initial_T_W_C, run, summary);
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
  // The loaded blocks took the first slots: the first frame's new blocks take the ones after them.
  (void)pipeline.prefault(options.prefault_blocks);
  summary->map_loaded = true;
  summary->map_loaded_blocks = header.block_count;
  summary->map_loaded_free_nodes = free_space != nullptr ? header.free_node_count : 0;
  summary->map_load_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return 0;
}

int read_odometry(const RunOptions& options, RunInputs* inputs) {
  const bool odometry_sim = inputs->odometry_sim = odometry_is_sim(options);
  std::vector<host::TimedPose>& odometry_O = inputs->odometry_O;
#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
  sim::OdometryDriftConfig drift_config;
  if (odometry_sim) {
    ErrorText odometry_error;
    const char* spec = options.odometry.size() > 4 ? options.odometry.c_str() + 4 : "";
    if (!sim::odometry_config_from_spec(spec, &drift_config, &odometry_error).ok()) {
      return error_exit(std::string("--odometry: ") + odometry_error.c_str());
    }
  }
  inputs->drifting_odometry = sim::DriftingOdometry(drift_config);
#else
  if (odometry_sim) return error_exit("--odometry sim: built without the sim port");
#endif
  if (!odometry_sim && !options.odometry.empty()) {
    ErrorText odometry_error;
    if (options.odometry.rfind("mcap:", 0) == 0 || options.odometry.rfind("rosbag:", 0) == 0) {
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
      // A bag's Odometry or PoseStamped topic (mcap:FILE?pose=TOPIC).
      replay::BagConfig bag;
      ErrorText odometry_warning;
      if (!replay::parse_bag_spec(options.odometry.c_str(), &bag, &odometry_error).ok() ||
          !replay::read_bag_poses(
               bag,
               [](void* context, std::int64_t stamp_ns, const Se3d& T) {
                 static_cast<std::vector<host::TimedPose>*>(context)->push_back(
                     {static_cast<double>(stamp_ns) * 1e-9, T});
               },
               &odometry_O, &odometry_error, &odometry_warning)
               .ok()) {
        return error_exit(std::string("--odometry: ") + odometry_error.c_str());
      }
      // Poses from /tf that took a transform before their stamp (the bag's /tf ended first).
      if (odometry_warning.c_str()[0] != '\0') {
        std::fprintf(stderr, "warning: --odometry: %s\n", odometry_warning.c_str());
      }
#else
      return error_exit("--odometry mcap: needs the replay port in this build");
#endif
    } else if (!host::read_tum_trajectory(options.odometry.c_str(), &odometry_O, &odometry_error)
                    .ok()) {
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
  return 0;
}

template int init_pipeline<MultiresVoxel>(const RunOptions&, const RunInputs&, const Se3d&,
                                          PipelineRun<MultiresVoxel>*, RunSummary*);
template int init_pipeline<Multires16Voxel>(const RunOptions&, const RunInputs&, const Se3d&,
                                            PipelineRun<Multires16Voxel>*, RunSummary*);
template int init_pipeline<TsdfVoxel>(const RunOptions&, const RunInputs&, const Se3d&,
                                      PipelineRun<TsdfVoxel>*, RunSummary*);
template int load_saved_map<MultiresVoxel>(const RunOptions&, const RunInputs&,
                                           PipelineRun<MultiresVoxel>*, RunSummary*);
template int load_saved_map<Multires16Voxel>(const RunOptions&, const RunInputs&,
                                             PipelineRun<Multires16Voxel>*, RunSummary*);
template int load_saved_map<TsdfVoxel>(const RunOptions&, const RunInputs&, PipelineRun<TsdfVoxel>*,
                                       RunSummary*);

}  // namespace octofuse::examples::detail
