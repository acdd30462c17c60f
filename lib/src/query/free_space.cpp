#include "octofuse/query/free_space.hpp"

#include <algorithm>
#include <cmath>

#include "octofuse/core/lanes.hpp"

namespace octofuse {

namespace {
// floor(log2(x)) for x > 0.
int floor_log2(std::uint32_t x) {
  return 31 - __builtin_clz(x);
}

int clamped_floor(float f) {
  constexpr float kLimit = 1e6f;
  if (!(f > -kLimit)) return -1000000;
  if (!(f < kLimit)) return 1000000;
  return floor_to_int(f);
}

// clamped_floor() of four values in one 4-lane pass, each lane the same integer: clamped first
// (NaN and below to -kLimit, at or above to kLimit, whose floors are themselves), then floored. A
// comparison gives -1 in a true lane; a cast between the two vector types keeps the bits.
Ints4 clamped_floor4(Lanes4 f) {
  constexpr float kLimit = 1e6f;
  const Lanes4 lo = Lanes4{-kLimit, -kLimit, -kLimit, -kLimit};
  const Lanes4 hi = Lanes4{kLimit, kLimit, kLimit, kLimit};
  const Ints4 above_lo = f > lo;
  const Ints4 below_hi = f < hi;
  const Ints4 f_or_hi = (below_hi & (Ints4)f) | (~below_hi & (Ints4)hi);
  const Ints4 clamped_bits = (above_lo & f_or_hi) | (~above_lo & (Ints4)lo);
  return floor_lanes((Lanes4)clamped_bits);
}
}  // namespace

FreeSpace::PixelRange FreeSpace::pixel_range(int u0, int v0, int u1, int v1) const {
  if (!reserved()) return PixelRange();
  return ranges_.range(u0, v0, u1, v1);
}

FreeSpace::Seen FreeSpace::classify(const Eigen::Vector3i& min_voxel, int size_voxels, Look look,
                                    FootprintDepths* depths) const {
  const float voxel = map_.voxel_size_m;
  const Eigen::Vector3f lo_W =
      map_.origin_W + min_voxel.cast<float>() * voxel - Eigen::Vector3f::Constant(margin_m_);
  const float side = static_cast<float>(size_voxels) * voxel + 2.0f * margin_m_;
  float z_min = 1e30f;
  float z_max = -1e30f;
  // One transform, then the cube's edges in the camera frame (the columns of R_C_W scaled).
  Eigen::Vector3f corners_C[8];
  const Eigen::Vector3f base_C = R_C_W_ * lo_W + t_C_W_;
  const Eigen::Vector3f ex = R_C_W_.col(0) * side;
  const Eigen::Vector3f ey = R_C_W_.col(1) * side;
  const Eigen::Vector3f ez = R_C_W_.col(2) * side;
  for (int c = 0; c < 8; ++c) {
    Eigen::Vector3f p = base_C;
    if (c & 1) p += ex;
    if (c & 2) p += ey;
    if (c & 4) p += ez;
    corners_C[c] = p;
    z_min = std::min(z_min, p.z());
    z_max = std::max(z_max, p.z());
  }
  if (z_max <= config_.near_m) return Seen::not_seen;  // behind the camera
  // Wholly outside one side plane of the view frustum (planes through the camera centre, so
  // this holds for octants straddling the camera plane too).
  const float left = camera_.cx + 0.5f;
  const float right = camera_.cx - (static_cast<float>(width_) - 0.5f);
  const float top = camera_.cy + 0.5f;
  const float bottom = camera_.cy - (static_cast<float>(height_) - 0.5f);
  int out_left = 0;
  int out_right = 0;
  int out_top = 0;
  int out_bottom = 0;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3f& p = corners_C[c];
    out_left += camera_.fx * p.x() + left * p.z() < 0.0f ? 1 : 0;
    out_right += camera_.fx * p.x() + right * p.z() >= 0.0f ? 1 : 0;
    out_top += camera_.fy * p.y() + top * p.z() < 0.0f ? 1 : 0;
    out_bottom += camera_.fy * p.y() + bottom * p.z() >= 0.0f ? 1 : 0;
  }
  if (out_left == 8 || out_right == 8 || out_top == 8 || out_bottom == 8) return Seen::not_seen;
  // Straddles the camera plane: its projection is unbounded.
  if (z_min <= config_.near_m) return Seen::straddle;
  float u_min = 1e30f;
  float u_max = -1e30f;
  float v_min = 1e30f;
  float v_max = -1e30f;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector2f px = camera_.project(corners_C[c]);
    u_min = std::min(u_min, px.x());
    u_max = std::max(u_max, px.x());
    v_min = std::min(v_min, px.y());
    v_max = std::max(v_max, px.y());
  }
  // The projection of a convex body in front of the camera lies in the hull of its corners'.
  return classify_footprint(z_min, z_max, u_min, u_max, v_min, v_max, look, depths);
}

