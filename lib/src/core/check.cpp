#include "octofuse/core/check.hpp"

#include <atomic>
#include <cstdio>
#include <cstdlib>

namespace octofuse {
namespace {

void default_check_handler(const char* file, int line, const char* expression) {
  std::fprintf(stderr, "octofuse: check failed at %s:%d: %s\n", file, line, expression);
}

std::atomic<CheckHandler> g_check_handler{&default_check_handler};
std::atomic<std::uint64_t> g_soft_check_failures{0};

}  // namespace

CheckHandler set_check_handler(CheckHandler handler) {
  return g_check_handler.exchange(handler != nullptr ? handler : &default_check_handler);
}

void check_failed(const char* file, int line, const char* expression) {
  g_check_handler.load()(file, line, expression);
  // A handler that returns does not resume the broken code path.
  std::abort();
}

std::uint64_t soft_check_failures() {
  return g_soft_check_failures.load();
}
void count_soft_check_failure() {
  g_soft_check_failures.fetch_add(1);
}

}  // namespace octofuse
