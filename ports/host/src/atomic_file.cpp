#include "octofuse/ports/host/atomic_file.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace octofuse::host {

AtomicFile::~AtomicFile() {
  abandon();
}

Status AtomicFile::open(const char* path) {
  if (file_ != nullptr) {
    error_.set("%s: already open", path_);
    return StatusCode::failed_precondition;
  }
  if (path == nullptr || path[0] == '\0') {
    error_.set("empty file name");
    return StatusCode::invalid_argument;
  }
  const std::size_t length = std::strlen(path);
  if (length >= kMaxPath) {
    error_.set("file name of %zu bytes is too long", length);
    return StatusCode::invalid_argument;
  }
  std::memcpy(path_, path, length + 1);
  std::memcpy(temporary_, path, length);
  std::memcpy(temporary_ + length, ".tmp", 5);
  file_ = std::fopen(temporary_, "wb");
  if (file_ == nullptr) {
    error_.set("%s: cannot create (%s)", temporary_, std::strerror(errno));
    return StatusCode::unavailable;
  }
  return ok_status();
}

Status AtomicFile::write(const void* data, std::size_t bytes) {
  if (file_ == nullptr) {
    error_.set("write to a file that is not open");
    return StatusCode::failed_precondition;
  }
  if (bytes != 0 && std::fwrite(data, 1, bytes, file_) != bytes) {
    error_.set("%s: write failed (%s)", temporary_, std::strerror(errno));
    return StatusCode::data_loss;
  }
  return ok_status();
}

Status AtomicFile::commit() {
  if (file_ == nullptr) {
    error_.set("commit of a file that is not open");
    return StatusCode::failed_precondition;
  }
  const bool stream_failed = std::ferror(file_) != 0;
  const bool flushed = std::fflush(file_) == 0;
  const int flush_errno = errno;
  const bool synced = flushed && ::fsync(::fileno(file_)) == 0;
  const int sync_errno = errno;
  const bool closed = std::fclose(file_) == 0;
  file_ = nullptr;
  if (stream_failed || !flushed || !synced || !closed) {
    const char* why = stream_failed ? "a write failed"
                      : !flushed    ? std::strerror(flush_errno)
                      : !synced     ? std::strerror(sync_errno)
                                    : "close failed";
    error_.set("%s: not written (%s)", path_, why);
    std::remove(temporary_);
    return StatusCode::data_loss;
  }
  if (std::rename(temporary_, path_) != 0) {
    error_.set("%s: cannot replace (%s)", path_, std::strerror(errno));
    std::remove(temporary_);
    return StatusCode::data_loss;
  }
  if (!sync_parent_folder(path_).ok()) {
    error_.set("%s: written, but its folder could not be synced", path_);
    return StatusCode::data_loss;
  }
  return ok_status();
}

void AtomicFile::abandon() {
  if (file_ == nullptr) return;
  std::fclose(file_);
  file_ = nullptr;
  std::remove(temporary_);
}

Status sync_parent_folder(const char* path) {
  char folder[4096];
  const char* slash = std::strrchr(path, '/');
  if (slash == nullptr) {
    std::memcpy(folder, ".", 2);
  } else if (slash == path) {
    std::memcpy(folder, "/", 2);
  } else {
    const std::size_t length = static_cast<std::size_t>(slash - path);
    if (length >= sizeof(folder)) return StatusCode::unavailable;
    std::memcpy(folder, path, length);
    folder[length] = '\0';
  }
  const int fd = ::open(folder, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return StatusCode::unavailable;
  const bool synced = ::fsync(fd) == 0;
  ::close(fd);
  return synced ? ok_status() : Status(StatusCode::unavailable);
}

}  // namespace octofuse::host
