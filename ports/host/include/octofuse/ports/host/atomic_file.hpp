#pragma once
// A file that appears whole or not at all: written to a temporary beside the destination
// ("<path>.tmp"), then flushed, fsync'ed, renamed over the destination and the folder fsync'ed.
// A crash or kill at any instant leaves the previous file (or none) or the new one, complete;
// never a mix. Writers that speak std::FILE* write through file(); commit() publishes.
//
//   AtomicFile out;
//   OCTOFUSE_TRY(out.open("out/mesh.ply"));
//   std::fwrite(bytes, 1, n, out.file());
//   OCTOFUSE_TRY(out.commit());          // or let it go out of scope: the temporary is removed
//
// The destination must be a regular file or absent (a symbolic link is followed to one): a
// device, FIFO, socket or folder is never replaced (`--save-map /dev/full` is refused, not
// turned into a regular file). A writer that checks what it wrote calls finish_writing(), reads
// temporary_path() back, then publish().

#include <cstddef>
#include <cstdio>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse::host {

class AtomicFile {
 public:
  AtomicFile() = default;
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  // Abandons an uncommitted file: the temporary is removed, the destination untouched.
  ~AtomicFile();

  // Creates the temporary. invalid_argument: empty path or one of kMaxPath bytes or more, or the
  // destination (or the temporary's name) is taken by something that is not a regular file;
  // unavailable: it cannot be created (missing folder, no permission, a read-only or virtual
  // file system); failed_precondition: already open.
  Status open(const char* path);
  // The temporary's stream, for fprintf/fwrite; nullptr when not open.
  std::FILE* file() const { return file_; }
  // data_loss on a short write; failed_precondition when not open.
  Status write(const void* data, std::size_t bytes);
  // Flushes, syncs, closes and renames over the destination, then syncs the folder. data_loss
  // when any of that fails (the temporary is removed, the destination untouched);
  // failed_precondition when not open. A stream error seen earlier on file() fails it too.
  Status commit();
  // commit() in two steps: flush, sync and close the temporary (data_loss on failure, the
  // temporary removed), then rename it over the destination and sync the folder.
  Status finish_writing();
  Status publish();
  // The temporary's name ("<path>.tmp"; the destination's after following a link).
  const char* temporary_path() const { return temporary_; }
  // Closes and removes the temporary; the destination stays as it was.
  void abandon();

  const char* path() const { return path_; }
  const char* last_error() const { return error_.c_str(); }

 private:
  std::FILE* file_ = nullptr;
  bool finished_ = false;  // finish_writing() done, publish() not yet
  // Fixed buffers: std::string would pull exception machinery into this port.
  static constexpr std::size_t kMaxPath = 4096;
  char path_[kMaxPath] = {};
  char temporary_[kMaxPath + 4] = {};
  ErrorText error_;
};

// Whether `path` can be written as an AtomicFile, checked without touching the destination: it is
// absent or a regular file (or a link to one), its folder exists, and the temporary can be
// created there (it is created and removed). ok, or open()'s codes with a one-line reason in
// `error`. Programs check every output this way before their first frame.
Status check_writable(const char* path, ErrorText* error);

// fsyncs the folder holding `path`, so a rename or a new file in it survives a power cut.
// unavailable when the folder cannot be opened or synced.
Status sync_parent_folder(const char* path);

}  // namespace octofuse::host
