#pragma once
// What the whole-pipeline tests share: a small sim camera (a quarter of VGA, so a Debug build
// stays quick; the full-size numbers come from octofuse-bench), a configuration for it and a
// run over its frames.

#include "octofuse/pipeline/pipeline.hpp"

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "octofuse/ports/host/trajectory_io.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/small_sim.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

using test::small_sim;

using octofuse::test::Buffer;

inline PipelineConfig small_config(const sim::SimSource& source, float voxel_m, int workers,
                                   std::uint32_t blocks = 20000) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  PipelineConfig config =
      default_pipeline_config(source.intrinsics(), voxel_m, 9, blocks,
                              (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>());
  config.preprocess.downsample_factor = 1;
  config.workers = workers;
  config.initial_T_W_C = T_W_C0;
  return config;
}

// Runs `frames` frames; returns the poses and (optionally) every frame's stats.
template <typename VoxelT>
std::vector<Se3d> run(const sim::SimConfig& sim_config, const PipelineConfig& config,
                      std::vector<FrameStats>* all_stats = nullptr) {
  sim::SimSource source(sim_config);
  REQUIRE(source.open().ok());
  Buffer buffer(bytes_required(config));
  Pipeline<VoxelT> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  std::vector<Se3d> poses;
  DepthFrame frame;
  while (source.next(frame).outcome == FrameOutcome::frame) {
    FrameStats stats;
    const Status status = pipeline.process(frame, &stats);
    REQUIRE((status.ok() || status.code() == StatusCode::resource_exhausted ||
             stats.result == FrameResult::lost));
    poses.push_back(pipeline.T_W_C());
    if (all_stats != nullptr) all_stats->push_back(stats);
  }
  return poses;
}

inline bool bit_identical(const std::vector<Se3d>& a, const std::vector<Se3d>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::memcmp(a[i].matrix().data(), b[i].matrix().data(), sizeof(double) * 16) != 0) {
      return false;
    }
  }
  return true;
}

}  // namespace
}  // namespace octofuse
