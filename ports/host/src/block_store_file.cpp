#include "octofuse/ports/host/block_store_file.hpp"

#include <fcntl.h>
#include <libgen.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include "octofuse/core/arena.hpp"
#include "octofuse/map/keys.hpp"
#include "octofuse/map/map_io.hpp"
#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/read_file.hpp"

#include <cstdlib>
#include <memory>

namespace octofuse::host {
namespace {

constexpr std::uint8_t kFileMagic[8] = {'O', 'C', 'T', 'O', 'S', 'T', 'O', 'R'};
constexpr std::uint32_t kFileVersion = 1;
constexpr std::uint32_t kEntryMagic = 0x4B4C4246u;  // "FBLK"
constexpr std::size_t kEntryHead = 4 + 8 + 4;       // magic, key, size
constexpr std::size_t kMaxGeometry = 256;
constexpr std::uint32_t kMaxRecord = 1u << 20;

void put_u32(std::uint8_t* p, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
void put_u64(std::uint8_t* p, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
std::uint32_t get_u32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}
std::uint64_t get_u64(const std::uint8_t* p) {
  return static_cast<std::uint64_t>(get_u32(p)) |
         (static_cast<std::uint64_t>(get_u32(p + 4)) << 32);
}

bool read_at(int fd, std::uint8_t* p, std::size_t n, std::uint64_t offset) {
  while (n > 0) {
    const ssize_t got = ::pread(fd, p, n, static_cast<off_t>(offset));
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) return false;
    p += got;
    n -= static_cast<std::size_t>(got);
    offset += static_cast<std::uint64_t>(got);
  }
  return true;
}
bool write_at(int fd, const std::uint8_t* p, std::size_t n, std::uint64_t offset) {
  while (n > 0) {
    const ssize_t put = ::pwrite(fd, p, n, static_cast<off_t>(offset));
    if (put < 0 && errno == EINTR) continue;
    if (put <= 0) return false;
    p += put;
    n -= static_cast<std::size_t>(put);
    offset += static_cast<std::uint64_t>(put);
  }
  return true;
}

}  // namespace

BlockStoreFile::~BlockStoreFile() {
  close();
}

void BlockStoreFile::close() {
  abandon_compaction();
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  index_.clear();
  std::free(buffer_);
  buffer_ = nullptr;
}

Status BlockStoreFile::open(const char* path, const std::uint8_t* geometry,
                            std::size_t geometry_size, ErrorText* error, ErrorText* warning) {
  close();
  stats_ = BlockStoreFileStats();
  live_bytes_ = 0;
  if (std::strlen(path) >= kMaxPath) {
    if (error != nullptr) error->set("block store path longer than %zu bytes", kMaxPath - 1);
    return StatusCode::invalid_argument;
  }
  std::snprintf(path_, sizeof(path_), "%s", path);
  std::snprintf(copy_path_, sizeof(copy_path_), "%s.compact", path);
  if (warning != nullptr) warning->clear();
  auto fail = [&](StatusCode code, const char* why) {
    if (error != nullptr) error->set("%s: %s", path, why);
    close();
    return Status(code);
  };
  const bool read_only = geometry == nullptr;
  read_only_ = read_only;
  if (geometry_size > kMaxGeometry) return fail(StatusCode::invalid_argument, "geometry too long");
  buffer_ = static_cast<std::uint8_t*>(std::malloc(kEntryHead + kMaxRecord + 4));
  if (buffer_ == nullptr) return fail(StatusCode::resource_exhausted, "no memory");
  // A compaction's copy left by a cut: FILE itself is whole.
  if (!read_only) (void)::unlink(copy_path_);
  fd_ = read_only ? ::open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK)
                  : ::open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) return fail(StatusCode::unavailable, std::strerror(errno));
  struct stat st;
  if (::fstat(fd_, &st) != 0 || !S_ISREG(st.st_mode)) {
    return fail(StatusCode::unavailable, "not a regular file");
  }
  const std::uint64_t size = static_cast<std::uint64_t>(st.st_size);
  if (read_only) {
    // The geometry is the file's own: read and check its header.
    std::uint8_t head[16];
    if (size < 20 || !read_at(fd_, head, 16, 0) ||
        std::memcmp(head, kFileMagic, sizeof(kFileMagic)) != 0) {
      return fail(StatusCode::invalid_argument, "not a block store");
    }
    if (get_u32(head + 8) != kFileVersion) {
      return fail(StatusCode::invalid_argument, "a block store of another version");
    }
    geometry_size = get_u32(head + 12);
    if (geometry_size > kMaxGeometry || size < 16 + geometry_size + 4 ||
        !read_at(fd_, geometry_, geometry_size + 4, 16) ||
        get_u32(geometry_ + geometry_size) != crc32(geometry_, geometry_size, crc32(head, 16))) {
      return fail(StatusCode::data_loss, "block store header damaged");
    }
    geometry = geometry_;
  } else if (geometry_size > 0) {
    std::memcpy(geometry_, geometry, geometry_size);
  }
  geometry_size_ = geometry_size;
  const std::size_t header_bytes = sizeof(kFileMagic) + 4 + 4 + geometry_size + 4;
  header_bytes_ = header_bytes;
  live_bytes_ = header_bytes;
  std::uint8_t header[16 + kMaxGeometry + 4];
  std::memcpy(header, kFileMagic, sizeof(kFileMagic));
  put_u32(header + 8, kFileVersion);
  put_u32(header + 12, static_cast<std::uint32_t>(geometry_size));
  if (geometry_size > 0) std::memcpy(header + 16, geometry, geometry_size);
  put_u32(header + 16 + geometry_size, crc32(header, 16 + geometry_size));
  if (size < header_bytes) {
    // New, or cut before its header was whole: nothing in it can be a record. Anything else this
    // short is not a store, and is not ours to overwrite.
    if (read_only) return fail(StatusCode::invalid_argument, "not a block store");
    std::uint8_t start[sizeof(header)];
    if (size > 0 && (!read_at(fd_, start, size, 0) || std::memcmp(start, header, size) != 0)) {
      return fail(StatusCode::invalid_argument, "not a block store (refusing to overwrite it)");
    }
    if (size > 0 && warning != nullptr) {
      warning->set("%s: header torn (%llu bytes); the store starts empty", path,
                   static_cast<unsigned long long>(size));
    }
    if (::ftruncate(fd_, 0) != 0 || !write_at(fd_, header, header_bytes, 0) ||
        ::fdatasync(fd_) != 0) {
      return fail(StatusCode::unavailable, "cannot write the header");
    }
    file_bytes_ = header_bytes;
    stats_.file_bytes = file_bytes_;
    return ok_status();
  }
  std::uint8_t found[sizeof(header)];
  if (!read_at(fd_, found, header_bytes, 0)) return fail(StatusCode::unavailable, "read failed");
  if (std::memcmp(found, kFileMagic, sizeof(kFileMagic)) != 0) {
    return fail(StatusCode::invalid_argument, "not a block store");
  }
  if (std::memcmp(found, header, header_bytes) != 0) {
    return fail(StatusCode::invalid_argument,
                "another version or map geometry (voxel type, size, depth or origin)");
  }
  // Index every whole entry; stop at the first torn or damaged one.
  std::uint64_t offset = header_bytes;
  std::uint8_t* record = buffer_;
  while (offset + kEntryHead + 4 <= size) {
    std::uint8_t head[kEntryHead];
    if (!read_at(fd_, head, kEntryHead, offset)) break;
    const std::uint32_t length = get_u32(head + 12);
    if (get_u32(head) != kEntryMagic || length == 0 || length > kMaxRecord ||
        offset + kEntryHead + length + 4 > size) {
      break;
    }
    if (!read_at(fd_, record, length + 4, offset + kEntryHead)) break;
    const std::uint32_t crc = crc32(record, length, crc32(head + 4, 12));
    if (crc != get_u32(record + length)) break;
    Entry& e = index_[get_u64(head + 4)];
    if (e.size > 0) live_bytes_ -= kEntryHead + e.size + 4;
    live_bytes_ += kEntryHead + length + 4;
    e.offset = offset + kEntryHead;
    e.size = length;
    ++stats_.entries;
    offset += kEntryHead + length + 4;
  }
  if (offset < size && read_only) {
    stats_.dropped_bytes = size - offset;
    if (warning != nullptr) {
      warning->set("%s: %llu bytes of a torn or damaged tail after %llu whole records (ignored)",
                   path, static_cast<unsigned long long>(size - offset),
                   static_cast<unsigned long long>(stats_.entries));
    }
  } else if (offset < size) {
    stats_.dropped_bytes = size - offset;
    if (::ftruncate(fd_, static_cast<off_t>(offset)) != 0 || ::fdatasync(fd_) != 0) {
      return fail(StatusCode::unavailable, "cannot drop the torn tail");
    }
    if (warning != nullptr) {
      warning->set("%s: dropped %llu bytes of a torn or damaged tail after %llu whole records",
                   path, static_cast<unsigned long long>(size - offset),
                   static_cast<unsigned long long>(stats_.entries));
    }
  }
  file_bytes_ = offset;
  stats_.file_bytes = file_bytes_;
  return ok_status();
}

