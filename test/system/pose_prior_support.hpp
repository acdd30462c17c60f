#pragma once
// What the pose-prior tests share: the small sim camera (as the pipeline tests), a configuration
// for each pose source, and a run that hands the pipeline a prior made from ground truth.

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/sim/odometry.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/small_sim.hpp"

namespace octofuse {
namespace {

using test::small_sim;

using octofuse::test::Buffer;

inline PipelineConfig small_config(const sim::SimSource& source, PoseSource pose_source) {
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  PipelineConfig config =
      default_pipeline_config(source.intrinsics(), 0.02f, 9, 20000,
                              (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>());
  config.preprocess.downsample_factor = 1;
  config.initial_T_W_C = T_W_C0;
  config.pose_source = pose_source;
  // The reference cast at every pixel: the margins below were set on this 160 x 120 sim with it,
  // and half resolution would leave ICP an 80 x 60 model (the prior's logic does not depend on it).
  config.budget.raycast_half = false;
  return config;
}

struct Run {
  std::vector<Se3d> poses;
  std::vector<Se3d> truth;
  std::vector<Se3d> priors;
  std::vector<FrameStats> stats;
  std::uint64_t frames_lost = 0;
};

// Prior for frame i from the true pose i (and i itself); returns false for "no prior".
using PriorFn = bool (*)(int index, const Se3d& truth, Se3d* prior, void* context);

// Runs the first `frames` frames of a sim path of `path_frames` (0: the same) frames.
inline Run run(int frames, const PipelineConfig& config, PriorFn make_prior, void* context,
               int path_frames = 0) {
  sim::SimSource source(small_sim(path_frames > 0 ? path_frames : frames));
  REQUIRE(source.open().ok());
  const std::size_t bytes = bytes_required(config);
  REQUIRE(bytes > 0);
  Buffer buffer(bytes);
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes, config).ok());
  Run out;
  DepthFrame frame;
  for (int i = 0; i < frames && source.next(frame).outcome == FrameOutcome::frame; ++i) {
    Se3d truth = Se3d::Identity();
    truth.matrix() = frame.T_W_C_ground_truth;
    PosePrior prior;
    Se3d prior_T_W_C = Se3d::Identity();
    if (make_prior != nullptr && make_prior(i, truth, &prior_T_W_C, context)) {
      prior.valid = true;
      prior.T_W_C = prior_T_W_C.matrix();
    }
    FrameStats stats;
    const Status status = pipeline.process(frame, prior, &stats);
    REQUIRE((status.ok() || stats.result == FrameResult::lost));
    out.poses.push_back(pipeline.T_W_C());
    out.truth.push_back(truth);
    out.priors.push_back(prior_T_W_C);
    out.stats.push_back(stats);
  }
  out.frames_lost = pipeline.frames_lost();
  return out;
}

}  // namespace
}  // namespace octofuse
