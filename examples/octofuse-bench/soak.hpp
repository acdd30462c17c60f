#pragma once
// octofuse-bench --soak: a long mission under a fixed memory cap. A source is replayed in a loop
// (LoopingSource) for N frames twice in one process: first under the cap, then with a large cap
// for reference. The soak passes when the capped run lost no frame the reference did not lose
// and its resident memory did not grow by more than a tolerance after its first pass.

#include <string>

#include "octofuse/pipeline/pipeline.hpp"

namespace octofuse::bench {

struct SoakOptions {
  std::string source_spec = "sim:room";
  long frames = 10000;
  float map_memory_mb = 16.0f;          // the capped run
  float reference_memory_mb = 1024.0f;  // the reference run (the programs' default)
  double rss_tolerance_mb = 1.0;        // allowed growth of resident memory after the first pass
  float voxel_size_m = 0.01f;
  int threads = 1;
  MapKind map_kind = MapKind::multires;        // both runs' map (the first of --maps)
  PoseSource pose_source = PoseSource::track;  // the first of --poses: ICP, or ground truth
  std::string out_dir = "bench-out";
  // --soak-map-file: the capped run keeps evicted blocks in this store (emptied first).
  std::string map_file;
};

// Runs both passes, prints a table per run and the verdict, writes soak.json and soak.md into
// out_dir. Returns 0 when the soak passed, 1 with one `error:` line when it did not (or a run
// failed), 2 when out_dir cannot be written.
int run_soak(const SoakOptions& options);

}  // namespace octofuse::bench
