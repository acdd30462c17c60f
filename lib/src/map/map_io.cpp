#include "octofuse/map/map_io.hpp"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>

#include "octofuse/map/block_store.hpp"
#include "octofuse/map/detail/little_endian.hpp"
#include "octofuse/map/detail/propagation.hpp"
#include "octofuse/map/free_octree.hpp"

namespace octofuse {

namespace {

constexpr std::uint8_t kMagic[8] = {'O', 'C', 'T', 'O', 'F', 'M', 'A', 'P'};
constexpr std::uint8_t kNodeTag = 'N';
constexpr std::uint8_t kBlockTag = 'B';
constexpr std::uint8_t kFreeTag = 'F';
constexpr std::uint8_t kEndTag = 'E';
constexpr std::uint8_t kHasFinestFlag = 1;
// Voxels are moved in chunks of this many through a stack buffer (1 KiB for multires).
constexpr int kVoxelChunk = 16;

// CRC-32 (IEEE, reflected) tables for slicing by 8: entries[0] is the byte-at-a-time table,
// entries[k][i] the CRC of byte i followed by k zero bytes, so eight bytes take eight look-ups
// instead of eight dependent steps (block records pass through it several times each).
struct CrcTable {
  std::uint32_t entries[8][256];
  constexpr CrcTable() : entries() {
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1u) != 0 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      entries[0][i] = c;
    }
    for (int k = 1; k < 8; ++k) {
      for (std::uint32_t i = 0; i < 256; ++i) {
        const std::uint32_t c = entries[k - 1][i];
        entries[k][i] = (c >> 8) ^ entries[0][c & 0xFFu];
      }
    }
  }
};
constexpr CrcTable kCrcTable;

std::uint32_t float_bits(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, sizeof(u));
  return u;
}
float bits_float(std::uint32_t u) {
  float f;
  std::memcpy(&f, &u, sizeof(f));
  return f;
}
using detail::get_u32;
using detail::put_u32;

bool tsdf_ok(float t) {
  return t >= -1.0f && t <= 1.0f;  // false for NaN
}
bool weight_ok(float w) {
  return w >= 0.0f && w <= kMaxSavedWeight;
}

