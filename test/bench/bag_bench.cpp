// What reading a bag costs: open() (the first pass over the file) and next() over every frame,
// in CPU time of the process and of the calling thread (the pipeline's, in a program: they differ
// by the ROS 1 reader's read-ahead thread) and in wall time, with the frames per second, the MB/s
// of file read and the memory the reader holds.
//
//   bench_bag mcap:FILE[?options] | rosbag:FILE[?options]   (Release build)

#include <sys/stat.h>

#include <time.h>

#include <cstdio>
#include <ctime>

#include "octofuse/ports/replay/bag_source.hpp"

namespace {

double cpu_s() {
  return static_cast<double>(std::clock()) / CLOCKS_PER_SEC;
}

double clock_s(clockid_t id) {
  timespec now{};
  ::clock_gettime(id, &now);
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: bench_bag mcap:FILE | rosbag:FILE\n");
    return 2;
  }
  octofuse::replay::BagConfig config;
  octofuse::ErrorText error;
  if (!octofuse::replay::parse_bag_spec(argv[1], &config, &error).ok()) {
    std::fprintf(stderr, "error: %s\n", error.c_str());
    return 2;
  }
  struct stat info;
  if (::stat(config.path, &info) != 0) {
    std::fprintf(stderr, "error: %s: no such file\n", config.path);
    return 1;
  }
  octofuse::replay::BagSource bag(config);
  const double t0 = cpu_s();
  if (!bag.open().ok()) {
    std::fprintf(stderr, "error: %s\n", bag.last_error());
    return 1;
  }
  const double t1 = cpu_s();
  const double thread1 = clock_s(CLOCK_THREAD_CPUTIME_ID);
  const double wall1 = clock_s(CLOCK_MONOTONIC);
  octofuse::DepthFrame frame;
  long frames = 0;
  for (;;) {
    const octofuse::NextFrame next = bag.next(frame);
    if (next.outcome == octofuse::FrameOutcome::frame) {
      ++frames;
      continue;
    }
    if (next.outcome != octofuse::FrameOutcome::skip) break;
  }
  const double t2 = cpu_s();
  const double thread_s = clock_s(CLOCK_THREAD_CPUTIME_ID) - thread1;
  const double wall_s = clock_s(CLOCK_MONOTONIC) - wall1;
  const double mb = static_cast<double>(info.st_size) / 1e6;
  const double pass_s = t2 - t1;
  const double per_frame_ms = 1e3 / static_cast<double>(frames);
  std::printf(
      "%s: %ld frames, %.1f MB; open (first pass) %.3f s; replay pass %.3f s = %.0f fps, %.0f "
      "MB/s, %.2f ms/frame; calling thread %.2f ms/frame, wall %.2f ms/frame; reader memory "
      "%.1f MB\n",
      config.path, frames, mb, t1 - t0, pass_s, frames / pass_s, mb / pass_s, pass_s * per_frame_ms,
      thread_s * per_frame_ms, wall_s * per_frame_ms,
      static_cast<double>(bag.bytes_reserved()) / 1e6);
  return 0;
}
