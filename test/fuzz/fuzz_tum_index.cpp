// The TUM/ICL index path through ReplaySource::open(): arbitrary depth.txt (first byte even) or
// groundtruth.txt (odd) next to a valid folder, then a full replay. open() either succeeds or
// explains itself; a replay always ends.
#include <sys/stat.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "octofuse/ports/replay/replay_source.hpp"

namespace {

char g_dir[64];

void remove_folder() {
  char path[128];
  for (const char* name : {"d.png", "depth.txt", "groundtruth.txt"}) {
    std::snprintf(path, sizeof(path), "%s/%s", g_dir, name);
    ::unlink(path);
  }
  ::rmdir(g_dir);
}

// A tmpfs folder (files per input on a disk would make I/O the bottleneck) with one valid 2x2
// 16-bit PNG, depth.txt listing it twice and an empty groundtruth.txt.
void make_folder() {
  const char* base = ::access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
  std::snprintf(g_dir, sizeof(g_dir), "%s/octofuse-fuzz-tum-XXXXXX", base);
  if (::mkdtemp(g_dir) == nullptr) std::abort();
  std::atexit(remove_folder);
  char path[128];
  std::snprintf(path, sizeof(path), "%s/d.png", g_dir);
  static const std::uint8_t kPng[] = {
      0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
      0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x02, 0x10, 0x00, 0x00, 0x00, 0x00, 0x07,
      0x4d, 0x8e, 0xbb, 0x00, 0x00, 0x00, 0x12, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0x60,
      0x7e, 0xc1, 0x7e, 0x81, 0x81, 0xf9, 0x25, 0xfb, 0x45, 0x00, 0x10, 0x1c, 0x03, 0x87, 0x45,
      0x4f, 0x51, 0x99, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};
  std::FILE* file = std::fopen(path, "wb");
  if (file == nullptr) std::abort();
  std::fwrite(kPng, 1, sizeof(kPng), file);
  std::fclose(file);
}

void write(const char* name, const std::uint8_t* data, std::size_t size) {
  char path[128];
  std::snprintf(path, sizeof(path), "%s/%s", g_dir, name);
  std::FILE* file = std::fopen(path, "wb");
  if (file == nullptr) std::abort();
  if (size > 0) std::fwrite(data, 1, size, file);
  std::fclose(file);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (g_dir[0] == '\0') make_folder();
  if (size == 0) return 0;
  static const char kDepthList[] = "1.0 d.png\n1.1 d.png\n";
  const bool fuzz_list = (data[0] & 1) == 0;
  if (fuzz_list) {
    write("depth.txt", data + 1, size - 1);
    write("groundtruth.txt", nullptr, 0);
  } else {
    write("depth.txt", reinterpret_cast<const std::uint8_t*>(kDepthList), sizeof(kDepthList) - 1);
    write("groundtruth.txt", data + 1, size - 1);
  }
  octofuse::replay::ReplayConfig config;
  config.format = octofuse::replay::DatasetFormat::tum;
  std::snprintf(config.path, sizeof(config.path), "%s", g_dir);
  config.max_width = 8;
  config.max_height = 8;
  config.max_frames = 32;
  config.max_name_bytes_per_frame = 16;
  octofuse::replay::ReplaySource source(config);
  if (!source.open().ok()) {
    if (source.last_error()[0] == '\0') __builtin_trap();  // every failure explains itself
    return 0;
  }
  std::size_t outcomes = 0;
  for (;;) {
    octofuse::DepthFrame frame;
    const octofuse::NextFrame got = source.next(frame);
    if (got.outcome == octofuse::FrameOutcome::end_of_stream) break;
    if (got.outcome == octofuse::FrameOutcome::error) __builtin_trap();
    if (got.outcome == octofuse::FrameOutcome::frame && frame.has_ground_truth &&
        !octofuse::is_rigid(frame.T_W_C_ground_truth, 1e-6)) {
      __builtin_trap();  // a delivered ground-truth pose is always a rotation
    }
    if (++outcomes > source.frame_count()) __builtin_trap();
  }
  return 0;
}
