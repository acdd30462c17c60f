#include "octofuse/fusion/integrator.hpp"

#include <algorithm>
#include <cmath>
#include <type_traits>

#include "octofuse/core/lanes.hpp"
#include "octofuse/map/detail/mip.hpp"
#include "octofuse/map/detail/propagation.hpp"

namespace octofuse {

using fusion_internal::FrameBlock;
using fusion_internal::FrameSetEntry;
using fusion_internal::kSeenCacheLog2;
using fusion_internal::kSeenCacheSize;
using fusion_internal::TaskTally;

// Everything the per-block kernel needs, in float, fixed for the frame.
template <typename VoxelT>
struct Integrator<VoxelT>::Frame {
  const float* depth = nullptr;
  std::ptrdiff_t stride = 0;
  int width = 0;
  int height = 0;
  float fx = 0, fy = 0, cx = 0, cy = 0;
  Eigen::Matrix3f R_C_W;
  Eigen::Vector3f t_C_W;
  Eigen::Matrix3f R_W_C;
  Eigen::Vector3f t_W_C;
  Eigen::Vector3f origin_W;
  float voxel_size_m = 0;
  float mu_m = 0;
  float inv_mu = 0;
  // Per scale, how far behind the measured depth a voxel is still updated: behind_mu * mu, or
  // kMinBehind_voxels of the scale where that is more.
  float behind_m[kMaxBlockScale + 1] = {};
  float near_m = 0;
  float far_m = 0;
  float y_max = 0;
  // Coarsest scale any block integrates at this frame: up-propagation stops there (paper 4.3.2).
  int mip_target = 0;
};

namespace {

constexpr std::size_t kPrefetchDistance = 8;
// At coarse scales mu can be as thin as a voxel or two. The trilinear cell around a zero crossing
// then often reaches a voxel behind the surface that no update reached, and the ray-cast cannot
// sample the crossing. Voxels are updated (to -1 past mu) at least this many voxels of their scale
// behind the measured depth: a cell's corners lie up to sqrt(3) voxels from the surface, more
// along an oblique ray. More voxels closed a few more holes but ate into thin parts behind the
// surface. At the default mu of 8 voxels this changes nothing below scale 2.
constexpr float kMinBehind_voxels = 2.5f;
// Hash slots and block headers are loaded this many list entries ahead.
constexpr std::size_t kLookAhead = 16;

// Fibonacci hashing: the top `bits` bits of the product depend on every bit of the key (packed
// coordinates put z in the high bits, which the low bits of a product never see).
std::size_t hash_key(std::uint64_t key, int bits) {
  return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ull) >> (64 - bits));
}

bool pose_ok(const Se3d& T) {
  return T.matrix().allFinite() && is_rigid(T.matrix(), 1e-3);
}

// One row of at most kBlockSide voxels (x fastest) projected into the depth image. The projection
// is done for all lanes in straight-line code the compiler vectorises; the depth reads and the
// updates that depend on them follow lane by lane. Each lane computes exactly what a voxel-by-voxel
// loop would, so the bits do not depend on the vectorisation.
struct RowProjection {
  float z_m[kBlockSide];        // camera-frame depth of the voxel centre
  float ray_scale[kBlockSide];  // |ray| per unit of z: depth differences to distances along the ray
  int pixel[kBlockSide];  // the pixel's index in the depth image (v * stride + u), -1 when outside
};

// Lane k's voxel centre in the camera frame is start + (offset_x[k], offset_y[k], offset_z[k]).
inline void project_row(float start_x, float start_y, float start_z,
                        const float (&offset_x)[kBlockSide], const float (&offset_y)[kBlockSide],
                        const float (&offset_z)[kBlockSide], float fx, float fy, float cx, float cy,
                        float u_end, float v_end, int stride, RowProjection& out) {
  const float stride_f = static_cast<float>(stride);
  // Kept a loop (not unrolled first), so the loop vectoriser takes it whole.
#pragma GCC unroll 1
  for (int k = 0; k < kBlockSide; ++k) {
    const float z = start_z + offset_z[k];
    const float inv_z = 1.0f / z;  // inf or negative lanes are masked below
    const float xn = (start_x + offset_x[k]) * inv_z;
    const float yn = (start_y + offset_y[k]) * inv_z;
    const float u = fx * xn + cx;
    const float w = fy * yn + cy;
    // Bitwise, not short-circuit: no branch in the loop. Also false for NaN.
    const bool inside = (z > 0.0f) & (u >= -0.5f) & (w >= -0.5f) & (u < u_end) & (w < v_end);
    // Round to the nearest pixel; masked lanes convert 0, never an out-of-range float.
    const float u_round = u + 0.5f;
    const float v_round = w + 0.5f;
    const float u_px = inside ? u_round : 0.0f;
    const float v_px = inside ? v_round : 0.0f;
    // v * stride + u in float: SSE2 has no 32-bit integer multiply. Exact, as the integer sum
    // is, while rows x stride is at most kMaxImageSpan_px (2^24; reserve and check_inputs check).
    const float index = static_cast<float>(static_cast<int>(v_px)) * stride_f +
                        static_cast<float>(static_cast<int>(u_px));
    out.pixel[k] = inside ? static_cast<int>(index) : -1;
    out.z_m[k] = z;
    out.ray_scale[k] = std::sqrt(1.0f + xn * xn + yn * yn);
  }
}

// The TSDF update of one voxel (eq. 2-3) from the measured depth at its pixel; false when the
// sample does not apply. The band ends behind_m behind the surface; kPastMu: behind_m > mu, and
// past mu the truncated distance is -1.
template <bool kPastMu, typename VoxelT>
inline bool update_voxel(VoxelT& v, float measured_m, float z_m, float ray_scale, float near_m,
                         float far_m, float mu_m, float inv_mu, float behind_m, float y_max) {
  if (!(measured_m >= near_m && measured_m <= far_m)) return false;
  const float d = (measured_m - z_m) * ray_scale;
  float f = 0.0f;
  if constexpr (kPastMu) {
    if (d < -behind_m) return false;
    f = d < -mu_m ? -1.0f : std::min(1.0f, d * inv_mu);
  } else {
    if (d < -behind_m) return false;
    f = std::min(1.0f, d * inv_mu);
  }
  if constexpr (IsMultiresVoxel<VoxelT>::value) {
    const float x = voxel_tsdf(v);
    const float y = voxel_weight(v);
    set_voxel_tsdf(v, std::clamp((y * x + f) / (y + 1.0f), -1.0f, 1.0f));
    // y = min(y_max, y + 1), delta_y += 1: only for applied updates (a reference counted
    // rejected ones too).
    count_voxel_sample(v, y_max);
  } else {
    v.tsdf = std::clamp((v.weight * v.tsdf + f) / (v.weight + 1.0f), -1.0f, 1.0f);
    v.weight = std::min(y_max, v.weight + 1.0f);
  }
  return true;
}

// Step 4's list entries: a block's pool index above its scale (the low 8 bits), so sorting the
// entries sorts by block index.
std::uint64_t pool_entry(std::uint32_t block, int scale) {
  return (std::uint64_t{block} << 8) | static_cast<std::uint8_t>(scale);
}
std::uint32_t pool_entry_block(std::uint64_t entry) {
  return static_cast<std::uint32_t>(entry >> 8);
}
int pool_entry_scale(std::uint64_t entry) {
  return static_cast<int>(entry & 0xFF);
}

