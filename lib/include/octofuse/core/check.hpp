#pragma once
// One check macro for programmer errors and broken invariants. A failed check calls the installed
// handler (default: print file:line and the expression to stderr, then abort). Boards install
// their own handler (log and reset). Bad *input* never goes through here: it gets a Status.

#include <cstdint>

namespace octofuse {

using CheckHandler = void (*)(const char* file, int line, const char* expression);

// Installs `handler` (null restores the default) and returns the previous one.
CheckHandler set_check_handler(CheckHandler handler);

[[noreturn]] void check_failed(const char* file, int line, const char* expression);

// "Should never happen, keep running" events: counted per process, read out by stats.
std::uint64_t soft_check_failures();
void count_soft_check_failure();

}  // namespace octofuse

#define OCTOFUSE_CHECK(cond)                                                               \
  do {                                                                                     \
    if (__builtin_expect(!(cond), 0)) ::octofuse::check_failed(__FILE__, __LINE__, #cond); \
  } while (false)

// Evaluates to `cond`; when false, counts a soft failure instead of stopping.
#define OCTOFUSE_SOFT_CHECK(cond) ((cond) ? true : (::octofuse::count_soft_check_failure(), false))
