#include "sources.hpp"

#include <cstdio>
#include <cstring>

#include "octofuse/core/error_text.hpp"

#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
#include "octofuse/ports/sim/sim_source.hpp"
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
#include "octofuse/ports/replay/bag_source.hpp"
#include "octofuse/ports/replay/replay_source.hpp"
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_OPENNI2)
#include "octofuse/ports/openni2/openni2_source.hpp"
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_V4L2)
#include "octofuse/ports/v4l2/v4l2_source.hpp"
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_LIBCAMERA)
#include "octofuse/ports/libcamera/libcamera_source.hpp"
#endif

namespace octofuse::examples {
namespace {

bool starts_with(const std::string& text, const char* prefix) {
  return text.rfind(prefix, 0) == 0;
}

}  // namespace

std::string supported_sources() {
  std::string out;
#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
  out += "                       sim:desk | sim:room (built-in scenes with ground truth)\n";
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
  out += "                       tum:DIR | 7scenes:DIR | icl:DIR | raw:FILE (recordings)\n";
  out += "                       mcap:FILE[?depth=T&info=T&pose=T&world=F&buffer=MB&reorder=MB\n";
  out += "                         &hold=N&tf_history=N] (ROS 2 bag; poses at image stamps)\n";
  out += "                       rosbag:FILE[?same options&readahead=0|1] (ROS 1 bag, format\n";
  out += "                         2.0; readahead: decompress chunks on a second thread)\n";
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_OPENNI2)
  out += "                       openni2[:URI] | oni:FILE (OpenNI2 camera or recording)\n";
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_V4L2)
  out += "                       v4l2:/dev/videoN (16-bit depth over V4L2)\n";
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_LIBCAMERA)
  out += "                       libcamera[:ID] (16-bit depth through libcamera)\n";
#endif
  return out;
}

std::unique_ptr<DepthSource> make_source(const std::string& spec, const SourceOptions& options,
                                         std::string* error) {
  ErrorText text;
#if defined(OCTOFUSE_EXAMPLES_HAVE_SIM)
  if (starts_with(spec, "sim:")) {
    sim::SimConfig config;
    if (!sim::sim_config_from_spec(spec.c_str(), &config, &text).ok()) {
      *error = text.c_str();
      return nullptr;
    }
    if (options.frames > 0) config.frame_count = static_cast<int>(options.frames);
    config.seed = options.seed;
    config.noise.enabled = config.noise.enabled && options.sim_noise;
    if (options.have_intrinsics) {
      config.camera.fx = static_cast<float>(options.intrinsics[0]);
      config.camera.fy = static_cast<float>(options.intrinsics[1]);
      config.camera.cx = static_cast<float>(options.intrinsics[2]);
      config.camera.cy = static_cast<float>(options.intrinsics[3]);
    }
    return std::make_unique<sim::SimSource>(config);
  }
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
  if (starts_with(spec, "tum:") || starts_with(spec, "7scenes:") || starts_with(spec, "icl:") ||
      starts_with(spec, "raw:")) {
    replay::ReplayConfig config;
    if (!replay::parse_replay_spec(spec.c_str(), &config, &text).ok()) {
      *error = text.c_str();
      return nullptr;
    }
    if (options.have_intrinsics) {
      config.has_intrinsics = true;
      config.intrinsics.fx = static_cast<float>(options.intrinsics[0]);
      config.intrinsics.fy = static_cast<float>(options.intrinsics[1]);
      config.intrinsics.cx = static_cast<float>(options.intrinsics[2]);
      config.intrinsics.cy = static_cast<float>(options.intrinsics[3]);
    }
    if (options.depth_scale > 0.0)
      config.depth_units_per_m = static_cast<float>(options.depth_scale);
    config.pacing =
        options.real_time ? replay::Pacing::real_time : replay::Pacing::as_fast_as_possible;
    return std::make_unique<replay::ReplaySource>(config);
  }
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
  if (starts_with(spec, "mcap:") || starts_with(spec, "rosbag:")) {
    replay::BagConfig config;
    if (!replay::parse_bag_spec(spec.c_str(), &config, &text).ok()) {
      *error = text.c_str();
      return nullptr;
    }
    if (options.have_intrinsics) {
      config.has_intrinsics = true;
      config.intrinsics.fx = static_cast<float>(options.intrinsics[0]);
      config.intrinsics.fy = static_cast<float>(options.intrinsics[1]);
      config.intrinsics.cx = static_cast<float>(options.intrinsics[2]);
      config.intrinsics.cy = static_cast<float>(options.intrinsics[3]);
    }
    if (options.depth_scale > 0.0)
      config.depth_units_per_m = static_cast<float>(options.depth_scale);
    return std::make_unique<replay::BagSource>(config);
  }
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_OPENNI2)
  if (spec == "openni2" || starts_with(spec, "openni2:") || starts_with(spec, "oni:")) {
    // The options struct borrows the URI; the source copies it in its constructor.
    const std::string uri = spec == "openni2" ? std::string() : spec.substr(spec.find(':') + 1);
    if (starts_with(spec, "oni:") && uri.empty()) {
      *error = "oni: needs a recording file";
      return nullptr;
    }
    ports::OpenNi2Options openni;
    openni.uri = uri.empty() ? nullptr : uri.c_str();
    return ports::make_openni2_source(openni);
  }
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_V4L2)
  if (starts_with(spec, "v4l2:")) {
    const std::string device = spec.substr(5);
    if (device.empty()) {
      *error = "v4l2: needs a device such as /dev/video0";
      return nullptr;
    }
    ports::V4l2Options v4l2_options;
    if (options.depth_scale > 0.0) {
      v4l2_options.metres_per_unit = static_cast<float>(1.0 / options.depth_scale);
    }
    // --intrinsics is applied by the runner once the size is negotiated.
    return ports::make_v4l2_source(device.c_str(), v4l2_options);
  }
