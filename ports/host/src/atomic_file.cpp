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
    error_.set("%s: already open", path_.c_str());
    return StatusCode::failed_precondition;
  }
  if (path == nullptr || path[0] == '\0') {
    error_.set("empty file name");
    return StatusCode::invalid_argument;
  }
  path_ = path;
  temporary_ = path_ + ".tmp";
  file_ = std::fopen(temporary_.c_str(), "wb");
  if (file_ == nullptr) {
    error_.set("%s: cannot create (%s)", temporary_.c_str(), std::strerror(errno));
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
    error_.set("%s: write failed (%s)", temporary_.c_str(), std::strerror(errno));
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
    error_.set("%s: not written (%s)", path_.c_str(), why);
    std::remove(temporary_.c_str());
    return StatusCode::data_loss;
  }
  if (std::rename(temporary_.c_str(), path_.c_str()) != 0) {
    error_.set("%s: cannot replace (%s)", path_.c_str(), std::strerror(errno));
    std::remove(temporary_.c_str());
    return StatusCode::data_loss;
  }
  if (!sync_parent_folder(path_.c_str()).ok()) {
    error_.set("%s: written, but its folder could not be synced", path_.c_str());
    return StatusCode::data_loss;
  }
  return ok_status();
}

void AtomicFile::abandon() {
  if (file_ == nullptr) return;
  std::fclose(file_);
  file_ = nullptr;
  std::remove(temporary_.c_str());
}

Status sync_parent_folder(const char* path) {
  std::string folder(path);
  const std::size_t slash = folder.rfind('/');
  if (slash == std::string::npos) {
    folder = ".";
  } else if (slash == 0) {
    folder = "/";
  } else {
    folder.resize(slash);
  }
  const int fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return StatusCode::unavailable;
  const bool synced = ::fsync(fd) == 0;
  ::close(fd);
  return synced ? ok_status() : Status(StatusCode::unavailable);
}

}  // namespace octofuse::host