// Voxel <-> bytes, in the file's field order: float types as their floats' bit patterns,
// Multires16Voxel as its four 16-bit fields.
void put_u16(std::uint8_t* p, std::uint16_t v) {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
}
std::uint16_t get_u16(const std::uint8_t* p) {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
float get_f32(const std::uint8_t* p) {
  return bits_float(get_u32(p));
}
constexpr int voxel_bytes(const TsdfVoxel*) {
  return 8;
}
constexpr int voxel_bytes(const MultiresVoxel*) {
  return 16;
}
constexpr int voxel_bytes(const Multires16Voxel*) {
  return 8;
}
// A finest voxel is written as its level's voxel type, with x_last = x and delta_y = 0 (it keeps
// neither: FinestVoxelT), so records and files are the same format either way.
constexpr int voxel_bytes(const MultiresFinestVoxel*) {
  return voxel_bytes(static_cast<const MultiresVoxel*>(nullptr));
}
constexpr int voxel_bytes(const Multires16FinestVoxel*) {
  return voxel_bytes(static_cast<const Multires16Voxel*>(nullptr));
}
void encode_voxel(const TsdfVoxel& v, std::uint8_t* p) {
  put_u32(p, float_bits(v.tsdf));
  put_u32(p + 4, float_bits(v.weight));
}
void encode_voxel(const MultiresVoxel& v, std::uint8_t* p) {
  put_u32(p, float_bits(v.x));
  put_u32(p + 4, float_bits(v.x_last));
  put_u32(p + 8, float_bits(v.y));
  put_u32(p + 12, float_bits(v.delta_y));
}
void encode_voxel(const Multires16Voxel& v, std::uint8_t* p) {
  put_u16(p, static_cast<std::uint16_t>(v.x_q));
  put_u16(p + 2, static_cast<std::uint16_t>(v.x_last_q));
  put_u16(p + 4, v.y_q);
  put_u16(p + 6, v.delta_y_q);
}
void encode_voxel(const MultiresFinestVoxel& v, std::uint8_t* p) {
  encode_voxel(widen_voxel(v), p);
}
void encode_voxel(const Multires16FinestVoxel& v, std::uint8_t* p) {
  encode_voxel(widen_voxel(v), p);
}
bool decode_voxel(const std::uint8_t* p, TsdfVoxel& v) {
  const float tsdf = get_f32(p);
  const float weight = get_f32(p + 4);
  if (!tsdf_ok(tsdf) || !weight_ok(weight)) return false;
  v.tsdf = tsdf;
  v.weight = weight;
  return true;
}
bool decode_voxel(const std::uint8_t* p, MultiresVoxel& v) {
  const float f[4] = {get_f32(p), get_f32(p + 4), get_f32(p + 8), get_f32(p + 12)};
  if (!tsdf_ok(f[0]) || !tsdf_ok(f[1]) || !weight_ok(f[2]) || !weight_ok(f[3])) return false;
  v.x = f[0];
  v.x_last = f[1];
  v.y = f[2];
  v.delta_y = f[3];
  return true;
}
bool decode_voxel(const std::uint8_t* p, Multires16Voxel& v) {
  // Every weight is valid; a TSDF step must lie in [-1, 1] (-32768 .. -16385 and 16385 .. 32767
  // are outside).
  const auto x = static_cast<std::int16_t>(get_u16(p));
  const auto x_last = static_cast<std::int16_t>(get_u16(p + 2));
  constexpr int kOne = static_cast<int>(kMultires16TsdfScale);
  if (x < -kOne || x > kOne || x_last < -kOne || x_last > kOne) return false;
  v.x_q = x;
  v.x_last_q = x_last;
  v.y_q = get_u16(p + 4);
  v.delta_y_q = get_u16(p + 6);
  return true;
}
// A finest voxel keeps x and y of a record's voxel (checked as that voxel).
template <typename FinestVoxel>
bool decode_finest_voxel(const std::uint8_t* p, FinestVoxel& v) {
  decltype(widen_voxel(v)) wide;
  if (!decode_voxel(p, wide)) return false;
  v = finest_part(wide);
  return true;
}
bool decode_voxel(const std::uint8_t* p, MultiresFinestVoxel& v) {
  return decode_finest_voxel(p, v);
}
bool decode_voxel(const std::uint8_t* p, Multires16FinestVoxel& v) {
  return decode_finest_voxel(p, v);
}

// Buffers bytes for the sink and keeps the running CRC of the current record.
class RecordWriter {
 public:
  explicit RecordWriter(ByteSink& sink) : sink_(sink) {}

  void bytes(const std::uint8_t* p, std::size_t count) {
    crc_ = crc32(p, count, crc_);
    raw(p, count);
  }
  void u8(std::uint8_t v) { bytes(&v, 1); }
  void u32(std::uint32_t v) {
    std::uint8_t b[4];
    put_u32(b, v);
    bytes(b, 4);
  }
  void u64(std::uint64_t v) {
    u32(static_cast<std::uint32_t>(v));
    u32(static_cast<std::uint32_t>(v >> 32));
  }
  void f32(float v) { u32(float_bits(v)); }
  template <typename VoxelT>
  void voxels(const VoxelT* v, int count) {
    constexpr int kBytes = voxel_bytes(static_cast<const VoxelT*>(nullptr));
    std::uint8_t chunk[kVoxelChunk * kBytes];
    for (int start = 0; start < count; start += kVoxelChunk) {
      const int n = count - start < kVoxelChunk ? count - start : kVoxelChunk;
      for (int i = 0; i < n; ++i) encode_voxel(v[start + i], chunk + i * kBytes);
      bytes(chunk, static_cast<std::size_t>(n) * kBytes);
    }
  }
  // Appends the record's CRC and starts the next record.
  void end_record() {
    std::uint8_t b[4];
    put_u32(b, crc_);
    raw(b, 4);
    crc_ = 0;
  }
  Status finish() {
    flush();
    return status_;
  }

 private:
  void raw(const std::uint8_t* p, std::size_t count) {
    while (count > 0) {
      if (used_ == sizeof(buffer_)) flush();
      const std::size_t n = count < sizeof(buffer_) - used_ ? count : sizeof(buffer_) - used_;
      std::memcpy(buffer_ + used_, p, n);
      used_ += n;
      p += n;
      count -= n;
    }
  }
  void flush() {
    if (used_ > 0 && status_.ok()) status_ = sink_.write(buffer_, used_);
    used_ = 0;
  }

  ByteSink& sink_;
  std::uint8_t buffer_[4096];
  std::size_t used_ = 0;
  std::uint32_t crc_ = 0;
  Status status_;
};

// Reads through a buffer, keeps the running CRC of the current record, and turns the first
// problem into a Status and a one-line message naming the record.
class RecordReader {
 public:
  RecordReader(ByteSource& source, ErrorText* error) : source_(source), error_(error) {}

  // Names the record being read, for messages ("block record 12"; no number when index < 0).
  void begin_record(const char* kind, std::int64_t index) {
    kind_ = kind;
    index_ = index;
    crc_ = 0;
  }
  // Names the record without restarting its checksum.
  void rename_record(const char* kind) { kind_ = kind; }
  bool ok() const { return status_.ok(); }
  Status status() const { return status_; }

  bool bytes(std::uint8_t* p, std::size_t count) {
    if (!raw(p, count)) return false;
    crc_ = crc32(p, count, crc_);
    return true;
  }
  bool u8(std::uint8_t& v) { return bytes(&v, 1); }
  bool u32(std::uint32_t& v) {
    std::uint8_t b[4];
    if (!bytes(b, 4)) return false;
    v = get_u32(b);
    return true;
  }
  bool u64(std::uint64_t& v) {
    std::uint32_t lo, hi;
    if (!u32(lo) || !u32(hi)) return false;
    v = static_cast<std::uint64_t>(lo) | (static_cast<std::uint64_t>(hi) << 32);
    return true;
  }
  bool f32(float& v) {
    std::uint32_t u;
    if (!u32(u)) return false;
    v = bits_float(u);
    return true;
  }
  template <typename VoxelT>
  bool voxels(VoxelT* v, int count) {
    constexpr int kBytes = voxel_bytes(static_cast<const VoxelT*>(nullptr));
    std::uint8_t chunk[kVoxelChunk * kBytes];
    for (int start = 0; start < count; start += kVoxelChunk) {
      const int n = count - start < kVoxelChunk ? count - start : kVoxelChunk;
      if (!bytes(chunk, static_cast<std::size_t>(n) * kBytes)) return false;
      for (int i = 0; i < n; ++i) {
        if (!decode_voxel(chunk + i * kBytes, v[start + i])) {
          return fail(StatusCode::data_loss, "voxel %d out of range", start + i);
        }
      }
    }
    return true;
  }
  // Reads the record's CRC and compares it with the bytes read since begin_record().
  bool end_record() {
    const std::uint32_t computed = crc_;
    std::uint8_t b[4];
    if (!raw(b, 4)) return false;
    if (get_u32(b) != computed) return fail(StatusCode::data_loss, "checksum mismatch");
    return true;
  }
  // True when the source has nothing left (a read error counts as not at the end).
  bool at_end() {
    if (pos_ < len_) return false;
    const bool more = fill();
    return !more && ok();
  }

  // Records the first failure; always returns false.
  bool fail(Status status, const char* format, ...) __attribute__((format(printf, 3, 4))) {
    if (!status_.ok()) return false;
    status_ = status;
    if (error_ != nullptr) {
      char what[160];
      va_list args;
      va_start(args, format);
      std::vsnprintf(what, sizeof(what), format, args);
      va_end(args);
      if (kind_ == nullptr) {
        error_->set("%s", what);
      } else if (index_ < 0) {
        error_->set("%s in the %s", what, kind_);
      } else {
        error_->set("%s in %s %lld", what, kind_, static_cast<long long>(index_));
      }
    }
    return false;
  }

 private:
  bool fill() {
    if (!status_.ok()) return false;
    pos_ = 0;
    len_ = 0;
    Result<std::size_t> got = source_.read(buffer_, sizeof(buffer_));
    if (!got.ok()) {
      fail(got.status(), "read error (%s)", got.status().name());
      return false;
    }
    len_ = got.value() > sizeof(buffer_) ? sizeof(buffer_) : got.value();
    return len_ > 0;
  }
  bool raw(std::uint8_t* p, std::size_t count) {
    while (count > 0) {
      if (pos_ == len_ && !fill()) {
        return fail(StatusCode::data_loss, "truncated");
      }
      const std::size_t n = count < len_ - pos_ ? count : len_ - pos_;
      std::memcpy(p, buffer_ + pos_, n);
      pos_ += n;
      p += n;
      count -= n;
    }
    return true;
  }

  ByteSource& source_;
  ErrorText* error_;
  std::uint8_t buffer_[4096];
  std::size_t pos_ = 0;
  std::size_t len_ = 0;
  std::uint32_t crc_ = 0;
  const char* kind_ = nullptr;
  std::int64_t index_ = -1;
  Status status_;
};

bool summary_ok(const NodeSummary& s) {
  return tsdf_ok(s.tsdf_mean) && tsdf_ok(s.tsdf_min) && tsdf_ok(s.tsdf_max) &&
         weight_ok(s.weight_mean);
}

// The one place a node's record is written and read; a new node field goes here (with a
// format version bump).
void write_node_record(RecordWriter& w, const OctreeNode& n) {
  w.u8(kNodeTag);
  w.u8(n.level);
  w.u64(n.morton);
  w.f32(n.summary.tsdf_mean);
  w.f32(n.summary.weight_mean);
  w.f32(n.summary.tsdf_min);
  w.f32(n.summary.tsdf_max);
  w.end_record();
}
// Every node after its parent, as the loader needs: in index order when the pool has that order
// (a map that never lost an inner node to eviction), else depth first from the root, children in
// child-index order. Either way the file depends only on the map.
template <typename VoxelT>
void write_node_records(RecordWriter& w, const Octree<VoxelT>& map) {
  bool parents_first = true;
  for (std::uint32_t i = 1; i < map.node_count() && parents_first; ++i) {
    parents_first = map.node(i).parent < i;
  }
  if (parents_first) {
    for (std::uint32_t i = 0; i < map.node_count(); ++i) write_node_record(w, map.node(i));
    return;
  }
  struct Frame {
    std::uint32_t node;
    int next_child;
  };
  Frame stack[kMaxVoxelDepth + 2];
  int top = 0;
  stack[top++] = Frame{Octree<VoxelT>::root_index(), 0};
  write_node_record(w, map.node(Octree<VoxelT>::root_index()));
  const int last_inner_level = map.block_level() - 1;
  while (top > 0) {
    Frame& f = stack[top - 1];
    const OctreeNode& n = map.node(f.node);
    if (n.level == last_inner_level || f.next_child == 8) {
      --top;
      continue;
    }
    const std::uint32_t child = n.children[f.next_child++];
    if (child == kNoIndex) continue;
    write_node_record(w, map.node(child));
    stack[top++] = Frame{child, 0};
  }
}

struct NodeRecord {
  Key key;
  NodeSummary summary;
};
bool read_node_record(RecordReader& r, NodeRecord& out) {
  std::uint8_t tag = 0;
  if (!r.u8(tag)) return false;
  if (tag != kNodeTag) return r.fail(StatusCode::data_loss, "wrong record tag");
  if (!r.u8(out.key.level) || !r.u64(out.key.morton) || !r.f32(out.summary.tsdf_mean) ||
      !r.f32(out.summary.weight_mean) || !r.f32(out.summary.tsdf_min) ||
      !r.f32(out.summary.tsdf_max) || !r.end_record()) {
    return false;
  }
  if (!summary_ok(out.summary)) return r.fail(StatusCode::data_loss, "summary out of range");
  return true;
}

// Checks node record `index`'s key in a cube of `depth`: the root first, every later node at a
// level above the blocks, aligned to its octant and inside the cube.
bool check_node_key(RecordReader& r, const Key& key, std::uint32_t index, int depth) {
  if (index == 0) {
    if (key.level != 0 || key.morton != 0) {
      return r.fail(StatusCode::data_loss, "the first node is not the root");
    }
    return true;
  }
  const bool level_ok = key.level >= 1 && key.level < depth - kBlockSideLog2;
  const int below = level_ok ? 3 * (depth - key.level) : 0;
  if (!level_ok || (key.morton & ((std::uint64_t{1} << below) - 1)) != 0 ||
      (key.morton >> (3 * depth)) != 0) {
    return r.fail(StatusCode::data_loss,
                  "node key outside the cube, not aligned or at a bad level");
  }
  return true;
}

template <typename VoxelT>
void write_block_record(RecordWriter& w, const VoxelBlock<VoxelT>& b) {
  w.u8(kBlockTag);
  w.u64(b.morton);
  w.u32(b.last_updated_frame);
  w.u8(static_cast<std::uint8_t>(b.current_scale));
  w.u8(static_cast<std::uint8_t>(b.min_scale));
  w.u8(static_cast<std::uint8_t>(b.mip_scale));
  const bool has_finest = VoxelBlock<VoxelT>::kSplitFinest && b.has_finest();
  w.u8(has_finest ? kHasFinestFlag : 0);
  w.f32(b.tsdf_min);
  w.f32(b.tsdf_max);
  w.f32(b.tsdf_mean);
  w.f32(b.weight_mean);
  if (!VoxelBlock<VoxelT>::kSplitFinest || has_finest) {
    w.voxels(b.finest_begin(), kBlockFinestVoxelCount);
  }
  // Scale 1 reads unobserved without a mid level: the record is the same either way.
  w.voxels(b.level_begin(1), kBlockMidVoxelCount);
  w.voxels(b.level_begin(2), kBlockVoxelCount - kBlockFinestVoxelCount - kBlockMidVoxelCount);
  w.end_record();
}

// Writes the header record (also used by tests to make headers).
void write_header_record(RecordWriter& w, const MapFileHeader& h) {
  w.bytes(kMagic, sizeof(kMagic));
  w.u32(h.version);
  w.u8(static_cast<std::uint8_t>(h.voxel_type));
  w.f32(h.voxel_size_m);
  w.f32(h.mu_m);
  w.u8(static_cast<std::uint8_t>(h.voxel_depth));
  w.f32(h.origin_W.x());
  w.f32(h.origin_W.y());
  w.f32(h.origin_W.z());
  w.u32(h.node_count);
  w.u32(h.block_count);
  w.u32(h.finest_count);
  w.u64(h.frames);
  w.u32(h.free_node_count);
  w.f32(h.free_margin_m);
  w.u8(static_cast<std::uint8_t>(h.free_octant_voxels));
  w.u8(static_cast<std::uint8_t>(h.free_max_count));
  w.end_record();
}

// Whether every field of `h` lies in a range this library can hold; else false with the field
// and its range in `why`. The loader checks every file's header with it, and save_map() the header
// it is about to write, so a map that saves always loads back.
bool header_fields_ok(const MapFileHeader& h, char* why, std::size_t why_size) {
#define HEADER_FIELD_BAD(...) (std::snprintf(why, why_size, __VA_ARGS__), false)
  if (h.version == 0 || h.version > kMapFormatVersion) {
    return HEADER_FIELD_BAD("format version %u not in [1, %u]", static_cast<unsigned>(h.version),
                            static_cast<unsigned>(kMapFormatVersion));
  }
  if (h.voxel_type != MapVoxelType::single_res && h.voxel_type != MapVoxelType::multires &&
      h.voxel_type != MapVoxelType::multires16) {
    return HEADER_FIELD_BAD("unknown voxel type %u", static_cast<unsigned>(h.voxel_type));
  }
  if (!(h.voxel_size_m >= kMinVoxelSize_m) || !(h.voxel_size_m <= kMaxVoxelSize_m)) {
    return HEADER_FIELD_BAD("voxel size %g m not in [%g, %g]", static_cast<double>(h.voxel_size_m),
                            static_cast<double>(kMinVoxelSize_m),
                            static_cast<double>(kMaxVoxelSize_m));
  }
  if (!(h.mu_m > 0.0f) || !(h.mu_m <= kMaxSavedMu_m)) {
    return HEADER_FIELD_BAD("truncation distance mu %g m not in (0, %g]",
                            static_cast<double>(h.mu_m), static_cast<double>(kMaxSavedMu_m));
  }
  if (h.voxel_depth < kMinVoxelDepth || h.voxel_depth > kMaxVoxelDepth) {
    return HEADER_FIELD_BAD("voxel depth %d not in [%d, %d]", h.voxel_depth, kMinVoxelDepth,
                            kMaxVoxelDepth);
  }
  if (!h.origin_W.allFinite() || !(h.origin_W.cwiseAbs().maxCoeff() <= kMaxOrigin_m)) {
    return HEADER_FIELD_BAD("origin (%g, %g, %g) m not finite or beyond %g m",
                            static_cast<double>(h.origin_W.x()),
                            static_cast<double>(h.origin_W.y()),
                            static_cast<double>(h.origin_W.z()), static_cast<double>(kMaxOrigin_m));
  }
  if (h.node_count == 0 || h.node_count > (1u << 31) || h.block_count > (1u << 30) ||
      h.finest_count > h.block_count ||
      (h.voxel_type == MapVoxelType::single_res && h.finest_count != 0)) {
    return HEADER_FIELD_BAD("inconsistent node, block or finest-level counts (%u, %u, %u)",
                            static_cast<unsigned>(h.node_count),
                            static_cast<unsigned>(h.block_count),
                            static_cast<unsigned>(h.finest_count));
  }
  if (h.frames > kMaxSavedFrames) {
    return HEADER_FIELD_BAD("frame count %llu above %llu",
                            static_cast<unsigned long long>(h.frames),
                            static_cast<unsigned long long>(kMaxSavedFrames));
  }
  const bool no_free_space = h.free_node_count == 0 && float_bits(h.free_margin_m) == 0 &&
                             h.free_octant_voxels == 0 && h.free_max_count == 0;
  if (no_free_space) return true;
  if (h.free_node_count < 1 || h.free_node_count > (1u << 31)) {
    return HEADER_FIELD_BAD("free-space node count %u not in [1, 2^31]",
                            static_cast<unsigned>(h.free_node_count));
  }
  if (!(h.free_margin_m > 0.0f) || !(h.free_margin_m <= kMaxSavedMu_m)) {
    return HEADER_FIELD_BAD("free-space margin %g m not in (0, %g]",
                            static_cast<double>(h.free_margin_m),
                            static_cast<double>(kMaxSavedMu_m));
  }
  const int octant = h.free_octant_voxels;
  const int block_level = h.voxel_depth - kBlockSideLog2;
  if (octant < 2 || octant > 64 || (octant & (octant - 1)) != 0 ||
      free_leaf_level(block_level, octant) < 1) {
    return HEADER_FIELD_BAD(
        "free-space octants of %d voxels (2 to 64, a power of two, below the root's "
        "children)",
        octant);
  }
  if (h.free_max_count < 1 || h.free_max_count > 255) {
    return HEADER_FIELD_BAD("free-space count cap %d not in [1, 255]", h.free_max_count);
  }
  return true;
#undef HEADER_FIELD_BAD
}

Result<MapFileHeader> read_header_record(RecordReader& r) {
  r.begin_record(nullptr, -1);  // a file without the magic is not told of a header
  std::uint8_t magic[sizeof(kMagic)];
  if (!r.bytes(magic, sizeof(magic))) {
    r.fail(StatusCode::invalid_argument, "not an octofuse map (too short)");
    return r.status();
  }
  if (std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) {
    r.fail(StatusCode::invalid_argument, "not an octofuse map (bad magic)");
    return r.status();
  }
  r.rename_record("header");
  MapFileHeader h;
  if (!r.u32(h.version)) return r.status();
  if (h.version > kMapFormatVersion) {
    r.fail(StatusCode::out_of_range, "format version %u is newer than this build reads (%u)",
           static_cast<unsigned>(h.version), static_cast<unsigned>(kMapFormatVersion));
    return r.status();
  }
  if (h.version == 0) {
    r.fail(StatusCode::data_loss, "format version 0");
    return r.status();
  }
  std::uint8_t type = 0;
  std::uint8_t depth = 0;
  std::uint8_t free_octant = 0;
  std::uint8_t free_cap = 0;
  if (!r.u8(type) || !r.f32(h.voxel_size_m) || !r.f32(h.mu_m) || !r.u8(depth) ||
      !r.f32(h.origin_W.x()) || !r.f32(h.origin_W.y()) || !r.f32(h.origin_W.z()) ||
      !r.u32(h.node_count) || !r.u32(h.block_count) || !r.u32(h.finest_count) || !r.u64(h.frames) ||
      !r.u32(h.free_node_count) || !r.f32(h.free_margin_m) || !r.u8(free_octant) ||
      !r.u8(free_cap) || !r.end_record()) {
    return r.status();
  }
  h.free_octant_voxels = free_octant;
  h.free_max_count = free_cap;
  if (type != static_cast<std::uint8_t>(MapVoxelType::single_res) &&
      type != static_cast<std::uint8_t>(MapVoxelType::multires) &&
      type != static_cast<std::uint8_t>(MapVoxelType::multires16)) {
    r.fail(StatusCode::data_loss, "unknown voxel type %u", static_cast<unsigned>(type));
    return r.status();
  }
  h.voxel_type = static_cast<MapVoxelType>(type);
  h.voxel_depth = depth;
  char why[160];
  if (!header_fields_ok(h, why, sizeof(why))) {
    r.fail(StatusCode::data_loss, "%s", why);
    return r.status();
  }
  return h;
}

void write_free_record(RecordWriter& w, const FreeNode& n) {
  w.u8(kFreeTag);
  w.u8(n.free_count);
  w.u32(n.free_frame);
  for (std::uint32_t child : n.children) w.u32(child);
  w.u8(n.sub_free);
  w.end_record();
}

// Reads free-space record `index` of the header's count and checks it alone: count, frame,
// children in range and after `index`.
bool read_free_record(RecordReader& r, const MapFileHeader& h, std::uint32_t index, FreeNode& out) {
  std::uint8_t tag = 0;
  if (!r.u8(tag)) return false;
  if (tag != kFreeTag) return r.fail(StatusCode::data_loss, "wrong record tag");
  if (!r.u8(out.free_count) || !r.u32(out.free_frame)) return false;
  for (std::uint32_t& child : out.children) {
    if (!r.u32(child)) return false;
  }
  out.sub_free = 0;
  if (h.version >= 2 && !r.u8(out.sub_free)) return false;
  if (!r.end_record()) return false;
  if (out.free_count > h.free_max_count) {
    return r.fail(StatusCode::data_loss, "free count above the file's cap");
  }
  // Frame 0 is also what a node that was never free holds.
  if (out.free_frame != 0 && out.free_frame >= h.frames) {
    return r.fail(StatusCode::data_loss, "free frame not before the map's frame count");
  }
  for (std::uint32_t child : out.children) {
    if (child != FreeOctree::kNoNode && (child <= index || child >= h.free_node_count)) {
      return r.fail(StatusCode::data_loss, "free-space child index out of range");
    }
  }
  return true;
}

// Reads the free-space records. With `free_space` (restored to the header's count beforehand)
// they also must form one tree: each node after the root is the child of exactly one earlier
// node, and no node below the finest octant level. Until its own record is read, a node's slot
// holds its parent in children[0] and its level in free_frame.
bool read_free_space(RecordReader& r, const MapFileHeader& h, int block_level,
                     FreeOctree* free_space) {
  const int octant = h.free_octant_voxels;
  if (h.free_node_count > 0 && octant != 2 && octant != 4 && octant != 8 && octant != 16 &&
      octant != 32 && octant != 64) {
    return r.fail(StatusCode::data_loss, "free-space octants of %d voxels", octant);
  }
  const int leaf_level = free_leaf_level(block_level, octant);
  for (std::uint32_t i = 0; i < h.free_node_count; ++i) {
    r.begin_record("free-space record", i);
    FreeNode node;
    if (!read_free_record(r, h, i, node)) return false;
    if (free_space == nullptr) continue;
    FreeNode& slot = free_space->restore_node(i);
    std::uint32_t level = 0;
    if (i > 0) {
      if (slot.children[0] == FreeOctree::kNoNode) {
        return r.fail(StatusCode::data_loss, "free-space node without a parent");
      }
      level = slot.free_frame;
    }
    if (node.sub_free != 0 && static_cast<int>(level) != leaf_level) {
      return r.fail(StatusCode::data_loss, "free sub-cells on a node above the finest octants");
    }
    for (std::uint32_t child : node.children) {
      if (child == FreeOctree::kNoNode) continue;
      if (static_cast<int>(level) >= leaf_level) {
        return r.fail(StatusCode::data_loss, "free-space node below the finest octant level");
      }
      FreeNode& below = free_space->restore_node(child);
      if (below.children[0] != FreeOctree::kNoNode) {
        return r.fail(StatusCode::data_loss, "free-space node with two parents");
      }
      below.children[0] = i;
      below.free_frame = level + 1;
    }
    slot = node;
  }
  return true;
}

bool same_bits(float a, float b) {
  return float_bits(a) == float_bits(b);
}

// A block record's fields before its voxels.
struct BlockFields {
  std::uint64_t morton = 0;
  std::uint32_t last_updated = 0;
  std::int8_t current = 0;
  std::int8_t min_scale = 0;
  std::int8_t mip = 0;
  bool has_finest = false;
  float summary[4] = {};
};

// Reads a block record up to its voxels and checks what needs no map: the tag, the key
// (block-aligned, inside a cube of `depth`), the scales, the flags and the summary.
template <typename VoxelT>
bool read_block_fields(RecordReader& r, int depth, BlockFields& out) {
  using Block = VoxelBlock<VoxelT>;
  std::uint8_t tag = 0;
  if (!r.u8(tag)) return false;
  if (tag != kBlockTag) return r.fail(StatusCode::data_loss, "wrong record tag");
  std::uint8_t current = 0, min_scale = 0, mip = 0, flags = 0;
  if (!r.u64(out.morton) || !r.u32(out.last_updated) || !r.u8(current) || !r.u8(min_scale) ||
      !r.u8(mip) || !r.u8(flags) || !r.f32(out.summary[0]) || !r.f32(out.summary[1]) ||
      !r.f32(out.summary[2]) || !r.f32(out.summary[3])) {
    return false;
  }
  const std::uint64_t aligned_mask = (std::uint64_t{1} << (3 * kBlockSideLog2)) - 1;
  if ((out.morton & aligned_mask) != 0 || (out.morton >> (3 * depth)) != 0) {
    return r.fail(StatusCode::data_loss, "block key outside the cube or not block-aligned");
  }
  out.current = static_cast<std::int8_t>(current);
  out.min_scale = static_cast<std::int8_t>(min_scale);
  out.mip = static_cast<std::int8_t>(mip);
  const bool integrated = out.min_scale != kNeverIntegrated;
  const bool state_ok = out.current >= 0 && out.current <= kMaxBlockScale &&
                        (integrated ? (out.min_scale >= 0 && out.min_scale <= out.current &&
                                       out.mip >= out.current && out.mip <= kMaxBlockScale)
                                    : out.mip == kNeverIntegrated);
  if (!state_ok) return r.fail(StatusCode::data_loss, "block scales inconsistent");
  if ((flags & ~kHasFinestFlag) != 0 || (!Block::kSplitFinest && flags != 0)) {
    return r.fail(StatusCode::data_loss, "unknown block flags");
  }
  out.has_finest = Block::kSplitFinest ? (flags & kHasFinestFlag) != 0 : true;
  if (Block::kSplitFinest && integrated && out.current == 0 && !out.has_finest) {
    return r.fail(StatusCode::data_loss, "block at scale 0 without its finest level");
  }
  if (!tsdf_ok(out.summary[0]) || !tsdf_ok(out.summary[1]) || !tsdf_ok(out.summary[2]) ||
      !weight_ok(out.summary[3])) {
    return r.fail(StatusCode::data_loss, "block summary out of range");
  }
  return true;
}

// Whether a split block read from a record needs a mid level: it holds a finest level, is at
// scale 1, or its scale-1 voxels (the record's, `mid`) are not all unobserved. A block that never
// went finer than scale 2, or gave its mid level back, has nothing there and reads the same
// without one.
template <typename VoxelT>
bool needs_mid_level(const BlockFields& fields, const VoxelT* mid) {
  if (fields.has_finest) return true;
  if (fields.min_scale != kNeverIntegrated && fields.current <= 1) return true;
  return std::memcmp(mid, kUnobservedMidLevel<VoxelT>.voxels,
                     sizeof(VoxelT) * kBlockMidVoxelCount) != 0;
}

template <typename VoxelT>
bool read_block_record(RecordReader& r, Octree<VoxelT>& map, std::uint32_t index,
                       std::uint32_t& finest_loaded, std::uint32_t finest_expected) {
  using Block = VoxelBlock<VoxelT>;
  BlockFields fields;
  if (!read_block_fields<VoxelT>(r, map.voxel_depth(), fields)) return false;
  // The key's parent node present, not a duplicate.
  const Key key{fields.morton, static_cast<std::uint8_t>(map.block_level())};
  AllocationCounts counts;
  const Status allocated = map.allocate(&key, 1, &counts);
  if (counts.new_nodes != 0 || counts.new_blocks != 1 || !allocated.ok() ||
      map.block_count() != index + 1) {
    return r.fail(StatusCode::data_loss, "block without its parent node, or a duplicate");
  }
  Block& block = map.block(index);
  block.last_updated_frame = fields.last_updated;
  block.current_scale = fields.current;
  block.min_scale = fields.min_scale;
  block.mip_scale = fields.mip;
  block.tsdf_min = fields.summary[0];
  block.tsdf_max = fields.summary[1];
  block.tsdf_mean = fields.summary[2];
  block.weight_mean = fields.summary[3];
  if (Block::kSplitFinest && fields.has_finest) {
    if (finest_loaded == finest_expected) {
      return r.fail(StatusCode::data_loss, "more finest levels than the header says");
    }
    if (!map.acquire_finest(block).ok()) {
      return r.fail(StatusCode::resource_exhausted, "the finest-level pool is too small");
    }
    ++finest_loaded;
  }
  if (fields.has_finest && !r.voxels(block.finest_begin(), kBlockFinestVoxelCount)) return false;
  VoxelT mid[kBlockMidVoxelCount];
  if (!r.voxels(mid, kBlockMidVoxelCount)) return false;
  if (Block::kSplitFinest && needs_mid_level(fields, mid) && !map.acquire_mid(block).ok()) {
    return r.fail(StatusCode::resource_exhausted, "the mid-level pool is too small");
  }
  if (block.has_mid()) std::copy(mid, mid + kBlockMidVoxelCount, block.level_begin(1));
  if (!r.voxels(block.level_begin(2),
                kBlockVoxelCount - kBlockFinestVoxelCount - kBlockMidVoxelCount)) {
    return false;
  }
  return r.end_record();
}

// The block records of a map of voxel type VoxelT, checked as read_block_record() does but into
// a small scratch buffer instead of a map.
template <typename VoxelT>
bool check_block_records(RecordReader& r, const MapFileHeader& h) {
  VoxelT scratch[kVoxelChunk];
  std::uint32_t finest_seen = 0;
  for (std::uint32_t i = 0; i < h.block_count; ++i) {
    r.begin_record("block record", i);
    BlockFields fields;
    if (!read_block_fields<VoxelT>(r, h.voxel_depth, fields)) return false;
    int count = kBlockVoxelCount - kBlockFinestVoxelCount;
    if (VoxelBlock<VoxelT>::kSplitFinest && fields.has_finest) {
      if (finest_seen == h.finest_count) {
        return r.fail(StatusCode::data_loss, "more finest levels than the header says");
      }
      ++finest_seen;
    }
    if (fields.has_finest) count = kBlockVoxelCount;
    for (int start = 0; start < count; start += kVoxelChunk) {
      if (!r.voxels(scratch, count - start < kVoxelChunk ? count - start : kVoxelChunk)) {
        return false;
      }
    }
    if (!r.end_record()) return false;
  }
  if (VoxelBlock<VoxelT>::kSplitFinest && finest_seen != h.finest_count) {
    return r.fail(StatusCode::data_loss, "fewer finest levels than the header says");
  }
  return true;
}

// Reads the end record and checks it against the header, and that nothing follows.
bool read_end_record(RecordReader& r, const MapFileHeader& h) {
  r.begin_record("end record", -1);
  std::uint8_t tag = 0;
  std::uint32_t nodes = 0;
  std::uint32_t blocks = 0;
  std::uint32_t free_nodes = 0;
  if (!r.u8(tag) || !r.u32(nodes) || !r.u32(blocks) || !r.u32(free_nodes) || !r.end_record()) {
    return false;
  }
  if (tag != kEndTag || nodes != h.node_count || blocks != h.block_count ||
      free_nodes != h.free_node_count) {
    return r.fail(StatusCode::data_loss, "end record does not match the header");
  }
  return true;
}

}  // namespace

