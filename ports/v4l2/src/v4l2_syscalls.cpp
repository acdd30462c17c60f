// The real system calls behind the V4L2 port's seam.

#include <fcntl.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include <new>

#include "octofuse/ports/v4l2/v4l2_source.hpp"

namespace octofuse::ports {
namespace {

class SystemV4l2Syscalls final : public V4l2Syscalls {
 public:
  int open(const char* path, int flags) override { return ::open(path, flags); }
  int close(int fd) override { return ::close(fd); }
  int ioctl(int fd, unsigned long request, void* arg) override { return ::ioctl(fd, request, arg); }
  void* mmap(std::size_t length, int prot, int flags, int fd, off_t offset) override {
    return ::mmap(nullptr, length, prot, flags, fd, offset);
  }
  int munmap(void* address, std::size_t length) override { return ::munmap(address, length); }
  int poll(struct pollfd* fds, nfds_t count, int timeout_ms) override {
    return ::poll(fds, count, timeout_ms);
  }
  std::int64_t monotonic_now_us() override {
    timespec now{};
    ::clock_gettime(CLOCK_MONOTONIC, &now);
    return static_cast<std::int64_t>(now.tv_sec) * 1000000 + now.tv_nsec / 1000;
  }
};

}  // namespace

V4l2Syscalls& system_v4l2_syscalls() {
  // A function-local static without a destructor to run at exit: the object holds no state.
  alignas(SystemV4l2Syscalls) static unsigned char storage[sizeof(SystemV4l2Syscalls)];
  static SystemV4l2Syscalls* instance = new (storage) SystemV4l2Syscalls();
  return *instance;
}

}  // namespace octofuse::ports