// Sorts `count` entries of `keys` by their bits from 8 up (a block index below `index_bound`),
// with `scratch` as the second buffer (LSD radix, 11 bits a pass); returns the buffer holding the
// result.
const std::uint64_t* sort_by_block(std::uint64_t* keys, std::uint64_t* scratch, std::size_t count,
                                   std::uint32_t index_bound) {
  constexpr int kDigitBits = 11;
  constexpr std::size_t kDigits = std::size_t{1} << kDigitBits;
  int index_bits = 0;
  while (index_bits < 32 && (std::uint64_t{1} << index_bits) < index_bound) ++index_bits;
  std::uint64_t* from = keys;
  std::uint64_t* to = scratch;
  for (int shift = 8; shift < 8 + index_bits && count > 1; shift += kDigitBits) {
    std::uint32_t offsets[kDigits] = {};
    for (std::size_t i = 0; i < count; ++i) ++offsets[(from[i] >> shift) & (kDigits - 1)];
    std::uint32_t sum = 0;
    for (std::size_t d = 0; d < kDigits; ++d) {
      const std::uint32_t n = offsets[d];
      offsets[d] = sum;
      sum += n;
    }
    for (std::size_t i = 0; i < count; ++i) {
      to[offsets[(from[i] >> shift) & (kDigits - 1)]++] = from[i];
    }
    std::uint64_t* swap = from;
    from = to;
    to = swap;
  }
  return from;
}

}  // namespace

template <typename VoxelT>
void Integrator<VoxelT>::integrate_block(VoxelBlock<VoxelT>& block, int scale, const Frame& f,
                                         TaskTally& tally) {
  if constexpr (kMultires) {
    if (block.integrated()) {
      const int previous = block.current_scale;
      if (scale < previous) {
        ++tally.refined;
        for (int l = previous; l > scale; --l) propagate_block_down(block, l, f.y_max);
      } else if (scale > previous) {
        ++tally.coarsened;
        // Lazy up-propagation may have left the target level stale: refresh it first.
        if (block.mip_scale < scale) propagate_block_up(block, block.mip_scale, scale);
      }
    }
  }
  const int n = block_scale_side(scale);
  const float vs = f.voxel_size_m * static_cast<float>(1 << scale);
  const float behind_m = f.behind_m[scale];
  const Eigen::Vector3f first_W = f.origin_W +
                                  block.coords.template cast<float>() * (8.0f * f.voxel_size_m) +
                                  Eigen::Vector3f::Constant(0.5f * vs);
  const Eigen::Vector3f base_C = f.R_C_W * first_W + f.t_C_W;
  const Eigen::Vector3f dx = f.R_C_W.col(0) * vs;
  const Eigen::Vector3f dy = f.R_C_W.col(1) * vs;
  const Eigen::Vector3f dz = f.R_C_W.col(2) * vs;
  std::uint32_t updated = 0;
  float lo = 1.0f;
  float hi = -1.0f;
  float sum = 0.0f;
  float sum_weight = 0.0f;
  int observed = 0;
  // Multires: the first up-propagation step (eq. 4) is summed while the voxels are visited.
  // Children reach their parent in the order propagate_block_up adds them (x fastest, then y,
  // z), so the parents get the same bits without a second pass over the level.
  const int target = kMultires && f.mip_target > scale ? f.mip_target : scale;
  const int pn = n >> 1;
  constexpr int kMaxParents = block_scale_count(1);
  float lift_sum[kMaxParents];
  float lift_weight[kMaxParents];
  int lift_count[kMaxParents];
  // voxels: the level's, finest_begin() at scale 0 (a type of its own: FinestVoxelT).
  auto visit = [&](auto lift_tag, auto past_mu_tag, auto scale0_tag, auto* const voxels) {
    constexpr bool kLift = decltype(lift_tag)::value;
    constexpr bool kPastMu = decltype(past_mu_tag)::value;
    constexpr bool kScale0 = decltype(scale0_tag)::value;
    if constexpr (kLift) {
      for (int k = 0; k < pn * pn * pn; ++k) {
        lift_sum[k] = 0.0f;
        lift_weight[k] = 0.0f;
        lift_count[k] = 0;
      }
    }
    int i = 0;
    const float u_end = static_cast<float>(f.width) - 0.5f;
    const float v_end = static_cast<float>(f.height) - 0.5f;
    // The frame's constants in locals: the voxel stores are floats, which could alias f's floats,
    // so read through f they are loaded again for every voxel.
    const float* const depth = f.depth;
    const int pixel_stride = static_cast<int>(f.stride);
    const float fx = f.fx;
    const float fy = f.fy;
    const float cx = f.cx;
    const float cy = f.cy;
    const float near_m = f.near_m;
    const float far_m = f.far_m;
    const float mu_m = f.mu_m;
    const float inv_mu = f.inv_mu;
    const float y_max = f.y_max;
    // Voxel i (the next in index order, x fastest) at (x, y, z) of its level, from lane k of a
    // projection.
    auto visit_voxel = [&](const RowProjection& row, int k, int x, int y, int z) {
      auto& v = voxels[i++];
      // An updated voxel is observed (its weight is at least 1: FusionConfig validates
      // y_max >= 1), so only the others test their weight.
      if (row.pixel[k] >= 0 &&
          update_voxel<kPastMu>(v, depth[row.pixel[k]], row.z_m[k], row.ray_scale[k], near_m, far_m,
                                mu_m, inv_mu, behind_m, y_max)) {
        ++updated;
      } else if (!voxel_observed(v)) {
        return;
      }
      const float t = voxel_tsdf(v);
      lo = std::min(lo, t);
      hi = std::max(hi, t);
      sum += t;
      sum_weight += voxel_weight(v);
      ++observed;
      if constexpr (kLift) {
        const int parent = (x >> 1) + (y >> 1) * pn + (z >> 1) * pn * pn;
        lift_sum[parent] += t;
        lift_weight[parent] += voxel_weight(v);
        ++lift_count[parent];
      }
    };
    // Voxel centres: a row's start plus the voxel's offset along the row (x dx, computed once per
    // block), added inside the vectorised projection, not stepped voxel by voxel.
    float offset_x[kBlockSide];
    float offset_y[kBlockSide];
    float offset_z[kBlockSide];
    for (int x = 0; x < kBlockSide; ++x) {
      offset_x[x] = static_cast<float>(x) * dx.x();
      offset_y[x] = static_cast<float>(x) * dx.y();
      offset_z[x] = static_cast<float>(x) * dx.z();
    }
    if constexpr (kScale0) {
      // Scale 0: one row per projection.
      for (int z = 0; z < n; ++z) {
        for (int y = 0; y < n; ++y) {
          const Eigen::Vector3f start_C =
              base_C + static_cast<float>(y) * dy + static_cast<float>(z) * dz;
          RowProjection row;
          project_row(start_C.x(), start_C.y(), start_C.z(), offset_x, offset_y, offset_z, fx, fy,
                      cx, cy, u_end, v_end, pixel_stride, row);
          for (int x = 0; x < n; ++x) visit_voxel(row, x, x, y, z);
        }
      }
    } else {
      // Coarser levels: kBlockSide / n rows per projection (scale 1: two, scale 2: the whole
      // block), not one row with lanes to spare. Scale 3 projects its one voxel and repeats it in
      // the unused lanes.
      const int rows_per_projection = std::min(kBlockSide / n, n * n);
      for (int first_row = 0; first_row < n * n; first_row += rows_per_projection) {
        float x_C[kBlockSide];
        float y_C[kBlockSide];
        float z_C[kBlockSide];
        for (int r = 0; r < rows_per_projection; ++r) {
          const int y = (first_row + r) % n;
          const int z = (first_row + r) / n;
          const Eigen::Vector3f start_C =
              base_C + static_cast<float>(y) * dy + static_cast<float>(z) * dz;
          for (int x = 0; x < n; ++x) {
            x_C[r * n + x] = start_C.x() + offset_x[x];
            y_C[r * n + x] = start_C.y() + offset_y[x];
            z_C[r * n + x] = start_C.z() + offset_z[x];
          }
        }
        for (int k = n * rows_per_projection; k < kBlockSide; ++k) {
          x_C[k] = x_C[0];
          y_C[k] = y_C[0];
          z_C[k] = z_C[0];
        }
        RowProjection row;
        // The lanes hold whole centres: a start of 0 adds nothing (0 + -0 is +0, which projects
        // the same).
        project_row(0.0f, 0.0f, 0.0f, x_C, y_C, z_C, fx, fy, cx, cy, u_end, v_end, pixel_stride,
                    row);
        for (int r = 0; r < rows_per_projection; ++r) {
          const int y = (first_row + r) % n;
          const int z = (first_row + r) / n;
          for (int x = 0; x < n; ++x) visit_voxel(row, r * n + x, x, y, z);
        }
      }
    }
  };
  // The band's far side as a compile-time choice: up to mu (always at 1 cm) the loop is the plain
  // one.
  auto visit_band = [&](auto lift_tag) {
    // Scale 0 and the coarser levels' loop shapes each in an instantiation of their own: in one
    // function the packing cost scale 0 4-8 % more instructions.
    auto visit_shape = [&](auto past_mu_tag) {
      if (n == kBlockSide) {
        visit(lift_tag, past_mu_tag, std::true_type{}, block.finest_begin());
      } else {
        visit(lift_tag, past_mu_tag, std::false_type{}, block.level_begin(scale));
      }
    };
    if (behind_m > f.mu_m) {
      visit_shape(std::true_type{});
    } else {
      visit_shape(std::false_type{});
    }
  };
  if constexpr (kMultires) {
    if (target > scale) {
      visit_band(std::true_type{});
      VoxelT* parents = block.level_begin(scale + 1);
      for (int k = 0; k < pn * pn * pn; ++k) {
        if (lift_count[k] == 0) continue;  // no observed child: the parent keeps its value
        const float count = static_cast<float>(lift_count[k]);
        set_parent_from_children(parents[k], lift_sum[k] / count,
                                 std::ceil(lift_weight[k] / count));
      }
      if (target > scale + 1) propagate_block_up(block, scale + 1, target);
    } else {
      visit_band(std::false_type{});
    }
    block.mip_scale = static_cast<std::int8_t>(target);
  } else {
    visit_band(std::false_type{});
    block.mip_scale = 0;  // single-res blocks keep scale 0 only
  }
  if (observed > 0) {
    block.tsdf_mean = sum / static_cast<float>(observed);
    block.weight_mean = std::ceil(sum_weight / static_cast<float>(observed));
  }
  block.tsdf_min = lo;
  block.tsdf_max = hi;
  block.current_scale = static_cast<std::int8_t>(scale);
  if (!block.integrated() || scale < block.min_scale) {
    block.min_scale = static_cast<std::int8_t>(scale);
  }
  tally.voxels_updated += updated;
  ++tally.blocks_per_scale[scale];
}

