#include "run_args.hpp"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "cli.hpp"

namespace octofuse::examples {

using cli::fail;

namespace {

// "tx,ty,tz,qx,qy,qz,qw": finite, |t| <= 1e6 m, a quaternion of norm within 1% of 1 (normalised).
bool parse_pose(const std::string& text, Se3d* T_W_C) {
  double v[7];
  std::size_t start = 0;
  for (int i = 0; i < 7; ++i) {
    const std::size_t comma = text.find(',', start);
    const bool last = i == 6;
    if (last != (comma == std::string::npos)) return false;
    const std::string token = text.substr(start, last ? std::string::npos : comma - start);
    if (!cli::parse_double(token, -1e6, 1e6, v[i])) return false;
    start = comma + 1;
  }
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::abs(q.norm() - 1.0) > 0.01) return false;
  q.normalize();
  *T_W_C = Se3d::Identity();
  T_W_C->linear() = q.toRotationMatrix();
  T_W_C->translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return true;
}

}  // namespace

void print_run_usage(const char* program, const char* default_source) {
  std::printf(
      "usage: %s [--source SPEC] [--out DIR] [--map multires|single]\n"
      "         [--voxel-size M] [--mu M] [--frames N] [--threads N]\n"
      "         [--intrinsics fx,fy,cx,cy] [--depth-scale S] [options]\n"
      "\n"
      "  --source SPEC        where depth comes from (default %s):\n%s"
      "  --out DIR            output folder (default octofuse-out)\n"
      "  --map KIND           multires (default) or single (single-resolution baseline)\n"
      "  --voxel-size M       finest voxel edge in metres (default 0.01)\n"
      "  --mu M               truncation distance in metres (default 8 voxels)\n"
      "  --map-size M         side of the mapped cube in metres (default 8)\n"
      "  --map-memory MB      memory for blocks and finest levels, when --max-blocks is not given\n"
      "                       (default 1024)\n"
      "  --max-blocks N       block pool capacity\n"
      "  --frames N           stop after N frames (sim: also the sequence length)\n"
      "  --threads N          worker threads (default 1)\n"
      "  --intrinsics fx,fy,cx,cy   override the source's intrinsics (pixels)\n"
      "  --depth-scale S      raw depth units per metre (TUM 5000, mm 1000)\n"
      "  --gt-poses           fuse with ground-truth poses instead of tracking\n"
      "  --odometry FILE      the vehicle's poses as a prior for ICP: a TUM trajectory (camera to\n"
      "                       world, interpolated to each frame's time; the first frame's pose\n"
      "                       anchors it), or "
      "sim[:drift=R,drift_rad=R,noise=M,noise_rad=R,seed=N]\n"
      "                       for a drifting noisy odometry of the source's ground truth\n"
      "                       (default 1 %%/m drift); writes DIR/odometry.txt\n"
      "  --odometry-mode M    prior (default): ICP from the odometry's motion, the odometry wins\n"
      "                       when ICP is lost or off by more than 3 cm / 2 deg;\n"
      "                       only: fuse at the odometry without ICP\n"
      "  --bilateral          bilateral-filter the depth before tracking\n"
      "  --icp-depth-knee M   ICP weighs pairs by 1/(1+(z/M)^4) (default 1; 0: all alike)\n"
      "  --no-noise           sim: noiseless depth\n"
      "  --seed N             sim: noise seed (default 1)\n"
      "  --real-time          replay at the recorded rate, dropping frames when late\n"
      "  --budget-new-blocks N, --budget-blocks N, --budget-raycast-steps N,\n"
      "  --budget-icp A,B,C   per-frame work budgets (ICP: finest,middle,coarsest)\n"
      "  --no-mesh            skip mesh.ply\n"
      "  --mesh-scale S       multires mesh.ply from each block's current scale (default) or\n"
      "                       finest: the finest scale it was fused at (static scenes)\n"
      "  --write-frames       also write DIR/frames/render_NNNNNN.png for every frame\n"
      "  --save-map FILE      write the map to FILE at the end (also when stopped)\n"
      "  --save-every N       and after every N frames (needs --save-map)\n"
      "  --load-map FILE      start from a saved map (its voxel type, size, mu and cube win over\n"
      "                       --map, --voxel-size, --mu, --map-size); the first frame's pose "
      "comes\n"
      "                       from the source's ground truth or --initial-pose\n"
      "  --initial-pose tx,ty,tz,qx,qy,qz,qw   first camera pose in the world (metres, unit\n"
      "                       quaternion), instead of the source's ground truth (default:\n"
      "                       the ground truth, else identity)\n"
      "  --no-free-space      do not record free space (queries then know only the TSDF band)\n"
      "  --query-points FILE  answer FILE's points (one 'x y z' per line, metres, world frame)\n"
      "                       against the final map into DIR/queries.txt:\n"
      "                       'x y z STATE DISTANCE', STATE outside|unknown|free|near|inside\n"
      "  --quiet              no progress line\n",
      program, default_source, supported_sources().c_str());
}

