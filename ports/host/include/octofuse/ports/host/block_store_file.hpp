#pragma once
// A BlockStore (octofuse/map/block_store.hpp) on a POSIX file: an append-only log of block
// records keyed by block position, the newest record of a key winning. Each entry is framed
// (magic, key, size, the block record, a CRC-32 over key, size and record), so a file cut at any
// byte (power loss, kill -9) reopens with every whole entry: open() drops a torn or damaged tail,
// truncates the file there and says so in `warning`. The index (key -> newest entry) lives in
// memory, built by reading the file at open(). Old entries of a key are reclaimed by compaction
// (compact_step(), a bounded amount of copying per call): when the file holds more than twice the
// newest records' bytes (and at least set_compact_min_bytes(), 8 MiB), their newest records are
// copied into FILE.compact, a few per call, while puts go on appending to FILE; once every newest
// record is in the copy, it is synced and renamed over FILE. A cut at any instant leaves FILE whole
// (open() removes a stale FILE.compact) or the finished copy.

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <map>
#include <memory>

#include "octofuse/core/error_text.hpp"
#include "octofuse/fusion/fusion_config.hpp"
#include "octofuse/map/block_store.hpp"
#include "octofuse/map/map_io.hpp"
#include "octofuse/query/free_space.hpp"

namespace octofuse::host {

struct BlockStoreFileStats {
  std::uint64_t entries = 0;        // whole entries in the file (every version of every key)
  std::uint64_t keys = 0;           // distinct blocks stored
  std::uint64_t file_bytes = 0;     // size of the file
  std::uint64_t bytes_written = 0;  // since open()
  std::uint64_t bytes_read = 0;     // since open()
  std::uint64_t dropped_bytes = 0;  // torn or damaged tail dropped by open()
  std::uint64_t live_bytes = 0;     // header and the newest entry of every key
  std::uint64_t compactions = 0;    // finished since open()
  std::uint64_t compact_bytes = 0;  // copied by compaction since open()
};

class BlockStoreFile final : public BlockStore {
 public:
  BlockStoreFile() = default;
  ~BlockStoreFile();
  BlockStoreFile(const BlockStoreFile&) = delete;
  BlockStoreFile& operator=(const BlockStoreFile&) = delete;

  // Opens `path`, creating it when absent. `geometry` (any bytes, e.g. voxel type, size, depth,
  // origin) is written into a new file's header and must match an existing one's
  // (invalid_argument otherwise: the store belongs to another map). ok, with `warning` set when a
  // torn tail was dropped; unavailable (cannot open, read or truncate), invalid_argument (not a
  // store, another geometry), each with a one-line `error`. With `geometry` null the store is
  // opened read only, with the geometry its header holds (geometry()): nothing is written, a torn
  // tail is ignored (and warned about), put() and compact_step() refuse.
  Status open(const char* path, const std::uint8_t* geometry, std::size_t geometry_size,
              ErrorText* error, ErrorText* warning);
  const std::uint8_t* geometry() const { return geometry_; }
  std::size_t geometry_size() const { return geometry_size_; }
  void close();
  bool is_open() const { return fd_ >= 0; }

  Status put(std::uint64_t block_morton, const std::uint8_t* record, std::size_t size) override;
  std::size_t find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi, std::uint64_t* keys,
                          std::size_t capacity) override;
  bool holds(std::uint64_t block_morton) override;
  Result<std::size_t> take(std::uint64_t block_morton, std::uint8_t* record,
                           std::size_t capacity) override;
  void release(std::uint64_t block_morton) override;

  // Makes what was appended durable (fdatasync): ok or unavailable.
  Status sync();
  // Compaction starts when the file exceeds twice the live bytes and this many bytes (default 8
  // MiB).
  void set_compact_min_bytes(std::uint64_t bytes) { compact_min_bytes_ = bytes; }
  // One step of compaction: starts one when the file is due, copies newest records into the copy
  // until about `max_bytes` were copied, and finishes it (sync, rename) when every newest record is
  // there. ok (also when nothing was due), or unavailable with a one-line `error` (the compaction
  // is abandoned and FILE stays as it was; a later step starts again).
  Status compact_step(std::size_t max_bytes, ErrorText* error);
  bool compacting() const { return compact_fd_ >= 0; }
  // Calls fn(key) for every stored key (in memory or not), increasing; read() gives the newest
  // record of one.
  template <typename Fn>
  void for_each_key(Fn&& fn) const {
    for (const auto& kv : index_) fn(kv.first);
  }
  Result<std::size_t> read(std::uint64_t block_morton, std::uint8_t* record, std::size_t capacity);
  bool in_memory(std::uint64_t block_morton) const;
  BlockStoreFileStats stats() const;

