// octofuse-bench: the numbers users compare. Runs a fixed matrix of settings over the built-in
// scenes (and 7-Scenes redkitchen when given), each cell several times interleaved with the cell
// it is compared against, and writes a markdown table, a JSON file and per-run stage-time plots.

#include <unistd.h>

#include <sys/stat.h>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "cli.hpp"
#include "octofuse/ports/host/json_writer.hpp"
#include "octofuse/ports/host/mesh_eval.hpp"
#include "octofuse/ports/sim/scenes.hpp"
#include "runner.hpp"
#include "soak.hpp"

namespace {

using octofuse::examples::Percentiles;
using octofuse::examples::percentiles;
using octofuse::examples::RunOptions;
using octofuse::examples::RunSummary;

struct Cell {
  std::string scene;  // source spec
  octofuse::MapKind map = octofuse::MapKind::multires;
  float voxel_m = 0.01f;
  int threads = 1;
  octofuse::PoseSource poses = octofuse::PoseSource::track;
  long frames = 0;
  octofuse::MeshReadScale mesh_read_scale = octofuse::MeshReadScale::current;
  bool raycast_half = true;  // the reference ray-cast at half resolution (the default)
  int allocation_step = octofuse::FusionConfig{}.allocation_pixel_step;  // --allocation-step
  // --allocation-group-px
  float allocation_group_px = octofuse::FusionConfig{}.allocation_group_block_px;

  std::string label() const {
    char text[192];
    char allocation[64] = "";
    if (allocation_step != octofuse::FusionConfig{}.allocation_pixel_step)
      std::snprintf(allocation, sizeof(allocation), " alloc%d", allocation_step);
    if (allocation_group_px != octofuse::FusionConfig{}.allocation_group_block_px) {
      const std::size_t used = std::strlen(allocation);
      std::snprintf(allocation + used, sizeof(allocation) - used, " group%gpx",
                    static_cast<double>(allocation_group_px));
    }
    std::snprintf(text, sizeof(text), "%s %s %gmm %dt %s%s%s", scene.c_str(),
                  octofuse::examples::map_option_name(map), static_cast<double>(voxel_m) * 1000.0,
                  threads, poses == octofuse::PoseSource::track ? "track" : "gt-poses",
                  raycast_half ? "" : " full-cast", allocation);
    return text;
  }
  std::string slug() const {
    std::string s = label();
    for (char& c : s) {
      if (c == ' ' || c == ':' || c == '/') c = '_';
    }
    return s;
  }
};

struct Repeat {
  Percentiles stage[5];  // preprocess, track, integrate, raycast, total
  double fps = 0.0;
  double peak_rss_mb = 0.0;
  RunSummary summary;
  double mesh_rmse_m = -1.0;
  double thin_recall = -1.0;
};

const char* kStageNames[5] = {"preprocess", "track", "integrate", "raycast", "total"};

// Resets the kernel's peak-RSS mark for this process (Linux >= 4.0) so each run reports its own.
void reset_peak_rss() {
  std::ofstream clear("/proc/self/clear_refs");
  if (clear) clear << "5";
}

double peak_rss_mb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::atof(line.c_str() + 6) / 1024.0;
  }
  return 0.0;
}

std::string cpu_model() {
  std::ifstream info("/proc/cpuinfo");
  std::string line;
  while (std::getline(info, line)) {
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  }
  return "unknown";
}

double median_of(std::vector<double> v) {
  return percentiles(std::move(v)).median;
}
double spread_of(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v.back() - v.front();
}

struct SimEvaluation {
  octofuse::sim::SimWorld world;
  std::vector<Eigen::Vector3d> thin_samples_W;
};

double scene_sdf(const Eigen::Vector3d& p_W, const void* context) {
  return static_cast<const SimEvaluation*>(context)->world.scene.distance_m(p_W);
}

