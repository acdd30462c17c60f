#include "octofuse/image/detail/depth_range_table.hpp"

#include <algorithm>

namespace octofuse {

namespace {
// floor(log2(x)) for x > 0.
int floor_log2(std::uint32_t x) {
  return 31 - __builtin_clz(x);
}
}  // namespace

void DepthRangeTable::build(ImageView<const float> depth_m,
                            ImageView<const std::uint8_t> beyond_range, float beyond_free_m) {
  float* lo = depth_min_;
  float* hi = depth_max_;
  std::uint8_t* invalid = depth_invalid_;
  // One output per loop, branch-free, so that each is vectorised.
  for (int y = 0; y < height_; ++y) {
    const float* row = depth_m.row(y);
    float* lo_row = lo + static_cast<std::size_t>(y) * static_cast<std::size_t>(width_);
    float* hi_row = hi + static_cast<std::size_t>(y) * static_cast<std::size_t>(width_);
    std::uint8_t* in_row = invalid + static_cast<std::size_t>(y) * static_cast<std::size_t>(width_);
    // NaN and infinities fail the test too.
    for (int x = 0; x < width_; ++x)
      lo_row[x] = ((row[x] > 0.0f) & (row[x] < kNoDepth)) ? row[x] : kNoDepth;
    for (int x = 0; x < width_; ++x)
      hi_row[x] = ((row[x] > 0.0f) & (row[x] < kNoDepth)) ? row[x] : 0.0f;
    for (int x = 0; x < width_; ++x) in_row[x] = lo_row[x] < kNoDepth ? 0 : 1;
    if (beyond_range.empty()) continue;
    // Seen free out to the range's end; no surface there (hi stays 0).
    const std::uint8_t* beyond_row = beyond_range.row(y);
    for (int x = 0; x < width_; ++x) {
      lo_row[x] = ((in_row[x] != 0) & (beyond_row[x] != 0)) ? beyond_free_m : lo_row[x];
    }
    for (int x = 0; x < width_; ++x) {
      in_row[x] = static_cast<std::uint8_t>(in_row[x] & (beyond_row[x] == 0 ? 1 : 0));
    }
  }
  // Aligned tiles of the levels the range table holds are its entries at multiples of the side.
  build_table();
  for (int level = 1; level < level_count_; ++level) {
    const int w = level_width_[level];
    const int h = level_height_[level];
    float* clo = depth_min_ + level_offset_[level];
    float* chi = depth_max_ + level_offset_[level];
    std::uint8_t* cin = depth_invalid_ + level_offset_[level];
    if (level < table_levels_) {
      const float* tlo = table_min(level);
      const float* thi = table_max(level);
      const std::uint8_t* tin = table_invalid(level);
      for (int y = 0; y < h; ++y) {
        const std::size_t row =
            (static_cast<std::size_t>(y) << level) * static_cast<std::size_t>(width_);
        for (int x = 0; x < w; ++x) {
          const std::size_t i = row + (static_cast<std::size_t>(x) << level);
          clo[y * w + x] = tlo[i];
          chi[y * w + x] = thi[i];
          cin[y * w + x] = tin[i];
        }
      }
      continue;
    }
    const int pw = level_width_[level - 1];
    const int ph = level_height_[level - 1];
    const float* plo = depth_min_ + level_offset_[level - 1];
    const float* phi = depth_max_ + level_offset_[level - 1];
    const std::uint8_t* pin = depth_invalid_ + level_offset_[level - 1];
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        float a = kNoDepth;
        float b = 0.0f;
        std::uint8_t c = 0;
        for (int dy = 0; dy < 2; ++dy) {
          const int py = 2 * y + dy;
          if (py >= ph) break;
          for (int dx = 0; dx < 2; ++dx) {
            const int px = 2 * x + dx;
            if (px >= pw) break;
            a = std::min(a, plo[py * pw + px]);
            b = std::max(b, phi[py * pw + px]);
            c = static_cast<std::uint8_t>(c | pin[py * pw + px]);
          }
        }
        clo[y * w + x] = a;
        chi[y * w + x] = b;
        cin[y * w + x] = c;
      }
    }
  }
}

