// ReloadLatencyProbe (examples/common/reload_latency.hpp): the frames that left a stored block out
// and the frames from the first of them to its read, on scripted store calls with hand-counted
// waits, and wired between a looped run and its --map-file store.

#include <catch2/catch.hpp>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "reload_latency.hpp"
#include "runner.hpp"
#include "support/memory_store.hpp"

using namespace octofuse;
using namespace octofuse::examples;

namespace {

// Stores one-byte records under keys 1 .. n.
void fill(MemoryStore& store, std::uint64_t n) {
  const std::uint8_t record = 7;
  for (std::uint64_t key = 1; key <= n; ++key) REQUIRE(store.put(key, &record, 1).ok());
}

bool take(BlockStore& store, std::uint64_t key) {
  std::uint8_t record[4];
  return store.take(key, record, sizeof(record)).ok();
}

}  // namespace

TEST_CASE("a block counts the frames that left it out and the frames to its read") {
  MemoryStore inner;
  fill(inner, 4);
  ReloadLatency latency;
  ReloadLatencyProbe probe(&inner, &latency);

  probe.begin_frame(10);
  CHECK(take(probe, 1));        // read ahead, never left out: 0 and 0
  CHECK(probe.holds(2));        // left out at frame 10
  CHECK(probe.holds(2));        // asked twice in one frame: still one frame
  CHECK(probe.holds(3));        // left out at frame 10
  CHECK_FALSE(probe.holds(9));  // not stored: nothing waits
  probe.end_frame();
  CHECK(latency.waiting == 2);

  probe.begin_frame(11);
  CHECK(probe.holds(2));  // left out again: 2 frames, since frame 10
  CHECK(take(probe, 3));  // 1 frame left out, 1 frame waited
  probe.end_frame();
  CHECK(latency.waiting == 1);

  probe.begin_frame(14);
  CHECK(take(probe, 2));  // 2 frames left out, 4 waited
  CHECK(probe.holds(4));
  probe.end_frame();

  probe.begin_frame(20);
  CHECK(take(probe, 4));        // 1 frame left out, 6 waited
  CHECK_FALSE(take(probe, 9));  // not stored: no read
  probe.end_frame();

  const FrameCountHistogram& left_out = latency.frames_left_out;
  const FrameCountHistogram& waited = latency.frames_waited;
  CHECK(left_out.reads[0] == 1);
  CHECK(left_out.reads[1] == 2);
  CHECK(left_out.reads[2] == 1);
  CHECK(left_out.max_frames == 2);
  CHECK(waited.reads[0] == 1);
  CHECK(waited.reads[1] == 1);
  CHECK(waited.reads[4] == 1);
  CHECK(waited.reads[6] == 1);
  CHECK(waited.max_frames == 6);
  std::uint64_t total = 0;
  for (std::uint64_t n : waited.reads) total += n;
  CHECK(total == 4);
  CHECK(latency.waiting == 0);
  CHECK(left_out.nonzero() == 3);
  // Left out 1, 1, 2: median 1, p90 2. Waited 1, 4, 6: median 4, p90 and p99 6, lowest 1.
  CHECK(left_out.frames_at(0.5) == 1);
  CHECK(left_out.frames_at(0.9) == 2);
  CHECK(waited.frames_at(0.5) == 4);
  CHECK(waited.frames_at(0.9) == 6);
  CHECK(waited.frames_at(0.99) == 6);
  CHECK(waited.frames_at(0.0) == 1);
  // Every call reached the store: the blocks taken count as in memory there.
  CHECK(inner.taken() == 4);
}

TEST_CASE("a block taken and released at once was not read back: it waits on") {
  MemoryStore inner;
  fill(inner, 2);
  ReloadLatency latency;
  ReloadLatencyProbe probe(&inner, &latency);

  probe.begin_frame(0);
  CHECK(probe.holds(1));
  probe.end_frame();
  probe.begin_frame(3);
  CHECK(take(probe, 1));
  probe.release(1);       // a pool was full
  CHECK(probe.holds(1));  // and this frame left it out too
  probe.end_frame();
  CHECK(latency.waiting == 1);
  CHECK(latency.frames_left_out.nonzero() == 0);
  CHECK(latency.frames_left_out.reads[0] == 0);
  CHECK(inner.releases == 1);

  probe.begin_frame(5);
  CHECK(take(probe, 1));  // left out in frames 0 and 3, waited since frame 0
  // Released after another block was taken (evicted unchanged, say): its read stands.
  CHECK(take(probe, 2));
  probe.release(1);
  probe.end_frame();
  CHECK(latency.frames_left_out.reads[2] == 1);
  CHECK(latency.frames_waited.reads[5] == 1);
  CHECK(latency.frames_left_out.reads[0] == 1);
  CHECK(latency.frames_waited.max_frames == 5);
  CHECK(latency.waiting == 0);
}

