// The same input gives the same output: byte-identical trajectories for any worker count, and
// the same pose and map bits on every machine.

#include "octofuse/pipeline/pipeline.hpp"

#include <catch2/catch.hpp>

#include "system/pipeline_support.hpp"

namespace octofuse {
namespace {

std::string write_trajectory(const std::vector<Se3d>& poses, const char* name) {
  const std::string dir = test::make_test_dir("trajectory");
  REQUIRE(!dir.empty());
  const std::string path = dir + "/" + name;
  host::TumTrajectoryWriter writer;
  REQUIRE(writer.open(path.c_str()).ok());
  for (std::size_t i = 0; i < poses.size(); ++i) {
    host::TimedPose pose;
    pose.timestamp_s = static_cast<double>(i) / 30.0;
    pose.T_W_C = poses[i];
    REQUIRE(writer.append(pose).ok());
  }
  REQUIRE(writer.close().ok());
  return test::read_bytes(path);
}

TEST_CASE("same input gives a byte-identical trajectory, twice and with 1 or 2 workers") {
  const sim::SimConfig sim_config = small_sim(40);
  sim::SimSource probe(sim_config);
  REQUIRE(probe.open().ok());
  const std::vector<Se3d> one = run<MultiresVoxel>(sim_config, small_config(probe, 0.02f, 1));
  const std::vector<Se3d> again = run<MultiresVoxel>(sim_config, small_config(probe, 0.02f, 1));
  const std::vector<Se3d> two = run<MultiresVoxel>(sim_config, small_config(probe, 0.02f, 2));
  REQUIRE(one.size() == 40);
  REQUIRE(bit_identical(one, again));
  REQUIRE(bit_identical(one, two));
  REQUIRE(write_trajectory(one, "determinism_1.txt") == write_trajectory(two, "determinism_2.txt"));
  // The estimate moved: identical but trivially constant trajectories would prove nothing.
  REQUIRE((one.front().translation() - one.back().translation()).norm() > 0.01);

  const std::vector<Se3d> single_1 = run<TsdfVoxel>(sim_config, [&] {
    PipelineConfig c = small_config(probe, 0.02f, 1);
    c.map_kind = MapKind::single_res;
    return c;
  }());
  const std::vector<Se3d> single_2 = run<TsdfVoxel>(sim_config, [&] {
    PipelineConfig c = small_config(probe, 0.02f, 2);
    c.map_kind = MapKind::single_res;
    return c;
  }());
  REQUIRE(bit_identical(single_1, single_2));
}

// FNV-1a over values' bits, a byte at a time from the low end: the same hash on any byte order,
// and struct padding never enters it.
struct BitHash {
  std::uint64_t value = 14695981039346656037ull;
  void add(std::uint64_t bits, int bytes) {
    for (int i = 0; i < bytes; ++i, bits >>= 8) {
      value = (value ^ (bits & 0xFF)) * 1099511628211ull;
    }
  }
  void add(float f) {
    std::uint32_t bits;
    std::memcpy(&bits, &f, sizeof bits);
    add(bits, 4);
  }
  void add(int i) { add(static_cast<std::uint32_t>(i), 4); }
};

// Every block in pool order: its place, its header and all 585 voxels (scale 0 of a block without
// a finest level reads as unobserved).
template <typename VoxelT>
std::uint64_t map_hash(const Octree<VoxelT>& map) {
  BitHash h;
  for (std::uint32_t i = 0; i < map.block_count(); ++i) {
    const VoxelBlock<VoxelT>& b = map.block(i);
    for (int k = 0; k < 3; ++k) h.add(b.coords[k]);
    h.add(b.last_updated_frame, 4);
    h.add(b.current_scale);
    h.add(b.min_scale);
    h.add(b.mip_scale);
    for (const float f : {b.tsdf_min, b.tsdf_max, b.tsdf_mean, b.weight_mean}) h.add(f);
    // Scale 0 keeps its TSDF and weight only (its x_last and delta_y are never read).
    for (int k = 0; k < kBlockVoxelCount; ++k) {
      const VoxelT v = b.voxel(k);
      h.add(voxel_tsdf(v));
      h.add(voxel_weight(v));
      if (k < kBlockFinestVoxelCount) continue;
      h.add(voxel_x_last(v));
      h.add(voxel_delta_y(v));
    }
  }
  return h.value;
}

std::string hex(std::uint64_t bits) {
  char text[24];
  std::snprintf(text, sizeof text, "0x%016llx", static_cast<unsigned long long>(bits));
  return text;
}

// Runs 6 frames of the small noisy sim (the first, then five tracked) at 2 cm with 1 and 3 workers,
// and with 1 worker after Pipeline::prefault() of every pool page (which must change nothing), and
// checks the final pose's 12 doubles and a hash of every block's voxels against the pinned bits;
// prints what it got, for re-pinning after a deliberate change.
template <typename VoxelT>
void check_pinned_bits(MapKind map_kind, bool raycast_half,
                       const std::uint64_t (&expected_pose_bits)[12],
                       std::uint64_t expected_map_hash) {
  constexpr int kFrames = 6;
  const sim::SimConfig sim_config = small_sim(40);
  struct Run {
    int workers;
    bool prefault;
  };
  for (const Run run : {Run{1, false}, Run{3, false}, Run{1, true}}) {
    const int workers = run.workers;
    CAPTURE(workers, run.prefault);
    sim::SimSource source(sim_config);
    REQUIRE(source.open().ok());
    PipelineConfig config = small_config(source, 0.02f, workers);
    config.map_kind = map_kind;
    config.budget.raycast_half = raycast_half;
    Buffer buffer(bytes_required(config));
    Pipeline<VoxelT> pipeline;
    REQUIRE(pipeline.prefault(64).code() == StatusCode::failed_precondition);
    REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
    // More than the pools hold: every slot's pages.
    if (run.prefault) REQUIRE(pipeline.prefault(0xFFFFFFFFu).ok());
    DepthFrame frame;
    for (int i = 0; i < kFrames; ++i) {
      CAPTURE(i);
      REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
      FrameStats stats;
      REQUIRE(pipeline.process(frame, &stats).ok());
      REQUIRE(stats.result == (i == 0 ? FrameResult::first : FrameResult::tracked));
      REQUIRE(stats.integration.blocks_integrated > 0);
      REQUIRE(stats.raycast.valid_pixels > 0);
    }
    // The estimate moved, so tracking did something these bits record.
    REQUIRE((pipeline.T_W_C().translation() - config.initial_T_W_C.translation()).norm() > 0.01);
    std::uint64_t pose_bits[12];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) {
        const double value = pipeline.T_W_C().matrix()(r, c);
        std::memcpy(&pose_bits[r * 4 + c], &value, sizeof value);
      }
    }
    const std::uint64_t map_bits = map_hash(pipeline.map());
    std::string printed = "pose bits (row-major 3x4):";
    for (const std::uint64_t bits : pose_bits) printed += " " + hex(bits);
    printed += "\nmap hash: " + hex(map_bits);
    INFO(printed);
    for (int k = 0; k < 12; ++k) CHECK(pose_bits[k] == expected_pose_bits[k]);
    CHECK(map_bits == expected_map_hash);
  }
}

