#include "run_args.hpp"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "cli.hpp"

namespace octofuse::examples {

using cli::fail;

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
      "  --odometry-weight T,R   prior mode: how strongly ICP is pulled towards the odometry\n"
      "                       (per m^2 and rad^2; default 300,300; 0,0: not at all)\n"
      "  --initial-pose tx,ty,tz,qx,qy,qz,qw   the first frame's pose when the source has no\n"
      "                       ground truth (default identity)\n"
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
      if (!need_value(&options.out_dir)) return fail("--out needs a folder");
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
      if (!need_value(&value) ||
          std::sscanf(value.c_str(), "%d,%d,%d", &levels[0], &levels[1], &levels[2]) != 3 ||
          levels[0] < 0 || levels[1] < 0 || levels[2] < 0 || levels[0] > 100 || levels[1] > 100 ||
          levels[2] > 100) {
        return fail("--budget-icp needs three iteration counts A,B,C in [0, 100]");
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
    } else if (arg == "--initial-pose") {
      double v[7];
      char tail = 0;
      if (!need_value(&value) ||
          std::sscanf(value.c_str(), "%lf,%lf,%lf,%lf,%lf,%lf,%lf%c", &v[0], &v[1], &v[2], &v[3],
                      &v[4], &v[5], &v[6], &tail) != 7) {
        return fail("--initial-pose needs tx,ty,tz,qx,qy,qz,qw");
      }
      bool finite = true;
      for (double x : v) finite = finite && std::isfinite(x);
      const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
      if (!finite || !(q.norm() > 1e-6)) {
        return fail("--initial-pose needs finite numbers and a non-zero quaternion");
      }
      options.initial_T_W_C = Se3d::Identity();
      options.initial_T_W_C.linear() = q.normalized().toRotationMatrix();
      options.initial_T_W_C.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
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
  std::printf("wrote %s/{trajectory.txt,mesh.ply,render.png,stats.json,stage_times.svg}\n",
              options.out_dir.c_str());
}

}  // namespace octofuse::examples
