// ReplaySource::open() and next() over a whole 7-Scenes (first byte even) or ICL-NUIM (odd)
// folder built from the input: records [file][length: 2 bytes, big-endian][bytes] write the files
// of a fixed table (length 0xFFFF writes a valid 2x2 16-bit PNG instead). Files missing, empty,
// corrupt or contradicting each other: open() either succeeds or explains itself, next() never
// errors, delivered poses are rotations, and a replay always ends.
#include <sys/stat.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "octofuse/ports/replay/replay_source.hpp"
#include "octofuse/ports/replay/text_parsers.hpp"

namespace {

char g_dir[64];

constexpr int kFiles = 8;
const char* const kSevenScenes[kFiles] = {"camera-intrinsics.txt", "frame-000000.depth.png",
                                          "frame-000000.pose.txt", "frame-000001.depth.png",
                                          "frame-000001.pose.txt", "frame-000003.depth.png",
                                          "frame-000003.pose.txt", "frame-000002.pose.txt"};
const char* const kIcl[kFiles] = {
    "depth.txt", "associations.txt", "groundtruth.txt", "a.gt.freiburg", "d.png",
    "e.png",     "rgb.txt",          "b.gt.freiburg"};

const std::uint8_t kPng[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
    0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x02, 0x10, 0x00, 0x00, 0x00, 0x00, 0x07,
    0x4d, 0x8e, 0xbb, 0x00, 0x00, 0x00, 0x12, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0x60,
    0x7e, 0xc1, 0x7e, 0x81, 0x81, 0xf9, 0x25, 0xfb, 0x45, 0x00, 0x10, 0x1c, 0x03, 0x87, 0x45,
    0x4f, 0x51, 0x99, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};

void clear_files() {
  char path[128];
  for (const char* const* table : {kSevenScenes, kIcl}) {
    for (int i = 0; i < kFiles; ++i) {
      std::snprintf(path, sizeof(path), "%s/%s", g_dir, table[i]);
      ::unlink(path);
    }
  }
}

void remove_folder() {
  clear_files();
  ::rmdir(g_dir);
}

// A tmpfs folder when there is one: files per input on a disk would make I/O the bottleneck.
void make_folder() {
  const char* base = ::access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
  std::snprintf(g_dir, sizeof(g_dir), "%s/octofuse-fuzz-folder-XXXXXX", base);
  if (::mkdtemp(g_dir) == nullptr) std::abort();
  std::atexit(remove_folder);
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
  clear_files();
  const bool seven = (data[0] & 1) == 0;
  const char* const* table = seven ? kSevenScenes : kIcl;
  std::size_t at = 1;
  while (at + 3 <= size) {
    const int file = data[at] % kFiles;
    const std::size_t length = (static_cast<std::size_t>(data[at + 1]) << 8) | data[at + 2];
    at += 3;
    if (length == 0xFFFF) {
      write(table[file], kPng, sizeof(kPng));
      continue;
    }
    const std::size_t available = length < size - at ? length : size - at;
    write(table[file], data + at, available);
    at += available;
  }

  octofuse::replay::ReplayConfig config;
  config.format = seven ? octofuse::replay::DatasetFormat::seven_scenes
                        : octofuse::replay::DatasetFormat::icl_nuim;
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
    if (got.outcome == octofuse::FrameOutcome::skip && source.last_error()[0] == '\0') {
      __builtin_trap();
    }
    if (got.outcome == octofuse::FrameOutcome::frame) {
      if (frame.depth_raw.width <= 0 || frame.depth_raw.width > config.max_width ||
          frame.depth_raw.height <= 0 || frame.depth_raw.height > config.max_height) {
        __builtin_trap();
      }
      // A delivered ground-truth pose is rigid within what the parsers accept.
      if (frame.has_ground_truth &&
          !octofuse::is_rigid(frame.T_W_C_ground_truth, octofuse::replay::kPoseRigidTolerance)) {
        __builtin_trap();
      }
    }
    if (++outcomes > source.frame_count()) __builtin_trap();
  }
  return 0;
}
