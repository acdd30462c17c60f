#include "octofuse/pipeline/steady_clock.hpp"

#include <chrono>

namespace octofuse {

std::int64_t steady_now_us(void* /*context*/) {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

Clock steady_clock() {
  return Clock{&steady_now_us, nullptr};
}

}  // namespace octofuse
