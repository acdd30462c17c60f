#include "run_args.hpp"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "cli.hpp"
#include "config_file.hpp"
#include "live_server.hpp"

namespace octofuse::examples {

using cli::fail;

namespace {

// One command-line option. The command line and configuration files go through this one table, so
// an option added here is configurable from a file and printed by --print-config with no more code.
struct RunOption {
  const char* name;  // without "--"; also the config-file key
  const char*
      value;         // the argument's name in the usage; nullptr: a flag (in a file: true or false)
  const char* help;  // the usage text (cli::format_option)
  // Applies `value` (a flag's setter gets ""); returns "" or what follows the name in the error.
  std::string (*set)(RunOptions& options, const std::string& value);
  // The effective value as the option's argument (flags: "true"/"false"); false when it is the
  // program's built-in default that no argument spells (printed as a comment).
  bool (*get)(const RunOptions& options, std::string* value);
};

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

std::string text_of(double number) {
  char text[32];
  const auto result = std::to_chars(text, text + sizeof(text), number);
  return std::string(text, result.ptr);
}

std::string text_of(float number) {
  char text[32];
  const auto result = std::to_chars(text, text + sizeof(text), number);
  return std::string(text, result.ptr);
}

std::string set_float(const std::string& value, double min, double max, float* out,
                      const char* error) {
  double number = 0.0;
  if (!cli::parse_double(value, min, max, number)) return error;
  *out = static_cast<float>(number);
  return std::string();
}

bool flag(bool on, std::string* value) {
  *value = on ? "true" : "false";
  return true;
}

const RunOption kRunOptions[] = {
    {"source", "SPEC", "where depth comes from (default %s):",
     [](RunOptions& o, const std::string& v) {
       o.source_spec = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.source_spec;
       return true;
     }},
    {"out", "DIR", "output folder (default octofuse-out)",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a folder name");
       o.out_dir = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.out_dir;
       return !o.out_dir.empty();
     }},
    {"record", "FILE",
     "write the frames received, their intrinsics, timestamps, ground\n"
     "truth and --odometry as a ROS 2 bag (MCAP); replay it with\n"
     "mcap:FILE (and --odometry mcap:FILE)",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a file name");
       o.record = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.record;
       return !o.record.empty();
     }},
    {"map", "KIND",
     "multires (default), single (single-resolution baseline) or\n"
     "multires16 (multires in 16-bit fixed point, half the memory)",
     [](RunOptions& o, const std::string& v) {
       if (!parse_map_option(v, &o.map_kind)) {
         return " must be multires, single or multires16, not '" + v + "'";
       }
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = map_option_name(o.map_kind);
       return true;
     }},
    {"voxel-size", "M", "finest voxel edge in metres (default 0.01)",
     [](RunOptions& o, const std::string& v) {
       return set_float(v, 1e-4, 1.0, &o.voxel_size_m, " needs metres in [0.0001, 1]");
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.voxel_size_m);
       return true;
     }},
    {"mu", "M", "truncation distance in metres (default 8 voxels)",
     [](RunOptions& o, const std::string& v) {
       return set_float(v, 1e-4, 10.0, &o.mu_m, " needs metres in [0.0001, 10]");
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.mu_m);
       return o.mu_m > 0.0f;
     }},
    {"band-behind", "F",
     "voxels are updated up to F * mu behind the surface, F in (0, 1]\n"
     "(default 1; shorter keeps thin objects and the surfaces behind\n"
     "them apart, see docs/results.md)",
     [](RunOptions& o, const std::string& v) {
       return set_float(v, 0.01, 1.0, &o.band_behind_mu, " needs a share of mu in [0.01, 1]");
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.band_behind_mu);
       return o.band_behind_mu != 1.0f;
     }},
    {"allocation-step", "N",
     "allocation marches every N-th pixel's ray in x and y (default 1:\n"
     "every pixel's; 2 marches a quarter of them, and free space beside\n"
     "thin bars is then not always safe, see docs/results.md)",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 1, 16, integer)) return std::string(" needs a count in [1, 16]");
       o.allocation_step = static_cast<int>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.allocation_step);
       return o.allocation_step != FusionConfig{}.allocation_pixel_step;
     }},
    {"allocation-group-px", "PX",
     "allocation marches one ray of each 2 x 2 group of pixels where a block\n"
     "spans at least PX pixels at its depth and the group's depths agree\n"
     "(default 8; 0 marches every ray, as before it)",
     [](RunOptions& o, const std::string& v) {
       return set_float(v, 0.0, 1000.0, &o.allocation_group_block_px, " needs pixels in [0, 1000]");
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.allocation_group_block_px);
       return o.allocation_group_block_px != FusionConfig{}.allocation_group_block_px;
     }},
    {"map-size", "M", "side of the mapped cube in metres (default 8)",
     [](RunOptions& o, const std::string& v) {
       return set_float(v, 0.1, 10000.0, &o.map_size_m, " needs metres in [0.1, 10000]");
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.map_size_m);
       return true;
     }},
    {"map-memory", "MB",
     "the map's memory: blocks, their finest and mid levels, inner nodes and\n"
     "hash (stats.json map_bytes_reserved), when --max-blocks is not given\n"
     "(default 1024)",
     [](RunOptions& o, const std::string& v) {
       return set_float(v, 1.0, 1e6, &o.map_memory_mb, " needs megabytes in [1, 1e6]");
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.map_memory_mb);
       return true;
     }},
    {"max-blocks", "N", "block pool capacity",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 1, 1 << 30, integer))
         return std::string(" needs a count in [1, 2^30]");
       o.max_blocks = static_cast<std::uint32_t>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.max_blocks);
       return o.max_blocks > 0;
     }},
    {"prefault-blocks", "N",
     "write the pages of the first N blocks (their levels and nodes) before\n"
     "the first frame, so it pays no first-touch page faults (default 8192; 0: none)",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 0, 1 << 30, integer))
         return std::string(" needs a count in [0, 2^30]");
       o.prefault_blocks = static_cast<std::uint32_t>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.prefault_blocks);
       return true;
     }},
    {"frames", "N", "stop after N frames (sim: also the sequence length)",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 1, 100000000, integer)) return std::string(" needs a positive count");
       o.max_frames = static_cast<long>(integer);
       o.source.frames = static_cast<long>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.max_frames);
       return o.max_frames > 0;
     }},
    {"threads", "N",
     "worker threads (default: the machine's cores, at most 64; the\n"
     "results are the same for any count)",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 1, 64, integer)) return std::string(" needs a count in [1, 64]");
       o.threads = static_cast<int>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.threads);
       return true;
     }},
    {"intrinsics", "fx,fy,cx,cy", "override the source's intrinsics (pixels)",
     [](RunOptions& o, const std::string& v) {
       if (!cli::parse_intrinsics(v, o.source.intrinsics)) {
         return std::string(" needs fx,fy,cx,cy with fx, fy > 0");
       }
       o.source.have_intrinsics = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       const double* k = o.source.intrinsics;
       *v = text_of(k[0]) + "," + text_of(k[1]) + "," + text_of(k[2]) + "," + text_of(k[3]);
       return o.source.have_intrinsics;
     }},
    {"depth-scale", "S", "raw depth units per metre (TUM 5000, mm 1000)",
     [](RunOptions& o, const std::string& v) {
       if (!cli::parse_double(v, 1e-3, 1e7, o.source.depth_scale)) {
         return std::string(" needs raw units per metre in [0.001, 1e7]");
       }
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.source.depth_scale);
       return o.source.depth_scale > 0.0;
     }},
    {"seed", "N", "sim: noise seed (default 1)",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 0, INT64_MAX, integer)) {
         return std::string(" needs a non-negative integer");
       }
       o.source.seed = static_cast<unsigned long long>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.source.seed);
       return o.source.seed <= static_cast<unsigned long long>(INT64_MAX);
     }},
    {"budget-new-blocks", "N", "per-frame work budget: new blocks",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 0, UINT32_MAX, integer)) return std::string(" needs a count");
       o.budget.max_new_blocks = static_cast<std::uint32_t>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.budget.max_new_blocks);
       return true;
     }},
    {"budget-blocks", "N", "per-frame work budget: blocks integrated",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 0, UINT32_MAX, integer)) return std::string(" needs a count");
       o.budget.max_integrated_blocks = static_cast<std::uint32_t>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.budget.max_integrated_blocks);
       return true;
     }},
    {"budget-raycast-steps", "N", "per-frame work budget: ray-cast steps",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 1, INT64_MAX, integer)) {
         return std::string(" needs a positive count");
       }
       o.budget.raycast_steps = static_cast<std::uint64_t>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.budget.raycast_steps);
       return o.budget.raycast_steps > 0 &&
              o.budget.raycast_steps <= static_cast<std::uint64_t>(INT64_MAX);
     }},
    {"raycast-half", nullptr,
     "reference ray-cast at half resolution (the default: every other pixel in x and y, a\n"
     "quarter of its work; the model ICP tracks against is coarser)",
     [](RunOptions& o, const std::string&) {
       o.budget.raycast_half = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.budget.raycast_half, v); }},
    {"raycast-full", nullptr,
     "reference ray-cast at every pixel (four times the work of --raycast-half)",
     [](RunOptions& o, const std::string&) {
       o.budget.raycast_half = false;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(!o.budget.raycast_half, v); }},
    {"budget-icp", "A,B,C", "per-frame work budget: ICP iterations (finest,middle,coarsest)",
     [](RunOptions& o, const std::string& v) {
       int levels[3];
       char tail = 0;
       if (std::sscanf(v.c_str(), "%d,%d,%d%c", &levels[0], &levels[1], &levels[2], &tail) != 3 ||
           levels[0] < 0 || levels[1] < 0 || levels[2] < 0 || levels[0] > 100 || levels[1] > 100 ||
           levels[2] > 100) {
         return std::string(" needs three iteration counts A,B,C in [0, 100]");
       }
       if (levels[0] + levels[1] + levels[2] == 0) {
         return std::string(" 0,0,0 would track nothing: give at least one iteration");
       }
       for (int l = 0; l < 3; ++l) o.budget.icp_iterations[l] = levels[l];
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       const int* it = o.budget.icp_iterations;
       *v = std::to_string(it[0]) + "," + std::to_string(it[1]) + "," + std::to_string(it[2]);
       return true;
     }},
    {"gt-poses", nullptr, "fuse with ground-truth poses instead of tracking",
     [](RunOptions& o, const std::string&) {
       o.pose_source = PoseSource::ground_truth;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       return flag(o.pose_source == PoseSource::ground_truth, v);
     }},
    {"icp-depth-knee", "M", "ICP weighs pairs by 1/(1+(z/M)^4) (default 1; 0: all alike)",
     [](RunOptions& o, const std::string& v) {
       return set_float(v, 0.0, 100.0, &o.icp_depth_knee_m, " needs metres in [0, 100]");
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.icp_depth_knee_m);
       return o.icp_depth_knee_m >= 0.0f;
     }},
    {"icp-quarter", nullptr,
     "ICP's finest passes take one pixel of each 2 x 2 against the half-resolution\n"
     "reference (half the checkerboard's work; on sim:desk 1-2 % worse ATE)",
     [](RunOptions& o, const std::string&) {
       o.icp_quarter = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.icp_quarter, v); }},
    {"icp-full-middle", nullptr,
     "ICP's middle-level passes take every pixel (default: every other pixel, the\n"
     "halves in turn, a quarter less ICP work)",
     [](RunOptions& o, const std::string&) {
       o.icp_full_middle = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.icp_full_middle, v); }},
    {"bilateral", nullptr, "bilateral-filter the depth before tracking",
     [](RunOptions& o, const std::string&) {
       o.bilateral = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.bilateral, v); }},
    {"no-noise", nullptr, "sim: noiseless depth",
     [](RunOptions& o, const std::string&) {
       o.source.sim_noise = false;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(!o.source.sim_noise, v); }},
    {"real-time", nullptr, "replay at the recorded rate, dropping frames when late",
     [](RunOptions& o, const std::string&) {
       o.source.real_time = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.source.real_time, v); }},
    {"write-frames", nullptr, "also write DIR/frames/render_NNNNNN.png for every frame",
     [](RunOptions& o, const std::string&) {
       o.write_frames = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.write_frames, v); }},
    {"no-mesh", nullptr, "skip mesh.ply",
     [](RunOptions& o, const std::string&) {
       o.write_mesh = false;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(!o.write_mesh, v); }},
    {"mesh-scale", "S",
     "multires mesh.ply from each block's current scale (default) or\n"
     "finest: the finest scale it was fused at (static scenes)",
     [](RunOptions& o, const std::string& v) {
       if (!parse_mesh_read_scale(v, &o.mesh_read_scale)) {
         return std::string(" must be current or finest");
       }
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.mesh_read_scale == MeshReadScale::finest_fused ? "finest" : "current";
       return true;
     }},
    {"odometry", "FILE",
     "the vehicle's poses as a prior for ICP: a TUM trajectory (camera to\n"
     "world, interpolated to each frame's time; the first frame's pose\n"
     "anchors it), a bag's poses (mcap:FILE or rosbag:FILE [?pose=TOPIC],\n"
     "Odometry or PoseStamped; else the camera in /tf's odom frame,\n"
     "?tf=FRAME), or\n"
     "sim[:drift=R,drift_rad=R,noise=M,noise_rad=R,seed=N]\n"
     "for a drifting noisy odometry of the source's ground truth\n"
     "(default 1 %/m drift); writes DIR/odometry.txt",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a TUM trajectory file or sim[:options]");
       o.odometry = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.odometry;
       return !o.odometry.empty();
     }},
    {"odometry-mode", "M",
     "prior (default): ICP from the odometry's motion, the odometry wins\n"
     "when ICP is lost or off by more than 3 cm / 2 deg;\n"
     "only: fuse at the odometry without ICP",
     [](RunOptions& o, const std::string& v) {
       if (v != "prior" && v != "only") return std::string(" must be prior or only");
       o.odometry_only = v == "only";
       o.odometry_mode_given = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.odometry_only ? "only" : "prior";
       return !o.odometry.empty();
     }},
    {"odometry-weight", "T,R",
     "prior mode: a fixed pull instead of --odometry-noise (per m^2 and\n"
     "rad^2 in ICP's normal equations; 0,0: not at all)",
     [](RunOptions& o, const std::string& v) {
       double t = 0.0, r = 0.0;
       char tail = 0;
       if (std::sscanf(v.c_str(), "%lf,%lf%c", &t, &r, &tail) != 2 || !std::isfinite(t) ||
           !std::isfinite(r) || t < 0.0 || r < 0.0) {
         return std::string(" needs T,R >= 0 (pull towards the odometry, per m^2 and rad^2)");
       }
       o.odometry_information[0] = t;
       o.odometry_information[1] = r;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.odometry_information[0]) + "," + text_of(o.odometry_information[1]);
       return o.odometry_information[0] >= 0.0;
     }},
    {"odometry-noise", "M,R",
     "prior mode: the odometry's error per axis of its motion over\n"
     "one frame (metres, radians; default 0.0015,0.0015): ICP is pulled\n"
     "towards it by the two estimates' uncertainties",
     [](RunOptions& o, const std::string& v) {
       double m = 0.0, r = 0.0;
       char tail = 0;
       if (std::sscanf(v.c_str(), "%lf,%lf%c", &m, &r, &tail) != 2 || !(m >= 1e-9) || !(m <= 1e3) ||
           !(r >= 1e-9) || !(r <= 1e3)) {
         return std::string(
             " needs M,R in [1e-9, 1e3] (the odometry's error per frame, metres and radians)");
       }
       o.odometry_noise[0] = m;
       o.odometry_noise[1] = r;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.odometry_noise[0]) + "," + text_of(o.odometry_noise[1]);
       return o.odometry_noise[0] > 0.0;
     }},
    {"initial-pose", "tx,ty,tz,qx,qy,qz,qw",
     "first camera pose in the world (metres, unit\n"
     "quaternion), instead of the source's ground truth (default:\n"
     "the ground truth, else identity)",
     [](RunOptions& o, const std::string& v) {
       if (!parse_pose(v, &o.initial_T_W_C)) {
         return std::string(" needs tx,ty,tz,qx,qy,qz,qw (metres, a unit quaternion)");
       }
       o.have_initial_pose = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       const Eigen::Vector3d t = o.initial_T_W_C.translation();
       const Eigen::Quaterniond q(o.initial_T_W_C.linear());
       *v = text_of(t.x()) + "," + text_of(t.y()) + "," + text_of(t.z()) + "," + text_of(q.x()) +
            "," + text_of(q.y()) + "," + text_of(q.z()) + "," + text_of(q.w());
       return o.have_initial_pose;
     }},
    {"save-map", "FILE",
     "write the map and its free space to FILE at the end (also when\n"
     "stopped)",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a file name");
       o.save_map_path = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.save_map_path;
       return !o.save_map_path.empty();
     }},
    {"save-every", "N", "and after every N frames (needs --save-map)",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 1, 100000000, integer)) {
         return std::string(" needs a positive frame count");
       }
       o.save_every = static_cast<long>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.save_every);
       return o.save_every > 0;
     }},
    {"load-map", "FILE",
     "start from a saved map (its voxel type, size, mu and cube win over\n"
     "--map, --voxel-size, --mu, --map-size; its free space comes back\n"
     "unless --no-free-space); the first frame's pose comes\n"
     "from the source's ground truth or --initial-pose",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a file name");
       o.load_map_path = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.load_map_path;
       return !o.load_map_path.empty();
     }},
    {"map-file", "FILE",
     "keep evicted blocks in FILE (an append-only store, created when\n"
     "absent), and the free space the pool forgets in FILE.free, and read\n"
     "them back when the camera returns (needs eviction)",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a file name");
       o.map_file_path = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.map_file_path;
       return !o.map_file_path.empty();
     }},
    {"map-file-finest", "on|off",
     "with --map-file, keep the finest levels the pool gives up in\n"
     "FILE.fine and read them back when their blocks refine (default on;\n"
     "off: they are interpolated afresh, no disk work for them)",
     [](RunOptions& o, const std::string& v) {
       if (v != "on" && v != "off") return std::string(" needs on or off");
       o.map_file_finest = v == "on";
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.map_file_finest ? "on" : "off";
       return !o.map_file_finest;
     }},
    {"evict", "HIGH,LOW",
     "when the block or finest-level pool is over HIGH % full, evict the\n"
     "blocks farthest from the camera until it is at LOW % (default\n"
     "90,80; off: a full pool refuses new blocks instead)",
     [](RunOptions& o, const std::string& v) {
       if (v == "off") {
         o.eviction.enabled = false;
         return std::string();
       }
       double high = 0.0;
       double low = 0.0;
       char tail = 0;
       if (std::sscanf(v.c_str(), "%lf,%lf%c", &high, &low, &tail) != 2 || !(low > 0.0) ||
           !(low < high) || !(high <= 100.0)) {
         return std::string(" needs HIGH,LOW percentages with 0 < LOW < HIGH <= 100, or off");
       }
       o.eviction.enabled = true;
       o.eviction.high_water = static_cast<float>(high / 100.0);
       o.eviction.low_water = static_cast<float>(low / 100.0);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       if (!o.eviction.enabled) {
         *v = "off";
       } else {
         *v =
             text_of(o.eviction.high_water * 100.0f) + "," + text_of(o.eviction.low_water * 100.0f);
       }
       return true;
     }},
    {"finest-turn", "N",
     "a block in view keeps a finest level it got for at least N frames\n"
     "before eviction may give it to another block of a view larger than\n"
     "the finest-level pool (default 30)",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 0, UINT32_MAX, integer)) {
         return std::string(" needs a count of frames");
       }
       o.eviction.finest_turn_frames = static_cast<std::uint32_t>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.eviction.finest_turn_frames);
       return true;
     }},
    {"budget-evict", "N", "evict at most N blocks per frame",
     [](RunOptions& o, const std::string& v) {
       std::int64_t integer = 0;
       if (!cli::parse_int(v, 1, UINT32_MAX, integer)) {
         return std::string(" needs a positive count");
       }
       o.budget.max_evictions = static_cast<std::uint32_t>(integer);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = std::to_string(o.budget.max_evictions);
       return o.budget.max_evictions > 0;
     }},
    {"deadline-ms", "D",
     "keep each frame within D ms (0: off): the budgets above are derived\n"
     "per frame from a cost model of this machine, learnt as it runs,\n"
     "cut in the degradation order (ICP, voxel updates, ray-cast steps,\n"
     "free space); stats.json says what each frame gave up",
     [](RunOptions& o, const std::string& v) {
       double number = 0.0;
       if (!cli::parse_double(v, 0.0, 10000.0, number)) {
         return std::string(" needs milliseconds in [0, 10000] (0: off)");
       }
       o.deadline_ms = number;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.deadline_ms);
       return o.deadline_ms > 0.0;
     }},
    {"deadline-calibration", "FILE",
     "start the cost model from FILE when it exists and write\n"
     "the learnt one to it after the run",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a file");
       o.deadline_calibration = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.deadline_calibration;
       return !o.deadline_calibration.empty();
     }},
    {"deadline-freeze", nullptr,
     "use FILE's model as it is, learning nothing: the same input and\n"
     "calibration give the same result on any machine and thread count",
     [](RunOptions& o, const std::string&) {
       o.deadline_freeze = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.deadline_freeze, v); }},
    {"no-free-space", nullptr, "do not record free space (queries then know only the TSDF band)",
     [](RunOptions& o, const std::string&) {
       o.free_space = false;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(!o.free_space, v); }},
    {"free-space-exact", nullptr,
     "settle octants beside nearer objects' silhouettes pixel by\n"
     "pixel: more air reads free, carving costs about 1.6x as much",
     [](RunOptions& o, const std::string&) {
       o.free_space_exact = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.free_space_exact, v); }},
    {"esdf", nullptr,
     "keep a distance field for planners (128^3 cells of 2 voxels over\n"
     "the middle of the cube, unknown space as obstacle); --query-points\n"
     "answers free points with it",
     [](RunOptions& o, const std::string&) {
       o.esdf = true;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(o.esdf, v); }},
    {"esdf-follow", "M",
     "--esdf with the window following the camera: re-centred on it\n"
     "whenever the camera is more than M metres from its centre (each\n"
     "move rebuilds the window over the next frames)",
     [](RunOptions& o, const std::string& v) {
       double number = 0.0;
       if (!cli::parse_double(v, 0.001, 1000.0, number)) {
         return std::string(" needs metres in [0.001, 1000]");
       }
       o.esdf = true;
       o.esdf_follow_m = static_cast<float>(number);
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = text_of(o.esdf_follow_m);
       return o.esdf_follow_m > 0.0f;
     }},
    {"query-points", "FILE",
     "answer FILE's points (one 'x y z' per line, metres, world frame)\n"
     "against the final map into DIR/queries.txt:\n"
     "'x y z STATE DISTANCE', STATE outside|unknown|free|near|inside",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs a file");
       o.query_points_path = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.query_points_path;
       return !o.query_points_path.empty();
     }},
    {"quiet", nullptr, "no progress line",
     [](RunOptions& o, const std::string&) {
       o.progress = false;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) { return flag(!o.progress, v); }},
    {"serve", "ADDR:PORT",
     "live view in a browser at http://ADDR:PORT/ (PORT alone: 127.0.0.1;\n"
     "another address, such as 0.0.0.0, opens it to the network)",
     [](RunOptions& o, const std::string& v) {
       if (v.empty()) return std::string(" needs PORT or ADDR:PORT");
       std::string host, port, why;
       if (!parse_serve_address(v, &host, &port, &why)) return " " + why;
       o.serve = v;
       return std::string();
     },
     [](const RunOptions& o, std::string* v) {
       *v = o.serve;
       return !o.serve.empty();
     }},
};