FreeSpace::Seen FreeSpace::classify_footprint(float z_min, float z_max, float u_min, float u_max,
                                              float v_min, float v_max, Look look,
                                              FootprintDepths* depths) const {
  const float w = static_cast<float>(width_);
  const float h = static_cast<float>(height_);
  if (u_max < -0.5f || v_max < -0.5f || u_min >= w - 0.5f || v_min >= h - 0.5f) {
    return Seen::not_seen;
  }
  // Pixel u covers [u - 0.5, u + 0.5); one more pixel on each side for the depth step between
  // neighbouring pixels.
  const Ints4 cells = clamped_floor4(Lanes4{u_min, u_max, v_min, v_max} + 0.5f);
  int u0 = cells[0] - 1;
  int u1 = cells[1] + 1;
  int v0 = cells[2] - 1;
  int v1 = cells[3] + 1;
  const bool inside = u0 >= 0 && v0 >= 0 && u1 < width_ && v1 < height_;
  u0 = std::max(u0, 0);
  v0 = std::max(v0, 0);
  u1 = std::min(u1, width_ - 1);
  v1 = std::min(v1, height_ - 1);
  // The footprint's pixels are merged exactly (the range table). Only the silhouette test reads
  // the tiles covering the footprint, at the finest pyramid level where they span at most
  // `tiles` x `tiles`, each exceeding the footprint by up to one tile on each side: 3 x 3 for
  // octants that descend anyway, up to 8 x 8 for leaves. The answers of leaves and of their
  // sub-cells are final (a partial one loses its free state); with exact_silhouettes, those left
  // partial by a window whose depths straddle the zone (a nearer object's silhouette, with depths
  // behind) are settled pixel by pixel (refine_footprint()).
  const float zone_lo = z_min - occlusion_clear_m_;
  const float zone_hi = z_max + clearance_m_;
  // Below level floor(log2(span)) - floor(log2(tiles)) the window spans more than `tiles` tiles
  // (floor(a / k) - floor(b / k) >= floor((a - b) / k)), so the search starts there.
  const int span = std::max(u1 - u0, v1 - v0);
  const int span_log2 = span > 0 ? floor_log2(static_cast<std::uint32_t>(span)) : 0;
  const int level_count = ranges_.level_count();
  auto window_level = [&](int tiles) {
    int level = std::max(
        0, std::min(span_log2 - floor_log2(static_cast<std::uint32_t>(tiles)), level_count - 1));
    while (level + 1 < level_count &&
           (((u1 >> level) - (u0 >> level)) >= tiles || ((v1 >> level) - (v0 >> level)) >= tiles)) {
      ++level;
    }
    return level;
  };
  // Leaves look for silhouettes at tiles of up to 8 x 8, the others at 3 x 3 (found only when
  // needed).
  int zone_level = -1;
  // The footprint's exact range decides, but for the silhouette test tile by tile.
  auto classify_range = [&](const PixelRange& range) {
    if (depths != nullptr) {
      depths->room_m = range.hi_m - z_min;
      depths->far_m = range.hi_m;
    }
    // Nothing measured in the footprint: this frame says nothing about the octant.
    if (range.lo_m >= kNoDepth) return Seen::not_seen;
    if (z_max < range.lo_m - clearance_m_) {
      // Every depth measured in the footprint lies beyond the octant: free when the footprint
      // is wholly measured, else nothing contradicts it but parts were not seen.
      return inside && !range.any_invalid ? Seen::free : Seen::clear;
    }
    // No surface measured in the footprint, only rays that went beyond the range: the part in
    // front of their end may be free (descend without clearing), the rest is not seen.
    if (range.hi_m <= 0.0f) return z_min < range.lo_m - clearance_m_ ? Seen::clear : Seen::not_seen;
    // Too far behind the farthest surface measured: not seen.
    if (z_min > range.hi_m + occlusion_clear_m_) return Seen::not_seen;
    if (z_min > range.hi_m) return Seen::occluded;
    // Some rays are blocked well in front of the octant (a nearer object's silhouette), the
    // others see through it, and no tile's depths could lie within it: nothing here contradicts
    // free space, but not all of it was seen.
    zone_level = window_level(look == Look::leaf ? 8 : 3);
    if (!ranges_.any_tile_in_zone(zone_level, u0, v0, u1, v1, zone_lo, zone_hi)) return Seen::clear;
    return Seen::partial;
  };
  const PixelRange range = ranges_.rect_range(u0, v0, u1, v1);
  const Seen seen = classify_range(range);
  if (look == Look::coarse) return seen;
  if (!config_.exact_silhouettes || seen != Seen::partial) return seen;
  // The window's nearest or farthest depth lies in the zone: a surface in or at the octant
  // (or just beside it, which only makes the answer cautious).
  const bool extreme_in_zone = (range.hi_m >= zone_lo && range.hi_m <= zone_hi) ||
                               (range.lo_m >= zone_lo && range.lo_m <= zone_hi);
  if (extreme_in_zone) return seen;
  // Depths in front of the zone and behind it: settled from tiles of up to 8 x 8, most of them
  // wholly inside the footprint.
  return refine_footprint(look == Look::leaf ? zone_level : window_level(8), u0, v0, u1, v1,
                          zone_lo, zone_hi, inside);
}