Status BlockStoreFile::put(std::uint64_t block_morton, const std::uint8_t* record,
                           std::size_t size) {
  if (fd_ < 0 || read_only_) return StatusCode::failed_precondition;
  if (size == 0 || size > kMaxRecord) return StatusCode::invalid_argument;
  std::uint8_t head[kEntryHead];
  put_u32(head, kEntryMagic);
  put_u64(head + 4, block_morton);
  put_u32(head + 12, static_cast<std::uint32_t>(size));
  std::uint8_t tail[4];
  put_u32(tail, crc32(record, size, crc32(head + 4, 12)));
  // Head, record and CRC in one write where possible; a cut anywhere leaves a torn tail that
  // open() drops.
  const std::size_t entry_bytes = kEntryHead + size + 4;
  std::memcpy(buffer_, head, kEntryHead);
  std::memcpy(buffer_ + kEntryHead, record, size);
  std::memcpy(buffer_ + kEntryHead + size, tail, 4);
  if (!write_at(fd_, buffer_, entry_bytes, file_bytes_)) {
    // Whatever part reached the file is a torn tail: cut it so later entries stay readable (if
    // that fails too, the next open() drops it).
    (void)::ftruncate(fd_, static_cast<off_t>(file_bytes_));
    return StatusCode::unavailable;
  }
  Entry& e = index_[block_morton];
  if (e.size > 0) live_bytes_ -= kEntryHead + e.size + 4;
  live_bytes_ += entry_bytes;
  if (compact_fd_ >= 0 && (e.size == 0 || e.copy_offset != 0)) {
    // New, or copied already: its newest record is not in the copy.
    e.copy_offset = 0;
    ++uncopied_;
  }
  e.offset = file_bytes_ + kEntryHead;
  e.size = static_cast<std::uint32_t>(size);
  e.in_memory = false;
  file_bytes_ += entry_bytes;
  ++stats_.entries;
  stats_.bytes_written += entry_bytes;
  stats_.file_bytes = file_bytes_;
  return ok_status();
}