const RunOption* find_run_option(const std::string& name) {
  for (const RunOption& option : kRunOptions) {
    if (name == option.name) return &option;
  }
  return nullptr;
}

// Applies one config-file line: a flag takes true (apply it) or false (leave the default).
bool apply_config_entry(const ConfigEntry& entry, const std::string& file_name, RunOptions* options,
                        std::string* error) {
  const std::string where = file_name + ":" + std::to_string(entry.line) + ": ";
  if (entry.key == "config" || entry.key == "print-config" || entry.key == "help") {
    *error = where + "'" + entry.key + "' can only be given on the command line";
    return false;
  }
  const RunOption* option = find_run_option(entry.key);
  if (option == nullptr) {
    *error = where + "unknown key '" + entry.key + "'";
    return false;
  }
  if (option->value == nullptr) {
    if (entry.value == "false") return true;
    if (entry.value != "true") {
      *error = where + entry.key + " takes true or false, not '" + entry.value + "'";
      return false;
    }
  }
  const std::string message = option->set(*options, entry.value);
  if (!message.empty()) {
    *error = where + entry.key + message;
    return false;
  }
  return true;
}

}  // namespace

void print_run_usage(const char* program, const char* default_source) {
  std::string text = std::string("usage: ") + program +
                     " [--source SPEC] [--out DIR] [--map multires|single|multires16]\n"
                     "         [--voxel-size M] [--mu M] [--frames N] [--threads N]\n"
                     "         [--intrinsics fx,fy,cx,cy] [--depth-scale S] [options]\n"
                     "\n";
  for (const RunOption& option : kRunOptions) {
    if (std::string(option.name) == "source") {
      // The default depends on the program, the list of sources (indented) on its build.
      std::string help = option.help;
      help.replace(help.find("%s"), 2, default_source);
      text += cli::format_option("--source", option.value, help.c_str()) + supported_sources();
      continue;
    }
    text += cli::format_option(std::string("--") + option.name, option.value, option.help);
  }
  text += cli::format_option("--config", "FILE",
                             "read options from FILE: one 'key = value' a line, the key an option\n"
                             "without '--', flags true or false, '#' starts a comment line;\n"
                             "options on the command line override the file");
  text += cli::format_option("--print-config", nullptr,
                             "print the effective options in that format and exit");
  text += cli::format_option("-h, --help", nullptr, "this text");
  std::fputs(text.c_str(), stdout);
}