FreeSpace::Seen FreeSpace::refine_footprint(int level, int u0, int v0, int u1, int v1,
                                            float zone_lo, float zone_hi, bool inside) const {
  // Depth-first over the tiles covering pixels [u0, u1] x [v0, v1], splitting only those whose
  // range can neither be settled as seen through nor as holding a surface in the zone: the
  // silhouettes of nearer objects and the tiles overhanging the footprint, down to pixels.
  struct Tile {
    int level;
    int x;
    int y;
  };
  // At most 8 x 8 tiles to start (a window of up to 8), then 3 more per level.
  constexpr int kCapacity = 128;
  Tile stack[kCapacity];
  int top = 0;
  // First the tiles wholly inside the footprint: one whose farthest surface lies in the zone
  // settles it (a surface running through the view of the octant, the common case).
  const int w = ranges_.level_width(level);
  const float* level_max = ranges_.level_max(level);
  const int side = 1 << level;
  for (int y = v0 >> level; y <= (v1 >> level); ++y) {
    const bool rows_inside = y * side >= v0 && y * side + side - 1 <= v1;
    for (int x = u0 >> level; x <= (u1 >> level); ++x) {
      stack[top++] = Tile{level, x, y};
      if (!rows_inside || x * side < u0 || x * side + side - 1 > u1) continue;
      const float hi = level_max[static_cast<std::size_t>(y) * static_cast<std::size_t>(w) +
                                 static_cast<std::size_t>(x)];
      if (hi >= zone_lo && hi <= zone_hi && hi > 0.0f) return Seen::partial;
    }
  }
  bool any_through = false;
  bool all_through = true;
  bool invalid = false;
  while (top > 0) {
    const Tile t = stack[--top];
    const std::size_t i =
        static_cast<std::size_t>(t.y) * static_cast<std::size_t>(ranges_.level_width(t.level)) +
        static_cast<std::size_t>(t.x);
    const float lo = ranges_.level_min(t.level)[i];
    const float hi = ranges_.level_max(t.level)[i];
    const bool tile_invalid = ranges_.level_invalid(t.level)[i] != 0;
    // Every pixel measured and seeing through (a superset of the footprint's part is too).
    if (lo > zone_hi && !tile_invalid) {
      any_through = true;
      continue;
    }
    const int px0 = t.x << t.level;
    const int py0 = t.y << t.level;
    const int px1 = px0 + (1 << t.level) - 1;
    const int py1 = py0 + (1 << t.level) - 1;
    const bool whole = px0 >= u0 && py0 >= v0 && px1 <= u1 && py1 <= v1;
    // A surface (hi is the farthest measured surface) in the zone.
    if ((whole || t.level == 0) && hi >= zone_lo && hi <= zone_hi && hi > 0.0f) {
      return Seen::partial;
    }
    if (t.level == 0) {
      if (tile_invalid) {
        invalid = true;
      } else {
        all_through = false;  // blocked in front, or beyond the range but short of the zone
      }
      continue;
    }
    if (whole && (hi < zone_lo || (hi <= 0.0f && lo < zone_lo))) {
      // Surfaces only in front (or beyond-range rays ending in front): not all seen through.
      all_through = false;
      invalid = invalid || tile_invalid;
      continue;
    }
    if (top + 4 > kCapacity) return Seen::partial;  // cannot happen (see kCapacity); cautious
    for (int c = 0; c < 4; ++c) {
      const Tile child{t.level - 1, 2 * t.x + (c & 1), 2 * t.y + (c >> 1)};
      const int cx0 = child.x << child.level;
      const int cy0 = child.y << child.level;
      const int cx1 = cx0 + (1 << child.level) - 1;
      const int cy1 = cy0 + (1 << child.level) - 1;
      if (cx1 < u0 || cy1 < v0 || cx0 > u1 || cy0 > v1) continue;
      if (child.x >= ranges_.level_width(child.level) ||
          child.y >= ranges_.level_height(child.level)) {
        continue;
      }
      stack[top++] = child;
    }
  }
  if (any_through && all_through && !invalid && inside) return Seen::free;
  return any_through ? Seen::clear : Seen::not_seen;
}