bool load_sim_evaluation(const std::string& spec, SimEvaluation* eval) {
  octofuse::sim::SceneId id;
  const std::string name = spec.substr(4);
  if (!octofuse::sim::scene_id_from_name(name.c_str(), &id).ok()) return false;
  if (!octofuse::sim::build_world(id, &eval->world).ok()) return false;
  std::vector<Eigen::Vector3d> samples(20000);
  const std::size_t n = eval->world.scene.sample_surface(octofuse::sim::kThinParts, 7,
                                                         samples.data(), samples.size());
  samples.resize(n);
  eval->thin_samples_W = std::move(samples);
  return true;
}

Repeat run_cell(const Cell& cell, const std::string& out_dir, const SimEvaluation* eval,
                int* exit_code) {
  RunOptions options;
  options.source_spec = cell.scene;
  options.source.frames = cell.frames;
  options.max_frames = cell.frames;
  options.map_kind = cell.map;
  options.voxel_size_m = cell.voxel_m;
  options.threads = cell.threads;
  options.pose_source = cell.poses;
  options.out_dir = out_dir;
  options.write_mesh = false;
  options.keep_mesh = eval != nullptr;
  options.mesh_read_scale = cell.mesh_read_scale;
  options.budget.raycast_half = cell.raycast_half;
  options.allocation_step = cell.allocation_step;
  options.allocation_group_block_px = cell.allocation_group_px;
  options.progress = false;
  options.map_memory_mb = cell.voxel_m < 0.005f ? 2048.0f : 1024.0f;
  Repeat r;
  reset_peak_rss();
  *exit_code = octofuse::examples::run_pipeline(options, &r.summary);
  r.peak_rss_mb = peak_rss_mb();
  std::vector<double> stage[5];
  for (const octofuse::FrameStats& s : r.summary.frames) {
    stage[0].push_back(s.times.validate_ms + s.times.preprocess_ms);
    stage[1].push_back(s.times.track_ms);
    stage[2].push_back(s.times.integrate_ms);
    stage[3].push_back(s.times.raycast_ms);
    stage[4].push_back(s.times.total_ms);
  }
  for (int i = 0; i < 5; ++i) r.stage[i] = percentiles(stage[i]);
  r.fps = r.stage[4].median > 0.0 ? 1000.0 / r.stage[4].median : 0.0;
  if (eval != nullptr && !r.summary.mesh_positions.empty()) {
    octofuse::host::MeshView mesh;
    mesh.vertices = r.summary.mesh_positions.data();
    mesh.vertex_count = r.summary.mesh_positions.size();
    mesh.indices = r.summary.mesh_indices.data();
    mesh.triangle_count = r.summary.mesh_indices.size() / 3;
    r.mesh_rmse_m = octofuse::host::mesh_accuracy(mesh, &scene_sdf, eval).rmse_m;
    // A thin-structure sample counts as recovered when a mesh vertex lies within 2 voxels.
    r.thin_recall = octofuse::host::mesh_completeness(mesh, eval->thin_samples_W,
                                                      2.0 * static_cast<double>(cell.voxel_m))
                        .fraction;
  }
  r.summary.mesh_positions.clear();
  r.summary.mesh_indices.clear();
  return r;
}

// Median over repeats of one stage statistic of a cell.
double stage_stat(const std::vector<Repeat>& reps, int stage, double Percentiles::*stat) {
  std::vector<double> values;
  for (const Repeat& rep : reps) values.push_back(rep.stage[stage].*stat);
  return median_of(values);
}