Status MemorySink::write(const std::uint8_t* bytes, std::size_t count) {
  if (count > capacity_ - size_) return StatusCode::resource_exhausted;
  std::memcpy(buffer_ + size_, bytes, count);
  size_ += count;
  return ok_status();
}

Result<std::size_t> MemorySource::read(std::uint8_t* bytes, std::size_t count) {
  const std::size_t n = count < size_ - offset_ ? count : size_ - offset_;
  if (n > 0) std::memcpy(bytes, bytes_ + offset_, n);
  offset_ += n;
  return n;
}

const char* map_voxel_type_name(MapVoxelType type) {
  return type == MapVoxelType::multires     ? "multires"
         : type == MapVoxelType::multires16 ? "multires16"
                                            : "single-res";
}

std::uint32_t crc32(const std::uint8_t* bytes, std::size_t count, std::uint32_t crc) {
  const auto& t = kCrcTable.entries;
  crc = ~crc;
  // Bytes assembled explicitly: the same result on any byte order.
  for (; count >= 8; count -= 8, bytes += 8) {
    const std::uint32_t lo = crc ^ (std::uint32_t{bytes[0]} | std::uint32_t{bytes[1]} << 8 |
                                    std::uint32_t{bytes[2]} << 16 | std::uint32_t{bytes[3]} << 24);
    crc = t[7][lo & 0xFFu] ^ t[6][(lo >> 8) & 0xFFu] ^ t[5][(lo >> 16) & 0xFFu] ^ t[4][lo >> 24] ^
          t[3][bytes[4]] ^ t[2][bytes[5]] ^ t[1][bytes[6]] ^ t[0][bytes[7]];
  }
  for (; count > 0; --count, ++bytes) crc = t[0][(crc ^ *bytes) & 0xFFu] ^ (crc >> 8);
  return ~crc;
}

