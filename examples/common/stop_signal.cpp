#include "stop_signal.hpp"

#include <unistd.h>

#include <csignal>
#include <cstdio>

namespace octofuse::examples {
namespace {

static_assert(std::atomic<bool>::is_always_lock_free, "a signal handler needs a lock-free flag");

std::atomic<bool> g_stop{false};
volatile std::sig_atomic_t g_signal = 0;

extern "C" void on_stop_signal(int signal_number) {
  if (g_stop.load()) _exit(128 + signal_number);  // the second signal: end now
  g_signal = signal_number;
  g_stop.store(true);
}

}  // namespace

const std::atomic<bool>* install_stop_handlers() {
  static bool installed = false;
  if (!installed) {
    struct sigaction action = {};
    action.sa_handler = on_stop_signal;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESTART;  // reads and writes in progress carry on
    sigaction(SIGINT, &action, nullptr);
    sigaction(SIGTERM, &action, nullptr);
    installed = true;
  }
  return &g_stop;
}

int stop_signal_number() {
  return static_cast<int>(g_signal);
}

const char* stop_signal_name(int signal_number) {
  if (signal_number == SIGINT) return "SIGINT";
  if (signal_number == SIGTERM) return "SIGTERM";
  static char text[32];
  std::snprintf(text, sizeof(text), "signal %d", signal_number);
  return text;
}

}  // namespace octofuse::examples
