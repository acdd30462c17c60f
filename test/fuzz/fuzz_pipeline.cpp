// Pipeline::process fed arbitrary depth images, timestamps, scales and ground-truth poses (NaN,
// huge, not rotations), up to four frames per input on a fresh pipeline: every call returns a
// Status and a FrameStats that says what happened; no crash, no sanitizer report, and a rejected
// frame leaves the pose untouched.
//
// Input: per frame a 96-byte header (flags, timestamp step, metres per unit, 16 pose doubles
// taken raw when bit 1 of the flags is set, else a pose built from 6 bytes) then 64x48 depth
// pixels, little-endian 16-bit; a short tail repeats the last bytes it has.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "octofuse/pipeline/pipeline.hpp"

namespace {

constexpr int kWidth = 64;
constexpr int kHeight = 48;
constexpr int kMaxFrames = 4;
constexpr std::size_t kHeaderBytes = 1 + 1 + 2 + 128 + 6;

using Map = octofuse::Pipeline<octofuse::MultiresVoxel>;

struct Fixture {
  octofuse::PipelineConfig config;
  void* buffer = nullptr;
  std::size_t bytes = 0;
  std::uint16_t depth[kWidth * kHeight];
};

std::int64_t fake_now(void* context) {
  return ++*static_cast<std::int64_t*>(context);
}

Fixture& fixture() {
  static Fixture* f = [] {
    Fixture* made = new Fixture();
    octofuse::PinholeCamera camera{50.0f, 50.0f, 31.5f, 23.5f, kWidth, kHeight};
    made->config = octofuse::default_pipeline_config(camera, 0.05f, 7, 2048,
                                                     Eigen::Vector3f(0.0f, 0.0f, 1.0f));
    made->config.map.finest_capacity = 256;  // a small finest pool: refusals get exercised too
    made->config.map.mid_capacity = 512;     // and a small mid pool
    // A small per-frame block list: init takes 0.05 ms instead of 18 (its table is cleared at
    // init), and frames that overflow it are exercised.
    made->config.fusion.max_blocks_per_frame = 4096;
    made->bytes = octofuse::bytes_required(made->config);
    if (made->bytes == 0) std::abort();
    made->buffer = std::aligned_alloc(octofuse::kArenaAlignment,
                                      octofuse::align_up(made->bytes, octofuse::kArenaAlignment));
    if (made->buffer == nullptr) std::abort();
    return made;
  }();
  return *f;
}

// Reads bytes at `at`, wrapping around the input so every frame gets data.
struct Reader {
  const std::uint8_t* data;
  std::size_t size;
  std::size_t at = 0;
  std::uint8_t byte() { return data[at++ % size]; }
  void bytes(void* out, std::size_t n) {
    auto* o = static_cast<std::uint8_t*>(out);
    for (std::size_t i = 0; i < n; ++i) o[i] = byte();
  }
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < kHeaderBytes) return 0;
  Fixture& f = fixture();
  std::int64_t ticks = 0;
  Map pipeline;
  const octofuse::Clock clock{&fake_now, &ticks};
  if (!pipeline.init(f.buffer, f.bytes, f.config, clock).ok()) __builtin_trap();

  Reader in{data, size};
  const int frames = 1 + data[0] % kMaxFrames;
  std::int64_t timestamp_us = 0;
  for (int k = 0; k < frames; ++k) {
    const std::uint8_t flags = in.byte();
    const std::int8_t step = static_cast<std::int8_t>(in.byte());
    std::uint16_t scale_code;
    in.bytes(&scale_code, 2);
    double raw_pose[16];
    in.bytes(raw_pose, sizeof(raw_pose));
    std::uint8_t pose_code[6];
    in.bytes(pose_code, sizeof(pose_code));
    in.bytes(f.depth, sizeof(f.depth));

    octofuse::DepthFrame frame;
    frame.depth_raw = octofuse::ImageView<const std::uint16_t>(f.depth, kWidth, kHeight);
    // Mostly millimetres; sometimes zero, negative, tiny or huge.
    frame.metres_per_unit =
        (flags & 4) != 0 ? static_cast<float>(scale_code) * 1e-5f - 0.1f : 0.001f;
    timestamp_us += static_cast<std::int64_t>(step) * 33333;  // may repeat or go backwards
    // Near the end of the clock's range when flag 8 is set; the margin exceeds any sum of steps,
    // so the harness itself never overflows (the pipeline must cope with the jumps).
    constexpr std::int64_t kNearMaxMargin = std::int64_t{1} << 40;
    frame.timestamp_us =
        (flags & 8) != 0 ? INT64_MAX - kNearMaxMargin + timestamp_us : timestamp_us;
    frame.sequence = static_cast<std::uint64_t>(k);
    frame.has_ground_truth = (flags & 1) != 0;
    if ((flags & 2) != 0) {
      std::memcpy(frame.T_W_C_ground_truth.data(), raw_pose, sizeof(raw_pose));
    } else {
      // A rigid pose near the map: small rotation and translation from 6 bytes.
      const double a = (pose_code[0] - 128) * 0.01, b = (pose_code[1] - 128) * 0.01,
                   c = (pose_code[2] - 128) * 0.01;
      Eigen::Matrix3d R = (Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()) *
                           Eigen::AngleAxisd(b, Eigen::Vector3d::UnitY()) *
                           Eigen::AngleAxisd(c, Eigen::Vector3d::UnitZ()))
                              .toRotationMatrix();
      frame.T_W_C_ground_truth.setIdentity();
      frame.T_W_C_ground_truth.topLeftCorner<3, 3>() = R;
      frame.T_W_C_ground_truth.topRightCorner<3, 1>() =
          Eigen::Vector3d(pose_code[3] - 128, pose_code[4] - 128, pose_code[5] - 128) * 0.01;
    }

    const octofuse::Se3d before = pipeline.T_W_C();
    octofuse::FrameStats stats;
    const octofuse::Status status = pipeline.process(frame, &stats);
    switch (stats.result) {
      case octofuse::FrameResult::tracked:
      case octofuse::FrameResult::first:
      case octofuse::FrameResult::lost:
      case octofuse::FrameResult::nearly_empty:
        break;
      case octofuse::FrameResult::rejected:
        if (status.ok()) __builtin_trap();  // a rejection always says why
        if (pipeline.T_W_C().matrix() != before.matrix()) __builtin_trap();
        break;
      default:
        __builtin_trap();
    }
    if (!pipeline.T_W_C().matrix().allFinite()) __builtin_trap();
    if (!octofuse::is_rigid(pipeline.T_W_C().matrix(), 1e-3)) __builtin_trap();
    if (stats.memory.blocks_used > stats.memory.block_capacity) __builtin_trap();
  }
  return 0;
}