MapConfig map_config_for(const MapFileHeader& header) {
  MapConfig config;
  config.voxel_size_m = header.voxel_size_m;
  config.voxel_depth = header.voxel_depth;
  config.origin_W = header.origin_W;
  config.node_capacity = header.node_count > 0 ? header.node_count : 1;
  config.block_capacity = header.block_count > 0 ? header.block_count : 1;
  config.finest_capacity = header.finest_count > 0 ? header.finest_count : 1;
  return config;
}

namespace {
bool same_geometry(const MapConfig& a, const MapConfig& b) {
  return same_bits(a.voxel_size_m, b.voxel_size_m) && a.voxel_depth == b.voxel_depth &&
         same_bits(a.origin_W.x(), b.origin_W.x()) && same_bits(a.origin_W.y(), b.origin_W.y()) &&
         same_bits(a.origin_W.z(), b.origin_W.z());
}
}  // namespace

template <typename VoxelT>
Status save_map(const Octree<VoxelT>& map, const FreeOctree* free_space, const MapSaveInfo& info,
                ByteSink& sink, ErrorText* error) {
  auto refuse = [&](Status status, const char* why) {
    if (error != nullptr) error->set("%s", why);
    return status;
  };
  if (!map.reserved()) return refuse(StatusCode::failed_precondition, "the map is not reserved");
  if (free_space != nullptr) {
    if (!free_space->reserved()) {
      return refuse(StatusCode::failed_precondition, "the free space is not reserved");
    }
    if (!same_geometry(free_space->map_config(), map.config())) {
      return refuse(StatusCode::invalid_argument, "the free space's geometry is not the map's");
    }
    // What the loader checks: a file this writes always loads.
    for (std::uint32_t i = 0; i < free_space->node_count(); ++i) {
      const std::uint32_t frame = free_space->node(i).free_frame;
      if (frame != 0 && frame >= info.frames) {
        return refuse(StatusCode::invalid_argument,
                      "a free-space node's frame is not before the frame count");
      }
    }
  }
  const MapMemory memory = map.memory();
  MapFileHeader h;
  h.voxel_type = map_voxel_type<VoxelT>();
  h.voxel_size_m = map.voxel_size_m();
  h.voxel_depth = map.voxel_depth();
  h.origin_W = map.config().origin_W;
  h.node_count = map.node_count();
  h.block_count = map.block_count();
  h.finest_count = memory.finest_used;
  h.mu_m = info.mu_m;
  h.frames = info.frames;
  if (free_space != nullptr) {
    h.free_node_count = free_space->node_count();
    h.free_margin_m = free_space->margin_m();
    h.free_octant_voxels = free_space->config().finest_octant_voxels;
    h.free_max_count = free_space->config().max_free_count;
  }
  // The loader checks every header field against these ranges: refuse here what it would
  // refuse there, before a byte is written.
  char why[160];
  if (!header_fields_ok(h, why, sizeof(why))) {
    if (error != nullptr) error->set("cannot be saved: %s", why);
    return StatusCode::invalid_argument;
  }
  RecordWriter w(sink);
  write_header_record(w, h);
  write_node_records(w, map);
  for (std::uint32_t i = 0; i < map.block_count(); ++i) write_block_record(w, map.block(i));
  for (std::uint32_t i = 0; i < h.free_node_count; ++i) write_free_record(w, free_space->node(i));
  w.u8(kEndTag);
  w.u32(h.node_count);
  w.u32(h.block_count);
  w.u32(h.free_node_count);
  w.end_record();
  const Status written = w.finish();
  if (!written.ok() && error != nullptr) error->set("not written (%s)", written.name());
  return written;
}

