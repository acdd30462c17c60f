#include "soak.hpp"

#include <fcntl.h>
#include <unistd.h>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <sys/stat.h>
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

#include "mesh_distance.hpp"
#include "octofuse/ports/host/json_writer.hpp"
#include "runner.hpp"

namespace octofuse::bench {
namespace {

using examples::percentiles;
using examples::reload_latency_since;
using examples::ReloadLatency;
using examples::RunOptions;
using examples::RunSummary;
using examples::write_reload_latency_json;

// Stored pass rows; a run with more passes (passes of a few frames) still prints and counts
// them. Sized before the first frame so the records' own pages are resident from the start.
constexpr std::size_t kMaxStoredPasses = 10000;
constexpr std::size_t kMaxListedLostFrames = 20;  // in the one-line verdict

struct ProcMemory {
  bool ok = false;
  double rss_mb = 0.0;  // VmRSS: resident now
  double hwm_mb = 0.0;  // VmHWM: peak resident since start or the last reset
};

// VmRSS and VmHWM of this process, read with read(2) into a stack buffer: sampling after every
// frame must not allocate, or the sampling itself would show up as growth.
ProcMemory read_proc_memory() {
  ProcMemory memory;
  const int fd = ::open("/proc/self/status", O_RDONLY | O_CLOEXEC);
  if (fd < 0) return memory;
  char text[8192];
  std::size_t size = 0;
  while (size + 1 < sizeof(text)) {
    const ssize_t n = ::read(fd, text + size, sizeof(text) - 1 - size);
    if (n <= 0) break;
    size += static_cast<std::size_t>(n);
  }
  ::close(fd);
  text[size] = '\0';
  auto field_mb = [&](const char* name, double* mb) {
    const char* at = std::strstr(text, name);
    if (at == nullptr) return false;
    char* end = nullptr;
    const double kb = std::strtod(at + std::strlen(name), &end);
    if (end == at + std::strlen(name)) return false;
    *mb = kb / 1024.0;
    return true;
  };
  memory.ok = field_mb("VmRSS:", &memory.rss_mb) && field_mb("VmHWM:", &memory.hwm_mb);
  return memory;
}

// Resets VmHWM to the current resident size (Linux >= 4.0); false where that is not possible.
bool reset_peak_rss() {
  const int fd = ::open("/proc/self/clear_refs", O_WRONLY | O_CLOEXEC);
  if (fd < 0) return false;
  const bool ok = ::write(fd, "5", 1) == 1;
  ::close(fd);
  return ok;
}

struct PassRow {
  int pass = 0;
  std::uint64_t first_frame = 0;  // frames given before this pass
  std::uint64_t frames = 0;       // given to the pipeline, rejected ones included
  std::uint64_t lost = 0;
  std::uint64_t rejected = 0;
  std::uint64_t evicted = 0;  // blocks
  std::uint32_t blocks_resident = 0;
  std::uint32_t block_capacity = 0;
  // What can grow under a fixed cap: the block pool's high-water mark over the run (slots are
  // touched when first handed out), octree nodes and free-space nodes (never evicted).
  std::uint32_t blocks_high_water = 0;
  std::uint32_t octree_nodes = 0;
  std::uint32_t free_space_nodes = 0;
  double rss_mb = 0.0;       // VmRSS after the pass's last frame
  double peak_rss_mb = 0.0;  // VmHWM over the run so far
  double median_ms = 0.0;
  double p99_ms = 0.0;
  // Refusals (blocks and nodes: holes in the map; free-space nodes) and, with a store, its
  // traffic. A finest or mid level refused is a degradation (the block fuses one scale coarser),
  // not a hole: counted apart, not a pass condition.
  std::uint64_t refusals = 0;
  std::uint64_t free_space_refusals = 0;
  std::uint64_t finest_refusals = 0;
  std::uint64_t mid_refusals = 0;
  std::uint64_t store_read = 0;
  std::uint64_t store_remapped = 0;
  std::uint64_t store_deferred = 0;
  std::uint64_t store_written = 0;
  std::uint64_t store_unchanged = 0;  // evicted unchanged since read back: not written
  std::uint64_t store_bytes_read = 0;
  std::uint64_t store_bytes_written = 0;
  std::uint64_t frames_waiting = 0;  // frames that left stored blocks in view for a later one
  // Blocks read back in the pass that some frame had left out (ReloadLatencyProbe): the frames
  // that went without each (median, p90, p99, max) and the frames from the first of them to the
  // read (median, p99); blocks left out and not read back at the pass's end.
  std::uint64_t reload_left_out = 0;
  std::uint64_t reload_median_frames = 0, reload_p90_frames = 0, reload_p99_frames = 0;
  std::uint64_t reload_max_frames = 0;
  std::uint64_t reload_median_waited = 0, reload_p99_waited = 0;
  std::uint64_t reload_waiting = 0;
  // The free-space store (FILE.free): regions read back and written, and their bytes.
  std::uint64_t free_store_read = 0;
  std::uint64_t free_store_written = 0;
  std::uint64_t free_store_bytes_read = 0;
  std::uint64_t free_store_bytes_written = 0;
  // The finest-level store (FILE.fine): levels given up and read back, and their bytes.
  std::uint64_t finest_store_read = 0;
  std::uint64_t finest_store_written = 0;
  std::uint64_t finest_store_bytes_read = 0;
  std::uint64_t finest_store_bytes_written = 0;
};

struct SoakRun {
  const char* name = "";
  float map_memory_mb = 0.0f;
  std::vector<PassRow> rows;  // kMaxStoredPasses, the first row_count used
  std::size_t row_count = 0;
  std::uint64_t passes = 0;
  std::vector<std::uint64_t> lost_frames;  // frame indices, one slot per frame
  std::size_t lost_count = 0;
  std::vector<double> pass_ms;  // the current pass's frame times, one slot per frame
  std::size_t pass_ms_count = 0;
  PassRow current;
  std::uint64_t frames = 0, lost = 0, rejected = 0, evicted = 0;
  std::uint32_t blocks_high_water = 0;
  ProcMemory last;  // sampled after the latest frame
  bool memory_unreadable = false;
  double peak_before_reset_mb = 0.0;
  bool after_first_pass = false;
  bool peak_reset = false;  // VmHWM was reset at the end of the first pass
  double rss_end_first_pass_mb = 0.0;
  double max_rss_after_first_pass_mb = 0.0;
  RunSummary summary;
  ReloadLatency reload_at_pass_start;  // summary.store_reload_latency when the pass began
  int exit_code = 0;
  double wall_s = 0.0;

