#pragma once
// The command line shared by octofuse-replay and octofuse-live (options listed in docs/replay.md),
// and the configuration files that spell the same options (see config_file.hpp).

#include <string>

#include "runner.hpp"

namespace octofuse::examples {

struct RunArgsRequest {
  bool help = false;          // -h/--help
  bool print_config = false;  // --print-config
};

// Fills `options` from argv (options not given keep their values): first the file named by
// --config FILE, then the command line, which overrides it. False with `error` set (no "error: "
// prefix; file problems as "FILE:LINE: ...") on an unknown option or key or a bad value.
bool parse_run_args(int argc, char** argv, RunOptions* options, RunArgsRequest* request,
                    std::string* error);
// The same, for main(): returns 0, or the exit code after printing "error: ...". Sets *help for
// -h/--help; with --print-config prints the effective options to stdout and sets *printed_config
// (the caller then exits with 0).
int parse_run_args(int argc, char** argv, RunOptions* options, bool* help,
                   bool* printed_config = nullptr);

// Applies config-file text as --config would; `file_name` names it in errors.
bool apply_run_config(const std::string& text, const std::string& file_name, RunOptions* options,
                      std::string* error);
// Every option as a config file: `key = value` where the value is set, "# key = (default)" where
// the program's built-in default applies. Read back with --config it gives the same options.
// False (with `error`) only for a value a config line cannot hold (a newline, surrounding blanks).
bool format_run_config(const RunOptions& options, std::string* text, std::string* error);

void print_run_usage(const char* program, const char* default_source);
// Prints the closing summary (frames, timing, memory, ATE, what was written).
void print_run_summary(const RunOptions& options, const RunSummary& summary);

}  // namespace octofuse::examples