template <typename VoxelT>
bool Integrator<VoxelT>::insert_frame_block(std::uint64_t key, const Eigen::Vector3i& coords,
                                            IntegrationReport& report) {
  std::size_t slot = hash_key(key, set_bits_);
  while (true) {
    FrameSetEntry& e = set_[slot];
    if (e.stamp != stamp_) break;
    if (e.key == key) return false;
    slot = (slot + 1) & set_mask_;
  }
  if (frame_block_count_ >= config_.max_blocks_per_frame) {
    ++report.keys_dropped;
    return false;
  }
  set_[slot].key = key;
  set_[slot].stamp = stamp_;
  FrameBlock& b = frame_blocks_[frame_block_count_++];
  b = FrameBlock();
  b.coords = coords;
  b.morton = morton_encode(coords);
  return true;
}

namespace {

// Block coordinates (each in [0, 2^21)) packed into one word: a cheap exact key for de-duplicating
// cells, unlike the Morton code, which is only computed once per distinct block.
constexpr std::uint64_t kCellMask = (std::uint64_t{1} << 21) - 1;
inline std::uint64_t pack_cell(int x, int y, int z) {
  return static_cast<std::uint64_t>(x) | (static_cast<std::uint64_t>(y) << 21) |
         (static_cast<std::uint64_t>(z) << 42);
}

// Slot of a packed cell in the small seen-cell cache.
inline std::size_t seen_slot(std::uint64_t key) {
  return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ull) >> (64 - kSeenCacheLog2));
}

// Ray-march geometry, in block units of the cube, fixed for the frame.
struct MarchSetup {
  // The camera centre and the columns of M, the world direction of the ray through pixel (u, v)
  // with unit camera z being M * ((u - cx) / fx, (v - cy) / fy, 1): in 4-lane vectors (the fourth
  // lane 0), each lane computing its component as scalar code would.
  Lanes4 centre_B;
  Lanes4 M_col[3];
  float inv_fx = 0;
  float inv_fy = 0;
  int side_blocks = 0;
  int step = 1;
  // > 0: the marched pixels go in 2 x 2 groups, and a group's other rays are skipped where its
  // first ray's depth is at most this (a block spans enough pixels there that a ray a step over
  // crosses the same blocks, nearly always) and their depths lie within `group_depth_gap_m` of it.
  float group_max_depth_m = 0.0f;
  float group_depth_gap_m = 0.0f;
};

// What one ray's march did.
enum class RayMarch { done, skipped, no_room };