  double growth_mb() const { return max_rss_after_first_pass_mb - rss_end_first_pass_mb; }
};

// One line for a store beside the block store (FILE.free, FILE.fine) when the pass used it.
void print_side_store(const SoakRun& run, const PassRow& row, const char* read_what,
                      const char* unit, std::uint64_t read, std::uint64_t written,
                      std::uint64_t bytes_read, std::uint64_t bytes_written) {
  if (read + written == 0) return;
  const double frames = row.frames > 0 ? static_cast<double>(row.frames) : 1.0;
  std::fprintf(stderr,
               "[soak %s %g MB] pass %d: %s %llu, written %llu %s, %.1f / %.1f KB per frame read "
               "/ written\n",
               run.name, static_cast<double>(run.map_memory_mb), row.pass, read_what,
               static_cast<unsigned long long>(read), static_cast<unsigned long long>(written),
               unit, static_cast<double>(bytes_read) / 1024.0 / frames,
               static_cast<double>(bytes_written) / 1024.0 / frames);
}

void print_row(const SoakRun& run, const PassRow& row) {
  std::fprintf(stderr,
               "[soak %s %g MB] pass %d: frames %llu-%llu, lost %llu, evicted %llu, blocks "
               "%u/%u (most %u), octree nodes %u, free-space nodes %u, RSS %.1f MB (peak %.1f), "
               "median %.1f ms, p99 %.1f ms\n",
               run.name, static_cast<double>(run.map_memory_mb), row.pass,
               static_cast<unsigned long long>(row.first_frame),
               static_cast<unsigned long long>(row.first_frame + row.frames - 1),
               static_cast<unsigned long long>(row.lost),
               static_cast<unsigned long long>(row.evicted), row.blocks_resident,
               row.block_capacity, row.blocks_high_water, row.octree_nodes, row.free_space_nodes,
               row.rss_mb, row.peak_rss_mb, row.median_ms, row.p99_ms);
  std::fprintf(stderr,
               "[soak %s %g MB] pass %d: refusals %llu (free space %llu; levels refused, fused "
               "coarser: finest %llu, mid %llu); store: read %llu, "
               "re-mapped %llu, deferred %llu, written %llu, unchanged %llu, %.1f / %.1f KB per "
               "frame read / "
               "written, frames "
               "waiting %llu\n",
               run.name, static_cast<double>(run.map_memory_mb), row.pass,
               static_cast<unsigned long long>(row.refusals),
               static_cast<unsigned long long>(row.free_space_refusals),
               static_cast<unsigned long long>(row.finest_refusals),
               static_cast<unsigned long long>(row.mid_refusals),
               static_cast<unsigned long long>(row.store_read),
               static_cast<unsigned long long>(row.store_remapped),
               static_cast<unsigned long long>(row.store_deferred),
               static_cast<unsigned long long>(row.store_written),
               static_cast<unsigned long long>(row.store_unchanged),
               row.frames > 0 ? static_cast<double>(row.store_bytes_read) / 1024.0 /
                                    static_cast<double>(row.frames)
                              : 0.0,
               row.frames > 0 ? static_cast<double>(row.store_bytes_written) / 1024.0 /
                                    static_cast<double>(row.frames)
                              : 0.0,
               static_cast<unsigned long long>(row.frames_waiting));
  if (row.store_read > 0 || row.reload_waiting > 0) {
    std::fprintf(stderr,
                 "[soak %s %g MB] pass %d: reload latency: %llu blocks read back had been left "
                 "out, for median %llu, p90 %llu, p99 %llu, max %llu frames (median %llu, p99 "
                 "%llu frames from the first to the read); %llu still left out\n",
                 run.name, static_cast<double>(run.map_memory_mb), row.pass,
                 static_cast<unsigned long long>(row.reload_left_out),
                 static_cast<unsigned long long>(row.reload_median_frames),
                 static_cast<unsigned long long>(row.reload_p90_frames),
                 static_cast<unsigned long long>(row.reload_p99_frames),
                 static_cast<unsigned long long>(row.reload_max_frames),
                 static_cast<unsigned long long>(row.reload_median_waited),
                 static_cast<unsigned long long>(row.reload_p99_waited),
                 static_cast<unsigned long long>(row.reload_waiting));
  }
  print_side_store(run, row, "free-space store: read", "regions", row.free_store_read,
                   row.free_store_written, row.free_store_bytes_read, row.free_store_bytes_written);
  print_side_store(run, row, "finest-level store: read back", "levels", row.finest_store_read,
                   row.finest_store_written, row.finest_store_bytes_read,
                   row.finest_store_bytes_written);
}

void close_pass(SoakRun& run) {
  PassRow& row = run.current;
  row.rss_mb = run.last.rss_mb;
  row.peak_rss_mb = std::max(run.peak_before_reset_mb, run.last.hwm_mb);
  const examples::Percentiles ms = percentiles(
      std::vector<double>(run.pass_ms.begin(), run.pass_ms.begin() + run.pass_ms_count));
  row.median_ms = ms.median;
  row.p99_ms = ms.p99;
  const ReloadLatency reload =
      reload_latency_since(run.summary.store_reload_latency, run.reload_at_pass_start);
  run.reload_at_pass_start = run.summary.store_reload_latency;
  row.reload_left_out = reload.frames_left_out.nonzero();
  row.reload_median_frames = reload.frames_left_out.frames_at(0.5);
  row.reload_p90_frames = reload.frames_left_out.frames_at(0.9);
  row.reload_p99_frames = reload.frames_left_out.frames_at(0.99);
  row.reload_max_frames = reload.frames_left_out.max_frames;
  row.reload_median_waited = reload.frames_waited.frames_at(0.5);
  row.reload_p99_waited = reload.frames_waited.frames_at(0.99);
  row.reload_waiting = reload.waiting;
  run.frames += row.frames;
  run.lost += row.lost;
  run.rejected += row.rejected;
  run.evicted += row.evicted;
  ++run.passes;
  if (run.row_count < run.rows.size()) run.rows[run.row_count++] = row;
  print_row(run, row);
}

void on_frame(SoakRun& run, const FrameStats& stats) {
  PassRow& row = run.current;
  ++row.frames;
  if (stats.result == FrameResult::rejected) {
    ++row.rejected;
  } else {
    if (stats.result == FrameResult::lost) {
      ++row.lost;
      if (run.lost_count < run.lost_frames.size()) {
        run.lost_frames[run.lost_count++] = stats.frame_index;
      }
    }
    row.evicted += stats.eviction.evicted;
    row.refusals += stats.integration.pool_refusals - stats.integration.finest_refusals -
                    stats.integration.mid_refusals;
    row.free_space_refusals += stats.free_space.pool_refused;
    row.finest_refusals += stats.integration.finest_refusals;
    row.mid_refusals += stats.integration.mid_refusals;
    row.store_read += stats.store.read;
    row.store_remapped += stats.store.remapped;
    row.store_deferred += stats.store.deferred;
    row.store_written += stats.store.written;
    row.store_unchanged += stats.store.unchanged;
    row.store_bytes_read += stats.store.bytes_read;
    row.store_bytes_written += stats.store.bytes_written;
    if (stats.store.waiting > 0) ++row.frames_waiting;
    row.free_store_read += stats.free_store.read;
    row.free_store_written += stats.free_store.written;
    row.free_store_bytes_read += stats.free_store.bytes_read;
    row.free_store_bytes_written += stats.free_store.bytes_written;
    row.finest_store_read += stats.store.finest_read;
    row.finest_store_written += stats.store.finest_written;
    row.finest_store_bytes_read += stats.store.finest_bytes_read;
    row.finest_store_bytes_written += stats.store.finest_bytes_written;
    row.blocks_resident = stats.memory.blocks_used;
    row.block_capacity = stats.memory.block_capacity;
    run.blocks_high_water = std::max(run.blocks_high_water, stats.memory.blocks_used);
    row.blocks_high_water = run.blocks_high_water;
    row.octree_nodes = stats.memory.nodes_used;
    if (stats.free_space.nodes_used > 0) row.free_space_nodes = stats.free_space.nodes_used;
    if (run.pass_ms_count < run.pass_ms.size())
      run.pass_ms[run.pass_ms_count++] = stats.times.total_ms;
  }
  run.last = read_proc_memory();
  if (!run.last.ok) run.memory_unreadable = true;
  if (run.after_first_pass) {
    // VmHWM catches a peak inside a frame; after its reset it holds only what came since.
    const double peak_mb =
        run.peak_reset ? std::max(run.last.rss_mb, run.last.hwm_mb) : run.last.rss_mb;
    run.max_rss_after_first_pass_mb = std::max(run.max_rss_after_first_pass_mb, peak_mb);
  }
}

void on_pass_start(SoakRun& run, int pass) {
  close_pass(run);
  if (pass == 1) {
    run.after_first_pass = true;
    run.rss_end_first_pass_mb = run.last.rss_mb;
    run.max_rss_after_first_pass_mb = run.last.rss_mb;
    run.peak_before_reset_mb = run.last.hwm_mb;
    run.peak_reset = reset_peak_rss();
  }
  const std::uint32_t free_space_nodes = run.current.free_space_nodes;
  run.current = PassRow();
  run.current.free_space_nodes = free_space_nodes;  // until a frame of this pass carves
  run.current.pass = pass;
  run.current.first_frame = run.frames;
  run.pass_ms_count = 0;
}

void run_one(const SoakOptions& soak, SoakRun& run) {
  RunOptions options;
  options.source_spec = soak.source_spec;
  options.max_frames = soak.frames;
  options.loop_source = true;
  options.voxel_size_m = soak.voxel_size_m;
  options.threads = soak.threads;
  options.map_kind = soak.map_kind;
  options.pose_source = soak.pose_source;
  options.map_memory_mb = run.map_memory_mb;
  options.write_mesh = false;
  options.progress = false;
  options.keep_frame_records = false;  // per-frame records would grow with the run
  options.keep_mesh = true;            // the two runs' surfaces are compared at the end
  if (!soak.map_file.empty() && run.map_memory_mb == soak.map_memory_mb &&
      std::string(run.name) == "capped") {
    std::remove(soak.map_file.c_str());  // a fresh store for a fresh run
    std::remove((soak.map_file + ".free").c_str());
    std::remove((soak.map_file + ".fine").c_str());
    options.map_file_path = soak.map_file;
  }
  options.on_frame = [&run](const FrameStats& stats) { on_frame(run, stats); };
  options.on_loop_start = [&run](int pass) { on_pass_start(run, pass); };
  std::fprintf(stderr, "[soak %s %g MB] %s, %ld frames ...\n", run.name,
               static_cast<double>(run.map_memory_mb), soak.source_spec.c_str(), soak.frames);
  reset_peak_rss();
  run.peak_before_reset_mb = 0.0;
  const auto start = std::chrono::steady_clock::now();
  run.exit_code = examples::run_pipeline(options, &run.summary);
  run.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (run.current.frames > 0) close_pass(run);
}

void write_run_json(host::JsonWriter& json, const SoakRun& run, double rss_tolerance_mb) {
  json.begin_object();
  json.key("name").value(run.name);
  json.key("map_memory_mb").value(static_cast<double>(run.map_memory_mb));
  json.key("exit_code").value(run.exit_code);
  json.key("failure").value(run.summary.failure.c_str());
  json.key("frames").value(run.frames);
  json.key("passes").value(run.passes);
  json.key("frames_lost").value(run.lost);
  json.key("frames_rejected").value(run.rejected);
  json.key("frames_skipped_by_source").value(run.summary.frames_skipped_by_source);
  json.key("blocks_evicted").value(run.evicted);
  json.key("map_bytes_reserved")
      .value(static_cast<std::uint64_t>(run.summary.map_memory.bytes_reserved));
  json.key("map_bytes_used").value(static_cast<std::uint64_t>(run.summary.map_memory.bytes_used));
  json.key("wall_s").value(run.wall_s);
  json.key("store_file_bytes").value(run.summary.store_file_bytes);
  json.key("store_reload_latency");
  write_reload_latency_json(json, run.summary.store_reload_latency);
  json.key("store_keys").value(run.summary.store_keys);
  json.key("store_live_bytes").value(run.summary.store_live_bytes);
  json.key("store_compactions").value(run.summary.store_compactions);
  json.key("free_store_file_bytes").value(run.summary.free_store_file_bytes);
  json.key("free_store_keys").value(run.summary.free_store_keys);
  json.key("free_store_read").value(static_cast<std::uint64_t>(run.summary.free_store_total.read));
  json.key("free_store_written")
      .value(static_cast<std::uint64_t>(run.summary.free_store_total.written));
  json.key("rss_end_first_pass_mb").value(run.rss_end_first_pass_mb);
  json.key("max_rss_after_first_pass_mb").value(run.max_rss_after_first_pass_mb);
  json.key("rss_growth_after_first_pass_mb").value(run.growth_mb());
  json.key("rss_flat").value(run.passes >= 2 && run.growth_mb() <= rss_tolerance_mb);
  json.key("peak_reset_after_first_pass").value(run.peak_reset);
  json.key("lost_frames").begin_array();
  for (std::size_t i = 0; i < run.lost_count; ++i) json.value(run.lost_frames[i]);
  json.end_array();
  json.key("pass_rows").begin_array();
  for (std::size_t i = 0; i < run.row_count; ++i) {
    const PassRow& row = run.rows[i];
    json.begin_object();
    json.key("pass").value(row.pass);
    json.key("first_frame").value(row.first_frame);
    json.key("frames").value(row.frames);
    json.key("lost").value(row.lost);
    json.key("rejected").value(row.rejected);
    json.key("blocks_evicted").value(row.evicted);
    json.key("blocks_resident").value(static_cast<std::uint64_t>(row.blocks_resident));
    json.key("block_capacity").value(static_cast<std::uint64_t>(row.block_capacity));
    json.key("blocks_high_water").value(static_cast<std::uint64_t>(row.blocks_high_water));
    json.key("octree_nodes").value(static_cast<std::uint64_t>(row.octree_nodes));
    json.key("free_space_nodes").value(static_cast<std::uint64_t>(row.free_space_nodes));
    json.key("rss_mb").value(row.rss_mb);
    json.key("peak_rss_mb").value(row.peak_rss_mb);
    json.key("median_ms").value(row.median_ms);
    json.key("p99_ms").value(row.p99_ms);
    json.key("refusals").value(row.refusals);
    json.key("free_space_refusals").value(row.free_space_refusals);
    json.key("finest_refusals").value(row.finest_refusals);
    json.key("mid_refusals").value(row.mid_refusals);
    json.key("store_read").value(row.store_read);
    json.key("store_remapped").value(row.store_remapped);
    json.key("store_deferred").value(row.store_deferred);
    json.key("store_written").value(row.store_written);
    json.key("store_unchanged").value(row.store_unchanged);
    json.key("store_bytes_read").value(row.store_bytes_read);
    json.key("store_bytes_written").value(row.store_bytes_written);
    json.key("frames_waiting").value(row.frames_waiting);
    json.key("reload_left_out").value(row.reload_left_out);
    json.key("reload_median_frames").value(row.reload_median_frames);
    json.key("reload_p90_frames").value(row.reload_p90_frames);
    json.key("reload_p99_frames").value(row.reload_p99_frames);
    json.key("reload_max_frames").value(row.reload_max_frames);
    json.key("reload_median_waited").value(row.reload_median_waited);
    json.key("reload_p99_waited").value(row.reload_p99_waited);
    json.key("reload_waiting").value(row.reload_waiting);
    json.key("free_store_read").value(row.free_store_read);
    json.key("free_store_written").value(row.free_store_written);
    json.key("free_store_bytes_read").value(row.free_store_bytes_read);
    json.key("free_store_bytes_written").value(row.free_store_bytes_written);
    json.key("finest_store_read").value(row.finest_store_read);
    json.key("finest_store_written").value(row.finest_store_written);
    json.key("finest_store_bytes_read").value(row.finest_store_bytes_read);
    json.key("finest_store_bytes_written").value(row.finest_store_bytes_written);
    json.end_object();
  }
  json.end_array();
  json.end_object();
}

// The capped run's final surface against the reference's, both ways, within one voxel.
struct SurfaceComparison {
  bool done = false;
  examples::SurfaceDistances capped_to_reference, reference_to_capped;
};

SurfaceComparison compare_surfaces(const SoakRun& capped, const SoakRun& reference, float voxel_m) {
  auto ref = [](const RunSummary& s) {
    return examples::MeshRef{s.mesh_positions.data(), s.mesh_positions.size(),
                             s.mesh_indices.data(), s.mesh_indices.size() / 3};
  };
  SurfaceComparison c;
  c.done = examples::compare_meshes(ref(capped.summary), ref(reference.summary), voxel_m,
                                    &c.capped_to_reference, &c.reference_to_capped) < 0;
  return c;
}

double share(std::size_t part, std::size_t whole) {
  return whole > 0 ? 100.0 * static_cast<double>(part) / static_cast<double>(whole) : 0.0;
}

std::string run_table(const SoakRun& run) {
  std::ostringstream md;
  char line[512];
  std::snprintf(line, sizeof(line),
                "\n%s run, --map-memory %g: %llu frames in %llu passes, %.0f s\n\n", run.name,
                static_cast<double>(run.map_memory_mb), static_cast<unsigned long long>(run.frames),
                static_cast<unsigned long long>(run.passes), run.wall_s);
  md << line
     << "| pass | frames | lost | evicted blocks | blocks resident (most) | octree nodes | "
        "free-space nodes | refusals | finest / mid levels refused | RSS MB | peak RSS MB | "
        "median ms | p99 ms |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (std::size_t i = 0; i < run.row_count; ++i) {
    const PassRow& row = run.rows[i];
    std::snprintf(line, sizeof(line),
                  "| %d | %llu-%llu | %llu | %llu | %u / %u (%u) | %u | %u | %llu | %llu / %llu | "
                  "%.1f | %.1f | %.1f | %.1f |\n",
                  row.pass, static_cast<unsigned long long>(row.first_frame),
                  static_cast<unsigned long long>(row.first_frame + row.frames - 1),
                  static_cast<unsigned long long>(row.lost),
                  static_cast<unsigned long long>(row.evicted), row.blocks_resident,
                  row.block_capacity, row.blocks_high_water, row.octree_nodes, row.free_space_nodes,
                  static_cast<unsigned long long>(row.refusals + row.free_space_refusals),
                  static_cast<unsigned long long>(row.finest_refusals),
                  static_cast<unsigned long long>(row.mid_refusals), row.rss_mb, row.peak_rss_mb,
                  row.median_ms, row.p99_ms);
    md << line;
  }
  if (run.passes > run.row_count) {
    md << "(" << run.passes - run.row_count << " more passes counted, not listed)\n";
  }
  return md.str();
}

}  // namespace

