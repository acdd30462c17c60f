#pragma once
// Little-endian 32-bit fields written and read byte by byte, so the bytes of the map's records
// (map_io.cpp, the free-space region records) do not depend on the machine.

#include <cstdint>

namespace octofuse::detail {

inline void put_u32(std::uint8_t* p, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
inline std::uint32_t get_u32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

}  // namespace octofuse::detail