// Marches pixel (u, v)'s ray over the band depth +- mu and emits each block cell inside the cube
// that `seen` (a direct-mapped cache of cells emitted recently) does not hold. room(n) says whether
// n more cells can be taken; no_room when the ray might not fit (nothing emitted). Cells outside
// the cube and far-off rays add to `outside`.
template <typename FrameT, typename Room, typename Emit>
inline RayMarch march_ray(const FrameT& f, const MarchSetup& m, int u, float depth, float yn2_1,
                          Lanes4 row_dir, std::uint64_t* seen, std::uint32_t& outside,
                          std::uint32_t& rays, Room& room, Emit& emit) {
  if (!(depth >= f.near_m && depth <= f.far_m)) return RayMarch::skipped;
  const float xn = (static_cast<float>(u) - f.cx) * m.inv_fx;
  const Lanes4 dir = row_dir + m.M_col[0] * xn;
  // The band +- mu along the ray is +- mu/|ray| in camera z.
  const float half_band_z = f.mu_m / std::sqrt(xn * xn + yn2_1);
  const Lanes4 a = m.centre_B + dir * (depth - half_band_z);
  const Lanes4 b = m.centre_B + dir * (depth + half_band_z);
  // Far outside the cube (a wild pose, NaN): skip before float-to-int conversions can overflow.
  // A comparison gives -1 in a true lane; the fourth lanes are 0.
  constexpr float kLimit = static_cast<float>(1 << 22);
  const Ints4 within = (a < kLimit) & (a > -kLimit) & (b < kLimit) & (b > -kLimit);
  if ((within[0] & within[1] & within[2]) == 0) {
    ++outside;
    return RayMarch::skipped;
  }
  // Amanatides-Woo traversal of the block grid from a to b.
  const Lanes4 d = b - a;
  const Ints4 a_cell = floor_lanes(a);
  const Ints4 b_cell = floor_lanes(b);
  int cell[3] = {a_cell[0], a_cell[1], a_cell[2]};
  const int last[3] = {b_cell[0], b_cell[1], b_cell[2]};
  int step_axis[3];
  float t_max[3];
  float t_delta[3];
  int max_cells = 1;
  for (int k = 0; k < 3; ++k) {
    if (d[k] > 0.0f) {
      step_axis[k] = 1;
      t_delta[k] = 1.0f / d[k];
      t_max[k] = (static_cast<float>(cell[k] + 1) - a[k]) * t_delta[k];
      max_cells += last[k] - cell[k];
    } else if (d[k] < 0.0f) {
      step_axis[k] = -1;
      t_delta[k] = -1.0f / d[k];
      t_max[k] = (a[k] - static_cast<float>(cell[k])) * t_delta[k];
      max_cells += cell[k] - last[k];
    } else {
      step_axis[k] = 0;
      t_max[k] = 2.0f;
      t_delta[k] = 2.0f;
    }
  }
  if (!room(max_cells)) return RayMarch::no_room;
  ++rays;
  for (int c = 0; c < max_cells; ++c) {
    if (static_cast<unsigned>(cell[0]) < static_cast<unsigned>(m.side_blocks) &&
        static_cast<unsigned>(cell[1]) < static_cast<unsigned>(m.side_blocks) &&
        static_cast<unsigned>(cell[2]) < static_cast<unsigned>(m.side_blocks)) {
      const std::uint64_t key = pack_cell(cell[0], cell[1], cell[2]);
      std::uint64_t& recent = seen[seen_slot(key)];
      if (recent != key) {
        recent = key;
        emit(key);
      }
    } else {
      ++outside;
    }
    if (cell[0] == last[0] && cell[1] == last[1] && cell[2] == last[2]) break;
    const int k =
        t_max[0] < t_max[1] ? (t_max[0] < t_max[2] ? 0 : 2) : (t_max[1] < t_max[2] ? 1 : 2);
    if (t_max[k] > 1.0f) break;
    cell[k] += step_axis[k];
    t_max[k] += t_delta[k];
  }
  return RayMarch::done;
}

// A pixel row's ray geometry.
struct RowRays {
  const float* depth;
  Lanes4 dir;   // the ray direction at xn = 0
  float yn2_1;  // yn^2 + 1
};

template <typename FrameT>
inline RowRays row_rays(const FrameT& f, const MarchSetup& m, int v) {
  RowRays r;
  r.depth = f.depth + v * f.stride;
  const float yn = (static_cast<float>(v) - f.cy) * m.inv_fy;
  r.dir = m.M_col[1] * yn + m.M_col[2];
  r.yn2_1 = yn * yn + 1.0f;
  return r;
}

// Marches the rays of pixel rows [v_begin, v_end), the first row from column u_begin: every
// step-th row and column, or (group_max_depth_m > 0) those pixels in 2 x 2 groups, where a
// group's first ray stands for the others as MarchSetup says. When a ray might not fit, the
// march stops before it (before its group) and returns true with its pixel in (stop_v, stop_u).
template <typename FrameT, typename Room, typename Emit>
bool march_rows(const FrameT& f, const MarchSetup& m, int v_begin, int u_begin, int v_end,
                std::uint64_t* seen, std::uint32_t& outside, std::uint32_t& rays, Room&& room,
                Emit&& emit, int& stop_v, int& stop_u) {
  if (m.group_max_depth_m <= 0.0f) {
    for (int v = v_begin; v < v_end; v += m.step) {
      const RowRays row = row_rays(f, m, v);
      for (int u = v == v_begin ? u_begin : 0; u < f.width; u += m.step) {
        if (march_ray(f, m, u, row.depth[u], row.yn2_1, row.dir, seen, outside, rays, room, emit) ==
            RayMarch::no_room) {
          stop_v = v;
          stop_u = u;
          return true;
        }
      }
    }
    return false;
  }
  const int s = m.step;
  for (int v = v_begin; v < v_end; v += 2 * s) {
    const int row_count = v + s < f.height ? 2 : 1;
    const RowRays rows[2] = {row_rays(f, m, v), row_rays(f, m, row_count == 2 ? v + s : v)};
    for (int u = v == v_begin ? u_begin : 0; u < f.width; u += 2 * s) {
      const float first = rows[0].depth[u];
      const bool stands_for_group =
          first >= f.near_m && first <= f.far_m && first <= m.group_max_depth_m;
      const int column_count = u + s < f.width ? 2 : 1;
      // Marches group member (dv, du), a member after the first only where the first does not
      // stand for it; true when its ray might not fit.
      auto no_room = [&](int dv, int du, bool first_ray) {
        const float depth = rows[dv].depth[u + du * s];
        if (!first_ray && stands_for_group && std::fabs(depth - first) <= m.group_depth_gap_m) {
          return false;
        }
        return march_ray(f, m, u + du * s, depth, rows[dv].yn2_1, rows[dv].dir, seen, outside, rays,
                         room, emit) == RayMarch::no_room;
      };
      bool stop = false;
      if (row_count == 2 && column_count == 2) {
        // The whole group (all but the image's last odd row or column), in member order.
        stop = no_room(0, 0, true) || no_room(0, 1, false) || no_room(1, 0, false) ||
               no_room(1, 1, false);
      } else {
        for (int i = 0; i < 4 && !stop; ++i) {
          const int dv = i >> 1;
          const int du = i & 1;
          if (dv < row_count && du < column_count) stop = no_room(dv, du, i == 0);
        }
      }
      if (stop) {
        stop_v = v;
        stop_u = u;
        return true;
      }
    }
  }
  return false;
}

// Whether 2 x 2 groups pay on this frame: at least a quarter of the valid depths, sampled on a
// sparse grid, lie where a group's first ray can stand for the group (depth at most
// group_max_depth_m). Below that the grouped loop's overhead outweighs the rays it saves.
template <typename FrameT>
bool groups_pay(const FrameT& f, float group_max_depth_m) {
  constexpr int kSampleStep_px = 8;
  std::uint32_t valid = 0;
  std::uint32_t near = 0;
  for (int v = kSampleStep_px / 2; v < f.height; v += kSampleStep_px) {
    const float* row = f.depth + v * f.stride;
    for (int u = kSampleStep_px / 2; u < f.width; u += kSampleStep_px) {
      const float depth = row[u];
      if (!(depth >= f.near_m && depth <= f.far_m)) continue;
      ++valid;
      if (depth <= group_max_depth_m) ++near;
    }
  }
  return near > 0 && 4 * near >= valid;
}

}  // namespace