Result<MapFileHeader> read_map_header(ByteSource& source, ErrorText* error) {
  RecordReader r(source, error);
  return read_header_record(r);
}

template <typename VoxelT>
Status load_map(ByteSource& source, Octree<VoxelT>& map, MapFileHeader* header_out,
                ErrorText* error) {
  return load_map(source, map, nullptr, header_out, error);
}

template <typename VoxelT>
Status load_map(ByteSource& source, Octree<VoxelT>& map, FreeOctree* free_space,
                MapFileHeader* header_out, ErrorText* error) {
  if (!map.reserved()) return StatusCode::failed_precondition;
  if (free_space != nullptr && !free_space->reserved()) return StatusCode::failed_precondition;
  map.clear();
  if (free_space != nullptr) free_space->clear();
  RecordReader r(source, error);
  auto failed = [&]() {
    map.clear();
    if (free_space != nullptr) free_space->clear();
    return r.status();
  };
  const Result<MapFileHeader> header = read_header_record(r);
  if (!header.ok()) return header.status();
  const MapFileHeader& h = header.value();
  if (h.voxel_type != map_voxel_type<VoxelT>()) {
    r.fail(StatusCode::invalid_argument, "holds a %s map, this one is %s",
           map_voxel_type_name(h.voxel_type), map_voxel_type_name(map_voxel_type<VoxelT>()));
    return r.status();
  }
  const MapConfig& config = map.config();
  if (!same_geometry(map_config_for(h), config)) {
    r.fail(StatusCode::invalid_argument,
           "voxel size, depth or origin differ from the map it is loaded into");
    return r.status();
  }
  const MapMemory memory = map.memory();
  if (h.node_count > memory.node_capacity || h.block_count > memory.block_capacity ||
      (Octree<VoxelT>::kSplitFinest && h.finest_count > memory.finest_capacity)) {
    r.fail(StatusCode::resource_exhausted,
           "needs %u nodes, %u blocks and %u finest levels; the pools hold %u, %u and %u",
           static_cast<unsigned>(h.node_count), static_cast<unsigned>(h.block_count),
           static_cast<unsigned>(h.finest_count), static_cast<unsigned>(memory.node_capacity),
           static_cast<unsigned>(memory.block_capacity),
           static_cast<unsigned>(memory.finest_capacity));
    return r.status();
  }
  if (free_space != nullptr && !same_geometry(free_space->map_config(), config)) {
    r.fail(StatusCode::invalid_argument, "the free space's geometry differs from the map's");
    return r.status();
  }
  if (free_space != nullptr && h.free_node_count > 0) {
    const FreeSpaceConfig& fs = free_space->config();
    if (!same_bits(h.free_margin_m, free_space->margin_m()) ||
        h.free_octant_voxels != fs.finest_octant_voxels || h.free_max_count != fs.max_free_count) {
      r.fail(StatusCode::invalid_argument,
             "free space carved with margin %g m, %d-voxel octants, count cap %d; this one has "
             "%g m, %d, %d",
             static_cast<double>(h.free_margin_m), h.free_octant_voxels, h.free_max_count,
             static_cast<double>(free_space->margin_m()), fs.finest_octant_voxels,
             static_cast<int>(fs.max_free_count));
      return r.status();
    }
    if (!free_space->begin_restore(h.free_node_count).ok()) {
      r.fail(StatusCode::resource_exhausted, "needs %u free-space nodes; the pool holds %u",
             static_cast<unsigned>(h.free_node_count),
             static_cast<unsigned>(free_space->node_capacity()));
      return failed();
    }
  }

  const int block_level = map.block_level();
  const int depth = map.voxel_depth();
  for (std::uint32_t i = 0; i < h.node_count; ++i) {
    r.begin_record("node record", i);
    NodeRecord node;
    if (!read_node_record(r, node)) return failed();
    if (!check_node_key(r, node.key, i, depth)) return failed();
    if (i > 0) {
      AllocationCounts counts;
      const Status allocated = map.allocate(&node.key, 1, &counts);
      if (!allocated.ok() || counts.new_nodes != 1 || map.node_count() != i + 1) {
        r.fail(StatusCode::data_loss, "node without its parent, or a duplicate");
        return failed();
      }
    }
    map.restore_node_summary(i, node.summary);
  }
  std::uint32_t finest_loaded = 0;
  for (std::uint32_t i = 0; i < h.block_count; ++i) {
    r.begin_record("block record", i);
    if (!read_block_record(r, map, i, finest_loaded, h.finest_count)) return failed();
  }
  if (!read_free_space(r, h, block_level, free_space)) return failed();
  if (!read_end_record(r, h)) return failed();
  if (finest_loaded != h.finest_count) {
    r.fail(StatusCode::data_loss, "fewer finest levels than the header says");
    return failed();
  }
  if (!r.at_end()) {
    if (r.ok()) r.fail(StatusCode::data_loss, "extra bytes after the end");
    return failed();
  }
  if (header_out != nullptr) *header_out = h;
  return ok_status();
}

