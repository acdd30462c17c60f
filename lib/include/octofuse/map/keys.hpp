#pragma once
// Octant keys: a Morton code of the octant's minimum corner in finest-voxel coordinates (21 bits
// per axis, x in the lowest bit of each triple) plus the tree level (0 = root, config.block_level()
// = voxel blocks, voxel_depth = single finest voxels). The low bits below the octant's size are
// always zero, so a key is canonical. Keys sort by Morton code first, which is the order the map
// allocates and iterates in.

#include <cstdint>

#include <Eigen/Core>

namespace octofuse {

inline constexpr int kMortonBitsPerAxis = 21;
inline constexpr std::uint32_t kMortonAxisMask = (1u << kMortonBitsPerAxis) - 1u;

// Interleaves the low 21 bits of x, y, z (x in bit 0, y in bit 1, z in bit 2, ...).
constexpr std::uint64_t morton_spread(std::uint32_t v) {
  std::uint64_t x = v & kMortonAxisMask;
  x = (x | (x << 32)) & 0x001F00000000FFFFull;
  x = (x | (x << 16)) & 0x001F0000FF0000FFull;
  x = (x | (x << 8)) & 0x100F00F00F00F00Full;
  x = (x | (x << 4)) & 0x10C30C30C30C30C3ull;
  x = (x | (x << 2)) & 0x1249249249249249ull;
  return x;
}
constexpr std::uint32_t morton_compact(std::uint64_t m) {
  std::uint64_t x = m & 0x1249249249249249ull;
  x = (x | (x >> 2)) & 0x10C30C30C30C30C3ull;
  x = (x | (x >> 4)) & 0x100F00F00F00F00Full;
  x = (x | (x >> 8)) & 0x001F0000FF0000FFull;
  x = (x | (x >> 16)) & 0x001F00000000FFFFull;
  x = (x | (x >> 32)) & 0x00000000001FFFFFull;
  return static_cast<std::uint32_t>(x);
}
// Coordinates must be in [0, 2^21); callers check the cube first.
inline std::uint64_t morton_encode(const Eigen::Vector3i& v) {
  return morton_spread(static_cast<std::uint32_t>(v.x())) |
         (morton_spread(static_cast<std::uint32_t>(v.y())) << 1) |
         (morton_spread(static_cast<std::uint32_t>(v.z())) << 2);
}
inline Eigen::Vector3i morton_decode(std::uint64_t m) {
  return {static_cast<int>(morton_compact(m)), static_cast<int>(morton_compact(m >> 1)),
          static_cast<int>(morton_compact(m >> 2))};
}

struct Key {
  std::uint64_t morton = 0;  // of the minimum corner, finest voxel coordinates
  std::uint8_t level = 0;    // 0 = root

  friend bool operator==(const Key& a, const Key& b) {
    return a.morton == b.morton && a.level == b.level;
  }
  friend bool operator!=(const Key& a, const Key& b) { return !(a == b); }
  // Morton order, then coarser level first (a parent sorts before its first child).
  friend bool operator<(const Key& a, const Key& b) {
    return a.morton != b.morton ? a.morton < b.morton : a.level < b.level;
  }
};

// Side of an octant at `level`, in finest voxels: 2^(voxel_depth - level).
constexpr int octant_size_voxels(int level, int voxel_depth) {
  return 1 << (voxel_depth - level);
}

// The key of the octant at `level` containing finest voxel `voxel` (inside the cube).
inline Key key_of_voxel(const Eigen::Vector3i& voxel, int level, int voxel_depth) {
  const int shift = voxel_depth - level;
  const std::uint64_t mask = ~((std::uint64_t{1} << (3 * shift)) - 1u);
  return Key{morton_encode(voxel) & mask, static_cast<std::uint8_t>(level)};
}
// Minimum corner of the octant, finest voxel coordinates.
inline Eigen::Vector3i key_corner_voxel(const Key& key) {
  return morton_decode(key.morton);
}
// Parent octant (level - 1); the root's parent is the root.
inline Key parent_key(const Key& key, int voxel_depth) {
  if (key.level == 0) return key;
  const int shift = voxel_depth - key.level + 1;
  const std::uint64_t mask = ~((std::uint64_t{1} << (3 * shift)) - 1u);
  return Key{key.morton & mask, static_cast<std::uint8_t>(key.level - 1)};
}
// Which child of its parent the octant is, 0..7 (bit 0 = +x half, bit 1 = +y, bit 2 = +z).
inline int child_index(const Key& key, int voxel_depth) {
  const int shift = voxel_depth - key.level;
  return static_cast<int>((key.morton >> (3 * shift)) & 7u);
}
// Child `child` (0..7, bits as in child_index) one level finer; key.level < voxel_depth.
inline Key child_key(const Key& key, int child, int voxel_depth) {
  const int shift = voxel_depth - key.level - 1;
  return Key{key.morton | (static_cast<std::uint64_t>(child & 7) << (3 * shift)),
             static_cast<std::uint8_t>(key.level + 1)};
}
// The octant at `level` (<= key.level) containing `key`.
inline Key parent_key_at(const Key& key, int level, int voxel_depth) {
  const int shift = voxel_depth - level;
  const std::uint64_t mask = ~((std::uint64_t{1} << (3 * shift)) - 1u);
  return Key{key.morton & mask, static_cast<std::uint8_t>(level)};
}

// True when `ancestor` contains `key` (an octant contains itself).
inline bool key_contains(const Key& ancestor, const Key& key, int voxel_depth) {
  if (ancestor.level > key.level) return false;
  return parent_key_at(key, ancestor.level, voxel_depth) == ancestor;
}
// Finest voxel coordinates snapped to the grid of scale `scale` (paper: x_l = s * floor(x / s)).
inline Eigen::Vector3i snap_to_scale(const Eigen::Vector3i& voxel, int scale) {
  return {(voxel.x() >> scale) << scale, (voxel.y() >> scale) << scale,
          (voxel.z() >> scale) << scale};
}
// Block coordinates (finest voxel / 8, floor) and back (the block's minimum voxel).
inline Eigen::Vector3i voxel_to_block(const Eigen::Vector3i& voxel) {
  return {voxel.x() >> 3, voxel.y() >> 3, voxel.z() >> 3};
}
inline Eigen::Vector3i block_to_voxel(const Eigen::Vector3i& block) {
  return {block.x() * 8, block.y() * 8, block.z() * 8};
}

}  // namespace octofuse