template <typename VoxelT>
std::uint32_t Integrator<VoxelT>::collect_blocks(const Octree<VoxelT>& map, const Frame& f,
                                                 IntegrationReport& report,
                                                 const WorkerTeam& team) {
  using fusion_internal::CollectTally;
  using fusion_internal::kCollectTasks;
  const float inv_block = 1.0f / (8.0f * f.voxel_size_m);
  MarchSetup m;
  const Eigen::Vector3f centre_B = (f.t_W_C - f.origin_W) * inv_block;
  const Eigen::Matrix3f M = f.R_W_C * inv_block;
  m.centre_B = Lanes4{centre_B.x(), centre_B.y(), centre_B.z(), 0.0f};
  for (int c = 0; c < 3; ++c) m.M_col[c] = Lanes4{M(0, c), M(1, c), M(2, c), 0.0f};
  m.inv_fx = 1.0f / f.fx;
  m.inv_fy = 1.0f / f.fy;
  m.side_blocks = map.voxels_per_side() >> kBlockSideLog2;
  m.step = config_.allocation_pixel_step;
  if (config_.allocation_group_block_px > 0.0f) {
    // A block of 8 voxels spans fx * 8 voxels / depth pixels; a skipped ray lies `step` pixels
    // from its group's first.
    const float group_max_depth_m =
        f.fx * 8.0f * f.voxel_size_m /
        (config_.allocation_group_block_px * static_cast<float>(m.step));
    // The grouped loop costs a few instructions a pixel more than the plain one (at 2 mm, where
    // blocks are small, about 5 % of the march): it only pays where enough groups can stand.
    if (groups_pay(f, group_max_depth_m)) {
      m.group_max_depth_m = group_max_depth_m;
      m.group_depth_gap_m = 0.5f * f.mu_m;
    }
  }
  // Rows per band unit: the step, or two of them for 2 x 2 groups.
  const int row_unit = m.group_max_depth_m > 0.0f ? 2 * m.step : m.step;
  const std::size_t rows = static_cast<std::size_t>((f.height + row_unit - 1) / row_unit);
  auto band_v = [&](std::size_t task, bool end) {
    const TaskRange r = task_range(rows, task, kCollectTasks);
    return static_cast<int>(end ? r.end : r.begin) * row_unit;
  };
  // 1a. Each band of rows lists its cells. Neighbouring rays cross the same blocks, in this row and
  // the rows above: the band's seen-cell cache keeps most repeats off its list.
  auto band_fn = [&](std::size_t task) {
    std::uint64_t* seen = seen_ + (task + 1) * kSeenCacheSize;
    for (std::size_t i = 0; i < kSeenCacheSize; ++i) seen[i] = ~std::uint64_t{0};
    std::uint64_t* cells = band_cells_ + task * band_capacity_;
    std::size_t count = 0;
    CollectTally tally;
    int stop_v = -1;
    int stop_u = 0;
    const std::size_t capacity = band_capacity_;
    if (march_rows(
            f, m, band_v(task, false), 0, band_v(task, true), seen, tally.outside, tally.rays,
            [&](int n) { return count + static_cast<std::size_t>(n) <= capacity; },
            [&](std::uint64_t key) { cells[count++] = key; }, stop_v, stop_u)) {
      tally.stop_row = stop_v;
      tally.stop_column = stop_u;
    }
    tally.count = static_cast<std::uint32_t>(count);
    collect_tallies_[task] = tally;
  };
  team.for_each_task(kCollectTasks, band_fn);

  // 1b. Merge the lists into the frame set in band order, which keeps each block's first
  // appearance in the serial ray order. A band whose list filled up is marched on from where it
  // stopped. New cells wait in a short FIFO while their set slot is prefetched (the set is too
  // large for the cache); the insertion order is unchanged.
  std::uint64_t* seen = seen_;
  for (std::size_t i = 0; i < kSeenCacheSize; ++i) seen[i] = ~std::uint64_t{0};
  constexpr std::uint64_t kPending = 16;
  std::uint64_t pending[kPending];
  std::uint64_t pushed = 0;
  auto insert_packed = [&](std::uint64_t key) {
    const Eigen::Vector3i coords(static_cast<int>(key & kCellMask),
                                 static_cast<int>((key >> 21) & kCellMask),
                                 static_cast<int>(key >> 42));
    insert_frame_block(key, coords, report);
  };
  auto push = [&](std::uint64_t key) {
    __builtin_prefetch(&set_[hash_key(key, set_bits_)], 1);
    std::uint64_t& entry = pending[pushed % kPending];
    if (pushed >= kPending) insert_packed(entry);
    entry = key;
    ++pushed;
  };
  for (std::size_t task = 0; task < kCollectTasks; ++task) {
    const CollectTally& tally = collect_tallies_[task];
    const std::uint64_t* cells = band_cells_ + task * band_capacity_;
    for (std::uint32_t i = 0; i < tally.count; ++i) {
      std::uint64_t& recent = seen[seen_slot(cells[i])];
      if (recent == cells[i]) continue;
      recent = cells[i];
      push(cells[i]);
    }
    std::uint32_t outside = tally.outside;
    std::uint32_t rays = tally.rays;
    if (tally.stop_row >= 0) {
      int unused_v = 0;
      int unused_u = 0;
      march_rows(
          f, m, tally.stop_row, tally.stop_column, band_v(task, true), seen, outside, rays,
          [](int) { return true; }, push, unused_v, unused_u);
    }
    report.rays_outside_cube += outside;
    report.allocation_rays += rays;
  }
  for (std::uint64_t i = pushed > kPending ? pushed - kPending : 0; i < pushed; ++i) {
    insert_packed(pending[i % kPending]);
  }
  return frame_block_count_;
}

template <typename VoxelT>
bool Integrator<VoxelT>::apply_budgets(std::uint32_t count, std::uint64_t cost,
                                       const FusionBudget& budget, IntegrationReport& report) {
  if (count <= budget.max_integrated_blocks && cost <= budget.max_voxel_updates) return false;
  report.budget_hit = true;
  // Nearest first; ties by Morton code so the order is total and deterministic.
  std::sort(frame_blocks_, frame_blocks_ + count, [](const FrameBlock& l, const FrameBlock& r) {
    return l.z_m != r.z_m ? l.z_m < r.z_m : l.morton < r.morton;
  });
  if constexpr (kMultires) {
    for (std::uint32_t i = count; i-- > 0 && cost > budget.max_voxel_updates;) {
      FrameBlock& b = frame_blocks_[i];
      if (b.scale >= kMaxBlockScale) continue;
      cost -=
          static_cast<std::uint64_t>(block_scale_count(b.scale) - block_scale_count(b.scale + 1));
      ++b.scale;
      ++report.budget_blocks_coarsened;
    }
  }
  std::uint32_t kept = count;
  while (kept > 0 && (cost > budget.max_voxel_updates || kept > budget.max_integrated_blocks)) {
    --kept;
    cost -= static_cast<std::uint64_t>(block_scale_count(frame_blocks_[kept].scale));
    frame_blocks_[kept].skip = 1;
    ++report.budget_blocks_skipped;
  }
  return true;
}