Status validate_map_header(const MapFileHeader& header, ErrorText* error) {
  char why[160];
  if (header_fields_ok(header, why, sizeof(why))) return ok_status();
  if (error != nullptr) error->set("%s", why);
  return StatusCode::data_loss;
}

Status check_map(ByteSource& source, MapFileHeader* header_out, ErrorText* error) {
  RecordReader r(source, error);
  const Result<MapFileHeader> header = read_header_record(r);
  if (!header.ok()) return header.status();
  const MapFileHeader& h = header.value();
  const int block_level = h.voxel_depth - kBlockSideLog2;
  for (std::uint32_t i = 0; i < h.node_count; ++i) {
    r.begin_record("node record", i);
    NodeRecord node;
    if (!read_node_record(r, node) || !check_node_key(r, node.key, i, h.voxel_depth)) {
      return r.status();
    }
  }
  const bool blocks_ok =
      h.voxel_type == MapVoxelType::single_res   ? check_block_records<TsdfVoxel>(r, h)
      : h.voxel_type == MapVoxelType::multires16 ? check_block_records<Multires16Voxel>(r, h)
                                                 : check_block_records<MultiresVoxel>(r, h);
  if (!blocks_ok || !read_free_space(r, h, block_level, nullptr) || !read_end_record(r, h)) {
    return r.status();
  }
  if (!r.at_end()) {
    if (r.ok()) r.fail(StatusCode::data_loss, "extra bytes after the end");
    return r.status();
  }
  if (header_out != nullptr) *header_out = h;
  return ok_status();
}

