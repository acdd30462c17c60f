#pragma once
// Voxel payloads. The TSDF is stored normalised by the truncation distance mu, so it lies in
// [-1, 1] (positive in front of the surface). A weight of 0 means "never observed"; its TSDF is
// then meaningless (initialised to 1, free space). Both types are trivially copyable 4-byte-float
// records; the map is templated on the type, never switched at run time.

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

// Read accessors shared by code that works over either voxel type (ray-casting, meshing).
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
inline bool voxel_observed(const TsdfVoxel& v) {
  return v.weight > 0.0f;
}
inline bool voxel_observed(const MultiresVoxel& v) {
  return v.y > 0.0f;
}

// True for the multi-resolution type (compile time; picks the integrator's code path).
template <typename VoxelT>
struct IsMultiresVoxel {
  static constexpr bool value = false;
};
template <>
struct IsMultiresVoxel<MultiresVoxel> {
  static constexpr bool value = true;
};

}  // namespace octofuse
