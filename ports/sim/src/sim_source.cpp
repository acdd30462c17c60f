#include "octofuse/ports/sim/sim_source.hpp"

#include <cerrno>
#include <cinttypes>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <new>

#include "octofuse/ports/sim/random.hpp"

namespace octofuse::sim {

PinholeCamera kinect_camera() {
  return PinholeCamera{525.0f, 525.0f, 319.5f, 239.5f, 640, 480};
}

SimSource::SimSource(const SimConfig& config) : config_(config) {}

SimSource::~SimSource() = default;

SourceCapabilities SimSource::capabilities() const {
  SourceCapabilities caps;
  caps.live = false;
  caps.has_ground_truth = true;
  caps.ring_size = config_.ring_size;
  caps.nominal_rate_hz = static_cast<float>(config_.rate_hz);
  return caps;
}

Status SimSource::validate_config() {
  const SimConfig& c = config_;
  if (!c.camera.valid()) {
    error_.set("sim: invalid camera %dx%d", c.camera.width, c.camera.height);
    return StatusCode::invalid_argument;
  }
  if (c.frame_count < 0 || c.ring_size < 1 || c.ring_size > 64) {
    error_.set("sim: frame_count %d must be >= 0 and ring_size %d in [1, 64]", c.frame_count,
               c.ring_size);
    return StatusCode::invalid_argument;
  }
  if (!std::isfinite(c.rate_hz) || !(c.rate_hz > 0.0) || !std::isfinite(c.metres_per_unit) ||
      !(c.metres_per_unit > 0.0f)) {
    error_.set("sim: rate_hz and metres_per_unit must be finite and > 0");
    return StatusCode::invalid_argument;
  }
  if (!std::isfinite(c.min_range_m) || !std::isfinite(c.max_range_m) || c.min_range_m < 0.0f ||
      !(c.min_range_m < c.max_range_m)) {
    error_.set("sim: bad sensor range [%g, %g] m", static_cast<double>(c.min_range_m),
               static_cast<double>(c.max_range_m));
    return StatusCode::invalid_argument;
  }
  const KinectNoiseModel& n = c.noise;
  if (!std::isfinite(n.lateral_sigma_px) || n.lateral_sigma_px < 0.0f ||
      n.lateral_sigma_px > 4.0f || !(n.baseline_m > 0.0) || !(n.disparity_step_px > 0.0) ||
      !(n.grazing_start_deg < n.grazing_full_deg)) {
    error_.set("sim: bad noise model");
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

template <typename Arena>
Status SimSource::reserve(Arena& arena) {
  const PinholeCamera& cam = config_.camera;
  const std::size_t pixels = static_cast<std::size_t>(cam.width) * cam.height;
  OCTOFUSE_TRY_ASSIGN(ring_,
                      arena.template allocate_array<std::uint16_t>(
                          pixels * static_cast<std::size_t>(config_.ring_size), kArenaAlignment));
  OCTOFUSE_TRY_ASSIGN(float* exact, arena.template allocate_array<float>(pixels, kArenaAlignment));
  OCTOFUSE_TRY_ASSIGN(float* cosine, arena.template allocate_array<float>(pixels, kArenaAlignment));
  exact_depth_m_ = ImageView<float>(exact, cam.width, cam.height);
  cos_incidence_ = ImageView<float>(cosine, cam.width, cam.height);
  return renderer_.reserve(arena, cam);
}

std::size_t SimSource::bytes_required(const SimConfig& config) {
  SimSource probe(config);
  if (!probe.validate_config().ok()) return 0;
  ArenaSizer sizer;
  if (!probe.reserve(sizer).ok()) return 0;
  return sizer.bytes_used();
}

Status SimSource::open() {
  close();
  OCTOFUSE_TRY(validate_config());
  if (!build_world(config_.scene, &world_).ok()) {
    error_.set("sim: scene '%s' does not fit its fixed capacity", scene_name(config_.scene));
    return StatusCode::internal;
  }
  frame_count_ = config_.frame_count > 0 ? config_.frame_count : world_.default_frame_count;

  ArenaSizer sizer;
  OCTOFUSE_TRY(reserve(sizer));
  const std::size_t bytes = sizer.bytes_used();
  memory_.reset(new (std::nothrow) unsigned char[bytes + kArenaAlignment]);
  if (!memory_) {
    error_.set("sim: cannot allocate %zu bytes", bytes);
    return StatusCode::resource_exhausted;
  }
  const std::uintptr_t base = reinterpret_cast<std::uintptr_t>(memory_.get());
  void* aligned = memory_.get() + (align_up(base, kArenaAlignment) - base);
  LinearArena arena(aligned, bytes);
  const Status reserved = reserve(arena);
  if (!reserved.ok()) {
    error_.set("sim: arena of %zu bytes too small", bytes);
    memory_.reset();
    return StatusCode::internal;
  }
  next_index_ = 0;
  open_ = true;
  error_.clear();
  return ok_status();
}

void SimSource::close() {
  open_ = false;
  ring_ = nullptr;
  exact_depth_m_ = ImageView<float>();
  cos_incidence_ = ImageView<float>();
  memory_.reset();
}

Se3d SimSource::ground_truth_T_W_C(int index) const {
  if (frame_count_ <= 1) return world_.path.T_W_C(0.0);
  const int clamped = index < 0 ? 0 : (index >= frame_count_ ? frame_count_ - 1 : index);
  return world_.path.T_W_C(static_cast<double>(clamped) / (frame_count_ - 1));
}

std::int64_t SimSource::timestamp_us(int index) const {
  return config_.start_timestamp_us + std::llround(index * 1e6 / config_.rate_hz);
}

NextFrame SimSource::next(DepthFrame& frame) {
  if (!open_) {
    error_.set("sim: next() before a successful open()");
    return NextFrame::failed(StatusCode::failed_precondition);
  }
  if (next_index_ >= frame_count_) return NextFrame::ended();
  const int index = next_index_;
  const Se3d T_W_C = ground_truth_T_W_C(index);

  RenderOptions options;
  options.max_range_m = config_.max_range_m;
  options.lateral_sigma_px = config_.noise.enabled ? config_.noise.lateral_sigma_px : 0.0f;
  options.jitter_key = hash_key(config_.seed, static_cast<std::uint64_t>(index), 0, 0);
  const Status rendered =
      renderer_.render(world_.scene, T_W_C, options, exact_depth_m_, cos_incidence_);
  if (!rendered.ok()) {
    error_.set("sim: frame %d could not be rendered (%s)", index, rendered.name());
    return NextFrame::failed(StatusCode::internal);
  }

  const PinholeCamera& cam = config_.camera;
  const std::size_t pixels = static_cast<std::size_t>(cam.width) * cam.height;
  std::uint16_t* slot = ring_ + pixels * static_cast<std::size_t>(index % config_.ring_size);
  const ImageView<std::uint16_t> raw(slot, cam.width, cam.height);
  apply_kinect_noise(config_.noise, cam.fx, exact_depth_m_, cos_incidence_, config_.metres_per_unit,
                     config_.min_range_m, config_.max_range_m, config_.seed,
                     static_cast<std::uint64_t>(index), raw);

  frame.depth_raw = raw;
  frame.metres_per_unit = config_.metres_per_unit;
  frame.timestamp_us = timestamp_us(index);
  frame.sequence = static_cast<std::uint64_t>(index);
  frame.has_ground_truth = true;
  frame.T_W_C_ground_truth = T_W_C.matrix();
  ++next_index_;
  return NextFrame::got_frame();
}

namespace {

bool parse_unsigned(const char* text, std::size_t length, std::uint64_t* value) {
  if (length == 0 || length > 19) return false;
  std::uint64_t v = 0;
  for (std::size_t i = 0; i < length; ++i) {
    if (text[i] < '0' || text[i] > '9') return false;
    v = v * 10 + static_cast<std::uint64_t>(text[i] - '0');
  }
  *value = v;
  return true;
}

bool equals(const char* text, std::size_t length, const char* word) {
  return std::strlen(word) == length && std::strncmp(text, word, length) == 0;
}

}  // namespace

Status sim_config_from_spec(const char* spec, SimConfig* config, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  if (spec == nullptr || config == nullptr) {
    err.set("sim: no source name");
    return StatusCode::invalid_argument;
  }
  const char* p = spec;
  if (std::strncmp(p, "sim:", 4) == 0) p += 4;
  const char* comma = std::strchr(p, ',');
  const std::size_t name_length =
      comma != nullptr ? static_cast<std::size_t>(comma - p) : std::strlen(p);
  SimConfig c;
  if (equals(p, name_length, "desk")) {
    c.scene = SceneId::desk;
  } else if (equals(p, name_length, "room")) {
    c.scene = SceneId::room;
  } else {
    err.set("sim: unknown scene '%.*s' (known: desk, room)", static_cast<int>(name_length), p);
    return StatusCode::invalid_argument;
  }
  while (comma != nullptr) {
    const char* option = comma + 1;
    comma = std::strchr(option, ',');
    const std::size_t length =
        comma != nullptr ? static_cast<std::size_t>(comma - option) : std::strlen(option);
    const char* eq = static_cast<const char*>(std::memchr(option, '=', length));
    if (eq == nullptr) {
      err.set("sim: option '%.*s' is not key=value", static_cast<int>(length), option);
      return StatusCode::invalid_argument;
    }
    const std::size_t key_length = static_cast<std::size_t>(eq - option);
    const char* value = eq + 1;
    const std::size_t value_length = length - key_length - 1;
    std::uint64_t number = 0;
    const bool is_number = parse_unsigned(value, value_length, &number);
    if (equals(option, key_length, "frames") && is_number && number > 0 && number <= 1000000) {
      c.frame_count = static_cast<int>(number);
    } else if (equals(option, key_length, "seed") && is_number) {
      c.seed = number;
    } else if (equals(option, key_length, "ring") && is_number && number >= 1 && number <= 64) {
      c.ring_size = static_cast<int>(number);
    } else if (equals(option, key_length, "noise") && equals(value, value_length, "on")) {
      c.noise.enabled = true;
    } else if (equals(option, key_length, "noise") && equals(value, value_length, "off")) {
      c.noise.enabled = false;
    } else {
      err.set("sim: bad option '%.*s' (frames=N, seed=N, ring=1..64, noise=on|off)",
              static_cast<int>(length), option);
      return StatusCode::invalid_argument;
    }
  }
  *config = c;
  return ok_status();
}

std::unique_ptr<SimSource> make_sim_source(const char* spec, ErrorText* error) {
  SimConfig config;
  if (!sim_config_from_spec(spec, &config, error).ok()) return nullptr;
  std::unique_ptr<SimSource> source(new (std::nothrow) SimSource(config));
  if (!source && error != nullptr) error->set("sim: out of memory");
  return source;
}

}  // namespace octofuse::sim
