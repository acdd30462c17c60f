#pragma once
// Turns a source spec from the command line into a DepthSource:
//   sim:desk | sim:room | tum:DIR | 7scenes:DIR | icl:DIR | raw:FILE
//   | mcap:FILE[?depth=T&info=T&pose=T&world=F] | rosbag:FILE[?...] | oni:FILE | openni2[:URI] |
//   v4l2:/dev/videoN | libcamera[:ID]
// Live and recorded-camera specs exist only when their port was built.

#include <memory>
#include <string>

#include "octofuse/sensor/depth_source.hpp"

namespace octofuse::examples {

struct SourceOptions {
  bool have_intrinsics = false;
  double intrinsics[4] = {0, 0, 0, 0};  // fx, fy, cx, cy
  double depth_scale = 0.0;             // raw units per metre; 0 = the format's default
  long frames = -1;                     // sim: frame count; -1 = the scene's default
  bool sim_noise = true;
  unsigned long long seed = 1;
  bool real_time = false;  // replay paced like a live camera (frames dropped when late)
};

// The source, or null with `error` set ("unknown source 'foo:'", "tum: needs a folder").
std::unique_ptr<DepthSource> make_source(const std::string& spec, const SourceOptions& options,
                                         std::string* error);

// octofuse-replay --list FILE: prints a bag's topics, types, counts and time span; the exit status.
int list_bag(const std::string& path);

// One line per spec form this build supports, for --help.
std::string supported_sources();

}  // namespace octofuse::examples