bool FreeSpace::centre_seen_beyond(const Eigen::Vector3i& min_voxel, int size_voxels,
                                   float behind_m, float far_m) const {
  const float voxel = map_.voxel_size_m;
  const float half = 0.5f * static_cast<float>(size_voxels);
  const Eigen::Vector3f centre_W =
      map_.origin_W + (min_voxel.cast<float>() + Eigen::Vector3f::Constant(half)) * voxel;
  const Eigen::Vector3f centre_C = R_C_W_ * centre_W + t_C_W_;
  // At the camera plane the projection says nothing: it may.
  if (!(centre_C.z() > config_.near_m)) return true;
  // 1 mm of slack covers the rounding between these bounds and the classification's arithmetic.
  constexpr float kSlack_m = 1e-3f;
  const float least_free_m = centre_C.z() + behind_m + clearance_m_ - kSlack_m;
  if (std::max(far_m, beyond_free_m_) <= least_free_m) return false;
  // The centre's pixel: outside the image or without depth, no footprint holding it is wholly
  // measured.
  const Eigen::Vector2f px = camera_.project(centre_C);
  const int u = clamped_floor(px.x() + 0.5f);
  const int v = clamped_floor(px.y() + 0.5f);
  if (u < 0 || v < 0 || u >= width_ || v >= height_) return false;
  const std::size_t i =
      static_cast<std::size_t>(v) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(u);
  if (ranges_.level_invalid(0)[i] != 0) return false;
  return ranges_.level_min(0)[i] > least_free_m;
}

