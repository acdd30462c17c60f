#pragma once
// Saving and loading a whole map and its free space through byte sinks and sources (no file
// access here: the host port's map_file.hpp puts them on files). The format is versioned,
// little-endian byte by byte, with a CRC-32 per record; the loader checks every field before it
// is used. lib/README.md ("Map files") gives the format record by record.

#include <cstddef>
#include <cstdint>
#include <type_traits>

#include <Eigen/Core>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/map/octree.hpp"

namespace octofuse {

class FreeOctree;  // map/free_octree.hpp

inline constexpr std::uint32_t kMapFormatVersion = 2;
// Largest weight a saved voxel or summary may hold (2^24: integers stay exact in a float).
inline constexpr float kMaxSavedWeight = 16777216.0f;
// Largest truncation distance and free-space margin a file may hold, in metres.
inline constexpr float kMaxSavedMu_m = 1e3f;
// Largest frame count a file may hold: records keep frame indices in 32 bits (136 years at 1 kHz).
inline constexpr std::uint64_t kMaxSavedFrames = 0xFFFFFFFFu;

// Where save_map() writes. write() returns ok or the sink's own error (unavailable, data_loss...),
// which save_map() passes on.
class ByteSink {
 public:
  virtual Status write(const std::uint8_t* bytes, std::size_t count) = 0;

 protected:
  ~ByteSink() = default;
};

// Where load_map() reads. read() fills up to `count` bytes and returns how many it read: fewer
// only at the end of the data; or an error (unavailable, data_loss...) passed on by load_map().
class ByteSource {
 public:
  virtual Result<std::size_t> read(std::uint8_t* bytes, std::size_t count) = 0;

 protected:
  ~ByteSource() = default;
};

// A sink over a caller's buffer (tests, boards writing to RAM before flash).
class MemorySink final : public ByteSink {
 public:
  MemorySink(std::uint8_t* buffer, std::size_t capacity) : buffer_(buffer), capacity_(capacity) {}
  // resource_exhausted when the buffer is full (nothing of this call is written then).
  Status write(const std::uint8_t* bytes, std::size_t count) override;
  std::size_t size() const { return size_; }

 private:
  std::uint8_t* buffer_;
  std::size_t capacity_;
  std::size_t size_ = 0;
};

// A source over bytes in memory.
class MemorySource final : public ByteSource {
 public:
  MemorySource(const std::uint8_t* bytes, std::size_t size) : bytes_(bytes), size_(size) {}
  Result<std::size_t> read(std::uint8_t* bytes, std::size_t count) override;

 private:
  const std::uint8_t* bytes_;
  std::size_t size_;
  std::size_t offset_ = 0;
};

// A sink that only counts: how many bytes save_map() would write.
class CountingSink final : public ByteSink {
 public:
  Status write(const std::uint8_t*, std::size_t count) override {
    size_ += count;
    return ok_status();
  }
  std::size_t size() const { return size_; }

