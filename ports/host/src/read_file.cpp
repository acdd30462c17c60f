#include "octofuse/ports/host/read_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace octofuse::host {

std::FILE* open_regular_for_reading(const char* path) {
  // Non-blocking: opening a FIFO without a writer returns at once; regular files ignore it.
  const int fd = ::open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) return nullptr;
  struct stat info;
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    const int why = S_ISDIR(info.st_mode) ? EISDIR : EINVAL;
    ::close(fd);
    errno = why;
    return nullptr;
  }
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags >= 0) (void)::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  std::FILE* file = ::fdopen(fd, "rb");
  if (file == nullptr) {
    const int why = errno;
    ::close(fd);
    errno = why;
  }
  return file;
}

const char* open_failure_text(int error_number) {
  return error_number == EINVAL ? "not a regular file" : std::strerror(error_number);
}

}  // namespace octofuse::host