bool apply_run_config(const std::string& text, const std::string& file_name, RunOptions* options,
                      std::string* error) {
  std::vector<ConfigEntry> entries;
  if (!parse_config_text(text, file_name, &entries, error)) return false;
  for (const ConfigEntry& entry : entries) {
    if (!apply_config_entry(entry, file_name, options, error)) return false;
  }
  return true;
}

bool format_run_config(const RunOptions& options, std::string* text, std::string* error) {
  text->clear();
  for (const RunOption& option : kRunOptions) {
    std::string value;
    const bool set = option.get(options, &value);
    if (!set) {
      *text += std::string("# ") + option.name + " = (default)\n";
      continue;
    }
    if (!config_value_writable(value)) {
      *error = std::string("--") + option.name + " value '" + value +
               "' cannot be written to a config file (newline or surrounding blanks)";
      return false;
    }
    *text += std::string(option.name) + " = " + value + "\n";
  }
  return true;
}

bool parse_run_args(int argc, char** argv, RunOptions* options, RunArgsRequest* request,
                    std::string* error) {
  *request = RunArgsRequest();
  // The file first, whatever its place on the line, so that the command line overrides it.
  std::string config_path;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "-h" || arg == "--help") {
      request->help = true;
      return true;
    }
    if (arg == "--config") {
      if (i + 1 >= argc) {
        *error = "--config needs a file";
        return false;
      }
      if (!config_path.empty()) {
        *error = "--config given twice";
        return false;
      }
      config_path = argv[++i];
      if (config_path.empty()) {
        *error = "--config needs a file";
        return false;
      }
    } else if (arg == "--print-config") {
      request->print_config = true;
    } else if (const RunOption* option = arg.size() > 2 && arg[0] == '-' && arg[1] == '-'
                                             ? find_run_option(arg.substr(2))
                                             : nullptr) {
      if (option->value != nullptr) ++i;
    }
  }
  if (!config_path.empty()) {
    std::vector<ConfigEntry> entries;
    if (!read_config_file(config_path, &entries, error)) return false;
    for (const ConfigEntry& entry : entries) {
      if (!apply_config_entry(entry, config_path, options, error)) return false;
    }
  }
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--config") {
      ++i;
      continue;
    }
    if (arg == "--print-config") continue;
    const RunOption* option =
        arg.size() > 2 && arg[0] == '-' && arg[1] == '-' ? find_run_option(arg.substr(2)) : nullptr;
    if (option == nullptr) {
      *error = "unknown option '" + arg + "' (see --help)";
      return false;
    }
    std::string value;
    if (option->value != nullptr) {
      if (i + 1 >= argc) {
        RunOptions scratch;
        const std::string message = option->set(scratch, std::string());
        *error = arg + (message.empty() ? std::string(" needs a value") : message);
        return false;
      }
      value = argv[++i];
    }
    const std::string message = option->set(*options, value);
    if (!message.empty()) {
      *error = arg + message;
      return false;
    }
  }
  // Options that need one another, whether they came from the file or the command line.
  if (options->odometry_mode_given && options->odometry.empty()) {
    *error = "--odometry-mode needs --odometry";
    return false;
  }
  if (!options->odometry.empty() && options->pose_source == PoseSource::ground_truth) {
    *error = "--odometry and --gt-poses exclude each other";
    return false;
  }
  if (!options->deadline_calibration.empty() && !(options->deadline_ms > 0.0)) {
    *error = "--deadline-calibration needs --deadline-ms D (D > 0)";
    return false;
  }
  if (options->deadline_freeze && options->deadline_calibration.empty()) {
    *error = "--deadline-freeze needs --deadline-calibration FILE";
    return false;
  }
  if (options->save_every > 0 && options->save_map_path.empty()) {
    *error = "--save-every needs --save-map FILE";
    return false;
  }
  return true;
}