int parse_run_args(int argc, char** argv, RunOptions* options_out, bool* help) {
  RunOptions& options = *options_out;
  *help = false;
  bool odometry_mode_given = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto need_value = [&](std::string* value) {
      if (i + 1 >= argc) return false;
      *value = argv[++i];
      return true;
    };
    std::string value;
    double number = 0.0;
    std::int64_t integer = 0;
    if (arg == "-h" || arg == "--help") {
      *help = true;
      return 0;
    } else if (arg == "--source") {
      if (!need_value(&options.source_spec)) return fail("--source needs a value");
    } else if (arg == "--out") {
      if (!need_value(&options.out_dir) || options.out_dir.empty()) {
        return fail("--out needs a folder name");
      }
    } else if (arg == "--map") {
      if (!need_value(&value)) return fail("--map needs multires or single");
      if (value == "multires") {
        options.map_kind = MapKind::multires;
      } else if (value == "single") {
        options.map_kind = MapKind::single_res;
      } else {
        return fail("--map must be multires or single, not '" + value + "'");
      }
    } else if (arg == "--voxel-size") {
      if (!need_value(&value) || !cli::parse_double(value, 1e-4, 1.0, number)) {
        return fail("--voxel-size needs metres in [0.0001, 1]");
      }
      options.voxel_size_m = static_cast<float>(number);
    } else if (arg == "--mu") {
      if (!need_value(&value) || !cli::parse_double(value, 1e-4, 10.0, number)) {
        return fail("--mu needs metres in [0.0001, 10]");
      }
      options.mu_m = static_cast<float>(number);
    } else if (arg == "--map-size") {
      if (!need_value(&value) || !cli::parse_double(value, 0.1, 10000.0, number)) {
        return fail("--map-size needs metres in [0.1, 10000]");
      }
      options.map_size_m = static_cast<float>(number);
    } else if (arg == "--map-memory") {
      if (!need_value(&value) || !cli::parse_double(value, 1.0, 1e6, number)) {
        return fail("--map-memory needs megabytes in [1, 1e6]");
      }
      options.map_memory_mb = static_cast<float>(number);
    } else if (arg == "--max-blocks") {
      if (!need_value(&value) || !cli::parse_int(value, 1, 1 << 30, integer)) {
        return fail("--max-blocks needs a count in [1, 2^30]");
      }
      options.max_blocks = static_cast<std::uint32_t>(integer);
    } else if (arg == "--frames") {
      if (!need_value(&value) || !cli::parse_int(value, 1, 100000000, integer)) {
        return fail("--frames needs a positive count");
      }
      options.max_frames = static_cast<long>(integer);
      options.source.frames = static_cast<long>(integer);
    } else if (arg == "--threads") {
      if (!need_value(&value) || !cli::parse_int(value, 1, 64, integer)) {
        return fail("--threads needs a count in [1, 64]");
      }
      options.threads = static_cast<int>(integer);
    } else if (arg == "--intrinsics") {
      if (!need_value(&value) || !cli::parse_intrinsics(value, options.source.intrinsics)) {
        return fail("--intrinsics needs fx,fy,cx,cy with fx, fy > 0");
      }
      options.source.have_intrinsics = true;
    } else if (arg == "--depth-scale") {
      if (!need_value(&value) || !cli::parse_double(value, 1e-3, 1e7, number)) {
        return fail("--depth-scale needs raw units per metre in [0.001, 1e7]");
      }
      options.source.depth_scale = number;
    } else if (arg == "--seed") {
      if (!need_value(&value) || !cli::parse_int(value, 0, INT64_MAX, integer)) {
        return fail("--seed needs a non-negative integer");
      }
      options.source.seed = static_cast<unsigned long long>(integer);
    } else if (arg == "--budget-new-blocks" || arg == "--budget-blocks") {
      if (!need_value(&value) || !cli::parse_int(value, 0, UINT32_MAX, integer)) {
        return fail(arg + " needs a count");
      }
      (arg == "--budget-blocks" ? options.budget.max_integrated_blocks
                                : options.budget.max_new_blocks) =
          static_cast<std::uint32_t>(integer);
    } else if (arg == "--budget-raycast-steps") {
      if (!need_value(&value) || !cli::parse_int(value, 1, INT64_MAX, integer)) {
        return fail("--budget-raycast-steps needs a positive count");
      }
      options.budget.raycast_steps = static_cast<std::uint64_t>(integer);
    } else if (arg == "--budget-icp") {
      int levels[3];
      int consumed = 0;
      if (!need_value(&value) ||
          std::sscanf(value.c_str(), "%d,%d,%d%n", &levels[0], &levels[1], &levels[2], &consumed) !=
              3 ||
          static_cast<std::size_t>(consumed) != value.size() || levels[0] < 0 || levels[1] < 0 ||
          levels[2] < 0 || levels[0] > 100 || levels[1] > 100 || levels[2] > 100) {
        return fail("--budget-icp needs three iteration counts A,B,C in [0, 100]");
      }
      if (levels[0] + levels[1] + levels[2] == 0) {
        return fail("--budget-icp 0,0,0 would track nothing: give at least one iteration");
      }
      for (int l = 0; l < 3; ++l) options.budget.icp_iterations[l] = levels[l];
    } else if (arg == "--gt-poses") {
      options.pose_source = PoseSource::ground_truth;
    } else if (arg == "--odometry") {
      if (!need_value(&options.odometry) || options.odometry.empty()) {
        return fail("--odometry needs a TUM trajectory file or sim[:options]");
      }
    } else if (arg == "--odometry-mode") {
      if (!need_value(&value) || (value != "prior" && value != "only")) {
        return fail("--odometry-mode must be prior or only");
      }
      odometry_mode_given = true;
      options.odometry_only = value == "only";
    } else if (arg == "--odometry-weight") {
      double t = 0.0, r = 0.0;
      char tail = 0;
      if (!need_value(&value) || std::sscanf(value.c_str(), "%lf,%lf%c", &t, &r, &tail) != 2 ||
          !std::isfinite(t) || !std::isfinite(r) || t < 0.0 || r < 0.0) {
        return fail(
            "--odometry-weight needs T,R >= 0 (pull towards the odometry, per m^2 and rad^2)");
      }
      options.odometry_information[0] = t;
      options.odometry_information[1] = r;
    } else if (arg == "--icp-depth-knee") {
      if (!need_value(&value) || !cli::parse_double(value, 0.0, 100.0, number)) {
        return fail("--icp-depth-knee needs metres in [0, 100]");
      }
      options.icp_depth_knee_m = static_cast<float>(number);
    } else if (arg == "--bilateral") {
      options.bilateral = true;
    } else if (arg == "--no-noise") {
      options.source.sim_noise = false;
    } else if (arg == "--real-time") {
      options.source.real_time = true;
    } else if (arg == "--write-frames") {
      options.write_frames = true;
    } else if (arg == "--no-mesh") {
      options.write_mesh = false;
    } else if (arg == "--mesh-scale") {
      if (!need_value(&value) || !parse_mesh_read_scale(value, &options.mesh_read_scale)) {
        return fail("--mesh-scale must be current or finest");
      }
    } else if (arg == "--save-map") {
      if (!need_value(&options.save_map_path) || options.save_map_path.empty()) {
        return fail("--save-map needs a file name");
      }
    } else if (arg == "--save-every") {
      if (!need_value(&value) || !cli::parse_int(value, 1, 100000000, integer)) {
        return fail("--save-every needs a positive frame count");
      }
      options.save_every = static_cast<long>(integer);
    } else if (arg == "--load-map") {
      if (!need_value(&options.load_map_path) || options.load_map_path.empty()) {
        return fail("--load-map needs a file name");
      }
    } else if (arg == "--initial-pose") {
      if (!need_value(&value) || !parse_pose(value, &options.initial_T_W_C)) {
        return fail("--initial-pose needs tx,ty,tz,qx,qy,qz,qw (metres, a unit quaternion)");
      }
      options.have_initial_pose = true;
    } else if (arg == "--no-free-space") {
      options.free_space = false;
    } else if (arg == "--query-points") {
      if (!need_value(&options.query_points_path) || options.query_points_path.empty()) {
        return fail("--query-points needs a file");
      }
    } else if (arg == "--quiet") {
      options.progress = false;
    } else {
      return fail("unknown option '" + arg + "' (see --help)");
    }
  }
  if (odometry_mode_given && options.odometry.empty()) {
    return fail("--odometry-mode needs --odometry");
  }
  if (!options.odometry.empty() && options.pose_source == PoseSource::ground_truth) {
    return fail("--odometry and --gt-poses exclude each other");
  }

  if (options.save_every > 0 && options.save_map_path.empty()) {
    return fail("--save-every needs --save-map FILE");
  }
  return 0;
}

