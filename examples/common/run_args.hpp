#pragma once
// The command line shared by octofuse-replay and octofuse-live (options listed in the README).

#include "runner.hpp"

namespace octofuse::examples {

// Fills `options` from argv (options not given keep their values). Returns 0, or the exit code
// after printing "error: ...". Sets *help for -h/--help.
int parse_run_args(int argc, char** argv, RunOptions* options, bool* help);
void print_run_usage(const char* program, const char* default_source);
// Prints the closing summary (frames, timing, memory, ATE, what was written).
void print_run_summary(const RunOptions& options, const RunSummary& summary);

}  // namespace octofuse::examples