// Integration of each multires cell against the single-res cell with the same settings (the
// matrix puts them next to each other), by four frame statistics: the median (a typical frame),
// the mean (sustained frame rate, the paper's measure), p90 and p99 (the slow frames a real-time
// budget must cover); and the memory each map uses.
std::string comparison_table(const std::vector<Cell>& cells,
                             const std::vector<std::vector<Repeat>>& results) {
  std::ostringstream md;
  constexpr int kIntegrate = 2;
  constexpr double Percentiles::*kStats[4] = {&Percentiles::median, &Percentiles::mean,
                                              &Percentiles::p90, &Percentiles::p99};
  for (std::size_t c = 0; c + 1 < cells.size(); ++c) {
    const Cell& m = cells[c];
    const Cell& s = cells[c + 1];
    if (m.map != octofuse::MapKind::multires || s.map != octofuse::MapKind::single_res ||
        m.scene != s.scene || m.voxel_m != s.voxel_m || m.threads != s.threads ||
        m.poses != s.poses) {
      continue;
    }
    double multires[4], single[4];
    for (int k = 0; k < 4; ++k) {
      multires[k] = stage_stat(results[c], kIntegrate, kStats[k]);
      single[k] = stage_stat(results[c + 1], kIntegrate, kStats[k]);
    }
    auto ratio = [&](int k) { return multires[k] > 0.0 ? single[k] / multires[k] : 0.0; };
    auto used_mb = [&](std::size_t cell) {
      return static_cast<double>(results[cell].front().summary.map_memory.bytes_used) / 1048576.0;
    };
    char row[512];
    std::snprintf(row, sizeof(row),
                  "| %s | %g mm | %d | %s | %.1f / %.1f / %.1f / %.1f | %.1f / %.1f / %.1f / %.1f "
                  "| %.2fx / %.2fx / %.2fx / %.2fx | %.0f/%.0f |\n",
                  m.scene.substr(0, m.scene.find('/')).c_str(),
                  static_cast<double>(m.voxel_m) * 1000.0, m.threads,
                  m.poses == octofuse::PoseSource::track ? "ICP" : "ground truth", multires[0],
                  multires[1], multires[2], multires[3], single[0], single[1], single[2], single[3],
                  ratio(0), ratio(1), ratio(2), ratio(3), used_mb(c), used_mb(c + 1));
    md << row;
  }
  // Nothing to compare when --maps leaves out the multires / single-res pair.
  if (md.str().empty()) return std::string();
  return "\nIntegration, multires vs single-res (same run; ms as median / mean / p90 / p99 of the "
         "frames; speed-up = single / multires):\n\n"
         "| scene | voxel | threads | poses | multires ms | single-res ms | speed-up | "
         "map MB used multires/single |\n"
         "|---|---|---|---|---|---|---|---|\n" +
         md.str();
}

// What the command line sets.
struct BenchArgs {
  bool quick = false;
  std::string data_dir, out_dir = "bench-out";
  long repeats = -1, frames = -1;
  std::vector<float> voxels = {0.01f, 0.002f};
  std::vector<std::string> sim_scenes = {"desk", "room"};
  std::vector<int> thread_counts = {1, 2};
  std::vector<octofuse::MapKind> maps = {octofuse::MapKind::multires,
                                         octofuse::MapKind::single_res};
  octofuse::MeshReadScale mesh_read_scale = octofuse::MeshReadScale::current;
  bool raycast_half = true;
  int allocation_step = octofuse::FusionConfig{}.allocation_pixel_step;
  float allocation_group_px = octofuse::FusionConfig{}.allocation_group_block_px;
  std::vector<octofuse::PoseSource> pose_modes = {octofuse::PoseSource::track,
                                                  octofuse::PoseSource::ground_truth};
  bool soak = false;
  octofuse::bench::SoakOptions soak_options;
};

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> items;
  std::stringstream list(text);
  std::string item;
  while (std::getline(list, item, ',')) items.push_back(item);
  return items;
}

using Option = octofuse::cli::Option<BenchArgs>;

