#pragma once
// Four 32-bit lanes in the compiler's vector type (GCC and Clang), for short fixed-size arithmetic
// that would otherwise be scalar Eigen (the library builds Eigen without its own SIMD): SSE2 and
// NEON registers on x86-64 and aarch64; armhf, whose NEON float lanes are not IEEE (flush to
// zero), computes them one by one. Each lane rounds as scalar code does (no contraction:
// -ffp-contract=off), so an expression written in the scalar code's order of operations gives
// the same bits on every target.

#include <cstdint>

namespace octofuse {

using Lanes4 = float __attribute__((vector_size(16)));
using Ints4 = std::int32_t __attribute__((vector_size(16)));

// floor() of one float for |x| < 2^31 without a libm call (the x86-64 baseline has no SSE4.1
// round): truncation, less one where it rounded up. floor_lanes() below is its lane-wise form.
inline int floor_to_int(float x) {
  const int i = static_cast<int>(x);
  return i - (x < static_cast<float>(i) ? 1 : 0);
}

// The floor of each lane, for lanes within int's range (callers bound or clamp them first):
// truncation, less one where it rounded up (negative non-integers). A comparison gives -1 in a
// true lane.
inline Ints4 floor_lanes(Lanes4 x) {
  const Ints4 truncated = __builtin_convertvector(x, Ints4);
  return truncated + (x < __builtin_convertvector(truncated, Lanes4));
}

}  // namespace octofuse
