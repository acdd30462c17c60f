#pragma once
// SimSource: a DepthSource that renders a built-in world (scenes.hpp) with a Kinect-like sensor
// and exact ground truth on every frame. Everything it needs is allocated once, in open(); next()
// never allocates.
//
//   auto source = octofuse::sim::make_sim_source("desk", &error);   // or "sim:room,frames=100"
//   source->open(); while (source->next(frame).outcome == FrameOutcome::frame) { ... }

#include <cstddef>
#include <cstdint>
#include <memory>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/error_text.hpp"
#include "octofuse/ports/sim/noise.hpp"
#include "octofuse/ports/sim/renderer.hpp"
#include "octofuse/ports/sim/scenes.hpp"
#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::sim {

// The Kinect v1 / TUM default: 640 x 480, fx = fy = 525, principal point at the centre.
PinholeCamera kinect_camera();

struct SimConfig {
  SceneId scene = SceneId::desk;
  int frame_count = 0;  // 0: the scene's default (desk 300, room 360); the path always spans them
  PinholeCamera camera = kinect_camera();
  float metres_per_unit = 0.001f;
  int ring_size = 4;  // frames that stay valid at once
  double rate_hz = 30.0;
  std::int64_t start_timestamp_us = 0;
  std::uint64_t seed = 1;
  KinectNoiseModel noise;    // noise.enabled = false gives exact (unit-rounded) depth
  float min_range_m = 0.2f;  // the sensor sees nothing nearer
  float max_range_m = 6.0f;  // or farther
};

class SimSource final : public DepthSource {
 public:
  explicit SimSource(const SimConfig& config);
  ~SimSource() override;
  SimSource(const SimSource&) = delete;
  SimSource& operator=(const SimSource&) = delete;

  // Builds the world and reserves the ring, the render buffers and the tile lists (one
  // allocation of bytes_required()). Returns ok, invalid_argument (a config value out of range:
  // camera, frame_count < 0, ring_size < 1, rate, scale, ranges), resource_exhausted (no memory),
  // internal (a built-in scene did not fit).
  Status open() override;
  // frame (ok), end_of_stream after frame_count frames, error/failed_precondition before open().
  NextFrame next(DepthFrame& frame) override;
  void close() override;
  PinholeCamera intrinsics() const override { return config_.camera; }
  SourceCapabilities capabilities() const override;
  const char* last_error() const override { return error_.c_str(); }

  // Bytes open() allocates for `config` (0 for a config open() would reject).
  static std::size_t bytes_required(const SimConfig& config);

  const SimConfig& config() const { return config_; }
  int frame_count() const { return frame_count_; }     // valid after open()
  const Scene& scene() const { return world_.scene; }  // valid after open()
  // Ground truth camera-to-world pose of frame `index` (clamped to [0, frame_count)).
  Se3d ground_truth_T_W_C(int index) const;
  std::int64_t timestamp_us(int index) const;
  // Exact depth (metres along z, before noise and range limits) of the latest frame.
  ImageView<const float> last_exact_depth_m() const { return exact_depth_m_; }
  const RenderStats& last_render_stats() const { return renderer_.last_stats(); }

 private:
  template <typename Arena>
  Status reserve(Arena& arena);
  Status validate_config();

  SimConfig config_;
  SimWorld world_;
  SceneRenderer renderer_;
  int frame_count_ = 0;
  int next_index_ = 0;
  bool open_ = false;
  std::unique_ptr<unsigned char[]> memory_;
  std::uint16_t* ring_ = nullptr;
  ImageView<float> exact_depth_m_;
  ImageView<float> cos_incidence_;
  ErrorText error_;
};

// Parses "desk", "room" or "sim:desk", optionally followed by comma-separated options:
// frames=N, seed=N, noise=on|off, ring=N (e.g. "sim:desk,frames=60,noise=off").
// Returns ok or invalid_argument (`error`, when given, says what was wrong).
Status sim_config_from_spec(const char* spec, SimConfig* config, ErrorText* error);

// A closed source for `spec` (see sim_config_from_spec), or null with `error` set.
std::unique_ptr<SimSource> make_sim_source(const char* spec, ErrorText* error);

}  // namespace octofuse::sim