const Option kOptions[] = {
    {"--quick", nullptr, "one small comparison (sim:desk, 1 cm, multires vs single), ~1 minute",
     [](BenchArgs& a, const std::string&) {
       a.quick = true;
       return std::string();
     }},
    {"--data", "DIR", "folder holding 7scenes-redkitchen (adds it to the matrix)",
     [](BenchArgs& a, const std::string& v) {
       a.data_dir = v;
       return std::string();
     }},
    {"--out", "DIR", "where bench.md, bench.json and the plots go (default bench-out)",
     [](BenchArgs& a, const std::string& v) {
       a.out_dir = v;
       return std::string();
     }},
    {"--repeats", "N", "runs per cell, interleaved with the compared cell (default 3)",
     [](BenchArgs& a, const std::string& v) {
       std::int64_t n = 0;
       if (!octofuse::cli::parse_int(v, 1, 100, n)) {
         return std::string("unknown or incomplete option '--repeats' (see --help)");
       }
       a.repeats = n;
       return std::string();
     }},
    {"--frames", "N", "frames per run (default: 120; quick: 40)",
     [](BenchArgs& a, const std::string& v) {
       std::int64_t n = 0;
       if (!octofuse::cli::parse_int(v, 2, 100000, n)) {
         return std::string("unknown or incomplete option '--frames' (see --help)");
       }
       a.frames = n;
       return std::string();
     }},
    {"--voxels", "LIST", "finest voxel sizes in metres, comma separated (default 0.01,0.002)",
     [](BenchArgs& a, const std::string& text) {
       a.voxels.clear();
       std::stringstream list(text);
       std::string item;
       double v = 0.0;
       while (std::getline(list, item, ',')) {
         if (!octofuse::cli::parse_double(item, 1e-4, 1.0, v)) {
           return std::string("--voxels needs metres like 0.01,0.002");
         }
         a.voxels.push_back(static_cast<float>(v));
       }
       return std::string();
     }},
    {"--scenes", "LIST", "sim scenes, comma separated (default desk,room)",
     [](BenchArgs& a, const std::string& v) {
       a.sim_scenes = split(v);
       for (const std::string& name : a.sim_scenes) {
         octofuse::sim::SceneId id;
         if (!octofuse::sim::scene_id_from_name(name.c_str(), &id).ok()) {
           return "--scenes: unknown scene '" + name + "'";
         }
       }
       return std::string();
     }},
    {"--threads", "LIST", "worker counts, comma separated (default 1,2)",
     [](BenchArgs& a, const std::string& v) {
       a.thread_counts.clear();
       std::int64_t n = 0;
       for (const std::string& item : split(v)) {
         if (!octofuse::cli::parse_int(item, 1, 64, n)) {
           return std::string("--threads needs counts like 1,2");
         }
         a.thread_counts.push_back(static_cast<int>(n));
       }
       return std::string();
     }},
    {"--poses", "MODE", "icp, gt or both (default both)",
     [](BenchArgs& a, const std::string& mode) {
       if (mode == "icp") {
         a.pose_modes = {octofuse::PoseSource::track};
       } else if (mode == "gt") {
         a.pose_modes = {octofuse::PoseSource::ground_truth};
       } else if (mode == "both") {
         a.pose_modes = {octofuse::PoseSource::track, octofuse::PoseSource::ground_truth};
       } else {
         return std::string("--poses must be icp, gt or both");
       }
       return std::string();
     }},
    {"--maps", "LIST",
     "maps per setting, compared side by side, comma separated: multires,\n"
     "single, multires16 (default multires,single)",
     [](BenchArgs& a, const std::string& v) {
       a.maps.clear();
       for (const std::string& item : split(v)) {
         octofuse::MapKind kind;
         if (!octofuse::examples::parse_map_option(item, &kind)) {
           return std::string("--maps needs map kinds like multires,multires16");
         }
         a.maps.push_back(kind);
       }
       return std::string();
     }},
    {"--mesh-scale", "S",
     "multires meshes (mesh RMSE, thin recall) at each block's current scale\n"
     "(default) or finest: the finest scale it was fused at",
     [](BenchArgs& a, const std::string& v) {
       if (!octofuse::examples::parse_mesh_read_scale(v, &a.mesh_read_scale)) {
         return std::string("--mesh-scale must be current or finest");
       }
       return std::string();
     }},
    {"--raycast-half", nullptr,
     "every run's reference ray-cast at half resolution (the default;\n"
     "octofuse-replay --raycast-half)",
     [](BenchArgs& a, const std::string&) {
       a.raycast_half = true;
       return std::string();
     }},
    {"--raycast-full", nullptr,
     "every run's reference ray-cast at every pixel (octofuse-replay\n"
     "--raycast-full)",
     [](BenchArgs& a, const std::string&) {
       a.raycast_half = false;
       return std::string();
     }},
    {"--allocation-step", "N",
     "every run's allocation marches every N-th pixel's ray in x and y\n"
     "(default 1; octofuse-replay --allocation-step)",
     [](BenchArgs& a, const std::string& v) {
       std::int64_t n = 0;
       if (!octofuse::cli::parse_int(v, 1, 16, n)) {
         return std::string("--allocation-step needs a count in [1, 16]");
       }
       a.allocation_step = static_cast<int>(n);
       return std::string();
     }},
    {"--allocation-group-px", "PX",
     "every run's allocation marches one ray of a 2 x 2 group where a block\n"
     "spans at least PX pixels (default 8; 0: every ray; octofuse-replay\n"
     "--allocation-group-px)",
     [](BenchArgs& a, const std::string& v) {
       double px = 0.0;
       if (!octofuse::cli::parse_double(v, 0.0, 1000.0, px)) {
         return std::string("--allocation-group-px needs pixels in [0, 1000]");
       }
       a.allocation_group_px = static_cast<float>(px);
       return std::string();
     }},
    {"--soak", nullptr,
     "instead of the matrix: replay a source in a loop under a memory cap and\n"
     "again with a large one; fails (exit 1) when the capped run lost a frame\n"
     "the other did not or its RSS grew after the first pass (soak.md,\n"
     "soak.json in --out). Uses the first of --voxels, --threads, --maps and\n"
     "--poses (--poses gt: both runs fuse ground-truth poses, so their surfaces\n"
     "differ only by the cap).",
     [](BenchArgs& a, const std::string&) {
       a.soak = true;
       return std::string();
     }},
    {"--soak-frames", "N", "frames per run (default 10000)",
     [](BenchArgs& a, const std::string& v) {
       std::int64_t n = 0;
       if (!octofuse::cli::parse_int(v, 2, 10000000, n)) {
         return std::string("--soak-frames needs a count in [2, 10000000]");
       }
       a.soak_options.frames = static_cast<long>(n);
       return std::string();
     }},
    {"--soak-map-file", "FILE",
     "the capped soak run keeps evicted blocks in FILE (--map-file; emptied first)",
     [](BenchArgs& a, const std::string& v) {
       a.soak_options.map_file = v;
       return v.empty() ? std::string("--soak-map-file is empty") : std::string();
     }},
    {"--soak-source", "SPEC", "source to loop, as octofuse-replay's --source (default sim:room)",
     [](BenchArgs& a, const std::string& v) {
       a.soak_options.source_spec = v;
       if (a.soak_options.source_spec.empty()) return std::string("--soak-source is empty");
       return std::string();
     }},
    {"--map-memory", "MB", "the capped run's map memory (default 16)",
     [](BenchArgs& a, const std::string& v) {
       double mb = 0.0;
       if (!octofuse::cli::parse_double(v, 1.0, 65536.0, mb)) {
         return std::string("--map-memory needs megabytes in [1, 65536]");
       }
       a.soak_options.map_memory_mb = static_cast<float>(mb);
       return std::string();
     }},
    {"--reference-memory", "MB", "the reference run's (default 1024)",
     [](BenchArgs& a, const std::string& v) {
       double mb = 0.0;
       if (!octofuse::cli::parse_double(v, 1.0, 65536.0, mb)) {
         return std::string("--reference-memory needs megabytes in [1, 65536]");
       }
       a.soak_options.reference_memory_mb = static_cast<float>(mb);
       return std::string();
     }},
    {"--rss-tolerance", "MB", "allowed RSS growth after the first pass (default 1)",
     [](BenchArgs& a, const std::string& v) {
       double mb = 0.0;
       if (!octofuse::cli::parse_double(v, 0.0, 65536.0, mb)) {
         return std::string("--rss-tolerance needs megabytes in [0, 65536]");
       }
       a.soak_options.rss_tolerance_mb = mb;
       return std::string();
     }},
};