namespace {

// Camera z of a block centre is affine in its coordinates: z = z0 + dz_block . coords; z over
// the pixel footprint of a voxel gives the scale.
struct BlockDepthModel {
  Eigen::Vector3f dz_block;
  float z0 = 0;
  float inv_footprint = 0;
};

// Step 2's list once the blocks that do not exist are dropped: what the budgets and step 4 need.
struct BlockList {
  std::uint32_t count = 0;
  std::uint64_t cost = 0;             // voxel updates
  int coarsest = 0;                   // coarsest scale listed
  int finest_scale = kMaxBlockScale;  // finest scale listed
};

// 2a. Each block's pool index and depth; the scale where it does not depend on the current one
// (most far blocks: no header to read), else -1. Returns the blocks not allocated yet.
template <typename VoxelT>
std::uint32_t find_blocks(const Octree<VoxelT>& map, FrameBlock* blocks, TaskRange range,
                          const BlockDepthModel& depth, const FusionConfig& config) {
  for (std::size_t i = range.begin; i < range.end && i < range.begin + kLookAhead; ++i) {
    map.prefetch_block(blocks[i].morton);
  }
  std::uint32_t missing = 0;
  for (std::size_t i = range.begin; i < range.end; ++i) {
    if (i + kLookAhead < range.end) map.prefetch_block(blocks[i + kLookAhead].morton);
    FrameBlock& b = blocks[i];
    b.block = map.find_block_index_morton(b.morton);
    b.z_m = depth.z0 + depth.dz_block.dot(b.coords.cast<float>());
    if (b.block == kNoIndex) ++missing;
    b.scale = IsMultiresVoxel<VoxelT>::value && config.fixed_scale < 0
                  ? static_cast<std::int8_t>(
                        scale_for_any_current(b.z_m * depth.inv_footprint, config.scale_hysteresis))
                  : std::int8_t{-1};
  }
  return missing;
}

// 2b. The scales find_blocks left open, from each block's current scale (blocks not yet
// allocated have never been integrated and take the raw scale).
template <typename VoxelT>
void select_scales(const Octree<VoxelT>& map, FrameBlock* blocks, TaskRange range,
                   float inv_footprint, const FusionConfig& config) {
  for (std::size_t i = range.begin; i < range.end; ++i) {
    FrameBlock& b = blocks[i];
    if constexpr (IsMultiresVoxel<VoxelT>::value) {
      if (config.fixed_scale >= 0) {
        b.scale = static_cast<std::int8_t>(config.fixed_scale);
        continue;
      }
      // Headers are scattered over the pool: load a few ahead.
      if (i + kLookAhead < range.end) {
        const FrameBlock& later = blocks[i + kLookAhead];
        if (later.block != kNoIndex && later.scale < 0) {
          __builtin_prefetch(&map.block(later.block).current_scale);
        }
      }
      if (b.scale >= 0) continue;
      int current = -1;
      if (b.block != kNoIndex) {
        const VoxelBlock<VoxelT>& block = map.block(b.block);
        if (block.integrated()) current = block.current_scale;
      }
      b.scale = static_cast<std::int8_t>(
          select_scale(b.z_m * inv_footprint, current, config.scale_hysteresis));
    } else {
      b.scale = 0;
    }
  }
}

// 2c. Allocates the `missing` blocks of the list, nearest first when the budget does not allow
// them all, in Morton order so the pool's indices are deterministic. `order` and `keys` are
// scratch for `missing` entries.
template <typename VoxelT>
void allocate_missing_blocks(Octree<VoxelT>& map, FrameBlock* blocks, std::uint32_t touched,
                             std::uint32_t missing, const FusionBudget& budget,
                             std::uint32_t* order, Key* keys, IntegrationReport& report) {
  std::uint32_t m = 0;
  for (std::uint32_t i = 0; i < touched; ++i) {
    if (blocks[i].block == kNoIndex) order[m++] = i;
  }
  const FrameBlock* fb = blocks;
  std::uint32_t to_allocate = missing;
  if (missing > budget.max_new_blocks) {
    std::sort(order, order + missing, [fb](std::uint32_t l, std::uint32_t r) {
      return fb[l].z_m != fb[r].z_m ? fb[l].z_m < fb[r].z_m : fb[l].morton < fb[r].morton;
    });
    to_allocate = budget.max_new_blocks;
    report.budget_blocks_not_allocated = missing - to_allocate;
    report.budget_hit = true;
  }
  std::sort(order, order + to_allocate,
            [fb](std::uint32_t l, std::uint32_t r) { return fb[l].morton < fb[r].morton; });
  const int level = map.block_level();
  for (std::uint32_t i = 0; i < to_allocate; ++i) {
    keys[i] =
        Key{morton_encode(block_to_voxel(fb[order[i]].coords)), static_cast<std::uint8_t>(level)};
  }
  AllocationCounts counts;
  const Status allocated = map.allocate(keys, to_allocate, &counts);
  report.blocks_allocated = counts.new_blocks;
  report.pool_refusals = counts.refused;
  if (allocated.code() == StatusCode::resource_exhausted) {
    report.status = StatusCode::resource_exhausted;
  }
  for (std::uint32_t i = 0; i < to_allocate; ++i) {
    FrameBlock& b = blocks[order[i]];
    b.block = map.find_block_index_morton(b.morton);
  }
}

// Moves the blocks that exist to the front of the list, in list order.
BlockList keep_existing_blocks(FrameBlock* blocks, std::uint32_t touched) {
  BlockList list;
  for (std::uint32_t i = 0; i < touched; ++i) {
    const FrameBlock& b = blocks[i];
    if (b.block == kNoIndex) continue;
    list.cost += static_cast<std::uint64_t>(block_scale_count(b.scale));
    list.coarsest = std::max<int>(list.coarsest, b.scale);
    list.finest_scale = std::min<int>(list.finest_scale, b.scale);
    blocks[list.count++] = b;
  }
  return list;
}

// A block integrates at the coarser `scale` this frame; the list's coarsest scale follows.
void integrate_coarser(FrameBlock& b, BlockList& list, int scale) {
  b.scale = static_cast<std::int8_t>(scale);
  list.coarsest = std::max(list.coarsest, scale);
}

// Counts a block refused a level: it integrates one scale coarser.
void refuse_level(FrameBlock& b, BlockList& list, int scale, IntegrationReport& report) {
  integrate_coarser(b, list, scale);
  ++(scale == 1 ? report.finest_refusals : report.mid_refusals);
  ++report.pool_refusals;
  report.status = StatusCode::resource_exhausted;
}

// More blocks about to integrate at scale 0 without a finest level than the pool has free: those
// that may hold the surface (VoxelBlock::may_hold_surface()) come first, and within each group
// those that waited longest for one (finest_turn, then list position: a total order) are served;
// the others are refused now. Without turns the same blocks, first in the list, would win every
// frame and the rest of a view larger than the pool would never be fused at scale 0. `scratch`
// holds list.count entries.
template <typename VoxelT>
void ration_finest_levels(Octree<VoxelT>& map, FrameBlock* blocks, BlockList& list,
                          std::uint64_t* scratch, IntegrationReport& report) {
  const MapMemory memory = map.memory();
  const std::uint32_t free =
      memory.finest_capacity > memory.finest_used ? memory.finest_capacity - memory.finest_used : 0;
  if (free >= list.count) return;  // room for every block in the list: no need to count
  // Surface blocks' keys, then the others'.
  std::uint32_t asking = 0;
  std::uint32_t surface = 0;
  for (int pass = 0; pass < 2; ++pass) {
    for (std::uint32_t i = 0; i < list.count; ++i) {
      const FrameBlock& b = blocks[i];
      if (b.skip != 0 || b.scale != 0) continue;
      const VoxelBlock<VoxelT>& block = map.block(b.block);
      if (block.has_finest() || block.may_hold_surface() != (pass == 0)) continue;
      scratch[asking++] = (std::uint64_t{block.finest_turn} << 32) | i;
    }
    if (pass == 0) surface = asking;
  }
  if (asking <= free) return;
  // The keys are distinct, so the served set does not depend on how the partition orders it.
  if (free < surface) {
    std::nth_element(scratch, scratch + free, scratch + surface);
  } else {
    std::nth_element(scratch + surface, scratch + free, scratch + asking);
  }
  for (std::uint32_t k = free; k < asking; ++k) {
    refuse_level(blocks[scratch[k] & 0xFFFFFFFFu], list, 1, report);
  }
  map.count_finest_refusals(asking - free);
}

// Fine levels for blocks about to integrate at scale 0 (1) for the first time, serially and in
// list order so the pools' indices do not depend on the worker count. Refused: one scale coarser
// (a block refused its finest level integrates at scale 1, one refused its mid level at 2). A
// block that held a finest level once (min_scale 0) and gave it up asks `source` for it first.
// A block given its finest level has its turn stamped with the frame.
template <typename VoxelT>
void acquire_fine_levels(Octree<VoxelT>& map, FrameBlock* blocks, BlockList& list,
                         FinestLevelSource<VoxelT>* source, std::uint32_t frame_index,
                         std::uint64_t* scratch, IntegrationReport& report) {
  using Answer = typename FinestLevelSource<VoxelT>::Answer;
  if (list.finest_scale == 0) ration_finest_levels(map, blocks, list, scratch, report);
  for (std::uint32_t i = 0; i < list.count && list.finest_scale <= 1; ++i) {
    FrameBlock& b = blocks[i];
    if (b.skip != 0 || b.scale > 1) continue;
    VoxelBlock<VoxelT>& block = map.block(b.block);
    if (source != nullptr && b.scale == 0 && !block.has_finest() && block.min_scale == 0) {
      const Answer answer = source->restore(map, b.block);
      if (answer == Answer::restored) {
        block.finest_turn = frame_index;
        continue;
      }
      if (answer == Answer::wait) integrate_coarser(b, list, 1);
    }
    if (!block.has_mid() && !map.acquire_mid(block).ok()) {
      refuse_level(b, list, 2, report);
      continue;
    }
    if (b.scale != 0 || block.has_finest()) continue;
    if (map.acquire_finest(block).ok()) {
      block.finest_turn = frame_index;
    } else {
      refuse_level(b, list, 1, report);
    }
  }
}

// The coarsest scale a block integrates at: up-propagation stops there.
int mip_target(const FrameBlock* blocks, const BlockList& list, bool budget_bound) {
  if (!budget_bound) return list.count > 0 ? list.coarsest : 0;
  // Blocks were coarsened or skipped: look again.
  int target = 0;
  for (std::uint32_t i = 0; i < list.count; ++i) {
    if (blocks[i].skip == 0 && blocks[i].scale > target) target = blocks[i].scale;
  }
  return target;
}

// Step 4's list: the blocks not skipped, sorted by pool index (`order` holds 2 * capacity entries:
// the list and the sort's scratch). Returns the sorted list; `sorted` is its length.
const std::uint64_t* pool_order(const FrameBlock* blocks, std::uint32_t count,
                                std::uint32_t block_count, std::uint64_t* order,
                                std::size_t capacity, std::uint32_t& sorted) {
  sorted = 0;
  for (std::uint32_t i = 0; i < count; ++i) {
    const FrameBlock& b = blocks[i];
    if (b.skip != 0) continue;
    order[sorted++] = pool_entry(b.block, b.scale);
  }
  return sort_by_block(order, order + capacity, sorted, block_count);
}

// Fetches a later block's header early, and once it has arrived (it says where a multires
// block's finest level is) its first voxels. Headers and levels rarely start on a cache line:
// fetch both ends.
template <typename VoxelT>
inline void prefetch_later_blocks(const Octree<VoxelT>& map, const std::uint64_t* order,
                                  std::size_t i, std::size_t end) {
  if (i + 2 * kPrefetchDistance < end) {
    const char* header = reinterpret_cast<const char*>(
        &map.block(pool_entry_block(order[i + 2 * kPrefetchDistance])));
    __builtin_prefetch(header, 1);
    __builtin_prefetch(header + 63, 1);
  }
  if (i + kPrefetchDistance < end) {
    const std::uint64_t later = order[i + kPrefetchDistance];
    const int later_scale = pool_entry_scale(later);
    const VoxelBlock<VoxelT>& lb = map.block(pool_entry_block(later));
    const char* first = later_scale == 0
                            ? reinterpret_cast<const char*>(lb.finest_begin())
                            : reinterpret_cast<const char*>(lb.level_begin(later_scale));
    const int bytes =
        block_scale_count(later_scale) *
        static_cast<int>(later_scale == 0 ? sizeof(FinestVoxelT<VoxelT>) : sizeof(VoxelT));
    __builtin_prefetch(first, 1);
    __builtin_prefetch(first + 64, 1);
    if (bytes > 64) __builtin_prefetch(first + std::min(bytes, 192) - 1, 1);
  }
}

void add_tallies(const TaskTally* tallies, std::size_t tasks, IntegrationReport& report) {
  for (std::size_t t = 0; t < tasks; ++t) {
    const TaskTally& tally = tallies[t];
    report.voxels_updated += tally.voxels_updated;
    for (int s = 0; s < 4; ++s) {
      report.blocks_per_scale[s] += tally.blocks_per_scale[s];
      report.blocks_integrated += tally.blocks_per_scale[s];
    }
    report.blocks_refined += tally.refined;
    report.blocks_coarsened += tally.coarsened;
  }
}

}  // namespace