int parse_run_args(int argc, char** argv, RunOptions* options, bool* help, bool* printed_config) {
  RunArgsRequest request;
  std::string error;
  *help = false;
  if (printed_config != nullptr) *printed_config = false;
  if (!parse_run_args(argc, argv, options, &request, &error)) return fail(error);
  *help = request.help;
  if (request.print_config && !request.help) {
    std::string text;
    if (!format_run_config(*options, &text, &error)) return fail(error);
    std::fputs(text.c_str(), stdout);
    if (printed_config != nullptr) *printed_config = true;
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
  if (summary.frames_dropped_by_source > 0) {
    std::printf("source: %llu frames dropped, never read (the loop was late for them)\n",
                static_cast<unsigned long long>(summary.frames_dropped_by_source));
  }
  std::printf("map: %u blocks of %u (%.1f MB used, %.1f MB reserved)\n",
              summary.map_memory.blocks_used, summary.map_memory.block_capacity,
              static_cast<double>(summary.map_memory.bytes_used) / 1048576.0,
              static_cast<double>(summary.map_memory.bytes_reserved) / 1048576.0);
  if (summary.have_ate) {
    std::printf("ATE RMSE %.2f cm (max %.2f cm)\n", summary.ate_rmse_m * 100.0,
                summary.ate_max_m * 100.0);
  }
  if (options.deadline_ms > 0.0 && !summary.frames.empty()) {
    std::printf("deadline %.1f ms: %llu of %zu frames over (%.2f %%)\n", options.deadline_ms,
                static_cast<unsigned long long>(summary.frames_over_deadline),
                summary.frames.size(),
                100.0 * static_cast<double>(summary.frames_over_deadline) /
                    static_cast<double>(summary.frames.size()));
    if (summary.frames_fusion_skipped > 0) {
      std::printf("deadline: %llu frames not fused, %llu of them tracked only\n",
                  static_cast<unsigned long long>(summary.frames_fusion_skipped),
                  static_cast<unsigned long long>(summary.frames_track_only));
    }
  }
  if (summary.map_loaded) {
    std::printf("loaded %s: %u blocks, %u free-space nodes in %.3f s\n",
                options.load_map_path.c_str(), summary.map_loaded_blocks,
                summary.map_loaded_free_nodes, summary.map_load_s);
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
        "odometry: %llu frames without it, %llu dropped as implausible, %llu fused at it after "
        "ICP was lost, %llu after ICP disagreed",
        static_cast<unsigned long long>(summary.frames_without_odometry),
        static_cast<unsigned long long>(summary.priors_dropped),
        static_cast<unsigned long long>(summary.frames_prior_lost),
        static_cast<unsigned long long>(summary.frames_prior_gate));
    if (summary.have_odometry_ate) {
      std::printf("; odometry alone ATE RMSE %.2f cm", summary.odometry_ate_rmse_m * 100.0);
    }
    if (!options.odometry_only) {
      std::printf("; weighed as %.2f mm and %.2f mrad of noise per frame",
                  summary.odometry_noise_m * 1e3, summary.odometry_noise_rad * 1e3);
    }
    std::printf("\n");
  }
}

}  // namespace octofuse::examples
