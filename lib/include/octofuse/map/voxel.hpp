#pragma once
// Voxel payloads. The TSDF is stored normalised by the truncation distance mu, so it lies in
// [-1, 1] (positive in front of the surface). A weight of 0 means "never observed"; its TSDF is
// then meaningless (initialised to 1, free space). The map is templated on the type, never
// switched at run time. Code shared by the types reads and writes the fields as float through
// the voxel_* / set_voxel_* functions below, never the members.

#include <algorithm>
#include <cstdint>

namespace octofuse {

// Single-resolution TSDF (the baseline): 8 bytes.
struct TsdfVoxel {
  float tsdf = 1.0f;    // normalised by mu, [-1, 1]
  float weight = 0.0f;  // number of fused samples, capped by the integrator
};

// Multi-resolution TSDF (paper eq. 3-5): 16 bytes.
struct MultiresVoxel {
  float x = 1.0f;        // normalised TSDF, [-1, 1]
  float x_last = 1.0f;   // x when this voxel last propagated down (eq. 5)
  float y = 0.0f;        // weight, capped at y_max
  float delta_y = 0.0f;  // weight added since the last down-propagation
};

// Compact multi-resolution TSDF for small boards: the fields of MultiresVoxel in 16-bit fixed
// point, 8 bytes (half the map memory per block). Every value is stored rounded to the nearest
// step (ties away from zero) by integer arithmetic on exactly computed floats, so the bits are
// the same for any thread count and on x86-64, aarch64 and armhf.
//
// TSDF x, x_last: int16 in steps of 2^-14 (16384 steps per mu). A power-of-two scale makes the
// conversions exact: to float is one exact multiply, and -1, 0 and 1 are represented exactly (a
// scale of 32767 would buy one bit but need a division per read). One step is mu / 16384: at the
// default mu of 8 voxels that is 1/2048 of a voxel (4.9 um at 1 cm), so a stored value is off by
// at most mu / 32768. The running mean (eq. 3) moves a voxel by (f - x) / (y + 1) per sample; a
// move below half a step rounds away, so the stored value may trail the float mean by up to
// (y_max + 1) / 2 steps: 0.3% of mu at y_max = 100 (0.25 mm at 1 cm voxels, mu 8 cm). Eight bits
// (steps of mu / 127) could trail by 40% of mu, too coarse for the surface.
// Weights y, delta_y: uint16 in steps of 2^-6. The integrator's weights are whole sample counts
// and up-propagation rounds its means up, so they are integers and exact; the six fractional bits
// keep a fractional y_max (and means not rounded up) within 1/128. The largest weight is
// 65535 / 64 = 1023.98, so y_max must not exceed it (the pipeline checks). delta_y saturates
// there: it is only ever added to y under min(y_max, ...), where a saturated value gives the same
// result as the exact one.
struct Multires16Voxel {
  std::int16_t x_q = 16384;       // x * 2^14
  std::int16_t x_last_q = 16384;  // x_last * 2^14
  std::uint16_t y_q = 0;          // y * 2^6
  std::uint16_t delta_y_q = 0;    // delta_y * 2^6, saturating
};

inline constexpr float kMultires16TsdfScale = 16384.0f;  // steps per unit of normalised TSDF
inline constexpr float kMultires16WeightScale = 64.0f;   // steps per unit of weight
// Largest weight a Multires16Voxel holds (y_max may not exceed it).
inline constexpr float kMultires16MaxWeight = 65535.0f / kMultires16WeightScale;

namespace voxel_detail {
// Nearest integer to c, ties away from zero, for |c| <= 65535: c - trunc(c) is exact there.
inline int round_to_int(float c) {
  const int t = static_cast<int>(c);
  const float frac = c - static_cast<float>(t);
  return t + (frac >= 0.5f ? 1 : 0) - (frac <= -0.5f ? 1 : 0);
}
}  // namespace voxel_detail

// Scale 0 of a multires block: the TSDF and weight alone. x_last and delta_y are read only where a
// level is the parent of a finer one (eq. 5), which scale 0 never is: without them a finest level
// takes half the bytes, and a capped map holds twice the finest levels.
struct MultiresFinestVoxel {
  float x = 1.0f;  // as MultiresVoxel::x
  float y = 0.0f;  // as MultiresVoxel::y
};
struct Multires16FinestVoxel {
  std::int16_t x_q = 16384;  // as Multires16Voxel::x_q
  std::uint16_t y_q = 0;     // as Multires16Voxel::y_q
};

// Normalised TSDF to its 16-bit step, clamped to [-1, 1] (NaN stores as -1).
inline std::int16_t quantise_tsdf16(float x) {
  float c = x * kMultires16TsdfScale;  // exact: a power of two
  c = c > kMultires16TsdfScale ? kMultires16TsdfScale : c;
  c = c >= -kMultires16TsdfScale ? c : -kMultires16TsdfScale;
  return static_cast<std::int16_t>(voxel_detail::round_to_int(c));
}
// Weight to its 16-bit step, clamped to [0, kMultires16MaxWeight] (NaN stores as 0).
inline std::uint16_t quantise_weight16(float w) {
  float c = w * kMultires16WeightScale;
  c = c > 65535.0f ? 65535.0f : c;
  c = c >= 0.0f ? c : 0.0f;
  return static_cast<std::uint16_t>(voxel_detail::round_to_int(c));
}
inline float dequantise_tsdf16(std::int16_t q) {
  return static_cast<float>(q) * (1.0f / kMultires16TsdfScale);
}
inline float dequantise_weight16(std::uint16_t q) {
  return static_cast<float>(q) * (1.0f / kMultires16WeightScale);
}

// Read accessors shared by code that works over any voxel type (ray-casting, meshing).
inline float voxel_tsdf(const TsdfVoxel& v) {
  return v.tsdf;
}
inline float voxel_weight(const TsdfVoxel& v) {
  return v.weight;
}
inline float voxel_tsdf(const MultiresVoxel& v) {
  return v.x;
}
inline float voxel_weight(const MultiresVoxel& v) {
  return v.y;
}
inline float voxel_tsdf(const Multires16Voxel& v) {
  return dequantise_tsdf16(v.x_q);
}
inline float voxel_weight(const Multires16Voxel& v) {
  return dequantise_weight16(v.y_q);
}
inline float voxel_tsdf(const MultiresFinestVoxel& v) {
  return v.x;
}
inline float voxel_weight(const MultiresFinestVoxel& v) {
  return v.y;
}
inline float voxel_tsdf(const Multires16FinestVoxel& v) {
  return dequantise_tsdf16(v.x_q);
}
inline float voxel_weight(const Multires16FinestVoxel& v) {
  return dequantise_weight16(v.y_q);
}
inline bool voxel_observed(const TsdfVoxel& v) {
  return v.weight > 0.0f;
}
inline bool voxel_observed(const MultiresVoxel& v) {
  return v.y > 0.0f;
}
inline bool voxel_observed(const Multires16Voxel& v) {
  return v.y_q != 0;
}
inline bool voxel_observed(const MultiresFinestVoxel& v) {
  return v.y > 0.0f;
}
inline bool voxel_observed(const Multires16FinestVoxel& v) {
  return v.y_q != 0;
}

// Writes, and the multi-resolution fields (x_last, delta_y), as float. The 16-bit type rounds
// what it is given to its step (see Multires16Voxel).
inline void set_voxel_tsdf(TsdfVoxel& v, float tsdf) {
  v.tsdf = tsdf;
}
inline void set_voxel_weight(TsdfVoxel& v, float weight) {
  v.weight = weight;
}
inline void set_voxel_tsdf(MultiresVoxel& v, float x) {
  v.x = x;
}
inline void set_voxel_weight(MultiresVoxel& v, float y) {
  v.y = y;
}
inline float voxel_x_last(const MultiresVoxel& v) {
  return v.x_last;
}
inline float voxel_delta_y(const MultiresVoxel& v) {
  return v.delta_y;
}
inline void set_voxel_x_last(MultiresVoxel& v, float x_last) {
  v.x_last = x_last;
}
inline void set_voxel_delta_y(MultiresVoxel& v, float delta_y) {
  v.delta_y = delta_y;
}
inline void set_voxel_tsdf(Multires16Voxel& v, float x) {
  v.x_q = quantise_tsdf16(x);
}
inline void set_voxel_weight(Multires16Voxel& v, float y) {
  v.y_q = quantise_weight16(y);
}
inline float voxel_x_last(const Multires16Voxel& v) {
  return dequantise_tsdf16(v.x_last_q);
}
inline float voxel_delta_y(const Multires16Voxel& v) {
  return dequantise_weight16(v.delta_y_q);
}
inline void set_voxel_x_last(Multires16Voxel& v, float x_last) {
  v.x_last_q = quantise_tsdf16(x_last);
}
inline void set_voxel_delta_y(Multires16Voxel& v, float delta_y) {
  v.delta_y_q = quantise_weight16(delta_y);
}

// A finest voxel has no interval of its own: it reads as one that just started (x_last = x,
// delta_y = 0), and writes of either are dropped.
inline void set_voxel_tsdf(MultiresFinestVoxel& v, float x) {
  v.x = x;
}
inline void set_voxel_weight(MultiresFinestVoxel& v, float y) {
  v.y = y;
}
inline float voxel_x_last(const MultiresFinestVoxel& v) {
  return v.x;
}
inline float voxel_delta_y(const MultiresFinestVoxel&) {
  return 0.0f;
}
inline void set_voxel_x_last(MultiresFinestVoxel&, float) {}
inline void set_voxel_delta_y(MultiresFinestVoxel&, float) {}
inline void set_voxel_tsdf(Multires16FinestVoxel& v, float x) {
  v.x_q = quantise_tsdf16(x);
}
inline void set_voxel_weight(Multires16FinestVoxel& v, float y) {
  v.y_q = quantise_weight16(y);
}
inline float voxel_x_last(const Multires16FinestVoxel& v) {
  return dequantise_tsdf16(v.x_q);
}
inline float voxel_delta_y(const Multires16FinestVoxel&) {
  return 0.0f;
}
inline void set_voxel_x_last(Multires16FinestVoxel&, float) {}
inline void set_voxel_delta_y(Multires16FinestVoxel&, float) {}

// After a sample is fused (eq. 3): y = min(y_max, y + 1) and delta_y += 1, as a store of each
// through the setters would give. In 16-bit steps both additions are exact, so they are integer
// additions there (saturating; the cap rounds as a stored y_max would).
inline void count_voxel_sample(MultiresVoxel& v, float y_max) {
  v.y = std::min(y_max, v.y + 1.0f);
  v.delta_y += 1.0f;
}
namespace voxel_detail {
// y + 1 in 16-bit weight steps, capped at y_max as a stored y_max would round.
inline std::uint16_t counted_weight16(std::uint16_t y_q, float y_max) {
  const int cap = quantise_weight16(y_max);
  const int y = y_q + static_cast<int>(kMultires16WeightScale);
  return static_cast<std::uint16_t>(y < cap ? y : cap);
}
}  // namespace voxel_detail
inline void count_voxel_sample(Multires16Voxel& v, float y_max) {
  const int delta_y = v.delta_y_q + static_cast<int>(kMultires16WeightScale);
  v.y_q = voxel_detail::counted_weight16(v.y_q, y_max);
  v.delta_y_q = static_cast<std::uint16_t>(delta_y < 65535 ? delta_y : 65535);
}

inline void count_voxel_sample(MultiresFinestVoxel& v, float y_max) {
  v.y = std::min(y_max, v.y + 1.0f);
}
inline void count_voxel_sample(Multires16FinestVoxel& v, float y_max) {
  v.y_q = voxel_detail::counted_weight16(v.y_q, y_max);
}

// A voxel's finest part (its TSDF and weight), and a finest voxel as its level's type (x_last = x,
// delta_y = 0): exact both ways.
inline TsdfVoxel finest_part(const TsdfVoxel& v) {
  return v;
}
inline MultiresFinestVoxel finest_part(const MultiresVoxel& v) {
  return MultiresFinestVoxel{v.x, v.y};
}
inline Multires16FinestVoxel finest_part(const Multires16Voxel& v) {
  return Multires16FinestVoxel{v.x_q, v.y_q};
}
inline TsdfVoxel widen_voxel(const TsdfVoxel& v) {
  return v;
}
inline MultiresVoxel widen_voxel(const MultiresFinestVoxel& v) {
  return MultiresVoxel{v.x, v.x, v.y, 0.0f};
}
inline Multires16Voxel widen_voxel(const Multires16FinestVoxel& v) {
  return Multires16Voxel{v.x_q, v.x_q, v.y_q, 0};
}

// The voxel a map of VoxelT keeps at scale 0 (the same type for single-resolution maps).
template <typename VoxelT>
struct FinestVoxelOf {
  using type = VoxelT;
};
template <>
struct FinestVoxelOf<MultiresVoxel> {
  using type = MultiresFinestVoxel;
};
template <>
struct FinestVoxelOf<Multires16Voxel> {
  using type = Multires16FinestVoxel;
};
template <typename VoxelT>
using FinestVoxelT = typename FinestVoxelOf<VoxelT>::type;

// True for the multi-resolution types (compile time; picks the integrator's code path).
template <typename VoxelT>
struct IsMultiresVoxel {
  static constexpr bool value = false;
};
template <>
struct IsMultiresVoxel<MultiresVoxel> {
  static constexpr bool value = true;
};
template <>
struct IsMultiresVoxel<Multires16Voxel> {
  static constexpr bool value = true;
};
template <>
struct IsMultiresVoxel<MultiresFinestVoxel> {
  static constexpr bool value = true;
};
template <>
struct IsMultiresVoxel<Multires16FinestVoxel> {
  static constexpr bool value = true;
};

}  // namespace octofuse