std::size_t BlockStoreFile::find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                                        std::uint64_t* keys, std::size_t capacity) {
  std::size_t n = 0;
  for (const auto& [key, entry] : index_) {
    if (n == capacity) break;
    if (entry.in_memory) continue;
    const Eigen::Vector3i c = morton_decode(key);
    if ((c.array() < lo.array()).any() || (c.array() > hi.array()).any()) continue;
    keys[n++] = key;
  }
  return n;
}

bool BlockStoreFile::holds(std::uint64_t block_morton) {
  const auto it = index_.find(block_morton);
  return it != index_.end() && !it->second.in_memory;
}

Result<std::size_t> BlockStoreFile::read(std::uint64_t block_morton, std::uint8_t* record,
                                         std::size_t capacity) {
  const auto it = index_.find(block_morton);
  if (fd_ < 0 || it == index_.end()) return StatusCode::out_of_range;
  if (it->second.size > capacity) return StatusCode::resource_exhausted;
  if (!read_at(fd_, record, it->second.size, it->second.offset)) return StatusCode::unavailable;
  stats_.bytes_read += it->second.size;
  return static_cast<std::size_t>(it->second.size);
}

Result<std::size_t> BlockStoreFile::take(std::uint64_t block_morton, std::uint8_t* record,
                                         std::size_t capacity) {
  const Result<std::size_t> size = read(block_morton, record, capacity);
  if (size.ok()) index_[block_morton].in_memory = true;
  return size;
}

