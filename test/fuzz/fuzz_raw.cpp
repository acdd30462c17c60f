// The SLAMBench .raw reader: arbitrary bytes as a .raw file, replayed to the end through
// ReplaySource. Every frame is delivered or skipped with a message, and the replay ends.
#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "octofuse/ports/replay/replay_source.hpp"

namespace {

// The input lives in an in-memory file (writing a real file per input would make the disk, not
// the parser, the bottleneck); the source opens it by its /proc path like any other file.
int g_memory_fd = -1;

const char* write_input(const std::uint8_t* data, std::size_t size) {
  static char path[64] = {};
  if (g_memory_fd < 0) {
    g_memory_fd = ::memfd_create("octofuse-fuzz.raw", 0);
    if (g_memory_fd < 0) std::abort();
    std::snprintf(path, sizeof(path), "/proc/self/fd/%d", g_memory_fd);
  }
  if (::ftruncate(g_memory_fd, 0) != 0) std::abort();
  if (size > 0 && ::pwrite(g_memory_fd, data, size, 0) != static_cast<ssize_t>(size)) std::abort();
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const char* path = write_input(data, size);

  octofuse::replay::ReplayConfig config;
  config.format = octofuse::replay::DatasetFormat::slambench_raw;
  std::snprintf(config.path, sizeof(config.path), "%s", path);
  config.has_intrinsics = true;
  config.intrinsics = octofuse::PinholeCamera{100.0f, 100.0f, 8.0f, 8.0f, 0, 0};
  config.max_width = 64;
  config.max_height = 64;
  config.max_frames = 64;
  octofuse::replay::ReplaySource source(config);
  if (!source.open().ok()) return 0;
  std::size_t outcomes = 0;
  for (;;) {
    octofuse::DepthFrame frame;
    const octofuse::NextFrame got = source.next(frame);
    if (got.outcome == octofuse::FrameOutcome::end_of_stream) break;
    if (got.outcome == octofuse::FrameOutcome::error) __builtin_trap();  // never for a file
    if (got.outcome == octofuse::FrameOutcome::frame &&
        (frame.depth_raw.width > 64 || frame.depth_raw.height > 64)) {
      __builtin_trap();
    }
    if (++outcomes > source.frame_count()) __builtin_trap();  // must end
  }
  return 0;
}
