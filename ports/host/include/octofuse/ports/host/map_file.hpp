#pragma once
// Map files on a POSIX file system: save_map()/load_map() (octofuse/map/map_io.hpp) over files.
// Saving writes a temporary, syncs it and renames it over the destination (AtomicFile), so a
// crash or power cut at any instant leaves the previous map file or the new one, whole. Errors
// come with a one-line reason in `error` that starts with the file name ("maps/a.ofmap:
// checksum mismatch in block record 12").

#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/map/map_io.hpp"
#include "octofuse/query/free_space.hpp"

namespace octofuse::host {

// ok; unavailable: the file cannot be created; data_loss: a write or the sync failed, or the
// written file, read back whole (check_map()), does not check (the destination is untouched);
// invalid_argument: the destination is not a regular file (AtomicFile), or see save_map, as
// failed_precondition. With
// `free_space` (may be null) the file holds the free space too.
template <typename VoxelT>
Status save_map_file(const char* path, const Octree<VoxelT>& map, const FreeSpace* free_space,
                     const MapSaveInfo& info, ErrorText* error);
template <typename VoxelT>
Status save_map_file(const char* path, const Octree<VoxelT>& map, const MapSaveInfo& info,
                     ErrorText* error) {
  return save_map_file(path, map, static_cast<const FreeSpace*>(nullptr), info, error);
}

// Reads the whole file and checks every record (check_map()): unavailable when it cannot be
// opened, else check_map()'s codes; the header in `header` (optional) when ok.
Status check_map_file(const char* path, MapFileHeader* header, ErrorText* error);

// The header of a map file (see read_map_header): unavailable when the file cannot be opened.
Result<MapFileHeader> read_map_file_header(const char* path, ErrorText* error);

// Loads a map file into `map` and, when `free_space` is not null, its free space (see load_map
// for the codes; unavailable when the file cannot be opened). On error both are empty.
template <typename VoxelT>
Status load_map_file(const char* path, Octree<VoxelT>& map, FreeSpace* free_space,
                     MapFileHeader* header, ErrorText* error);
template <typename VoxelT>
Status load_map_file(const char* path, Octree<VoxelT>& map, MapFileHeader* header,
                     ErrorText* error) {
  return load_map_file(path, map, static_cast<FreeSpace*>(nullptr), header, error);
}

extern template Status save_map_file(const char*, const Octree<TsdfVoxel>&, const FreeSpace*,
                                     const MapSaveInfo&, ErrorText*);
extern template Status save_map_file(const char*, const Octree<MultiresVoxel>&, const FreeSpace*,
                                     const MapSaveInfo&, ErrorText*);
extern template Status load_map_file(const char*, Octree<TsdfVoxel>&, FreeSpace*, MapFileHeader*,
                                     ErrorText*);
extern template Status load_map_file(const char*, Octree<MultiresVoxel>&, FreeSpace*,
                                     MapFileHeader*, ErrorText*);
extern template Status save_map_file(const char*, const Octree<Multires16Voxel>&, const FreeSpace*,
                                     const MapSaveInfo&, ErrorText*);
extern template Status load_map_file(const char*, Octree<Multires16Voxel>&, FreeSpace*,
                                     MapFileHeader*, ErrorText*);

}  // namespace octofuse::host
