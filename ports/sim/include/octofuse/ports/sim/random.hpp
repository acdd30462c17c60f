#pragma once
// Small deterministic random numbers, the same on every standard library and CPU (std::
// distributions differ between implementations). Noise is a pure function of (seed, frame, pixel,
// stream), so a frame's noise does not depend on the order pixels are visited in.

#include <cstdint>

namespace octofuse::sim {

// SplitMix64's finaliser: a bijective 64-bit mix.
constexpr std::uint64_t mix64(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

constexpr std::uint64_t hash_key(std::uint64_t seed, std::uint64_t a, std::uint64_t b,
                                 std::uint64_t c) {
  return mix64(seed ^ mix64(a ^ mix64(b ^ mix64(c))));
}

// Uniform in (0, 1) from the top 53 bits.
constexpr double uniform_from_bits(std::uint64_t bits) {
  return (static_cast<double>(bits >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

// Zero mean, unit variance, from one 64-bit value: the sum of four 16-bit uniforms (Irwin-Hall),
// scaled. Bounded at +-sqrt(12) sigma, which suits a sensor model and needs no libm.
constexpr double gaussian_from_bits(std::uint64_t bits) {
  double sum = 0.0;
  for (int i = 0; i < 4; ++i) {
    sum += (static_cast<double>((bits >> (16 * i)) & 0xffffu) + 0.5) * (1.0 / 65536.0);
  }
  return (sum - 2.0) * 1.7320508075688772;  // variance 4/12 -> 1
}

// A sequential generator for sampling (SplitMix64).
class SplitMix64 {
 public:
  explicit SplitMix64(std::uint64_t seed) : state_(seed) {}
  std::uint64_t next() {
    const std::uint64_t out = mix64(state_);
    state_ += 0x9e3779b97f4a7c15ull;
    return out;
  }
  double uniform() { return uniform_from_bits(next()); }

 private:
  std::uint64_t state_;
};

}  // namespace octofuse::sim