void usage() {
  std::printf(
      "usage: octofuse-bench [--quick] [--data DIR] [--out DIR] [--repeats N] [--frames N]\n"
      "         [options]\n\n%s",
      octofuse::cli::options_usage(kOptions).c_str());
}

}  // namespace

int main(int argc, char** argv) {
  BenchArgs args;
  std::string parse_error;
  switch (octofuse::cli::parse_options(argc, argv, 1, kOptions, "unknown or incomplete option ",
                                       &args, &parse_error)) {
    case octofuse::cli::Parsed::help:
      usage();
      return 0;
    case octofuse::cli::Parsed::error:
      return octofuse::cli::fail(parse_error);
    case octofuse::cli::Parsed::options:
      break;
  }
  const bool quick = args.quick;
  const std::string& data_dir = args.data_dir;
  const std::string& out_dir = args.out_dir;
  long repeats = args.repeats, frames = args.frames;
  std::vector<float>& voxels = args.voxels;
  std::vector<std::string>& sim_scenes = args.sim_scenes;
  const std::vector<int>& thread_counts = args.thread_counts;
  const std::vector<octofuse::MapKind>& maps = args.maps;
  const octofuse::MeshReadScale mesh_read_scale = args.mesh_read_scale;
  const std::vector<octofuse::PoseSource>& pose_modes = args.pose_modes;
  const bool soak = args.soak;
  octofuse::bench::SoakOptions& soak_options = args.soak_options;
  if (voxels.empty() || thread_counts.empty() || maps.empty()) {
    return octofuse::cli::fail("--voxels, --threads and --maps need at least one value");
  }
  if (soak) {
    if (quick) return octofuse::cli::fail("--soak and --quick exclude each other");
    soak_options.voxel_size_m = voxels.front();
    soak_options.threads = thread_counts.front();
    soak_options.map_kind = maps.front();
    soak_options.pose_source = pose_modes.front();
    soak_options.out_dir = out_dir;
    return octofuse::bench::run_soak(soak_options);
  }
  if (repeats < 0) repeats = quick ? 1 : 3;
  if (frames < 0) frames = quick ? 40 : 120;
  if (::mkdir(out_dir.c_str(), 0755) != 0 && errno != EEXIST) {
    return octofuse::cli::fail("cannot create " + out_dir);
  }

  // The matrix: pairs of cells that differ in one setting sit next to each other and are
  // interleaved on every repeat.
  std::vector<Cell> cells;
  std::vector<std::string> scenes;
  if (quick) sim_scenes = {"desk"};
  for (const std::string& name : sim_scenes) scenes.push_back("sim:" + name);
  if (!data_dir.empty()) scenes.push_back("7scenes:" + data_dir + "/7scenes-redkitchen");
  if (quick) voxels = {0.01f};
  for (const std::string& scene : scenes) {
    for (float voxel : voxels) {
      for (int threads : quick ? std::vector<int>{1} : thread_counts) {
        for (auto poses :
             quick ? std::vector<octofuse::PoseSource>{octofuse::PoseSource::track} : pose_modes) {
          for (auto map : quick ? std::vector<octofuse::MapKind>{octofuse::MapKind::multires,
                                                                 octofuse::MapKind::single_res}
                                : maps) {
            cells.push_back(Cell{scene, map, voxel, threads, poses, frames, mesh_read_scale,
                                 args.raycast_half, args.allocation_step,
                                 args.allocation_group_px});
          }
        }
      }
    }
  }

  std::vector<SimEvaluation> evals(scenes.size());
  std::vector<bool> have_eval(scenes.size(), false);
  for (std::size_t s = 0; s < scenes.size(); ++s) {
    if (scenes[s].rfind("sim:", 0) == 0) have_eval[s] = load_sim_evaluation(scenes[s], &evals[s]);
  }
  auto eval_for = [&](const Cell& cell) -> const SimEvaluation* {
    for (std::size_t s = 0; s < scenes.size(); ++s) {
      if (scenes[s] == cell.scene && have_eval[s]) return &evals[s];
    }
    return nullptr;
  };

  std::vector<std::vector<Repeat>> results(cells.size());
  for (long r = 0; r < repeats; ++r) {
    for (std::size_t c = 0; c < cells.size(); ++c) {
      std::fprintf(stderr, "[repeat %ld/%ld] %s ...\n", r + 1, repeats, cells[c].label().c_str());
      const std::string run_dir = out_dir + "/" + cells[c].slug();
      int exit_code = 0;
      Repeat rep =
          run_cell(cells[c], r == 0 ? run_dir : std::string(), eval_for(cells[c]), &exit_code);
      if (exit_code != 0) {
        return octofuse::cli::fail("run failed: " + cells[c].label());
      }
      results[c].push_back(std::move(rep));
    }
  }

  // Report: medians over repeats; spread = max - min of the per-repeat medians.
  const unsigned cores = std::thread::hardware_concurrency();
  std::ostringstream md;
  md << "Machine: " << cpu_model() << ", " << cores << " cores. Frames per run: " << frames
     << ", repeats: " << repeats << " (medians over repeats; +- is the spread of the repeats).\n\n";
  md << "| scene | map | voxel | threads | poses | preprocess | track | integrate | ray-cast | "
        "total median (p90/p99/max) ms | fps | map MB used/reserved | peak RSS MB | ATE cm | "
        "lost | mesh RMSE mm | thin recall |\n";
  md << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  octofuse::host::JsonWriter json;
  json.begin_object();
  json.key("machine").begin_object();
  json.key("cpu").value(cpu_model().c_str());
  json.key("cores").value(static_cast<std::int64_t>(cores));
  json.end_object();
  json.key("frames").value(static_cast<std::int64_t>(frames));
  json.key("repeats").value(static_cast<std::int64_t>(repeats));
  json.key("cells").begin_array();
  for (std::size_t c = 0; c < cells.size(); ++c) {
    const Cell& cell = cells[c];
    const std::vector<Repeat>& reps = results[c];
    std::vector<double> per_stage[5][5], fps, rss, ate, rmse, recall;
    for (const Repeat& rep : reps) {
      for (int s = 0; s < 5; ++s) {
        per_stage[s][0].push_back(rep.stage[s].median);
        per_stage[s][1].push_back(rep.stage[s].p90);
        per_stage[s][2].push_back(rep.stage[s].p99);
        per_stage[s][3].push_back(rep.stage[s].max);
        per_stage[s][4].push_back(rep.stage[s].mean);
      }
      fps.push_back(rep.fps);
      rss.push_back(rep.peak_rss_mb);
      if (rep.summary.have_ate) ate.push_back(rep.summary.ate_rmse_m);
      if (rep.mesh_rmse_m >= 0.0) rmse.push_back(rep.mesh_rmse_m);
      if (rep.thin_recall >= 0.0) recall.push_back(rep.thin_recall);
    }
    const RunSummary& first = reps.front().summary;
    const double used_mb = static_cast<double>(first.map_memory.bytes_used) / 1048576.0;
    const double reserved_mb = static_cast<double>(first.map_memory.bytes_reserved) / 1048576.0;
    char row[1024];
    std::snprintf(
        row, sizeof(row),
        "| %s | %s | %g mm | %d | %s | %.1f | %.1f | %.1f | %.1f | %.1f +-%.1f (%.1f/%.1f/%.1f) | "
        "%.1f | %.0f/%.0f | %.0f | %s | %llu | %s | %s |\n",
        cell.scene.substr(0, cell.scene.find('/')).c_str(),
        octofuse::examples::map_option_name(cell.map), static_cast<double>(cell.voxel_m) * 1000.0,
        cell.threads, cell.poses == octofuse::PoseSource::track ? "ICP" : "ground truth",
        median_of(per_stage[0][0]), median_of(per_stage[1][0]), median_of(per_stage[2][0]),
        median_of(per_stage[3][0]), median_of(per_stage[4][0]), spread_of(per_stage[4][0]),
        median_of(per_stage[4][1]), median_of(per_stage[4][2]), median_of(per_stage[4][3]),
        median_of(fps), used_mb, reserved_mb, median_of(rss),
        ate.empty()
            ? "-"
            : std::to_string(std::round(median_of(ate) * 1000.0) / 10.0).substr(0, 5).c_str(),
        static_cast<unsigned long long>(first.frames_lost),
        rmse.empty()
            ? "-"
            : std::to_string(std::round(median_of(rmse) * 10000.0) / 10.0).substr(0, 5).c_str(),
        recall.empty() ? "-" : std::to_string(median_of(recall)).substr(0, 4).c_str());
    md << row;

    json.begin_object();
    json.key("label").value(cell.label().c_str());
    json.key("scene").value(cell.scene.c_str());
    json.key("map").value(octofuse::examples::map_option_name(cell.map));
    json.key("voxel_size_m").value(static_cast<double>(cell.voxel_m));
    json.key("threads").value(cell.threads);
    json.key("poses").value(cell.poses == octofuse::PoseSource::track ? "icp" : "ground_truth");
    json.key("frames").value(static_cast<std::uint64_t>(first.frames.size()));
    for (int s = 0; s < 5; ++s) {
      json.key(kStageNames[s]).begin_object();
      json.key("median_ms").value(median_of(per_stage[s][0]));
      json.key("p90_ms").value(median_of(per_stage[s][1]));
      json.key("p99_ms").value(median_of(per_stage[s][2]));
      json.key("max_ms").value(median_of(per_stage[s][3]));
      json.key("mean_ms").value(median_of(per_stage[s][4]));
      json.key("spread_of_medians_ms").value(spread_of(per_stage[s][0]));
      json.end_object();
    }
    json.key("fps").value(median_of(fps));
    json.key("map_bytes_used").value(static_cast<std::uint64_t>(first.map_memory.bytes_used));
    json.key("map_bytes_reserved")
        .value(static_cast<std::uint64_t>(first.map_memory.bytes_reserved));
    json.key("arena_bytes").value(static_cast<std::uint64_t>(first.arena_bytes));
    json.key("peak_rss_mb").value(median_of(rss));
    json.key("frames_lost").value(first.frames_lost);
    if (!ate.empty()) json.key("ate_rmse_m").value(median_of(ate));
    if (!rmse.empty()) json.key("mesh_rmse_m").value(median_of(rmse));
    if (!recall.empty()) json.key("thin_recall").value(median_of(recall));
    json.end_object();
  }
  json.end_array();
  json.end_object();
  md << comparison_table(cells, results);

  const std::string md_path = out_dir + "/bench.md";
  std::ofstream(md_path) << md.str();
  octofuse::ErrorText error;
  if (!json.write_file((out_dir + "/bench.json").c_str(), &error).ok()) {
    return octofuse::cli::fail(error.c_str());
  }
  std::printf("%s\nwrote %s, %s/bench.json and a stage_times.svg per cell\n", md.str().c_str(),
              md_path.c_str(), out_dir.c_str());
  return 0;
}