template <typename VoxelT>
StatusCode Integrator<VoxelT>::check_inputs(const Octree<VoxelT>& map, ImageView<const float> depth,
                                            const PinholeCamera& camera, const Se3d& T_W_C) const {
  if (!reserved_ || !map.reserved()) return StatusCode::failed_precondition;
  if (depth.empty() || !camera.valid() || camera.width != depth.width ||
      camera.height != depth.height || !pose_ok(T_W_C) ||
      static_cast<std::int64_t>(depth.stride) * depth.height > fusion_internal::kMaxImageSpan_px) {
    return StatusCode::invalid_argument;
  }
  if (depth.width != width_ || depth.height != height_) return StatusCode::failed_precondition;
  return StatusCode::ok;
}

template <typename VoxelT>
typename Integrator<VoxelT>::Frame Integrator<VoxelT>::frame_constants(const Octree<VoxelT>& map,
                                                                       ImageView<const float> depth,
                                                                       const PinholeCamera& camera,
                                                                       const Se3d& T_W_C) const {
  Frame f;
  f.depth = depth.data;
  f.stride = depth.stride;
  f.width = depth.width;
  f.height = depth.height;
  f.fx = camera.fx;
  f.fy = camera.fy;
  f.cx = camera.cx;
  f.cy = camera.cy;
  const Se3d T_C_W = T_W_C.inverse();
  f.R_C_W = T_C_W.linear().cast<float>();
  f.t_C_W = T_C_W.translation().cast<float>();
  f.R_W_C = T_W_C.linear().cast<float>();
  f.t_W_C = T_W_C.translation().cast<float>();
  f.origin_W = map.config().origin_W;
  f.voxel_size_m = map.voxel_size_m();
  f.mu_m = config_.mu_m;
  f.inv_mu = 1.0f / config_.mu_m;
  for (int s = 0; s <= kMaxBlockScale; ++s) {
    const float cell_m = f.voxel_size_m * static_cast<float>(1 << s);
    const float behind_m = config_.behind_mu * f.mu_m;
    // Single-resolution blocks never reach past mu (they have no coarse scales to close).
    f.behind_m[s] = kMultires ? std::max(behind_m, kMinBehind_voxels * cell_m)
                              : std::max(behind_m, std::min(f.mu_m, kMinBehind_voxels * cell_m));
  }
  f.near_m = config_.near_m;
  f.far_m = config_.far_m;
  f.y_max = config_.y_max;
  return f;
}

template <typename VoxelT>
void Integrator<VoxelT>::start_frame_set() {
  ++stamp_;
  if (stamp_ == 0) {  // wrapped: old stamps could alias, start clean
    for (std::size_t i = 0; i <= set_mask_; ++i) set_[i] = FrameSetEntry();
    stamp_ = 1;
  }
  frame_block_count_ = 0;
}

