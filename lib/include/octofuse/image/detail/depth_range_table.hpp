#pragma once
// The depth range of any pixel rectangle of a depth image from a few reads: a 2-D sparse table
// (at every pixel, the min/max over the 2^t x 2^t pixels from it) beside a min/max pyramid of
// aligned tiles. Free-space carving compares each octant with the range of exactly the pixels of
// its footprint; lib/README.md ("Free space") describes how.

#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/image/image_view.hpp"

namespace octofuse {

class DepthRangeTable {
 public:
  // No depth seen: the least depth of a range without any.
  static constexpr float kNoDepth = 1e30f;
  // The least depth seen free to (kNoDepth: none; pixels measured beyond the range count with the
  // range's end), the greatest measured surface depth (0: none) and whether some pixel had no
  // depth.
  struct Range {
    float lo_m = kNoDepth;
    float hi_m = 0.0f;
    bool any_invalid = false;
  };
  static constexpr int kMaxPyramidLevels = 16;
  static constexpr int kMaxTableLevels = 7;  // squares up to 64 pixels

  // Carves the pyramid and the table for `width` x `height` images from `arena`.
  // invalid_argument: an empty or too large image; resource_exhausted: the arena is too small.
  template <typename Arena>
  Status reserve(Arena& arena, int width, int height);

  // Builds both from `depth_m` (metres, 0 or non-finite: no depth). `beyond_range` (empty, or the
  // same size): pixels without depth whose sensor measured beyond the depth range; they count as
  // seen free out to `beyond_free_m`, with no surface.
  void build(ImageView<const float> depth_m, ImageView<const std::uint8_t> beyond_range,
             float beyond_free_m);

  // The range of pixels [u0, u1] x [v0, v1] (clipped to the image; empty after clipping reads
  // as nothing measured).
  Range range(int u0, int v0, int u1, int v1) const;
  // The same for a non-empty rectangle inside the image, from ceil(w / s) x ceil(h / s) squares
  // of the table (s the largest tabled power of two not above the shorter side; 4 reads for a
  // square-ish one).
  Range rect_range(int u0, int v0, int u1, int v1) const;
  // Whether one of the pyramid tiles of `level` covering [u0, u1] x [v0, v1] has a range that
  // overlaps [zone_lo, zone_hi].
  bool any_tile_in_zone(int level, int u0, int v0, int u1, int v1, float zone_lo,
                        float zone_hi) const;

  int width() const { return width_; }
  int height() const { return height_; }
  // Pyramid level l: ceil(w / 2^l) x ceil(h / 2^l) tiles of 2^l x 2^l pixels.
  int level_count() const { return level_count_; }
  int level_width(int level) const { return level_width_[level]; }
  int level_height(int level) const { return level_height_[level]; }
  const float* level_min(int level) const { return depth_min_ + level_offset_[level]; }
  const float* level_max(int level) const { return depth_max_ + level_offset_[level]; }
  // 1: some pixel of the tile has no depth.
  const std::uint8_t* level_invalid(int level) const {
    return depth_invalid_ + level_offset_[level];
  }

 private:
  // Levels 1 .. table_levels_ - 1 of the range table, from the pyramid's level 0.
  void build_table();
  // Level t of the range table, a full image each (level 0 is the pyramid's level 0).
  float* table_min(int t) const { return t == 0 ? depth_min_ : table_min_ + table_offset(t); }
  float* table_max(int t) const { return t == 0 ? depth_max_ : table_max_ + table_offset(t); }
  std::uint8_t* table_invalid(int t) const {
    return t == 0 ? depth_invalid_ : table_invalid_ + table_offset(t);
  }
  std::size_t table_offset(int t) const {
    return static_cast<std::size_t>(t - 1) * static_cast<std::size_t>(width_) *
           static_cast<std::size_t>(height_);
  }

  // Pyramid levels stored back to back.
  float* depth_min_ = nullptr;
  float* depth_max_ = nullptr;
  std::uint8_t* depth_invalid_ = nullptr;
  int level_count_ = 0;
  int level_width_[kMaxPyramidLevels] = {};
  int level_height_[kMaxPyramidLevels] = {};
  std::size_t level_offset_[kMaxPyramidLevels] = {};
  // Table levels 1 .. table_levels_ - 1, back to back.
  float* table_min_ = nullptr;
  float* table_max_ = nullptr;
  std::uint8_t* table_invalid_ = nullptr;
  int table_levels_ = 1;
  int width_ = 0;
  int height_ = 0;
};

template <typename Arena>
Status DepthRangeTable::reserve(Arena& arena, int width, int height) {
  if (width < 1 || height < 1) return StatusCode::invalid_argument;
  std::size_t total = 0;
  int levels = 0;
  int w = width;
  int h = height;
  for (;;) {
    if (levels == kMaxPyramidLevels) return StatusCode::invalid_argument;
    level_width_[levels] = w;
    level_height_[levels] = h;
    level_offset_[levels] = total;
    total += static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
    ++levels;
    if (w == 1 && h == 1) break;
    w = (w + 1) / 2;
    h = (h + 1) / 2;
  }
  Result<float*> lo = arena.template allocate_array<float>(total, kArenaAlignment);
  OCTOFUSE_TRY(lo);
  Result<float*> hi = arena.template allocate_array<float>(total, kArenaAlignment);
  OCTOFUSE_TRY(hi);
  Result<std::uint8_t*> invalid =
      arena.template allocate_array<std::uint8_t>(total, kArenaAlignment);
  OCTOFUSE_TRY(invalid);
  int table_levels = 1;
  while (table_levels < kMaxTableLevels && (2 << (table_levels - 1)) <= std::min(width, height)) {
    ++table_levels;
  }
  const std::size_t table_total = static_cast<std::size_t>(table_levels - 1) *
                                  static_cast<std::size_t>(width) *
                                  static_cast<std::size_t>(height);
  Result<float*> table_lo = arena.template allocate_array<float>(table_total, kArenaAlignment);
  OCTOFUSE_TRY(table_lo);
  Result<float*> table_hi = arena.template allocate_array<float>(table_total, kArenaAlignment);
  OCTOFUSE_TRY(table_hi);
  Result<std::uint8_t*> table_invalid =
      arena.template allocate_array<std::uint8_t>(table_total, kArenaAlignment);
  OCTOFUSE_TRY(table_invalid);
  depth_min_ = lo.value();
  depth_max_ = hi.value();
  depth_invalid_ = invalid.value();
  table_min_ = table_lo.value();
  table_max_ = table_hi.value();
  table_invalid_ = table_invalid.value();
  table_levels_ = table_levels;
  level_count_ = levels;
  width_ = width;
  height_ = height;
  return ok_status();
}

}  // namespace octofuse