FreeSpace::SubCellUpdate FreeSpace::classify_sub_cells(
    const Eigen::Vector3i& leaf_min_voxel) const {
  SubCellUpdate update;
  constexpr int n = 2;
  const float voxel = map_.voxel_size_m;
  const float sub_side = static_cast<float>(sub_cell_voxels_) * voxel;
  // The sub-cells' corners on an (n + 1)^3 grid, each with the bounds of the projection of a
  // camera-axis-aligned box of half-side r around it. The grown sub-cell (margin_m on each side)
  // lies within r = margin * sqrt(3) of the sub-cell, and x/z is quasi-convex, so the bounds over
  // its 8 corners' boxes bound the grown sub-cell's projection.
  constexpr int kGrid = n + 1;
  constexpr int kPoints = kGrid * kGrid * kGrid;
  // Structure of arrays, so the bounds of all 27 points are computed in vector lanes.
  float px[kPoints];
  float py[kPoints];
  float pz[kPoints];
  const float r = margin_m_ * kSubCellGrowth;
  const Eigen::Vector3f lo_W = map_.origin_W + leaf_min_voxel.cast<float>() * voxel;
  const Eigen::Vector3f base_C = R_C_W_ * lo_W + t_C_W_;
  const Eigen::Vector3f sx = R_C_W_.col(0) * sub_side;
  const Eigen::Vector3f sy = R_C_W_.col(1) * sub_side;
  const Eigen::Vector3f sz = R_C_W_.col(2) * sub_side;
  for (int k = 0; k <= n; ++k) {
    for (int j = 0; j <= n; ++j) {
      for (int i = 0; i <= n; ++i) {
        const Eigen::Vector3f p = base_C + static_cast<float>(i) * sx + static_cast<float>(j) * sy +
                                  static_cast<float>(k) * sz;
        const int q = (k * kGrid + j) * kGrid + i;
        px[q] = p.x();
        py[q] = p.y();
        pz[q] = p.z();
      }
    }
  }
  // Per point, the bounds of the projection of a camera-axis-aligned box of half-side r around it;
  // points at the camera (not ok) get bounds too, unused.
  float z_lo[kPoints];
  float z_hi[kPoints];
  float u_lo[kPoints];
  float u_hi[kPoints];
  float v_lo[kPoints];
  float v_hi[kPoints];
  bool ok[kPoints];
  const float near_m = config_.near_m;
  const float fx = camera_.fx;
  const float fy = camera_.fy;
  const float cx = camera_.cx;
  const float cy = camera_.cy;
#pragma GCC unroll 1
  for (int q = 0; q < kPoints; ++q) {
    z_lo[q] = pz[q] - r;
    z_hi[q] = pz[q] + r;
    ok[q] = z_lo[q] > near_m;
    const float near_inv = 1.0f / z_lo[q];
    const float far_inv = 1.0f / z_hi[q];
    const float x_hi = px[q] + r;
    const float x_lo = px[q] - r;
    const float y_hi = py[q] + r;
    const float y_lo = py[q] - r;
    u_hi[q] = fx * x_hi * (x_hi >= 0.0f ? near_inv : far_inv) + cx;
    u_lo[q] = fx * x_lo * (x_lo >= 0.0f ? far_inv : near_inv) + cx;
    v_hi[q] = fy * y_hi * (y_hi >= 0.0f ? near_inv : far_inv) + cy;
    v_lo[q] = fy * y_lo * (y_lo >= 0.0f ? far_inv : near_inv) + cy;
  }
  // Each sub-cell's bounds over its 8 corners, reduced one axis at a time (x, then y, then z):
  // the same minima and maxima as corner by corner, in fewer comparisons.
  struct Bounds {
    float z_lo, z_hi, u_lo, u_hi, v_lo, v_hi;
    bool ok;
  };
  auto merge = [](const Bounds& a, const Bounds& b) {
    return Bounds{std::min(a.z_lo, b.z_lo),
                  std::max(a.z_hi, b.z_hi),
                  std::min(a.u_lo, b.u_lo),
                  std::max(a.u_hi, b.u_hi),
                  std::min(a.v_lo, b.v_lo),
                  std::max(a.v_hi, b.v_hi),
                  a.ok && b.ok};
  };
  auto point = [&](int q) {
    return Bounds{z_lo[q], z_hi[q], u_lo[q], u_hi[q], v_lo[q], v_hi[q], ok[q]};
  };
  Bounds along_x[kGrid][kGrid][n];  // [k][j][i]: points i and i + 1
  for (int k = 0; k <= n; ++k) {
    for (int j = 0; j <= n; ++j) {
      for (int i = 0; i < n; ++i) {
        const int q = (k * kGrid + j) * kGrid + i;
        along_x[k][j][i] = merge(point(q), point(q + 1));
      }
    }
  }
  Bounds along_xy[kGrid][n][n];
  for (int k = 0; k <= n; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) along_xy[k][j][i] = merge(along_x[k][j][i], along_x[k][j + 1][i]);
    }
  }
  for (int k = 0; k < n; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const Bounds b = merge(along_xy[k][j][i], along_xy[k + 1][j][i]);
        const bool cell_ok = b.ok;
        const float z_min = b.z_lo;
        const float z_max = b.z_hi;
        const float u_min = b.u_lo;
        const float u_max = b.u_hi;
        const float v_min = b.v_lo;
        const float v_max = b.v_hi;
        // At the camera: nothing measurable is that close; the sub-cell keeps its state.
        if (!cell_ok) continue;
        const auto bit = static_cast<std::uint8_t>(1u << ((k * n + j) * n + i));
        switch (
            classify_footprint(z_min, z_max, u_min, u_max, v_min, v_max, Look::sub_cell, nullptr)) {
          case Seen::free:
            update.set = static_cast<std::uint8_t>(update.set | bit);
            break;
          case Seen::partial:
          case Seen::occluded:
            update.clear = static_cast<std::uint8_t>(update.clear | bit);
            break;
          default:
            break;
        }
      }
    }
  }
  return update;
}