#endif
#if defined(OCTOFUSE_EXAMPLES_HAVE_LIBCAMERA)
  if (spec == "libcamera" || starts_with(spec, "libcamera:")) {
    const std::string id = spec == "libcamera" ? std::string() : spec.substr(10);
    ports::LibcameraOptions camera;
    camera.camera_id = id.empty() ? nullptr : id.c_str();  // copied by the source
    if (options.depth_scale > 0.0) {
      camera.metres_per_unit = static_cast<float>(1.0 / options.depth_scale);
    }
    return ports::make_libcamera_source(camera);
  }
#endif
  (void)options;
  (void)text;
  *error =
      "unknown or unsupported source '" + spec + "'; this build supports:\n" + supported_sources();
  return nullptr;
}

int list_bag(const std::string& path) {
#if defined(OCTOFUSE_EXAMPLES_HAVE_REPLAY)
  replay::BagConfig config;
  if (path.empty() || path.size() >= sizeof(config.path)) {
    std::fprintf(stderr, "error: --list needs a bag file\n");
    return 2;
  }
  std::memcpy(config.path, path.c_str(), path.size() + 1);
  config.format = replay::BagFormat::automatic;  // MCAP or ROS 1, by the magic
  replay::BagSource bag(config);
  if (!bag.scan().ok()) {
    std::fprintf(stderr, "error: %s\n", bag.last_error());
    return 1;
  }
  std::printf("%-40s %-36s %8s %12s %12s\n", "topic", "type", "count", "first_s", "last_s");
  std::uint64_t first = ~std::uint64_t{0}, last = 0;
  for (int i = 0; i < bag.topic_count(); ++i) {
    const replay::BagTopic topic = bag.topic(i);
    std::printf("%-40s %-36s %8llu %12.3f %12.3f\n", topic.channel->topic,
                topic.channel->schema_name, static_cast<unsigned long long>(topic.count),
                static_cast<double>(topic.first_log_ns) * 1e-9,
                static_cast<double>(topic.last_log_ns) * 1e-9);
    if (topic.count > 0) {
      if (topic.first_log_ns < first) first = topic.first_log_ns;
      if (topic.last_log_ns > last) last = topic.last_log_ns;
    }
  }
  if (last >= first) {
    std::printf("time span %.3f s (%.3f to %.3f)\n", static_cast<double>(last - first) * 1e-9,
                static_cast<double>(first) * 1e-9, static_cast<double>(last) * 1e-9);
  }
  if (bag.scan_warning()[0] != '\0') std::fprintf(stderr, "warning: %s\n", bag.scan_warning());
  return 0;
#else
  std::fprintf(stderr, "error: this build has no bag reader (replay port)\n");
  (void)path;
  return 1;
#endif
}

}  // namespace octofuse::examples
