#include "octofuse/ports/host/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <climits>
#include <cstdlib>
#include <cstring>

#include "octofuse/core/result.hpp"

namespace octofuse::host {
namespace {

const char* file_kind(mode_t mode) {
  return S_ISDIR(mode)    ? "a folder"
         : S_ISCHR(mode)  ? "a character device"
         : S_ISBLK(mode)  ? "a block device"
         : S_ISFIFO(mode) ? "a FIFO"
         : S_ISSOCK(mode) ? "a socket"
                          : "not a regular file";
}

// Resolves `path` into `destination` (followed when it is a symbolic link) and checks that it is
// absent or a regular file, and that "<destination>.tmp" is absent or a regular file.
Status resolve_destination(const char* path, char* destination, char* temporary,
                           std::size_t capacity, ErrorText& error) {
  if (path == nullptr || path[0] == '\0') {
    error.set("empty file name");
    return StatusCode::invalid_argument;
  }
  std::size_t length = std::strlen(path);
  if (length + 5 > capacity) {
    error.set("file name of %zu bytes is too long", length);
    return StatusCode::invalid_argument;
  }
  std::memcpy(destination, path, length + 1);
  struct stat st;
  if (::lstat(path, &st) == 0) {
    if (S_ISLNK(st.st_mode)) {
      // Replace the file the link names, not the link.
      char resolved[PATH_MAX];
      if (::realpath(path, resolved) == nullptr) {
        error.set("%s: a link to nothing (%s)", path, std::strerror(errno));
        return StatusCode::invalid_argument;
      }
      length = std::strlen(resolved);
      if (length + 5 > capacity) {
        error.set("%s: the linked file's name is too long", path);
        return StatusCode::invalid_argument;
      }
      std::memcpy(destination, resolved, length + 1);
      if (::stat(destination, &st) != 0) {
        error.set("%s: cannot inspect (%s)", path, std::strerror(errno));
        return StatusCode::unavailable;
      }
    }
    if (!S_ISREG(st.st_mode)) {
      error.set("%s: is %s, not a regular file; it is not replaced", path, file_kind(st.st_mode));
      return StatusCode::invalid_argument;
    }
  } else if (errno != ENOENT) {
    error.set("%s: cannot inspect (%s)", path, std::strerror(errno));
    return StatusCode::unavailable;
  }
  std::memcpy(temporary, destination, length);
  std::memcpy(temporary + length, ".tmp", 5);
  if (::lstat(temporary, &st) == 0 && !S_ISREG(st.st_mode)) {
    error.set("%s: is %s, in the way of the temporary", temporary, file_kind(st.st_mode));
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

// Creates (or truncates) the regular file `temporary` for writing: never follows a link, never
// blocks on a FIFO that appeared since it was checked.
int create_temporary(const char* temporary, ErrorText& error) {
  const int fd =
      ::open(temporary, O_WRONLY | O_CREAT | O_TRUNC | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC, 0644);
  if (fd < 0) {
    error.set("%s: cannot create (%s)", temporary, std::strerror(errno));
    return -1;
  }
  struct stat st;
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    error.set("%s: not a regular file", temporary);
    return -1;
  }
  return fd;
}

}  // namespace

AtomicFile::~AtomicFile() {
  abandon();
}

Status AtomicFile::open(const char* path) {
  if (file_ != nullptr) {
    error_.set("%s: already open", path_);
    return StatusCode::failed_precondition;
  }
  const Status resolved = resolve_destination(path, path_, temporary_, kMaxPath, error_);
  if (!resolved.ok()) return resolved;
  const int fd = create_temporary(temporary_, error_);
  if (fd < 0) return StatusCode::unavailable;
  file_ = ::fdopen(fd, "wb");
  if (file_ == nullptr) {
    error_.set("%s: cannot open (%s)", temporary_, std::strerror(errno));
    ::close(fd);
    std::remove(temporary_);
    return StatusCode::unavailable;
  }
  finished_ = false;
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
  OCTOFUSE_TRY(finish_writing());
  return publish();
}

Status AtomicFile::finish_writing() {
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
  finished_ = true;
  return ok_status();
}

Status AtomicFile::publish() {
  if (!finished_) {
    error_.set("publish of a file not finished");
    return StatusCode::failed_precondition;
  }
  finished_ = false;
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
  if (file_ == nullptr && !finished_) return;
  if (file_ != nullptr) std::fclose(file_);
  file_ = nullptr;
  finished_ = false;
  std::remove(temporary_);
}

Status check_writable(const char* path, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  char destination[4096];
  char temporary[4096 + 4];
  OCTOFUSE_TRY(resolve_destination(path, destination, temporary, 4096, err));
  struct stat st;
  const bool existed = ::lstat(temporary, &st) == 0;
  const int fd = create_temporary(temporary, err);
  if (fd < 0) return StatusCode::unavailable;
  ::close(fd);
  if (!existed) std::remove(temporary);
  return ok_status();
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