void print_run_summary(const RunOptions& options, const RunSummary& summary) {
  std::vector<double> totals;
  for (const auto& s : summary.frames) totals.push_back(s.times.total_ms);
  const auto total = percentiles(totals);
  std::printf(
      "%zu frames (%llu lost, %llu rejected, %llu skipped by the source) in %.1f s; "
      "per frame median %.1f ms, p99 %.1f ms\n",
      summary.frames.size(), static_cast<unsigned long long>(summary.frames_lost),
      static_cast<unsigned long long>(summary.frames_rejected),
      static_cast<unsigned long long>(summary.frames_skipped_by_source), summary.wall_s,
      total.median, total.p99);
  std::printf("map: %u blocks of %u (%.1f MB used, %.1f MB reserved)\n",
              summary.map_memory.blocks_used, summary.map_memory.block_capacity,
              static_cast<double>(summary.map_memory.bytes_used) / 1048576.0,
              static_cast<double>(summary.map_memory.bytes_reserved) / 1048576.0);
  if (summary.have_ate) {
    std::printf("ATE RMSE %.2f cm (max %.2f cm)\n", summary.ate_rmse_m * 100.0,
                summary.ate_max_m * 100.0);
  }
  if (summary.map_loaded) {
    std::printf("loaded %s: %u blocks in %.3f s\n", options.load_map_path.c_str(),
                summary.map_loaded_blocks, summary.map_load_s);
  }
  if (!summary.files_written.empty()) {
    std::string names;
    for (const std::string& name : summary.files_written) {
      names += (names.empty() ? "" : ",") + name;
    }
    std::printf("wrote %s/{%s}\n", options.out_dir.c_str(), names.c_str());
  }
  if (summary.map_saves > 0) {
    std::printf("wrote %s (%.1f MB in %.3f s; %u saves)\n", options.save_map_path.c_str(),
                static_cast<double>(summary.map_file_bytes) / 1048576.0, summary.map_last_save_s,
                summary.map_saves);
  }
  if (!options.odometry.empty()) {
    std::printf(
        "odometry: %llu frames without it, %llu fused at it after ICP was lost, %llu "
        "after ICP disagreed",
        static_cast<unsigned long long>(summary.frames_without_odometry),
        static_cast<unsigned long long>(summary.frames_prior_lost),
        static_cast<unsigned long long>(summary.frames_prior_gate));
    if (summary.have_odometry_ate) {
      std::printf("; odometry alone ATE RMSE %.2f cm", summary.odometry_ate_rmse_m * 100.0);
    }
    std::printf("\n");
  }
}

}  // namespace octofuse::examples
