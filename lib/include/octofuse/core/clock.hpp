#pragma once
// The library reads time only through an injected clock, so tests can drive it and boards can
// use their own timer. A null clock reads 0 (stage times then report 0).

#include <cstdint>

namespace octofuse {

struct Clock {
  std::int64_t (*now_us)(void* context) = nullptr;  // monotonic microseconds
  void* context = nullptr;

  std::int64_t now() const { return now_us != nullptr ? now_us(context) : 0; }
};

}  // namespace octofuse
