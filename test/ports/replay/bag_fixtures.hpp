#pragma once
// Frames a bag test starts from (sim or 7-Scenes), dumped for the independent MCAP writer
// (make_bag.py) and kept in memory to compare with what the bag reader gives back.

#include <sys/wait.h>

#include <catch2/catch.hpp>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "octofuse/sensor/depth_source.hpp"
#include "support/test_dir.hpp"

namespace octofuse::test {

struct KeptFrame {
  std::vector<std::uint16_t> depth;
  int width = 0;
  int height = 0;
  float metres_per_unit = 0.0f;
  std::int64_t timestamp_us = 0;
  bool has_pose = false;
  Eigen::Matrix4d T_W_C = Eigen::Matrix4d::Identity();
};

struct KeptFrames {
  PinholeCamera camera;
  std::vector<KeptFrame> frames;
};

// Up to `count` frames of an opened source.
inline KeptFrames keep_frames(DepthSource& source, int count) {
  KeptFrames kept;
  kept.camera = source.intrinsics();
  DepthFrame frame;
  while (static_cast<int>(kept.frames.size()) < count) {
    const NextFrame next = source.next(frame);
    if (next.outcome == FrameOutcome::skip) continue;
    if (next.outcome != FrameOutcome::frame) break;
    KeptFrame k;
    k.width = frame.depth_raw.width;
    k.height = frame.depth_raw.height;
    for (int y = 0; y < k.height; ++y) {
      for (int x = 0; x < k.width; ++x) k.depth.push_back(frame.depth_raw(x, y));
    }
    k.metres_per_unit = frame.metres_per_unit;
    k.timestamp_us = frame.timestamp_us;
    k.has_pose = frame.has_ground_truth;
    k.T_W_C = frame.T_W_C_ground_truth;
    kept.frames.push_back(std::move(k));
  }
  return kept;
}

// The dump make_bag.py reads (its docstring has the layout).
inline void write_frame_dump(const std::string& path, const KeptFrames& kept) {
  std::ofstream out(path, std::ios::binary);
  auto put = [&](const void* p, std::size_t n) { out.write(static_cast<const char*>(p), n); };
  out << "OFDUMP1\n";
  const std::uint32_t head[3] = {static_cast<std::uint32_t>(kept.frames.size()),
                                 static_cast<std::uint32_t>(kept.camera.width),
                                 static_cast<std::uint32_t>(kept.camera.height)};
  put(head, sizeof(head));
  const float k[4] = {kept.camera.fx, kept.camera.fy, kept.camera.cx, kept.camera.cy};
  put(k, sizeof(k));
  for (const KeptFrame& f : kept.frames) {
    put(&f.timestamp_us, 8);
    put(&f.metres_per_unit, 4);
    const std::uint8_t has = f.has_pose ? 1 : 0;
    put(&has, 1);
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) put(&f.T_W_C(r, c), 8);
    }
    put(f.depth.data(), f.depth.size() * 2);
  }
}

// Runs make_bag.py; its exit status (77: a compression module is missing).
inline int make_bag(const std::string& dump, const std::string& bag, const std::string& options) {
#if !defined(OCTOFUSE_PYTHON)
  (void)dump;
  (void)bag;
  (void)options;
  return 77;  // no interpreter found at configure time
#else
  const std::string command = std::string(OCTOFUSE_PYTHON) + " " + OCTOFUSE_MAKE_BAG + " " + dump +
                              " " + bag + " " + options;
  const int rc = std::system(command.c_str());
  return rc < 0 ? rc : WEXITSTATUS(rc);
#endif
}

// Runs make_rosbag.py (a ROS 1 bag through python3-rosbag); its exit status (77: python3-rosbag
// or the compression's module is missing).
inline int make_rosbag(const std::string& dump, const std::string& bag,
                       const std::string& options) {
#if !defined(OCTOFUSE_PYTHON) || !defined(OCTOFUSE_MAKE_ROSBAG)
  (void)dump;
  (void)bag;
  (void)options;
  return 77;
#else
  const std::string command = std::string(OCTOFUSE_PYTHON) + " " + OCTOFUSE_MAKE_ROSBAG + " " +
                              dump + " " + bag + " " + options;
  const int rc = std::system(command.c_str());
  return rc < 0 ? rc : WEXITSTATUS(rc);
#endif
}

// Several ROS 1 bags of one dump in one run of make_rosbag.py: {path, options} each.
inline int make_rosbags(const std::string& dump,
                        const std::vector<std::pair<std::string, std::string>>& bags) {
  const std::string batch = dump + ".batch";
  {
    std::ofstream out(batch);
    for (const auto& bag : bags) out << dump << " " << bag.first << " " << bag.second << "\n";
  }
  return make_rosbag("--batch", batch, "");
}

// A dump of `frames` in a test directory, and the bags the writers make of it.
struct Fixture {
  std::string dir = make_test_dir("bag");
  std::string dump = dir + "/frames.bin";
  KeptFrames kept;
  explicit Fixture(KeptFrames frames) : kept(std::move(frames)) { write_frame_dump(dump, kept); }
  // The bag's path, or empty when the writer lacks a compression module (the case skips).
  std::string bag(const std::string& name, const std::string& options) {
    const std::string path = dir + "/" + name;
    const int rc = make_bag(dump, path, options);
    if (rc == 77) {
      WARN("make_bag.py " << options << ": python module missing, case skipped");
      return std::string();
    }
    REQUIRE(rc == 0);
    return path;
  }
  // ROS 1 bags (make_rosbag.py, in one run): {name, options} each. Their paths, or none when
  // python3-rosbag or roslz4 is missing (the case skips).
  std::vector<std::string> rosbags(const std::vector<std::pair<std::string, std::string>>& bags) {
    std::vector<std::pair<std::string, std::string>> jobs;
    std::vector<std::string> paths;
    for (const auto& bag : bags) {
      paths.push_back(dir + "/" + bag.first);
      jobs.push_back({paths.back(), bag.second});
    }
    const int rc = make_rosbags(dump, jobs);
    if (rc == 77) {
      WARN("make_rosbag.py: python3-rosbag or roslz4 missing, case skipped");
      return {};
    }
    REQUIRE(rc == 0);
    return paths;
  }
  std::string rosbag(const std::string& name, const std::string& options) {
    const std::vector<std::string> paths = rosbags({{name, options}});
    return paths.empty() ? std::string() : paths[0];
  }
};

}  // namespace octofuse::test
