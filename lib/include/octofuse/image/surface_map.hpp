#pragma once
// Per-pixel surface samples: what ray-casting produces and what ICP associates against. Both
// images have the same size. A pixel is invalid when its normal is the zero vector (its vertex
// is then unspecified). The frame of the points is part of the variable name at each use
// (`model_W`, `live_C`).
// Normals point into free space (towards the sensor that saw the surface), as TSDF gradients do:
// ICP's normal-agreement gate compares live and model normals with their signs.

#include <Eigen/Core>
#include <cstdint>

#include "octofuse/image/image_view.hpp"

namespace octofuse {

// A normal that marks an invalid pixel: all components exactly zero (NaN is not). Same as
// isZero(0.0f), without its abs per component: ICP tests this per pixel and iteration.
inline bool is_invalid_normal(const Eigen::Vector3f& n) {
  return n.x() == 0.0f && n.y() == 0.0f && n.z() == 0.0f;
}

struct SurfaceMap {
  ImageView<Eigen::Vector3f> vertices;  // metres
  ImageView<Eigen::Vector3f> normals;   // unit length, or zero where invalid
  // 2: only pixels with even x and y were cast; each odd one holds a copy of its even neighbour
  // above and to the left. Readers that look a pixel up should take the nearest cast one.
  int pixel_stride = 1;

  int width() const { return vertices.width; }
  int height() const { return vertices.height; }
  bool valid(int x, int y) const { return !is_invalid_normal(normals(x, y)); }
};

struct ConstSurfaceMap {
  ImageView<const Eigen::Vector3f> vertices;
  ImageView<const Eigen::Vector3f> normals;
  int pixel_stride = 1;  // as SurfaceMap::pixel_stride

  ConstSurfaceMap() = default;
  ConstSurfaceMap(const SurfaceMap& m)  // NOLINT: implicit, like T* -> const T*
      : vertices(m.vertices), normals(m.normals), pixel_stride(m.pixel_stride) {}
  int width() const { return vertices.width; }
  int height() const { return vertices.height; }
  bool valid(int x, int y) const { return !is_invalid_normal(normals(x, y)); }
};

// The valid pixels of `map`. At pixel stride 2 only the cast pixels (even x and y) are read, each
// counted with the copies beside and below it: the count of the whole image when the copies hold
// what SurfaceMap::pixel_stride says, a quarter of the reads.
inline std::uint32_t valid_pixel_count(const ConstSurfaceMap& map) {
  const int w = map.width();
  const int h = map.height();
  std::uint32_t count = 0;
  if (map.pixel_stride == 2) {
    for (int y = 0; y < h; y += 2) {
      std::uint32_t cast = 0;
      for (int x = 0; x + 1 < w; x += 2) cast += map.valid(x, y) ? 1u : 0u;
      // An odd width's last column has no copy beside it, an odd height's last row none below.
      const std::uint32_t last = (w & 1) != 0 && map.valid(w - 1, y) ? 1u : 0u;
      count += (y + 1 < h ? 2u : 1u) * (2u * cast + last);
    }
    return count;
  }
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) count += map.valid(x, y) ? 1u : 0u;
  }
  return count;
}

}  // namespace octofuse
