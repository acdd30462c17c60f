#include "runner.hpp"

#include <sys/stat.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <thread>
#include <vector>

#include "octofuse/ports/host/map_file.hpp"
#include "runner_steps.hpp"

namespace octofuse::examples {
namespace detail {

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

}  // namespace detail

namespace {

using detail::error_exit;

// A run, step by step (runner_steps.hpp); a step that fails ends it with its exit code.
template <typename VoxelT>
int run_typed(const RunOptions& options, RunSummary* summary) {
  detail::RunInputs inputs;
  detail::PipelineRun<VoxelT> run;
  detail::LoopResult loop;
  if (const int rc = detail::open_inputs(options, summary, &inputs); rc != 0) return rc;
  if (inputs.load_map) {
    if (const int rc = detail::load_saved_map(options, inputs, &run, summary); rc != 0) return rc;
  }
  if (const int rc = detail::read_odometry(options, &inputs); rc != 0) return rc;
  if (const int rc = detail::run_frames(options, &inputs, &run, summary, &loop); rc != 0) {
    return rc;
  }
  return detail::write_outputs(options, &inputs, &run, &loop, summary);
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