 private:
  std::size_t size_ = 0;
};

enum class MapVoxelType : std::uint8_t { single_res = 1, multires = 2, multires16 = 3 };

template <typename VoxelT>
constexpr MapVoxelType map_voxel_type() {
  if constexpr (std::is_same_v<VoxelT, Multires16Voxel>) return MapVoxelType::multires16;
  return IsMultiresVoxel<VoxelT>::value ? MapVoxelType::multires : MapVoxelType::single_res;
}
const char* map_voxel_type_name(MapVoxelType type);

// What a map file's header says.
struct MapFileHeader {
  std::uint32_t version = kMapFormatVersion;
  MapVoxelType voxel_type = MapVoxelType::multires;
  float voxel_size_m = 0.0f;
  float mu_m = 0.0f;  // fusion's truncation distance: a pipeline continuing the map must use it
  int voxel_depth = 0;
  Eigen::Vector3f origin_W = Eigen::Vector3f::Zero();
  std::uint32_t node_count = 0;
  std::uint32_t block_count = 0;
  std::uint32_t finest_count = 0;  // multires blocks holding a finest level
  std::uint64_t frames = 0;        // frames processed when saved (the next frame's index)
  // Free space (0 nodes: saved without). Loading it needs a FreeOctree with the same settings.
  std::uint32_t free_node_count = 0;
  float free_margin_m = 0.0f;  // FreeOctree::margin_m(): the distance bound depends on it
  int free_octant_voxels = 0;  // FreeSpaceConfig::finest_octant_voxels
  int free_max_count = 0;      // FreeSpaceConfig::max_free_count
};

// CRC-32 (IEEE 802.3, reflected, as zlib's crc32()) of `count` bytes, continuing from `crc`.
std::uint32_t crc32(const std::uint8_t* bytes, std::size_t count, std::uint32_t crc = 0);

// What a map file records beside the map itself (see MapFileHeader).
struct MapSaveInfo {
  std::uint64_t frames = 0;
  float mu_m = 0.0f;
};

// Writes `map` (reserved) and, when `free_space` is not null, its free space to `sink`. ok;
// invalid_argument, before anything is written, when a header field would be out of the range
// the loader accepts (validate_map_header(): info.mu_m not in (0, kMaxSavedMu_m], info.frames
// above kMaxSavedFrames...), the free space's geometry is not the map's or a free node's frame is
// not before info.frames; failed_precondition when the map or the free space is not reserved; or
// the sink's error (what was written before it is incomplete: the host port writes a temporary
// and renames it only once check_map() has read it back whole). `error` (optional) says why.
template <typename VoxelT>
Status save_map(const Octree<VoxelT>& map, const FreeOctree* free_space, const MapSaveInfo& info,
                ByteSink& sink, ErrorText* error = nullptr);
// The map alone (a file without free space).
template <typename VoxelT>
Status save_map(const Octree<VoxelT>& map, const MapSaveInfo& info, ByteSink& sink) {
  return save_map(map, static_cast<const FreeOctree*>(nullptr), info, sink);
}

// Reads and checks the header record only. ok; invalid_argument: not a map file (magic);
// out_of_range: a newer format version; data_loss: truncated, checksum mismatch or a field out
// of range; or the source's error. `error` (optional) says what is wrong in one line.
Result<MapFileHeader> read_map_header(ByteSource& source, ErrorText* error = nullptr);

// ok, or data_loss with the field and its range in `error` (optional): every field of `header`
// in the range a map of this library can have (version, voxel type, voxel size in
// [kMinVoxelSize_m, kMaxVoxelSize_m], mu in (0, kMaxSavedMu_m], depth, origin, counts, frames at
// most kMaxSavedFrames, free-space settings as validate(FreeSpaceConfig) accepts them). The loader
// checks every file's header with it and save_map() the header it is about to write, so whatever
// saves loads.
Status validate_map_header(const MapFileHeader& header, ErrorText* error = nullptr);

// Reads a whole map from `source` and checks every record as load_map() does, without a map to
// load into: the header's fields, each record's tag, checksum and values (keys in the cube and
// aligned, block scales and flags, every voxel and summary in range, free-space records), the
// end record against the header and that nothing follows. Not checked (they need the map): that
// each node's and block's parent precedes it, duplicates, and the free-space tree's shape. ok
// (and the header in `header_out`, optional) or load_map()'s codes with a one-line reason. The
// host port runs it on every map file it writes, reading back what reached the disk, before the
// file replaces the previous one.
Status check_map(ByteSource& source, MapFileHeader* header_out = nullptr,
                 ErrorText* error = nullptr);

// The MapConfig a map file needs (geometry from the header, pools exactly as large as its
// counts, at least 1). Callers usually raise the capacities before reserving.
MapConfig map_config_for(const MapFileHeader& header);

// Replaces the contents of `map` (reserved) with the map in `source`. Returns ok, or (with a
// one-line reason in `error`): invalid_argument when the source is not a map file or holds the
// another voxel type or a different geometry (voxel size, depth, origin) than `map` was reserved
// with; out_of_range for a newer format version; resource_exhausted when the map's pools are too
// small for it; data_loss when it is truncated, corrupt (a checksum, a tag, a key, a state or a
// value out of range) or followed by extra bytes; or the source's error. On any error the map is
// left empty (cleared), never half-loaded. `header_out` (optional) gets the header on success.
// The file's free space, if any, is checked record by record and skipped.
template <typename VoxelT>
Status load_map(ByteSource& source, Octree<VoxelT>& map, MapFileHeader* header_out = nullptr,
                ErrorText* error = nullptr);
// The same, and the file's free space into `free_space` (not null, reserved over the map's
// geometry), which is cleared (nothing known free) when the file has none. Further errors:
// failed_precondition when it is not reserved; invalid_argument when its geometry is not the
// map's or the file's free space was carved with other settings (margin, octant size, count
// cap); resource_exhausted when its pool is too small; data_loss for a free-space record that
// is damaged or does not fit in the tree. On any error both are left cleared.
template <typename VoxelT>
Status load_map(ByteSource& source, Octree<VoxelT>& map, FreeOctree* free_space,
                MapFileHeader* header_out, ErrorText* error);

extern template Status save_map(const Octree<TsdfVoxel>&, const FreeOctree*, const MapSaveInfo&,
                                ByteSink&, ErrorText*);
extern template Status save_map(const Octree<MultiresVoxel>&, const FreeOctree*, const MapSaveInfo&,
                                ByteSink&, ErrorText*);
extern template Status load_map(ByteSource&, Octree<TsdfVoxel>&, MapFileHeader*, ErrorText*);
extern template Status load_map(ByteSource&, Octree<MultiresVoxel>&, MapFileHeader*, ErrorText*);
extern template Status load_map(ByteSource&, Octree<TsdfVoxel>&, FreeOctree*, MapFileHeader*,
                                ErrorText*);
extern template Status load_map(ByteSource&, Octree<MultiresVoxel>&, FreeOctree*, MapFileHeader*,
                                ErrorText*);
extern template Status save_map(const Octree<Multires16Voxel>&, const FreeOctree*,
                                const MapSaveInfo&, ByteSink&, ErrorText*);
extern template Status load_map(ByteSource&, Octree<Multires16Voxel>&, MapFileHeader*, ErrorText*);
extern template Status load_map(ByteSource&, Octree<Multires16Voxel>&, FreeOctree*, MapFileHeader*,
                                ErrorText*);

}  // namespace octofuse