TEST_CASE("waits of the last bucket or more count there with their maximum exact") {
  MemoryStore inner;
  fill(inner, 3);
  ReloadLatency latency;
  ReloadLatencyProbe probe(&inner, &latency);
  probe.begin_frame(0);
  CHECK(probe.holds(1));
  CHECK(probe.holds(2));
  probe.begin_frame(kReloadLatencyBuckets + 100);
  CHECK(take(probe, 1));
  probe.end_frame();
  const ReloadLatency first = latency;
  probe.begin_frame(kReloadLatencyBuckets + 200);
  CHECK(take(probe, 2));
  CHECK(take(probe, 3));
  probe.end_frame();
  const FrameCountHistogram& waited = latency.frames_waited;
  CHECK(waited.reads[kReloadLatencyBuckets - 1] == 2);
  CHECK(waited.max_frames == kReloadLatencyBuckets + 200);
  CHECK(waited.frames_at(0.5) == kReloadLatencyBuckets - 1);
  CHECK(latency.frames_left_out.reads[1] == 2);

  // Since `first`: one read that waited (the longest of the run) and one that did not.
  const ReloadLatency since = reload_latency_since(latency, first);
  CHECK(since.frames_waited.reads[0] == 1);
  CHECK(since.frames_waited.reads[kReloadLatencyBuckets - 1] == 1);
  CHECK(since.frames_waited.nonzero() == 1);
  CHECK(since.frames_waited.max_frames == kReloadLatencyBuckets + 200);
  CHECK(since.frames_left_out.max_frames == 1);
  // Since a copy of itself: nothing, not even the run's maximum.
  const ReloadLatency none = reload_latency_since(latency, latency);
  CHECK(none.frames_waited.nonzero() == 0);
  CHECK(none.frames_waited.reads[0] == 0);
  CHECK(none.frames_waited.max_frames == 0);
  CHECK(none.frames_waited.frames_at(0.5) == 0);
}

TEST_CASE("a looped run with a store counts every block it read back in its reload latency") {
  const std::string store_path = "reload_latency_test.store";
  std::remove(store_path.c_str());
  std::remove((store_path + ".free").c_str());
  RunOptions options;
  options.source_spec = "sim:desk,frames=12";
  options.voxel_size_m = 0.02f;
  options.pose_source = PoseSource::ground_truth;
  options.max_blocks = 400;  // under one pass's map: blocks go to the store and come back
  options.budget.max_store_reads = 16;  // returns wait for their turn
  options.max_frames = 24;
  options.loop_source = true;
  options.write_mesh = false;
  options.progress = false;
  options.keep_frame_records = false;
  options.map_file_path = store_path;
  RunSummary summary;
  REQUIRE(run_pipeline(options, &summary) == 0);
  INFO("written " << summary.store_total.written << ", read " << summary.store_total.read
                  << ", deferred " << summary.store_total.deferred << ", waiting "
                  << summary.store_reload_latency.waiting);
  const ReloadLatency& latency = summary.store_reload_latency;
  std::uint64_t counted = 0;
  for (std::uint64_t n : latency.frames_left_out.reads) counted += n;
  // The second pass returns to the first one's space: blocks come back from the store.
  CHECK(summary.store_total.written > 0);
  CHECK(summary.store_total.read > 0);
  CHECK(counted == summary.store_total.read + summary.store_total.remapped);
  CHECK(summary.store_total.deferred > 0);
  CHECK(latency.frames_left_out.nonzero() > 0);
  // Each frame that left a block out is one of the pipeline's deferred block-frames.
  std::uint64_t frames_left_out = 0;
  for (std::size_t i = 0; i < kReloadLatencyBuckets; ++i) {
    frames_left_out += i * latency.frames_left_out.reads[i];
  }
  CHECK(latency.frames_left_out.max_frames < kReloadLatencyBuckets);
  CHECK(frames_left_out <= summary.store_total.deferred);
  CHECK(latency.frames_waited.max_frames >= latency.frames_left_out.max_frames);
  std::remove(store_path.c_str());
  std::remove((store_path + ".free").c_str());
}
