// Saving mid-sequence, loading into a fresh pipeline and tracking on: the resumed run stays on
// the ground truth like the uninterrupted one, fuses into the blocks it loaded instead of
// starting a new map, and its map file holds what the uninterrupted run's map holds.

#include <catch2/catch.hpp>
#include <cstdlib>
#include <string>
#include <vector>

#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/small_sim.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

constexpr int kFrames = 30;
constexpr int kSaveAt = 15;

// Noiseless, as the tracking test: within 1 cm, no frame lost.
sim::SimConfig sim_config() {
  return test::small_sim(kFrames, false);
}

struct Run {
  explicit Run(const PipelineConfig& config) : bytes(bytes_required(config)), buffer(bytes) {
    REQUIRE(pipeline.init(buffer.data, bytes, config).ok());
  }

  // Processes frames [from, to) of the sequence (earlier frames are read and dropped).
  void frames(sim::SimSource& source, int from, int to) {
    DepthFrame frame;
    for (int i = 0; i < to; ++i) {
      REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
      if (i < from) continue;
      FrameStats s;
      const Status status = pipeline.process(frame, &s);
      REQUIRE((status.ok() || status.code() == StatusCode::resource_exhausted));
      REQUIRE((s.result == FrameResult::tracked || s.result == FrameResult::first));
      stats.push_back(s);
      error_m.push_back(
          (pipeline.T_W_C().translation() - source.ground_truth_T_W_C(i).translation()).norm());
    }
  }

  std::size_t bytes;
  test::Buffer buffer;
  Pipeline<MultiresVoxel> pipeline;
  std::vector<FrameStats> stats;
  std::vector<double> error_m;
};

TEST_CASE("a map saved mid-sequence, loaded and tracked on matches the uninterrupted run") {
  sim::SimSource probe(sim_config());
  REQUIRE(probe.open().ok());
  const Se3d T_W_C0 = probe.ground_truth_T_W_C(0);
  PipelineConfig config =
      default_pipeline_config(probe.intrinsics(), 0.01f, 9, 20000,
                              (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>());
  config.preprocess.downsample_factor = 1;
  config.initial_T_W_C = T_W_C0;

  Run whole(config);
  {
    sim::SimSource source(sim_config());
    REQUIRE(source.open().ok());
    whole.frames(source, 0, kFrames);
  }

  const std::string dir = test::make_test_dir("map_persistence");
  REQUIRE(!dir.empty());
  const std::string path = dir + "/half.ofmap";
  std::uint32_t blocks_at_save = 0;
  {
    Run first(config);
    sim::SimSource source(sim_config());
    REQUIRE(source.open().ok());
    first.frames(source, 0, kSaveAt);
    blocks_at_save = first.pipeline.map().block_count();
    ErrorText error;
    MapSaveInfo info;
    info.frames = first.pipeline.frame_count();
    info.mu_m = first.pipeline.config().fusion.mu_m;
    REQUIRE(host::save_map_file(path.c_str(), first.pipeline.map(), info, &error).ok());
  }

  // A fresh pipeline: the map from the file, the first pose from the source's ground truth.
  Run resumed(config);
  MapFileHeader header;
  ErrorText error;
  REQUIRE(host::load_map_file(path.c_str(), resumed.pipeline.map(), &header, &error).ok());
  REQUIRE(header.frames == kSaveAt);
  REQUIRE(resumed.pipeline.resume_frame_count(header.frames).ok());
  {
    sim::SimSource source(sim_config());
    REQUIRE(source.open().ok());
    resumed.frames(source, kSaveAt, kFrames);
  }
  CHECK(resumed.stats.front().frame_index == kSaveAt);
  CHECK(resumed.stats.front().result == FrameResult::first);
  // The first resumed frame fuses into the loaded blocks: it allocates what the uninterrupted
  // run allocated at that frame (what the view newly shows), not everything it sees.
  const IntegrationReport& first_resumed = resumed.stats.front().integration;
  const IntegrationReport& same_frame = whole.stats[kSaveAt].integration;
  INFO("allocated " << first_resumed.blocks_allocated << " (uninterrupted "
                    << same_frame.blocks_allocated << ") of " << first_resumed.blocks_integrated
                    << " integrated; " << blocks_at_save << " blocks saved");
  CHECK(first_resumed.blocks_allocated <= same_frame.blocks_allocated + 20);
  CHECK(first_resumed.blocks_allocated < first_resumed.blocks_integrated / 2);
  // Tracking goes on as well as without the interruption.
  for (std::size_t i = 0; i < resumed.error_m.size(); ++i) {
    INFO("frame " << kSaveAt + i);
    CHECK(resumed.error_m[i] < 0.01);
    CHECK(resumed.error_m[i] < whole.error_m[kSaveAt + i] + 0.005);
  }
  // The same surface: block counts within 2% of the uninterrupted run's.
  const double whole_blocks = whole.pipeline.map().block_count();
  const double resumed_blocks = resumed.pipeline.map().block_count();
  CHECK(std::abs(resumed_blocks - whole_blocks) < 0.02 * whole_blocks);
}

}  // namespace
}  // namespace octofuse