FreeSpaceReport FreeSpace::carve(ImageView<const float> depth_m, const PinholeCamera& camera,
                                 const Se3d& T_W_C, std::uint32_t frame,
                                 ImageView<const std::uint8_t> beyond_range, float beyond_free_m) {
  FreeSpaceReport report;
  if (!reserved() || depth_m.width != width_ || depth_m.height != height_) return report;
  if (!beyond_range.empty() && (beyond_range.width != width_ || beyond_range.height != height_ ||
                                !(beyond_free_m > 0.0f && beyond_free_m < kNoDepth))) {
    beyond_range = ImageView<const std::uint8_t>();
  }
  ranges_.build(depth_m, beyond_range, beyond_free_m);
  beyond_free_m_ = beyond_range.empty() ? 0.0f : beyond_free_m;
  const Se3f T_C_W = T_W_C.inverse().cast<float>();
  R_C_W_ = T_C_W.linear();
  t_C_W_ = T_C_W.translation();
  camera_ = camera;
  const Eigen::Vector3f camera_voxel =
      (T_W_C.translation().cast<float>() - map_.origin_W) / map_.voxel_size_m;
  for (int a = 0; a < 3; ++a) camera_voxel_[a] = clamped_floor(camera_voxel[a]);

  // When the pool's room may be short of what this frame carves, a first walk counts the nodes
  // it would make by distance from the camera, and the frame makes only those within the largest
  // distance whose nodes fit: the farthest air is what a small pool does without.
  // A frame makes at most max_new_nodes nodes: with that much room, one walk.
  const std::uint32_t room = nodes_.capacity() - nodes_.used();
  std::uint32_t bands = kDistanceBands;
  if (room < config_.max_new_nodes) {
    std::uint32_t histogram[kDistanceBands] = {};
    FreeSpaceReport count;
    walk(frame, /*counting=*/true, kDistanceBands, count, histogram);
    std::uint64_t total = 0;
    for (std::uint32_t b = 0; b < kDistanceBands; ++b) {
      if (total + histogram[b] > room) {
        bands = b;
        break;
      }
      total += histogram[b];
    }
  }
  walk(frame, /*counting=*/false, bands, report, nullptr);
  report.nodes_used = nodes_.used();
  report.bytes_used = bytes_used();
  return report;
}