 private:
  struct Entry {
    std::uint64_t offset = 0;  // of the record (after the frame's head)
    std::uint32_t size = 0;
    bool in_memory = false;
    std::uint64_t copy_offset = 0;  // of the record in the compaction's copy; 0: not copied
  };
  void abandon_compaction();
  int fd_ = -1;
  int compact_fd_ = -1;  // the copy being written, or -1
  bool read_only_ = false;
  std::uint8_t geometry_[256 + 4] = {};  // with room for the header's CRC
  std::size_t geometry_size_ = 0;
  std::uint64_t compact_min_bytes_ = std::uint64_t{8} << 20;
  // FILE and FILE.compact (fixed buffers: the port uses no exception-throwing std::string).
  static constexpr std::size_t kMaxPath = 4096;
  char path_[kMaxPath] = {};
  char copy_path_[kMaxPath + 8] = {};
  std::uint64_t header_bytes_ = 0;
  std::uint64_t live_bytes_ = 0;   // header + the newest entry of every key
  std::uint64_t copy_bytes_ = 0;   // size of the copy so far
  std::uint64_t copy_cursor_ = 0;  // next key to look at
  std::uint64_t uncopied_ = 0;     // keys whose newest record is not in the copy yet
  std::map<std::uint64_t, Entry> index_;
  std::uint64_t file_bytes_ = 0;
  BlockStoreFileStats stats_;
  std::uint8_t* buffer_ = nullptr;  // one framed entry (malloc'd at open())
};

// Whether `path` starts as a block store does (its magic); false when it cannot be read.
bool is_block_store_file(const char* path);

// The map geometry a store is made for, as its header's geometry bytes (the voxel type, then the
// voxel size, the cube depth and the origin as little-endian floats): a store opened with another
// map's geometry is refused, and a store opened read only says what map it holds.
struct StoreGeometry {
  MapVoxelType voxel_type = MapVoxelType::multires;
  float voxel_size_m = 0.0f;
  int voxel_depth = 0;
  Eigen::Vector3f origin_W = Eigen::Vector3f::Zero();
};
constexpr std::size_t kStoreGeometryBytes = 1 + 4 * 5;
void encode_store_geometry(const StoreGeometry& geometry, std::uint8_t* out);
// false when the bytes are not a geometry a map can have (type, size, depth or origin).
bool decode_store_geometry(const std::uint8_t* bytes, std::size_t size, StoreGeometry* out);

// A map reserved on the heap, with its memory.
template <typename VoxelT>
struct HeapMap {
  std::unique_ptr<void, void (*)(void*)> memory{nullptr, std::free};
  Octree<VoxelT> map;
};

// The finest-level store beside a block store at FILE (Pipeline::set_finest_store()): FILE with
// ".fine" appended, whose geometry is the block store's with kFinestStoreGeometryTag after it.
inline constexpr std::uint8_t kFinestStoreGeometryTag = 'S';
constexpr std::size_t kFinestStoreGeometryBytes = kStoreGeometryBytes + 1;
void encode_finest_store_geometry(const StoreGeometry& geometry, std::uint8_t* out);

// A finest-level store to merge as well, and the weight cap of the run (FusionConfig::y_max),
// which catching a record's finest level up with its coarser levels uses.
struct FinestMerge {
  BlockStoreFile* store = nullptr;
  float y_max = FusionConfig{}.y_max;
};

// `map`'s blocks (none when null) and every stored block not in memory, merged into a map of
// `geometry` (map's own when given) reserved here on the heap; with `finest.store`, every merged
// block without a finest level that has a finest record gets it back at its scale, ready to
// refine as if it had kept it (restore_finest_from_record()). ok, resource_exhausted (no memory for
// the merge) or data_loss (a damaged stored record), with a one-line `error` naming `path`.
template <typename VoxelT>
Status merge_map_with_store(const Octree<VoxelT>* map, const MapConfig& geometry,
                            BlockStoreFile& store, const char* path,
                            std::unique_ptr<HeapMap<VoxelT>>* out, ErrorText* error,
                            const FinestMerge& finest = {});

// The free space's store (Pipeline::set_free_space_store()) beside a block store at FILE: FILE
// with ".free" appended, whose geometry is the block store's with kFreeStoreGeometryTag after it
// (so neither opens as the other).
inline constexpr std::uint8_t kFreeStoreGeometryTag = 'F';
constexpr std::size_t kFreeStoreGeometryBytes = kStoreGeometryBytes + 1;
void encode_free_store_geometry(const StoreGeometry& geometry, std::uint8_t* out);

// A free space reserved on the heap, with its memory.
struct HeapFreeSpace {
  std::unique_ptr<void, void (*)(void*)> memory{nullptr, std::free};
  FreeSpace space;
};

// `free_space` and every region `free_store` holds that is not in memory, merged as reloading
// merges them (the tree's own nodes winning), into a free space reserved here on the heap with
// room for all of it. ok, resource_exhausted (no memory) or data_loss (a damaged stored region),
// with a one-line `error` naming `path`.
Status merge_free_space_with_store(const FreeSpace& free_space, BlockStoreFile& free_store,
                                   const char* path, std::unique_ptr<HeapFreeSpace>* out,
                                   ErrorText* error);

// The whole map: `map`'s blocks and every stored block not in memory, merged, and the free space
// with the regions `free_store` holds (when both are given), written by save_map_file() (loadable
// as any map file). ok, merge_map_with_store()'s, merge_free_space_with_store()'s or
// save_map_file()'s codes.
template <typename VoxelT>
Status save_map_file_with_store(const char* path, const Octree<VoxelT>& map,
                                const FreeSpace* free_space, BlockStoreFile& store,
                                const MapSaveInfo& info, ErrorText* error,
                                BlockStoreFile* free_store = nullptr,
                                const FinestMerge& finest = {});

}  // namespace octofuse::host