TEST_CASE("the same frames give the same pose and map bits on x86-64, aarch64 and armhf") {
  // With the reference cast at every pixel (the test below pins the default, half resolution).
  // The constants are what the x86-64 Release build printed; the aarch64 and armhf builds, run
  // under qemu, give the same. A change that moves a rounding anywhere in sensing, fusion,
  // ray-casting or tracking changes them: check that the new values are the same on all three
  // before writing them here.
  constexpr std::uint64_t kPoseBits[12] = {
      0x3fef98fa37efe4a3, 0xbfb7cb44d51e1a18, 0x3fc05e970b3985ad, 0x3fae32c20e443b6a,
      0xbfc43c65a1b406b0, 0xbfe2adcc1b72d6d5, 0x3fe97c431c1f8fe9, 0xbfde1dcf8134180a,
      0x3f448314151a58b0, 0xbfe9cfd6c554f234, 0xbfe2ea08f04b781e, 0x3ff14993df683295};
  check_pinned_bits<MultiresVoxel>(MapKind::multires, false, kPoseBits, 0x90623640122d2f42);
}

// The default reference cast at half resolution (ICP paired with its marched pixels), the same.
TEST_CASE("with the half-resolution reference cast the bits are the same on every machine") {
  constexpr std::uint64_t kPoseBits[12] = {
      0x3fef98e1ba2b1a0e, 0xbfb7e41956236553, 0x3fc0587fb51b824e, 0x3fae083f85f1f1ef,
      0xbfc43ed20a95a6b4, 0xbfe2af56be4cad92, 0x3fe97b02ff762a9a, 0xbfde1c28ee166c6f,
      0x3f30a574f947b8f4, 0xbfe9ce5d5c0f3682, 0xbfe2ec0c66ae43c9, 0x3ff149ec3aec9b72};
  check_pinned_bits<MultiresVoxel>(MapKind::multires, true, kPoseBits, 0xd30f2643a4492579);
}

// The 16-bit map, the same way: its rounding is integer arithmetic on exactly computed floats,
// so the bits depend neither on the worker count nor on the machine. The constants are what the
// x86-64 Release build printed for 1 and 3 workers; the aarch64 and armhf builds must match them.
TEST_CASE("the 16-bit map gives the same pose and map bits for 1 and 3 workers and any machine",
          "[multires16]") {
  constexpr std::uint64_t kPoseBits[12] = {
      0x3fef98e0911d84de, 0xbfb7cfdbb0f8d051, 0x3fc060041e6a594b, 0x3fae2b87a458b863,
      0xbfc43ee79b06dbaf, 0xbfe2ad5bc1b31531, 0x3fe97c75955b48da, 0xbfde1de8136f7e5d,
      0x3f433811331f588a, 0xbfe9d01723f76892, 0xbfe2e9b12cb35f22, 0x3ff1497944f7354e};
  check_pinned_bits<Multires16Voxel>(MapKind::multires16, false, kPoseBits, 0x603d6e4a64de0dd3);
}

}  // namespace
}  // namespace octofuse
