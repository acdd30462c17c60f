#pragma once
// Tiny datasets the replay tests write for themselves: TUM, ICL-NUIM, 7-Scenes folders and
// SLAMBench .raw files with known pixels and poses.

#include <sys/stat.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "octofuse/math/se3.hpp"
#include "octofuse/ports/host/png_writer.hpp"
#include "support/test_dir.hpp"

namespace octofuse::test {

// Depth with a per-frame pattern; `invalid` marks some pixels 65535 (7-Scenes' marker).
inline std::vector<std::uint16_t> pattern_depth(int width, int height, int frame,
                                                bool invalid = false) {
  std::vector<std::uint16_t> depth(static_cast<std::size_t>(width) * height);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      std::uint16_t v = static_cast<std::uint16_t>(1000 + 97 * frame + 13 * x + 7 * y);
      if ((x + y) % 5 == 0) v = 0;
      if (invalid && x == y) v = 65535;
      depth[static_cast<std::size_t>(y) * width + x] = v;
    }
  }
  return depth;
}

inline bool write_depth_png(const std::string& path, const std::vector<std::uint16_t>& depth,
                            int width, int height) {
  ErrorText error;
  return host::write_png_gray16(path.c_str(),
                                ImageView<const std::uint16_t>(depth.data(), width, height), &error)
      .ok();
}

inline Se3d pose_for_frame(int frame) {
  Se3d T = Se3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.1 * frame, Eigen::Vector3d(0.0, 1.0, 0.2).normalized())
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.5 * frame, -0.25, 1.0 + 0.125 * frame);
  return T;
}

inline std::string tum_pose_line(double t, const Se3d& T) {
  const Eigen::Quaterniond q(T.linear());
  char line[256];
  std::snprintf(line, sizeof(line), "%.6f %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", t,
                T.translation().x(), T.translation().y(), T.translation().z(), q.x(), q.y(), q.z(),
                q.w());
  return line;
}

inline std::string matrix_text(const Eigen::Matrix4d& T) {
  std::string text;
  char number[64];
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      std::snprintf(number, sizeof(number), "%.17g%s", T(r, c), c == 3 ? "\n" : "\t");
      text += number;
    }
  }
  return text;
}

struct TumFixture {
  std::string dir;
  int width = 8;
  int height = 6;
  int frames = 3;
  std::vector<double> timestamps;  // seconds
};

// DIR/depth.txt, DIR/depth/<t>.png (5000 units/m), DIR/groundtruth.txt at 100 Hz starting 4 ms
// after each frame's time... see the test for the association.
inline TumFixture write_tum(const std::string& parent, const char* name, int frames = 3,
                            bool with_ground_truth = true) {
  TumFixture fixture;
  fixture.dir = parent + "/" + name;
  fixture.frames = frames;
  ::mkdir(fixture.dir.c_str(), 0755);
  ::mkdir((fixture.dir + "/depth").c_str(), 0755);
  std::string list = "# depth maps\n# file: 'fixture'\n# timestamp filename\n";
  std::string gt = "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n";
  for (int i = 0; i < frames; ++i) {
    const double t = 1305031102.175304 + i / 30.0;
    fixture.timestamps.push_back(t);
    char name_buffer[64];
    std::snprintf(name_buffer, sizeof(name_buffer), "depth/%.6f.png", t);
    char line[128];
    std::snprintf(line, sizeof(line), "%.6f %s\n", t, name_buffer);
    list += line;
    write_depth_png(fixture.dir + "/" + name_buffer, pattern_depth(8, 6, i), 8, 6);
    // A decoy pose 15 ms before (farther) and the true one 3 ms after each frame.
    gt += tum_pose_line(t - 0.015, Se3d::Identity());
    gt += tum_pose_line(t + 0.003, pose_for_frame(i));
  }
  write_text(fixture.dir + "/depth.txt", list);
  if (with_ground_truth) write_text(fixture.dir + "/groundtruth.txt", gt);
  return fixture;
}

// frame-XXXXXX.depth.png (mm, with 65535 pixels), .pose.txt, camera-intrinsics.txt.
inline std::string write_seven_scenes(const std::string& parent, int frames = 3) {
  const std::string dir = parent + "/seven";
  ::mkdir(dir.c_str(), 0755);
  write_text(dir + "/camera-intrinsics.txt", "585 0 320\n0 585 240\n0 0 1\n");
  for (int i = 0; i < frames; ++i) {
    char stem[64];
    std::snprintf(stem, sizeof(stem), "/frame-%06d", i);
    write_depth_png(dir + stem + ".depth.png", pattern_depth(10, 4, i, true), 10, 4);
    write_text(dir + stem + ".pose.txt", matrix_text(pose_for_frame(i).matrix()));
  }
  return dir;
}

// SLAMBench .raw: `frames` frames of width x height, RGB of the same size.
inline std::string raw_frame_bytes(int width, int height, int frame) {
  std::string bytes;
  auto put32 = [&](std::uint32_t v) {
    for (int k = 0; k < 4; ++k) bytes += static_cast<char>((v >> (8 * k)) & 0xFF);
  };
  put32(static_cast<std::uint32_t>(width));
  put32(static_cast<std::uint32_t>(height));
  for (std::uint16_t v : pattern_depth(width, height, frame)) {
    bytes += static_cast<char>(v & 0xFF);
    bytes += static_cast<char>(v >> 8);
  }
  put32(static_cast<std::uint32_t>(width));
  put32(static_cast<std::uint32_t>(height));
  for (int i = 0; i < width * height * 3; ++i) bytes += static_cast<char>((i + frame) & 0xFF);
  return bytes;
}

}  // namespace octofuse::test