void DepthRangeTable::build_table() {
  // The range table: each level merges four squares of the one below, offset by half a side
  // (clamped to the last row / column, which then lies inside the square anyway).
  for (int t = 1; t < table_levels_; ++t) {
    const int half = 1 << (t - 1);
    const float* plo = table_min(t - 1);
    const float* phi = table_max(t - 1);
    const std::uint8_t* pin = table_invalid(t - 1);
    float* clo = table_min(t);
    float* chi = table_max(t);
    std::uint8_t* cin = table_invalid(t);
    const int x_split = std::max(width_ - half, 0);
    for (int y = 0; y < height_; ++y) {
      const std::size_t r0 = static_cast<std::size_t>(y) * static_cast<std::size_t>(width_);
      const std::size_t r1 = static_cast<std::size_t>(std::min(y + half, height_ - 1)) *
                             static_cast<std::size_t>(width_);
      const float* a_lo = plo + r0;
      const float* b_lo = plo + r1;
      const float* a_hi = phi + r0;
      const float* b_hi = phi + r1;
      const std::uint8_t* a_in = pin + r0;
      const std::uint8_t* b_in = pin + r1;
      float* o_lo = clo + r0;
      float* o_hi = chi + r0;
      std::uint8_t* o_in = cin + r0;
      // One output per loop, so that each is vectorised.
      for (int x = 0; x < x_split; ++x) {
        o_lo[x] = std::min(std::min(a_lo[x], a_lo[x + half]), std::min(b_lo[x], b_lo[x + half]));
      }
      for (int x = 0; x < x_split; ++x) {
        o_hi[x] = std::max(std::max(a_hi[x], a_hi[x + half]), std::max(b_hi[x], b_hi[x + half]));
      }
      for (int x = 0; x < x_split; ++x) {
        o_in[x] = static_cast<std::uint8_t>(a_in[x] | a_in[x + half] | b_in[x] | b_in[x + half]);
      }
      const int last = width_ - 1;
      for (int x = x_split; x < width_; ++x) {
        o_lo[x] = std::min(std::min(a_lo[x], a_lo[last]), std::min(b_lo[x], b_lo[last]));
        o_hi[x] = std::max(std::max(a_hi[x], a_hi[last]), std::max(b_hi[x], b_hi[last]));
        o_in[x] = static_cast<std::uint8_t>(a_in[x] | a_in[last] | b_in[x] | b_in[last]);
      }
    }
  }
}

DepthRangeTable::Range DepthRangeTable::range(int u0, int v0, int u1, int v1) const {
  Range out;
  u0 = std::max(u0, 0);
  v0 = std::max(v0, 0);
  u1 = std::min(u1, width_ - 1);
  v1 = std::min(v1, height_ - 1);
  if (u0 > u1 || v0 > v1) return out;
  return rect_range(u0, v0, u1, v1);
}

DepthRangeTable::Range DepthRangeTable::rect_range(int u0, int v0, int u1, int v1) const {
  const int rect_w = u1 - u0 + 1;
  const int rect_h = v1 - v0 + 1;
  const int t =
      std::min(floor_log2(static_cast<std::uint32_t>(std::min(rect_w, rect_h))), table_levels_ - 1);
  const int s = 1 << t;
  const float* plo = table_min(t);
  const float* phi = table_max(t);
  const std::uint8_t* pin = table_invalid(t);
  // Squares at u0, u0 + s, ... and the last one flush with u1 (overlaps change no min or max).
  const int x_last = u1 - s + 1;
  const int y_last = v1 - s + 1;
  float lo = kNoDepth;
  float hi = 0.0f;
  std::uint8_t invalid = 0;
  for (int y = v0;; y += s) {
    const int yy = std::min(y, y_last);
    const std::size_t row = static_cast<std::size_t>(yy) * static_cast<std::size_t>(width_);
    for (int x = u0;; x += s) {
      const std::size_t i = row + static_cast<std::size_t>(std::min(x, x_last));
      lo = std::min(lo, plo[i]);
      hi = std::max(hi, phi[i]);
      invalid = static_cast<std::uint8_t>(invalid | pin[i]);
      if (x >= x_last) break;
    }
    if (y >= y_last) break;
  }
  Range range;
  range.lo_m = lo;
  range.hi_m = hi;
  range.any_invalid = invalid != 0;
  return range;
}

bool DepthRangeTable::any_tile_in_zone(int level, int u0, int v0, int u1, int v1, float zone_lo,
                                       float zone_hi) const {
  const int w = level_width_[level];
  const float* plo = depth_min_ + level_offset_[level];
  const float* phi = depth_max_ + level_offset_[level];
  for (int y = v0 >> level; y <= (v1 >> level); ++y) {
    for (int x = u0 >> level; x <= (u1 >> level); ++x) {
      if (plo[y * w + x] <= zone_hi && phi[y * w + x] >= zone_lo) return true;
    }
  }
  return false;
}

}  // namespace octofuse
