#pragma once
// The host's monotonic clock (std::chrono::steady_clock) as a Clock, for programs and tests on a
// machine with the C++ standard library's clocks. Boards pass their own timer instead.

#include <cstdint>

#include "octofuse/pipeline/clock.hpp"

namespace octofuse {

// Microseconds of std::chrono::steady_clock since its epoch; `context` is unused. Fits
// Clock::now_us and any other `std::int64_t (*)(void*)` time source.
std::int64_t steady_now_us(void* context);

// A Clock reading steady_now_us.
Clock steady_clock();

}  // namespace octofuse
