#pragma once
// SIGINT/SIGTERM for the host programs: the first one only raises a flag that the run loop polls
// between frames, so the frame in progress finishes and every output is written; a second one
// ends the process at once (exit status 128 + the signal), for a run that does not stop.

#include <atomic>

namespace octofuse::examples {

// Installs the handlers (once; later calls return the same flag). The flag is set from the
// handler: a lock-free atomic, the only kind a handler may touch.
const std::atomic<bool>* install_stop_handlers();
// The signal that raised the flag, 0 when none did.
int stop_signal_number();
// "SIGINT", "SIGTERM" or "signal N".
const char* stop_signal_name(int signal_number);

}  // namespace octofuse::examples