std::uint32_t FreeSpace::distance_band(const Eigen::Vector3i& min_voxel, int size) const {
  // Squared distance in voxels from the camera's voxel to the nearest voxel of the octant.
  std::int64_t d2 = 0;
  for (int a = 0; a < 3; ++a) {
    const std::int64_t lo = min_voxel[a];
    const std::int64_t hi = lo + size - 1;
    const std::int64_t c = camera_voxel_[a];
    const std::int64_t d = c < lo ? lo - c : c > hi ? c - hi : 0;
    d2 += d * d;
  }
  const double band = std::sqrt(static_cast<double>(d2)) / config_.finest_octant_voxels;
  return band >= kDistanceBands - 1 ? kDistanceBands - 1 : static_cast<std::uint32_t>(band);
}

void FreeSpace::walk(std::uint32_t frame, bool counting, std::uint32_t bands,
                     FreeSpaceReport& report, std::uint32_t* histogram) {
  // Counting: nothing is written; a node the walk would make gets kVirtual, whose state is empty
  // and whose children do not exist (so the count may exceed what the frame makes, never fall
  // short of it).
  constexpr std::uint32_t kVirtual = kNoNode - 1;
  struct Entry {
    std::uint32_t node;
    std::uint32_t parent;
    std::uint8_t slot;
    std::uint8_t level;
    Eigen::Vector3i min_voxel;
  };
  Entry stack[kStackCapacity];
  int top = 0;
  stack[top++] = Entry{0, kNoNode, 0, 0, Eigen::Vector3i::Zero()};
  const int depth = map_.voxel_depth;
  const int leaf = leaf_level();
  auto real = [](std::uint32_t index) { return index < kVirtual; };

  // The octant at `min_voxel` of side `size` (child `slot` of `parent`).
  auto allocate_child = [&](std::uint32_t parent, int slot, const Eigen::Vector3i& min_voxel,
                            int size) -> std::uint32_t {
    if (report.new_nodes >= config_.max_new_nodes) {
      ++report.refused;
      report.budget_hit = true;
      return kNoNode;
    }
    const std::uint32_t band = distance_band(min_voxel, size);
    if (counting) {
      ++histogram[band];
      ++report.new_nodes;
      return kVirtual;
    }
    if (band >= bands) {
      ++report.far_dropped;
      return kNoNode;
    }
    if (!real(parent)) return kNoNode;
    const Result<std::uint32_t> fresh = nodes_.allocate();
    if (!fresh.ok()) {
      ++report.refused;
      ++report.pool_refused;
      return kNoNode;
    }
    ++report.new_nodes;
    nodes_[parent].children[slot] = fresh.value();
    return fresh.value();
  };

  while (top > 0) {
    const Entry e = stack[--top];
    if (report.node_visits >= config_.max_node_visits) {
      report.budget_hit = true;
      break;
    }
    ++report.node_visits;
    // Counting: a leaf that exists makes no node whatever the frame shows in it (only its state
    // would change), so it is not classified.
    if (counting && e.level == leaf && real(e.node)) continue;
    // A leaf not in the tree changes only if it or one of its sub-cells is seen free, which needs
    // the pixel its centre projects to (in every such footprint) measured beyond the centre.
    if (!exhaustive_ && e.level == leaf && !real(e.node) &&
        !centre_seen_beyond(e.min_voxel, 1 << (depth - e.level), 0.0f, kNoDepth)) {
      ++report.looks_skipped;
      continue;
    }
    const int size = 1 << (depth - e.level);
    FootprintDepths depths;
    const Seen seen =
        classify(e.min_voxel, size, e.level == leaf ? Look::leaf : Look::coarse, &depths);
    if (seen == Seen::not_seen) continue;
    std::uint32_t index = e.node;
    if (seen == Seen::clear) {
      // Nothing seen in it, only parts unmeasured (invalid pixels, the image border): a free
      // octant stays free; elsewhere the parts wholly in view may be free.
      if (real(index) && nodes_[index].free_count > 0) continue;
    }
    if (seen == Seen::free) {
      if (index == kNoNode) index = allocate_child(e.parent, e.slot, e.min_voxel, size);
      if (counting || !real(index)) continue;
      FreeNode& n = nodes_[index];
      n.free_count = static_cast<std::uint8_t>(
          std::min<int>(n.free_count + 1, static_cast<int>(config_.max_free_count)));
      n.free_frame = frame;
      ++report.marked_free;
      continue;
    }
    // Partly seen: what this frame shows inside decides each part.
    if (e.level == leaf) {
      // A leaf at the camera: nothing measurable is that close, so nothing clears it.
      if (seen == Seen::straddle) continue;
      const std::uint8_t before = !real(index)                   ? 0
                                  : nodes_[index].free_count > 0 ? kAllSubCells
                                                                 : nodes_[index].sub_free;
      // A leaf with no free half only gains from the closer look, so it takes it every other
      // frame, leaves alternating like a checkerboard (half the cost; marking free waits a
      // frame, clearing never does).
      const int leaf_index = (e.min_voxel.x() + e.min_voxel.y() + e.min_voxel.z()) / size;
      const bool gain_only = before == 0 && seen != Seen::occluded;
      SubCellUpdate update;
      // Occluded wholly, or no measured depth lies beyond its nearest point by more than the
      // clearance (so no half of it can be free): cleared without a closer look.
      if (seen == Seen::occluded || (seen == Seen::partial && depths.room_m <= clearance_m_)) {
        update.clear = kAllSubCells;
      } else if (gain_only && ((static_cast<std::uint32_t>(leaf_index) + frame) & 1u) != 0) {
        continue;
      } else if (!exhaustive_ && gain_only &&
                 !centre_seen_beyond(e.min_voxel, size, margin_m_ * kSubCellGrowth, depths.far_m)) {
        // Only a free sub-cell would change it, and none can be: the closer look would find
        // nothing (the same answer, without projecting the 27 grid points).
        ++report.looks_skipped;
        continue;
      } else {
        update = classify_sub_cells(e.min_voxel);
      }
      const auto after = static_cast<std::uint8_t>((before & ~update.clear) | update.set);
      if (index == kNoNode && after != 0) {
        index = allocate_child(e.parent, e.slot, e.min_voxel, size);
      }
      if (counting || !real(index)) continue;
      FreeNode& n = nodes_[index];
      if ((before & ~after) != 0) ++report.cleared;
      if (update.set != 0) {
        n.free_frame = frame;
        ++report.marked_free;
      }
      if (after == kAllSubCells) {
        n.free_count = static_cast<std::uint8_t>(std::max<int>(n.free_count, 1));
        n.sub_free = 0;
      } else {
        n.free_count = 0;
        n.sub_free = after;
      }
      continue;
    }
    // Occluded: nothing recorded below means nothing to clear.
    if (!real(index) && seen == Seen::occluded) continue;
    if (index == kNoNode) index = allocate_child(e.parent, e.slot, e.min_voxel, size);
    if (index == kNoNode) continue;
    const int half = size / 2;
    std::uint32_t children[8];
    for (int c = 0; c < 8; ++c) children[c] = real(index) ? nodes_[index].children[c] : kNoNode;
    if (real(index) && nodes_[index].free_count > 0) {
      const std::uint8_t count = nodes_[index].free_count;
      const std::uint32_t when = nodes_[index].free_frame;
      for (int c = 0; c < 8; ++c) {
        if (children[c] == kNoNode) {
          children[c] = allocate_child(index, c, child_min_voxel(e.min_voxel, c, half), half);
        }
        // Refused or beyond the distance the pool allows: that part loses its free state (never
        // wrongly free).
        if (counting || !real(children[c])) continue;
        FreeNode& k = nodes_[children[c]];
        if (k.free_count == 0 || k.free_frame < when) {
          k.free_count = count;
          k.free_frame = when;
        }
      }
      if (!counting) {
        nodes_[index].free_count = 0;
        ++report.cleared;
      }
    }
    for (int c = 7; c >= 0; --c) {
      const std::uint32_t child = children[c];
      if (seen == Seen::occluded && child == kNoNode) continue;
      stack[top++] =
          Entry{child, index, static_cast<std::uint8_t>(c), static_cast<std::uint8_t>(e.level + 1),
                child_min_voxel(e.min_voxel, c, half)};
    }
  }
}

}  // namespace octofuse