void BlockStoreFile::release(std::uint64_t block_morton) {
  const auto it = index_.find(block_morton);
  if (it != index_.end()) it->second.in_memory = false;
}

Status BlockStoreFile::sync() {
  if (fd_ < 0) return StatusCode::failed_precondition;
  return ::fdatasync(fd_) == 0 ? ok_status() : Status(StatusCode::unavailable);
}

bool BlockStoreFile::in_memory(std::uint64_t block_morton) const {
  const auto it = index_.find(block_morton);
  return it != index_.end() && it->second.in_memory;
}

BlockStoreFileStats BlockStoreFile::stats() const {
  BlockStoreFileStats s = stats_;
  s.keys = index_.size();
  s.live_bytes = live_bytes_;
  return s;
}

void BlockStoreFile::abandon_compaction() {
  if (compact_fd_ < 0) return;
  ::close(compact_fd_);
  compact_fd_ = -1;
  (void)::unlink(copy_path_);
  for (auto& kv : index_) kv.second.copy_offset = 0;
}

Status BlockStoreFile::compact_step(std::size_t max_bytes, ErrorText* error) {
  if (fd_ < 0 || read_only_) return StatusCode::failed_precondition;
  const char* copy_path = copy_path_;
  auto fail = [&](const char* why) {
    if (error != nullptr) error->set("%s: compaction abandoned: %s", copy_path, why);
    abandon_compaction();
    return Status(StatusCode::unavailable);
  };
  if (compact_fd_ < 0) {
    if (file_bytes_ < compact_min_bytes_ || file_bytes_ <= 2 * live_bytes_) return ok_status();
    compact_fd_ = ::open(copy_path, O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (compact_fd_ < 0) {
      if (error != nullptr) {
        error->set("%s: cannot start a compaction: %s", copy_path, std::strerror(errno));
      }
      return StatusCode::unavailable;
    }
    std::uint8_t header[16 + kMaxGeometry + 4];
    if (!read_at(fd_, header, header_bytes_, 0) ||
        !write_at(compact_fd_, header, header_bytes_, 0)) {
      return fail("cannot copy the header");
    }
    copy_bytes_ = header_bytes_;
    copy_cursor_ = 0;
    uncopied_ = index_.size();
  }
  std::size_t copied = 0;
  bool restarted = false;
  while (copied < max_bytes && uncopied_ > 0) {
    auto it = index_.lower_bound(copy_cursor_);
    while (it != index_.end() && it->second.copy_offset != 0) ++it;
    if (it == index_.end()) {
      if (restarted) {
        uncopied_ = 0;  // a whole turn found nothing left to copy
        break;
      }
      copy_cursor_ = 0;  // keys put again behind the cursor since it passed them
      restarted = true;
      continue;
    }
    restarted = false;
    Entry& e = it->second;
    const std::size_t entry_bytes = kEntryHead + e.size + 4;
    if (!read_at(fd_, buffer_, entry_bytes, e.offset - kEntryHead)) return fail("read failed");
    if (get_u32(buffer_ + kEntryHead + e.size) !=
        crc32(buffer_ + kEntryHead, e.size, crc32(buffer_ + 4, 12))) {
      return fail("a record is damaged on the medium");
    }
    if (!write_at(compact_fd_, buffer_, entry_bytes, copy_bytes_)) return fail("write failed");
    e.copy_offset = copy_bytes_ + kEntryHead;
    copy_bytes_ += entry_bytes;
    copied += entry_bytes;
    stats_.compact_bytes += entry_bytes;
    --uncopied_;
    copy_cursor_ = it->first + 1;
    if (copy_cursor_ == 0) copy_cursor_ = it->first;  // the largest key: wrap on the next turn
  }
  if (uncopied_ > 0) return ok_status();
  // Every newest record is in the copy: make it durable, then put it in FILE's place.
  if (::fdatasync(compact_fd_) != 0) return fail("sync failed");
  if (::rename(copy_path, path_) != 0) return fail(std::strerror(errno));
  char folder[kMaxPath];
  std::snprintf(folder, sizeof(folder), "%s", path_);
  const int dir_fd = ::open(::dirname(folder), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd >= 0) {
    (void)::fsync(dir_fd);  // the rename itself survives a power cut
    ::close(dir_fd);
  }
  ::close(fd_);
  fd_ = compact_fd_;
  compact_fd_ = -1;
  for (auto& kv : index_) {
    kv.second.offset = kv.second.copy_offset;
    kv.second.copy_offset = 0;
  }
  file_bytes_ = copy_bytes_;
  stats_.file_bytes = file_bytes_;
  stats_.entries = index_.size();
  ++stats_.compactions;
  return ok_status();
}

bool is_block_store_file(const char* path) {
  std::FILE* file = open_regular_for_reading(path);
  if (file == nullptr) return false;
  std::uint8_t magic[sizeof(kFileMagic)];
  const bool read = std::fread(magic, 1, sizeof(magic), file) == sizeof(magic);
  std::fclose(file);
  return read && std::memcmp(magic, kFileMagic, sizeof(kFileMagic)) == 0;
}

void encode_store_geometry(const StoreGeometry& geometry, std::uint8_t* out) {
  out[0] = static_cast<std::uint8_t>(geometry.voxel_type);
  const float fields[5] = {geometry.voxel_size_m, static_cast<float>(geometry.voxel_depth),
                           geometry.origin_W.x(), geometry.origin_W.y(), geometry.origin_W.z()};
  for (int i = 0; i < 5; ++i) {
    std::uint32_t bits;
    std::memcpy(&bits, &fields[i], 4);
    put_u32(out + 1 + 4 * i, bits);
  }
}

bool decode_store_geometry(const std::uint8_t* bytes, std::size_t size, StoreGeometry* out) {
  if (size != kStoreGeometryBytes) return false;
  float fields[5];
  for (int i = 0; i < 5; ++i) {
    const std::uint32_t bits = get_u32(bytes + 1 + 4 * i);
    std::memcpy(&fields[i], &bits, 4);
  }
  StoreGeometry g;
  if (bytes[0] < static_cast<std::uint8_t>(MapVoxelType::single_res) ||
      bytes[0] > static_cast<std::uint8_t>(MapVoxelType::multires16)) {
    return false;
  }
  g.voxel_type = static_cast<MapVoxelType>(bytes[0]);
  g.voxel_size_m = fields[0];
  if (!(fields[1] >= 0.0f && fields[1] <= 64.0f) ||
      fields[1] != static_cast<float>(static_cast<int>(fields[1]))) {
    return false;
  }
  g.voxel_depth = static_cast<int>(fields[1]);
  g.origin_W = Eigen::Vector3f(fields[2], fields[3], fields[4]);
  MapConfig config;
  config.voxel_size_m = g.voxel_size_m;
  config.voxel_depth = g.voxel_depth;
  config.origin_W = g.origin_W;
  if (!validate(config).ok() || !g.origin_W.allFinite()) return false;
  *out = g;
  return true;
}

template <typename VoxelT>
Status merge_map_with_store(const Octree<VoxelT>* map, const MapConfig& geometry,
                            BlockStoreFile& store, const char* path,
                            std::unique_ptr<HeapMap<VoxelT>>* out, ErrorText* error,
                            const FinestMerge& finest) {
  auto find = [&](std::uint64_t key) {
    return map != nullptr ? map->find_block_index_morton(key) : kNoIndex;
  };
  std::size_t extra = 0;
  store.for_each_key([&](std::uint64_t key) {
    if (find(key) == kNoIndex) ++extra;
  });
  if (finest.store != nullptr) {
    // A finest record whose block is nowhere else (its block store write failed) comes back
    // itself.
    finest.store->for_each_key([&](std::uint64_t key) {
      if (find(key) == kNoIndex && !store.in_memory(key) && !store.holds(key)) ++extra;
    });
  }
  MapConfig config = map != nullptr ? map->config() : geometry;
  const std::size_t in_memory = map != nullptr ? map->block_count() : 0;
  config.block_capacity = static_cast<std::uint32_t>(in_memory + extra + 1);
  config.finest_capacity = config.block_capacity;
  config.mid_capacity = config.block_capacity;
  config.node_capacity =
      config.block_capacity * static_cast<std::uint32_t>(config.block_level()) + 1;
  const std::size_t bytes = Octree<VoxelT>::bytes_required(config);
  const std::size_t record_bytes = block_record_max_bytes<VoxelT>();
  const std::size_t rounded = (bytes + kArenaAlignment - 1) / kArenaAlignment * kArenaAlignment;
  auto merged = std::make_unique<HeapMap<VoxelT>>();
  merged->memory.reset(bytes > 0 ? std::aligned_alloc(kArenaAlignment, rounded) : nullptr);
  auto* record = static_cast<std::uint8_t*>(std::malloc(record_bytes));
  const std::unique_ptr<void, void (*)(void*)> record_owner(record, std::free);
  auto* indices =
      static_cast<std::uint32_t*>(std::malloc(sizeof(std::uint32_t) * config.block_capacity));
  const std::unique_ptr<void, void (*)(void*)> indices_owner(indices, std::free);
  if (merged->memory == nullptr || record == nullptr || indices == nullptr) {
    if (error != nullptr) error->set("%s: no memory to merge the map with its store", path);
    return StatusCode::resource_exhausted;
  }
  LinearArena arena(merged->memory.get(), bytes);
  if (!merged->map.reserve(arena, config).ok()) {
    if (error != nullptr) error->set("%s: cannot reserve the merged map", path);
    return StatusCode::resource_exhausted;
  }
  std::size_t count = 0;
  // Blocks in memory first (they are newer than any stored record of theirs), then the stored.
  for (std::size_t i = 0; i < in_memory; ++i) {
    const Result<std::size_t> size =
        encode_block_record(map->block(static_cast<std::uint32_t>(i)), record, record_bytes);
    const Result<std::uint32_t> index =
        size.ok() ? restore_block_record(merged->map, record, size.value()) : size.status();
    if (!index.ok()) {
      if (error != nullptr)
        error->set("%s: cannot merge a block (%s)", path, index.status().name());
      return index.status();
    }
    indices[count++] = index.value();
  }
  Status failed;
  store.for_each_key([&](std::uint64_t key) {
    if (!failed.ok() || find(key) != kNoIndex) return;
    const Result<std::size_t> size = store.read(key, record, record_bytes);
    ErrorText why;
    const Result<std::uint32_t> index =
        size.ok() ? restore_block_record(merged->map, record, size.value(), &why) : size.status();
    if (!index.ok()) {
      if (error != nullptr) {
        error->set("%s: a stored block cannot be read back (%s%s%s)", path, index.status().name(),
                   why.empty() ? "" : ": ", why.c_str());
      }
      failed = index.status();
      return;
    }
    indices[count++] = index.value();
  });
  if (!failed.ok()) return failed;
  if (finest.store != nullptr) {
    // Blocks that gave their finest level up take it back from their newest finest record
    // (one that kept or took a finest level since is newer than the record: it stays).
    finest.store->for_each_key([&](std::uint64_t key) {
      if (!failed.ok()) return;
      const std::uint32_t index = merged->map.find_block_index_morton(key);
      if (index != kNoIndex && merged->map.block(index).has_finest()) return;  // no read needed
      const Result<std::size_t> size = finest.store->read(key, record, record_bytes);
      ErrorText why;
      Status merged_one = size.status();
      if (size.ok()) {
        if (index == kNoIndex) {
          const Result<std::uint32_t> restored =
              restore_block_record(merged->map, record, size.value(), &why);
          merged_one = restored.status();
          if (restored.ok()) indices[count++] = restored.value();
        } else {
          merged_one = restore_finest_from_record(merged->map, index, record, size.value(),
                                                  finest.y_max, &why);
          // A block that cannot take it (never integrated) keeps what it has. (Its index is
          // listed already: its summary is propagated below.)
          if (merged_one.code() == StatusCode::failed_precondition) merged_one = ok_status();
        }
      }
      if (!merged_one.ok()) {
        if (error != nullptr) {
          error->set("%s: a stored finest level cannot be merged (%s%s%s)", path, merged_one.name(),
                     why.empty() ? "" : ": ", why.c_str());
        }
        failed = merged_one;
      }
    });
    if (!failed.ok()) return failed;
  }
  merged->map.propagate_summaries(indices, count);
  *out = std::move(merged);
  return ok_status();
}

template <typename VoxelT>
Status save_map_file_with_store(const char* path, const Octree<VoxelT>& map,
                                const FreeSpace* free_space, BlockStoreFile& store,
                                const MapSaveInfo& info, ErrorText* error,
                                BlockStoreFile* free_store, const FinestMerge& finest) {
  std::unique_ptr<HeapMap<VoxelT>> merged;
  OCTOFUSE_TRY(merge_map_with_store(&map, map.config(), store, path, &merged, error, finest));
  if (free_space == nullptr || free_store == nullptr) {
    return save_map_file(path, merged->map, free_space, info, error);
  }
  std::unique_ptr<HeapFreeSpace> merged_free;
  OCTOFUSE_TRY(merge_free_space_with_store(*free_space, *free_store, path, &merged_free, error));
  return save_map_file(path, merged->map, &merged_free->space, info, error);
}

void encode_free_store_geometry(const StoreGeometry& geometry, std::uint8_t* out) {
  encode_store_geometry(geometry, out);
  out[kStoreGeometryBytes] = kFreeStoreGeometryTag;
}

void encode_finest_store_geometry(const StoreGeometry& geometry, std::uint8_t* out) {
  encode_store_geometry(geometry, out);
  out[kStoreGeometryBytes] = kFinestStoreGeometryTag;
}

Status merge_free_space_with_store(const FreeSpace& free_space, BlockStoreFile& free_store,
                                   const char* path, std::unique_ptr<HeapFreeSpace>* out,
                                   ErrorText* error) {
  // Room for the tree and, per stored region, its nodes and a path down to it.
  std::size_t key_count = 0;
  free_store.for_each_key([&](std::uint64_t key) {
    if (!free_store.in_memory(key)) ++key_count;
  });
  auto* keys = static_cast<std::uint64_t*>(std::malloc(sizeof(std::uint64_t) * (key_count + 1)));
  const std::unique_ptr<void, void (*)(void*)> keys_owner(keys, std::free);
  if (keys == nullptr) {
    if (error != nullptr) error->set("%s: no memory to merge the free space with its store", path);
    return StatusCode::resource_exhausted;
  }
  std::size_t listed = 0;
  std::uint64_t nodes = free_space.node_count();
  const int region_level = free_space.region_level();
  Status failed;
  free_store.for_each_key([&](std::uint64_t key) {
    if (free_store.in_memory(key) || !failed.ok()) return;
    keys[listed++] = key;
    nodes += static_cast<std::uint64_t>(region_level);
    // The node count is in the record's head; a damaged head is caught by the graft below.
    std::uint8_t record[FreeOctree::kRegionRecordMaxBytes];
    const Result<std::size_t> size = free_store.read(key, record, sizeof(record));
    if (!size.ok()) {
      failed = size.status();
      return;
    }
    nodes += FreeOctree::region_record_nodes(record, size.value());
  });
  if (!failed.ok()) {
    if (error != nullptr) error->set("%s: cannot read a stored free-space region", path);
    return failed.code() == StatusCode::unavailable ? failed : Status(StatusCode::data_loss);
  }
  if (nodes > 0xFFFFFFF0u) {
    if (error != nullptr) error->set("%s: the stored free space is too large to merge", path);
    return StatusCode::resource_exhausted;
  }
  FreeSpaceConfig config = free_space.config();
  config.node_capacity = static_cast<std::uint32_t>(nodes);
  const std::size_t bytes = FreeSpace::bytes_required(config, free_space.map_config(), 1, 1);
  const std::size_t rounded = (bytes + kArenaAlignment - 1) / kArenaAlignment * kArenaAlignment;
  auto merged = std::make_unique<HeapFreeSpace>();
  merged->memory.reset(bytes > 0 ? std::aligned_alloc(kArenaAlignment, rounded) : nullptr);
  if (merged->memory == nullptr) {
    if (error != nullptr) error->set("%s: no memory to merge the free space with its store", path);
    return StatusCode::resource_exhausted;
  }
  LinearArena arena(merged->memory.get(), bytes);
  FreeSpace& space = merged->space;
  if (!space.reserve(arena, config, free_space.map_config(), 1, 1).ok() ||
      !space.begin_restore(free_space.node_count()).ok()) {
    if (error != nullptr) error->set("%s: cannot reserve the merged free space", path);
    return StatusCode::resource_exhausted;
  }
  for (std::uint32_t i = 0; i < free_space.node_count(); ++i) {
    space.restore_node(i) = free_space.node(i);
  }
  std::uint8_t record[FreeOctree::kRegionRecordMaxBytes];
  for (std::size_t k = 0; k < listed; ++k) {
    const std::uint64_t key = keys[k];
    const Result<std::size_t> size = free_store.read(key, record, sizeof(record));
    const Status grafted =
        size.ok() ? space.graft_region_record(key, record, size.value()) : size.status();
    if (!grafted.ok()) {
      if (error != nullptr) {
        error->set("%s: cannot merge a stored free-space region (%s)", path, grafted.name());
      }
      return grafted.code() == StatusCode::resource_exhausted ? grafted
                                                              : Status(StatusCode::data_loss);
    }
  }
  *out = std::move(merged);
  return ok_status();
}

#define OCTOFUSE_MERGE_WITH_STORE(VoxelT)                                                          \
  template Status merge_map_with_store(const Octree<VoxelT>*, const MapConfig&, BlockStoreFile&,   \
                                       const char*, std::unique_ptr<HeapMap<VoxelT>>*, ErrorText*, \
                                       const FinestMerge&);
OCTOFUSE_MERGE_WITH_STORE(TsdfVoxel)
OCTOFUSE_MERGE_WITH_STORE(MultiresVoxel)
OCTOFUSE_MERGE_WITH_STORE(Multires16Voxel)
#undef OCTOFUSE_MERGE_WITH_STORE

template Status save_map_file_with_store(const char*, const Octree<TsdfVoxel>&, const FreeSpace*,
                                         BlockStoreFile&, const MapSaveInfo&, ErrorText*,
                                         BlockStoreFile*, const FinestMerge&);
template Status save_map_file_with_store(const char*, const Octree<MultiresVoxel>&,
                                         const FreeSpace*, BlockStoreFile&, const MapSaveInfo&,
                                         ErrorText*, BlockStoreFile*, const FinestMerge&);
template Status save_map_file_with_store(const char*, const Octree<Multires16Voxel>&,
                                         const FreeSpace*, BlockStoreFile&, const MapSaveInfo&,
                                         ErrorText*, BlockStoreFile*, const FinestMerge&);

}  // namespace octofuse::host