template Status save_map(const Octree<TsdfVoxel>&, const FreeOctree*, const MapSaveInfo&, ByteSink&,
                         ErrorText*);
template Status save_map(const Octree<MultiresVoxel>&, const FreeOctree*, const MapSaveInfo&,
                         ByteSink&, ErrorText*);
template Status load_map(ByteSource&, Octree<TsdfVoxel>&, MapFileHeader*, ErrorText*);
template Status load_map(ByteSource&, Octree<MultiresVoxel>&, MapFileHeader*, ErrorText*);
template Status load_map(ByteSource&, Octree<TsdfVoxel>&, FreeOctree*, MapFileHeader*, ErrorText*);
template Status load_map(ByteSource&, Octree<MultiresVoxel>&, FreeOctree*, MapFileHeader*,
                         ErrorText*);
template Status save_map(const Octree<Multires16Voxel>&, const FreeOctree*, const MapSaveInfo&,
                         ByteSink&, ErrorText*);
template Status load_map(ByteSource&, Octree<Multires16Voxel>&, MapFileHeader*, ErrorText*);
template Status load_map(ByteSource&, Octree<Multires16Voxel>&, FreeOctree*, MapFileHeader*,
                         ErrorText*);

// --- Block records for a BlockStore (block_store.hpp): the map file's block record, alone.

template <typename VoxelT>
std::size_t block_record_max_bytes() {
  // tag, key, frame, scales and flags, summary, every voxel, CRC.
  return 1 + 8 + 4 + 4 + 16 +
         static_cast<std::size_t>(kBlockVoxelCount) *
             voxel_bytes(static_cast<const VoxelT*>(nullptr)) +
         4;
}

template <typename VoxelT>
Result<std::size_t> encode_block_record(const VoxelBlock<VoxelT>& block, std::uint8_t* out,
                                        std::size_t capacity) {
  if (capacity < block_record_max_bytes<VoxelT>()) return StatusCode::resource_exhausted;
  MemorySink sink(out, capacity);
  RecordWriter w(sink);
  write_block_record(w, block);
  const Status written = w.finish();
  if (!written.ok()) return written;
  return sink.size();
}

namespace {

// A whole block record checked and its voxels read into `finest` (scale 0, left as it is when the
// record holds none), `mid` (scale 1) and `coarse` (scales 2 and 3): ok or data_loss.
template <typename VoxelT, typename FinestT>
Status decode_block_record(const std::uint8_t* record, std::size_t size, int voxel_depth,
                           BlockFields& fields, FinestT* finest, VoxelT* mid, VoxelT* coarse,
                           ErrorText* error) {
  MemorySource source(record, size);
  RecordReader r(source, error);
  r.begin_record("stored block", -1);
  if (!read_block_fields<VoxelT>(r, voxel_depth, fields)) return r.status();
  if ((fields.has_finest && !r.voxels(finest, kBlockFinestVoxelCount)) ||
      !r.voxels(mid, kBlockMidVoxelCount) ||
      !r.voxels(coarse, kBlockVoxelCount - kBlockFinestVoxelCount - kBlockMidVoxelCount) ||
      !r.end_record()) {
    return r.status();
  }
  if (!r.at_end()) {
    r.fail(StatusCode::data_loss, "extra bytes after the record");
    return r.status();
  }
  return ok_status();
}

}  // namespace

template <typename VoxelT>
Result<std::uint32_t> restore_block_record(Octree<VoxelT>& map, const std::uint8_t* record,
                                           std::size_t size, ErrorText* error) {
  using Block = VoxelBlock<VoxelT>;
  BlockFields fields;
  // Voxels into scratch first: a damaged record changes nothing.
  static_assert(sizeof(VoxelT) <= 16, "scratch sized for 16-byte voxels");
  VoxelT scratch[kBlockVoxelCount];
  OCTOFUSE_TRY(decode_block_record(record, size, map.voxel_depth(), fields, scratch,
                                   scratch + kBlockFinestVoxelCount,
                                   scratch + kBlockFinestVoxelCount + kBlockMidVoxelCount, error));
  const Key key{fields.morton, static_cast<std::uint8_t>(map.block_level())};
  const Eigen::Vector3i coords = voxel_to_block(key_corner_voxel(key));
  if (map.find_block_index(coords) != kNoIndex) return StatusCode::failed_precondition;
  // With the finest-level pool full the block comes back demoted, as release_finest() leaves it;
  // with the mid-level pool full, as release_mid() does.
  bool demote_finest = false;
  bool demote_mid = false;
  const bool mid = Block::kSplitFinest && needs_mid_level(fields, scratch + kBlockFinestVoxelCount);
  if (Block::kSplitFinest && (fields.has_finest || mid)) {
    const MapMemory memory = map.memory();
    demote_mid = mid && memory.mid_used >= memory.mid_capacity;
    demote_finest =
        fields.has_finest && (demote_mid || memory.finest_used >= memory.finest_capacity);
  }
  AllocationCounts counts;
  const Status allocated = map.allocate(&key, 1, &counts);
  if (counts.refused > 0) return StatusCode::resource_exhausted;
  if (!allocated.ok() || counts.new_blocks != 1) return StatusCode::out_of_range;
  const std::uint32_t index = map.find_block_index(coords);
  Block& block = map.block(index);
  if (mid && !demote_mid) {
    const Status acquired = map.acquire_mid(block);
    OCTOFUSE_CHECK(acquired.ok());  // room checked above
  }
  if (Block::kSplitFinest && fields.has_finest && !demote_finest) {
    const Status finest = map.acquire_finest(block);
    OCTOFUSE_CHECK(finest.ok());  // room checked above
  }
  block.last_updated_frame = fields.last_updated;
  block.current_scale = fields.current;
  block.min_scale = fields.min_scale;
  block.mip_scale = fields.mip;
  block.tsdf_min = fields.summary[0];
  block.tsdf_max = fields.summary[1];
  block.tsdf_mean = fields.summary[2];
  block.weight_mean = fields.summary[3];
  block.stored_clean = 1;
  if (fields.has_finest && !demote_finest) {
    Block::narrow_copy(scratch, kBlockFinestVoxelCount, block.finest_begin());
  }
  const int inline_first = kBlockFinestVoxelCount + kBlockMidVoxelCount;
  if (block.has_mid()) {
    std::copy(scratch + kBlockFinestVoxelCount, scratch + inline_first, block.level_begin(1));
  }
  std::copy(scratch + inline_first, scratch + kBlockVoxelCount, block.level_begin(2));
  if constexpr (Block::kSplitFinest) {
    if (demote_finest || demote_mid) {
      // The scale kept from the record's finer voxels, through levels lent for the moment.
      const int keep = demote_mid ? 2 : 1;
      FinestLevel<VoxelT> lent_finest;
      MidLevel<VoxelT> lent_mid;
      if (demote_finest) {
        Block::narrow_copy(scratch, kBlockFinestVoxelCount, lent_finest.voxels);
        block.finest = &lent_finest;
      }
      if (demote_mid) {
        std::copy(scratch + kBlockFinestVoxelCount, scratch + inline_first, lent_mid.voxels);
        block.mid = &lent_mid;
      }
      Octree<VoxelT>::coarsen_block(block, keep);
      if (demote_finest) block.finest = nullptr;
      if (demote_mid) block.mid = nullptr;
    }
  }
  return index;
}

