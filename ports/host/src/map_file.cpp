#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/read_file.hpp"

#include <cerrno>
#include <cstdio>
#include <cstring>

#include "octofuse/ports/host/atomic_file.hpp"
#include "octofuse/query/free_space.hpp"

namespace octofuse::host {
namespace {

class FileSink final : public ByteSink {
 public:
  explicit FileSink(AtomicFile& file) : file_(file) {}
  Status write(const std::uint8_t* bytes, std::size_t count) override {
    return file_.write(bytes, count);
  }

 private:
  AtomicFile& file_;
};

class FileSource final : public ByteSource {
 public:
  explicit FileSource(std::FILE* file) : file_(file) {}
  Result<std::size_t> read(std::uint8_t* bytes, std::size_t count) override {
    const std::size_t n = std::fread(bytes, 1, count, file_);
    if (n < count && std::ferror(file_) != 0) return StatusCode::unavailable;
    return n;
  }

 private:
  std::FILE* file_;
};

// Closes on every path out.
struct OpenFile {
  std::FILE* file = nullptr;
  explicit OpenFile(const char* path) : file(open_regular_for_reading(path)) {}
  ~OpenFile() {
    if (file != nullptr) std::fclose(file);
  }
  OpenFile(const OpenFile&) = delete;
  OpenFile& operator=(const OpenFile&) = delete;
};

Status cannot_open(const char* path, ErrorText* error) {
  if (error != nullptr) error->set("%s: cannot open (%s)", path, open_failure_text(errno));
  return StatusCode::unavailable;
}

// "path: reason" from the loader's reason.
void prefix_path(const char* path, const ErrorText& reason, ErrorText* error) {
  if (error != nullptr) error->set("%s: %s", path, reason.c_str());
}

}  // namespace

template <typename VoxelT>
Status save_map_file(const char* path, const Octree<VoxelT>& map, const FreeSpace* free_space,
                     const MapSaveInfo& info, ErrorText* error) {
  AtomicFile file;
  const Status opened = file.open(path);
  if (!opened.ok()) {
    if (error != nullptr) error->set("%s", file.last_error());
    return opened;
  }
  FileSink sink(file);
  ErrorText reason;
  const Status saved = save_map(map, free_space, info, sink, &reason);
  if (!saved.ok()) {
    if (error != nullptr) {
      if (file.last_error()[0] != '\0') {
        error->set("%s", file.last_error());
      } else {
        error->set("%s: %s", path, reason.c_str());
      }
    }
    return saved;  // the temporary goes with `file`
  }
  const Status finished = file.finish_writing();
  if (!finished.ok()) {
    if (error != nullptr) error->set("%s", file.last_error());
    return finished;
  }
  // Read back what reached the disk, every record, before it replaces the previous file: a map
  // this reports saved loads.
  const Status checked = check_map_file(file.temporary_path(), nullptr, &reason);
  if (!checked.ok()) {
    if (error != nullptr) {
      error->set("%s: not saved, the written file does not read back (%s)", path, reason.c_str());
    }
    file.abandon();
    return checked.code() == StatusCode::unavailable ? checked : Status(StatusCode::data_loss);
  }
  const Status published = file.publish();
  if (!published.ok() && error != nullptr) error->set("%s", file.last_error());
  return published;
}

Status check_map_file(const char* path, MapFileHeader* header, ErrorText* error) {
  OpenFile in(path);
  if (in.file == nullptr) return cannot_open(path, error);
  FileSource source(in.file);
  ErrorText reason;
  const Status checked = check_map(source, header, &reason);
  if (!checked.ok()) prefix_path(path, reason, error);
  return checked;
}

Result<MapFileHeader> read_map_file_header(const char* path, ErrorText* error) {
  OpenFile in(path);
  if (in.file == nullptr) return cannot_open(path, error);
  FileSource source(in.file);
  ErrorText reason;
  Result<MapFileHeader> header = read_map_header(source, &reason);
  if (!header.ok()) prefix_path(path, reason, error);
  return header;
}

template <typename VoxelT>
Status load_map_file(const char* path, Octree<VoxelT>& map, FreeSpace* free_space,
                     MapFileHeader* header, ErrorText* error) {
  OpenFile in(path);
  if (in.file == nullptr) {
    if (map.reserved()) map.clear();
    if (free_space != nullptr && free_space->reserved()) free_space->clear();
    return cannot_open(path, error);
  }
  FileSource source(in.file);
  ErrorText reason;
  const Status loaded = load_map(source, map, free_space, header, &reason);
  if (!loaded.ok()) prefix_path(path, reason, error);
  return loaded;
}

template Status save_map_file(const char*, const Octree<TsdfVoxel>&, const FreeSpace*,
                              const MapSaveInfo&, ErrorText*);
template Status save_map_file(const char*, const Octree<MultiresVoxel>&, const FreeSpace*,
                              const MapSaveInfo&, ErrorText*);
template Status load_map_file(const char*, Octree<TsdfVoxel>&, FreeSpace*, MapFileHeader*,
                              ErrorText*);
template Status load_map_file(const char*, Octree<MultiresVoxel>&, FreeSpace*, MapFileHeader*,
                              ErrorText*);
template Status save_map_file(const char*, const Octree<Multires16Voxel>&, const FreeSpace*,
                              const MapSaveInfo&, ErrorText*);
template Status load_map_file(const char*, Octree<Multires16Voxel>&, FreeSpace*, MapFileHeader*,
                              ErrorText*);

}  // namespace octofuse::host
