// The host file readers: mesh.ply (first byte even) and TUM trajectory files (odd), from a file
// holding the rest of the input. A read either succeeds with a consistent result (indices in
// range, unit quaternions, increasing timestamps) or fails with a message; nothing else.
#include <unistd.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "octofuse/ports/host/ply.hpp"
#include "octofuse/ports/host/trajectory_io.hpp"

namespace {

char g_path[80];

void remove_file() {
  ::unlink(g_path);
}

void make_path() {
  const char* base = ::access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
  std::snprintf(g_path, sizeof(g_path), "%s/octofuse-fuzz-reader-XXXXXX", base);
  const int fd = ::mkstemp(g_path);
  if (fd < 0) std::abort();
  ::close(fd);
  std::atexit(remove_file);
}

struct TrajectoryCheck {
  double last_s = -1.0;
  std::size_t poses = 0;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (g_path[0] == '\0') make_path();
  if (size == 0 || size > (1u << 20)) return 0;
  std::FILE* file = std::fopen(g_path, "wb");
  if (file == nullptr) std::abort();
  if (size > 1) std::fwrite(data + 1, 1, size - 1, file);
  std::fclose(file);

  octofuse::ErrorText error;
  if ((data[0] & 1) == 0) {
    octofuse::host::Mesh mesh;
    const octofuse::Status status = octofuse::host::read_ply(g_path, &mesh, &error);
    if (!status.ok()) {
      if (error.c_str()[0] == '\0') __builtin_trap();
      if (!mesh.vertices.empty() || !mesh.indices.empty()) __builtin_trap();
      return 0;
    }
    if (mesh.indices.size() % 3 != 0) __builtin_trap();
    for (std::uint32_t index : mesh.indices) {
      if (index >= mesh.vertices.size()) __builtin_trap();
    }
    if (!mesh.vertex_scale.empty() && mesh.vertex_scale.size() != mesh.vertices.size()) {
      __builtin_trap();
    }
    return 0;
  }
  TrajectoryCheck check;
  const octofuse::Status status = octofuse::host::for_each_tum_pose(
      g_path,
      [](const octofuse::host::TimedPose& pose, void* context) {
        TrajectoryCheck& c = *static_cast<TrajectoryCheck*>(context);
        if (!std::isfinite(pose.timestamp_s) || !pose.T_W_C.matrix().allFinite()) {
          __builtin_trap();
        }
        if (c.poses > 0 && !(pose.timestamp_s >= c.last_s)) __builtin_trap();
        if (!octofuse::is_rigid(pose.T_W_C.matrix(), 1e-6)) __builtin_trap();
        c.last_s = pose.timestamp_s;
        ++c.poses;
      },
      &check, &error);
  if (!status.ok() && error.c_str()[0] == '\0') __builtin_trap();
  return 0;
}