int run_soak(const SoakOptions& soak) {
#if defined(__GLIBC__)
  // Looping reopens the source each pass, and a replay source reserves its buffers again (4 MB,
  // aligned). After the first such free glibc raises its mmap threshold above that size; the
  // reservations then came from the heap and were not reused: 2.9 MB more resident per pass of
  // 7-Scenes, the harness's growth, not the map's. A fixed threshold (glibc's default, 128 KiB)
  // keeps every large block mapped and returns it on free.
  mallopt(M_MMAP_THRESHOLD, 128 * 1024);
#endif
  if (::mkdir(soak.out_dir.c_str(), 0755) != 0 && errno != EEXIST) {
    std::fprintf(stderr, "error: cannot create %s\n", soak.out_dir.c_str());
    return 2;
  }
  SoakRun runs[2];
  runs[0].name = "capped";
  runs[0].map_memory_mb = soak.map_memory_mb;
  runs[1].name = "reference";
  runs[1].map_memory_mb = soak.reference_memory_mb;
  const std::size_t frames = static_cast<std::size_t>(soak.frames);
  for (SoakRun& run : runs) {
    run.rows.resize(std::min(frames, kMaxStoredPasses));
    run.lost_frames.resize(frames);
    run.pass_ms.resize(frames);
  }
  // The capped run goes first, in a fresh process: pages an earlier run left resident in the heap
  // could otherwise absorb its growth unseen.
  for (SoakRun& run : runs) {
    run_one(soak, run);
    if (run.exit_code != 0) return 1;  // the runner printed why
  }
  const SoakRun& capped = runs[0];
  const SoakRun& reference = runs[1];

  std::vector<std::uint64_t> lost_only_capped;
  for (std::size_t i = 0; i < capped.lost_count; ++i) {
    const auto begin = reference.lost_frames.begin();
    const auto end = begin + static_cast<std::ptrdiff_t>(reference.lost_count);
    if (!std::binary_search(begin, end, capped.lost_frames[i])) {
      lost_only_capped.push_back(capped.lost_frames[i]);
    }
  }

  std::string reason;
  char text[512];
  if (capped.memory_unreadable) {
    reason = "cannot read VmRSS and VmHWM from /proc/self/status";
  } else if (!capped.summary.failure.empty()) {
    reason = "the capped run failed: " + capped.summary.failure;
  } else if (!reference.summary.failure.empty()) {
    reason = "the reference run failed: " + reference.summary.failure;
  } else if (capped.passes < 2) {
    std::snprintf(text, sizeof(text),
                  "the run ended in its first pass (%llu frames): nothing to compare memory "
                  "with; raise --soak-frames above the source's length",
                  static_cast<unsigned long long>(capped.frames));
    reason = text;
  } else if (!lost_only_capped.empty()) {
    reason = "the capped run lost " + std::to_string(lost_only_capped.size()) +
             " frames the reference did not:";
    for (std::size_t i = 0; i < lost_only_capped.size() && i < kMaxListedLostFrames; ++i) {
      reason += " " + std::to_string(lost_only_capped[i]);
    }
    if (lost_only_capped.size() > kMaxListedLostFrames) reason += " ...";
  } else if (capped.growth_mb() > soak.rss_tolerance_mb) {
    std::snprintf(text, sizeof(text),
                  "resident memory grew by %.2f MB after the first pass (%.1f -> %.1f MB; "
                  "tolerance %g MB)",
                  capped.growth_mb(), capped.rss_end_first_pass_mb,
                  capped.max_rss_after_first_pass_mb, soak.rss_tolerance_mb);
    reason = text;
  }

  std::ostringstream md;
  std::snprintf(
      text, sizeof(text),
      "Soak: %s, %ld frames, %g mm voxels, %s map, %s poses, %d thread(s); the source "
      "replayed in a loop, relocalised to the first frame's pose at the start of each "
      "pass.\n",
      soak.source_spec.c_str(), soak.frames, static_cast<double>(soak.voxel_size_m) * 1000.0,
      examples::map_option_name(soak.map_kind), pose_source_name(soak.pose_source), soak.threads);
  md << text;
  for (const SoakRun& run : runs) md << run_table(run);
  std::snprintf(text, sizeof(text),
                "\nCapped run: RSS flat after the first pass: %s (%.2f MB at the end of pass 0, "
                "at most %.2f MB after it: growth %.2f MB, tolerance %g MB%s); %llu frames lost, "
                "%zu of them not lost by the reference (%llu lost).\n",
                capped.passes >= 2 && capped.growth_mb() <= soak.rss_tolerance_mb ? "yes" : "no",
                capped.rss_end_first_pass_mb, capped.max_rss_after_first_pass_mb,
                capped.growth_mb(), soak.rss_tolerance_mb,
                capped.peak_reset ? "" : "; VmHWM could not be reset, RSS sampled per frame",
                static_cast<unsigned long long>(capped.lost), lost_only_capped.size(),
                static_cast<unsigned long long>(reference.lost));
  md << text;
  // What the capped map keeps of the surface (a measurement, not a pass condition).
  const SurfaceComparison surface = compare_surfaces(capped, reference, soak.voxel_size_m);
  if (surface.done) {
    const examples::SurfaceDistances& a = surface.capped_to_reference;
    const examples::SurfaceDistances& b = surface.reference_to_capped;
    std::snprintf(text, sizeof(text),
                  "Surface at the end (octofuse-map compare of the two runs' meshes): %.1f %% of "
                  "the capped map's vertices within one voxel of the reference's surface (median "
                  "%.2f mm, p99 %.2f mm), %.1f %% of the reference's within one voxel of the "
                  "capped one's (median %.2f mm, p99 %.2f mm).\n",
                  share(a.within, a.points), 1e3 * a.median_m, 1e3 * a.p99_m,
                  share(b.within, b.points), 1e3 * b.median_m, 1e3 * b.p99_m);
    md << text;
  }
  md << (reason.empty() ? "Soak passed.\n" : "Soak failed: " + reason + "\n");

  host::JsonWriter json;
  json.begin_object();
  json.key("source").value(soak.source_spec.c_str());
  json.key("frames").value(static_cast<std::int64_t>(soak.frames));
  json.key("voxel_size_m").value(static_cast<double>(soak.voxel_size_m));
  json.key("threads").value(soak.threads);
  json.key("map").value(examples::map_option_name(soak.map_kind));
  json.key("poses").value(pose_source_name(soak.pose_source));
  json.key("rss_tolerance_mb").value(soak.rss_tolerance_mb);
  json.key("runs").begin_array();
  for (const SoakRun& run : runs) write_run_json(json, run, soak.rss_tolerance_mb);
  json.end_array();
  json.key("lost_only_capped").begin_array();
  for (std::uint64_t index : lost_only_capped) json.value(index);
  json.end_array();
  if (surface.done) {
    json.key("surface").begin_object();
    json.key("capped_within_voxel")
        .value(share(surface.capped_to_reference.within, surface.capped_to_reference.points));
    json.key("capped_median_m").value(surface.capped_to_reference.median_m);
    json.key("capped_p99_m").value(surface.capped_to_reference.p99_m);
    json.key("reference_within_voxel")
        .value(share(surface.reference_to_capped.within, surface.reference_to_capped.points));
    json.key("reference_median_m").value(surface.reference_to_capped.median_m);
    json.key("reference_p99_m").value(surface.reference_to_capped.p99_m);
    json.end_object();
  }
  json.key("passed").value(reason.empty());
  json.key("reason").value(reason.c_str());
  json.end_object();

  const std::string md_path = soak.out_dir + "/soak.md";
  std::ofstream(md_path) << md.str();
  ErrorText error;
  if (!json.write_file((soak.out_dir + "/soak.json").c_str(), &error).ok()) {
    std::fprintf(stderr, "error: %s\n", error.c_str());
    return 2;
  }
  std::printf("%s\nwrote %s and %s/soak.json\n", md.str().c_str(), md_path.c_str(),
              soak.out_dir.c_str());
  if (!reason.empty()) {
    std::fprintf(stderr, "error: soak failed: %s\n", reason.c_str());
    return 1;
  }
  return 0;
}

}  // namespace octofuse::bench