template <typename VoxelT>
std::uint32_t Integrator<VoxelT>::look_up_blocks(const Octree<VoxelT>& map, const Frame& f,
                                                 const PinholeCamera& camera, std::uint32_t touched,
                                                 const WorkerTeam& team) {
  BlockDepthModel depth;
  depth.dz_block = f.R_C_W.row(2).transpose() * (8.0f * f.voxel_size_m);
  depth.z0 = f.R_C_W.row(2).dot(f.origin_W + Eigen::Vector3f::Constant(4.0f * f.voxel_size_m)) +
             f.t_C_W.z();
  depth.inv_footprint = 1.0f / (camera.fx * map.voxel_size_m());
  const std::size_t tasks =
      std::min<std::size_t>(static_cast<std::size_t>(config_.task_count), touched);
  for (std::size_t t = 0; t < tasks; ++t) tallies_[t] = TaskTally();
  auto look_up_task = [&](std::size_t task) {
    const TaskRange range = task_range(touched, task, tasks);
    tallies_[task].missing = find_blocks(map, frame_blocks_, range, depth, config_);
    select_scales(map, frame_blocks_, range, depth.inv_footprint, config_);
  };
  team.for_each_task(tasks, look_up_task);
  std::uint32_t missing = 0;
  for (std::size_t t = 0; t < tasks; ++t) missing += tallies_[t].missing;
  return missing;
}

template <typename VoxelT>
std::uint32_t Integrator<VoxelT>::integrate_blocks(Octree<VoxelT>& map, const Frame& f,
                                                   std::uint32_t count, std::uint32_t frame_index,
                                                   const WorkerTeam& team,
                                                   IntegrationReport& report) {
  std::uint32_t sorted = 0;
  const std::uint64_t* order = pool_order(frame_blocks_, count, map.block_count(), pool_order_,
                                          config_.max_blocks_per_frame, sorted);
  const std::size_t tasks =
      std::min<std::size_t>(static_cast<std::size_t>(config_.task_count), sorted);
  for (std::size_t t = 0; t < tasks; ++t) tallies_[t] = TaskTally();
  auto integrate_task = [&](std::size_t task) {
    const TaskRange range = task_range(sorted, task, tasks);
    TaskTally& tally = tallies_[task];
    for (std::size_t i = range.begin; i < range.end; ++i) {
      prefetch_later_blocks(map, order, i, range.end);
      VoxelBlock<VoxelT>& block = map.block(pool_entry_block(order[i]));
      integrate_block(block, pool_entry_scale(order[i]), f, tally);
      block.last_updated_frame = frame_index;
      block.stored_clean = 0;
      // For step 5, while the header is in the cache.
      block_indices_[i] = block.parent_node;
    }
  };
  team.for_each_task(tasks, integrate_task);
  add_tallies(tallies_, tasks, report);
  return sorted;
}

template <typename VoxelT>
IntegrationReport Integrator<VoxelT>::collect_and_look_up(const Octree<VoxelT>& map, const Frame& f,
                                                          const PinholeCamera& camera,
                                                          const WorkerTeam& team) {
  IntegrationReport report;
  // 1. Blocks the bands cross.
  start_frame_set();
  const std::uint32_t touched = collect_blocks(map, f, report, team);
  report.blocks_touched = touched;
  // 2a-b. Look the blocks up and pick their scales (read-only on the map).
  report.blocks_requested = look_up_blocks(map, f, camera, touched, team);
  return report;
}

template <typename VoxelT>
IntegrationReport Integrator<VoxelT>::integrate_looked_up(Octree<VoxelT>& map, Frame& f,
                                                          std::uint32_t frame_index,
                                                          const FusionBudget& budget,
                                                          const WorkerTeam& team,
                                                          IntegrationReport report) {
  // 2c. Allocate the missing blocks (block_indices_ is free until step 4 and lists their
  // positions) and keep those that exist.
  const std::uint32_t touched = report.blocks_touched;
  const std::uint32_t missing = report.blocks_requested;
  if (missing > 0) {
    allocate_missing_blocks(map, frame_blocks_, touched, missing, budget, block_indices_, keys_,
                            report);
  }
  if (report.keys_dropped > 0) report.status = StatusCode::resource_exhausted;
  BlockList list = keep_existing_blocks(frame_blocks_, touched);

  // 3. Budgets (the scales were picked in step 2), then finest levels for the blocks at scale 0.
  const bool budget_bound = apply_budgets(list.count, list.cost, budget, report);
  if constexpr (kMultires) {
    acquire_fine_levels(map, frame_blocks_, list, finest_source_, frame_index, pool_order_, report);
  }
  f.mip_target = mip_target(frame_blocks_, list, budget_bound);

  // 4. Integrate in pool order, in a fixed number of tasks. Blocks are independent, so the order
  // changes no bits; sorted, their headers and voxels are read in address order.
  const std::uint32_t integrated = integrate_blocks(map, f, list.count, frame_index, team, report);

  // 5. Node summaries above the integrated blocks (their parents, listed by step 4).
  map.propagate_summaries_from_parents(block_indices_, integrated, team);
  return report;
}

template <typename VoxelT>
IntegrationReport Integrator<VoxelT>::integrate(Octree<VoxelT>& map, ImageView<const float> depth,
                                                const PinholeCamera& camera, const Se3d& T_W_C,
                                                std::uint32_t frame_index,
                                                const FusionBudget& budget,
                                                const WorkerTeam& team) {
  begun_ = Begun();
  IntegrationReport report;
  report.status = check_inputs(map, depth, camera, T_W_C);
  if (!report.status.ok()) return report;
  Frame f = frame_constants(map, depth, camera, T_W_C);
  return integrate_looked_up(map, f, frame_index, budget, team,
                             collect_and_look_up(map, f, camera, team));
}

template <typename VoxelT>
IntegrationReport Integrator<VoxelT>::begin_frame(const Octree<VoxelT>& map,
                                                  ImageView<const float> depth,
                                                  const PinholeCamera& camera, const Se3d& T_W_C,
                                                  const WorkerTeam& team) {
  begun_ = Begun();
  IntegrationReport report;
  report.status = check_inputs(map, depth, camera, T_W_C);
  if (!report.status.ok()) return report;
  const Frame f = frame_constants(map, depth, camera, T_W_C);
  report = collect_and_look_up(map, f, camera, team);
  begun_.map = &map;
  begun_.depth = depth.data;
  begun_.T_W_C = T_W_C;
  begun_.report = report;
  return report;
}

template <typename VoxelT>
IntegrationReport Integrator<VoxelT>::finish_frame(Octree<VoxelT>& map,
                                                   ImageView<const float> depth,
                                                   const PinholeCamera& camera, const Se3d& T_W_C,
                                                   std::uint32_t frame_index,
                                                   const FusionBudget& budget,
                                                   const WorkerTeam& team) {
  IntegrationReport report;
  report.status = check_inputs(map, depth, camera, T_W_C);
  if (!report.status.ok()) return report;
  const bool same =
      begun_.map == &map && begun_.depth == depth.data && begun_.T_W_C.matrix() == T_W_C.matrix();
  report = begun_.report;
  begun_ = Begun();
  if (!same) {
    IntegrationReport refused;
    refused.status = StatusCode::failed_precondition;
    return refused;
  }
  Frame f = frame_constants(map, depth, camera, T_W_C);
  // 2a-b again: the collected list stands, the blocks' pool indices and scales may not.
  report.blocks_requested = look_up_blocks(map, f, camera, report.blocks_touched, team);
  return integrate_looked_up(map, f, frame_index, budget, team, report);
}

template class Integrator<TsdfVoxel>;
template class Integrator<MultiresVoxel>;
template class Integrator<Multires16Voxel>;

}  // namespace octofuse