template <typename VoxelT>
bool block_record_holds_finest(const std::uint8_t* record, std::size_t size) {
  if constexpr (VoxelBlock<VoxelT>::kSplitFinest) {
    MemorySource source(record, size);
    RecordReader r(source, nullptr);
    r.begin_record("stored block", -1);
    BlockFields fields;
    // The depth only bounds the key: the largest a cube may have, so any key passes here.
    return read_block_fields<VoxelT>(r, kMaxVoxelDepth, fields) && fields.has_finest;
  } else {
    (void)record;
    (void)size;
    return false;
  }
}

template <typename VoxelT>
Status restore_finest_from_record(Octree<VoxelT>& map, std::uint32_t index,
                                  const std::uint8_t* record, std::size_t size, float y_max,
                                  ErrorText* error) {
  using Block = VoxelBlock<VoxelT>;
  if constexpr (!Block::kSplitFinest) {
    (void)map, (void)index, (void)record, (void)size, (void)y_max, (void)error;
    return StatusCode::failed_precondition;
  } else {
    if (index >= map.block_count()) return StatusCode::out_of_range;
    Block& block = map.block(index);
    if (block.has_finest() || !block.integrated() || block.current_scale < 1) {
      return StatusCode::failed_precondition;
    }
    // The record as a block of its own, its levels lent for the moment and read straight into
    // them (a damaged record changes nothing of the map).
    FinestLevel<VoxelT> rec_finest;
    MidLevel<VoxelT> rec_mid;
    Block rec;
    rec.finest = &rec_finest;
    rec.mid = &rec_mid;
    BlockFields fields;
    OCTOFUSE_TRY(decode_block_record(record, size, map.voxel_depth(), fields, rec_finest.voxels,
                                     rec_mid.voxels, rec.level_begin(2), error));
    if (fields.morton != block.morton || !fields.has_finest ||
        fields.min_scale == kNeverIntegrated) {
      if (error != nullptr) error->set("the record is another block's or holds no finest level");
      return StatusCode::invalid_argument;
    }
    const bool need_mid = !block.has_mid();
    const MapMemory memory = map.memory();
    if (memory.finest_used >= memory.finest_capacity ||
        (need_mid && memory.mid_used >= memory.mid_capacity)) {
      return StatusCode::resource_exhausted;  // before anything changes
    }
    rec.current_scale = fields.current;
    rec.min_scale = fields.min_scale;
    rec.mip_scale = fields.mip;
    // A record taken at scale 0 holds the block's own finest voxels, not ones derived from a
    // coarser level; a block now coarser than the level it holds fused there since.
    bool unchanged = fields.current == 0 && block.current_scale == (need_mid ? 2 : 1);
    // Its finest level up to date with its own coarser levels (a record taken while the block
    // integrated coarser than scale 0), as the integrator would refine it.
    for (int l = rec.current_scale; l > 0; --l) propagate_block_down(rec, l, y_max);
    rec.current_scale = 0;
    // The block's finest held level (1 with its mid level, else 2) is the parent of the levels
    // coming back: its values when the block gave them up are the record's at that level, as
    // demotion made them (coarsen_block(), the same code). The change since is the block's
    // value less that, and the weight it gained: x_last and delta_y, which the integrator's
    // down-propagation (eq. 5) reads when it refines the block.
    const int parent_scale = need_mid ? 2 : 1;
    Octree<VoxelT>::coarsen_block(rec, parent_scale);
    const int side = block_scale_side(parent_scale);
    VoxelT* now = block.level_begin(parent_scale);
    const VoxelT* then = rec.level_begin(parent_scale);
    for (int i = 0; i < side * side * side; ++i) {
      unchanged = unchanged && voxel_tsdf(now[i]) == voxel_tsdf(then[i]) &&
                  voxel_weight(now[i]) == voxel_weight(then[i]);
      set_voxel_x_last(now[i], voxel_tsdf(then[i]));
      set_voxel_delta_y(now[i], std::max(0.0f, voxel_weight(now[i]) - voxel_weight(then[i])));
    }
    OCTOFUSE_CHECK(map.acquire_finest(block).ok());  // room checked above
    if (need_mid) {
      // The record's scale 1, whose finest voxels are up to date with it.
      VoxelT* mid = block.level_begin(1);
      std::copy(rec_mid.voxels, rec_mid.voxels + kBlockMidVoxelCount, mid);
      for (int i = 0; i < kBlockMidVoxelCount; ++i) {
        set_voxel_x_last(mid[i], voxel_tsdf(mid[i]));
        set_voxel_delta_y(mid[i], 0.0f);
      }
    }
    std::copy(rec_finest.voxels, rec_finest.voxels + kBlockFinestVoxelCount, block.finest_begin());
    block.min_scale = 0;
    block.stored_clean = 0;
    if (unchanged) {
      // Not fused since it gave the level up: the block is again exactly as it was then, at
      // scale 0 (refining it would fill its unobserved finest voxels from the parents).
      block.current_scale = 0;
      Octree<VoxelT>::update_block_summary(block);
    }
    return ok_status();
  }
}

#define OCTOFUSE_BLOCK_RECORD(VoxelT)                                                             \
  template std::size_t block_record_max_bytes<VoxelT>();                                          \
  template Result<std::size_t> encode_block_record(const VoxelBlock<VoxelT>&, std::uint8_t*,      \
                                                   std::size_t);                                  \
  template Result<std::uint32_t> restore_block_record(Octree<VoxelT>&, const std::uint8_t*,       \
                                                      std::size_t, ErrorText*);                   \
  template bool block_record_holds_finest<VoxelT>(const std::uint8_t*, std::size_t);              \
  template Status restore_finest_from_record(Octree<VoxelT>&, std::uint32_t, const std::uint8_t*, \
                                             std::size_t, float, ErrorText*);
OCTOFUSE_BLOCK_RECORD(TsdfVoxel)
OCTOFUSE_BLOCK_RECORD(MultiresVoxel)
OCTOFUSE_BLOCK_RECORD(Multires16Voxel)
#undef OCTOFUSE_BLOCK_RECORD

}  // namespace octofuse
