// octofuse-replay: the main job. Runs the pipeline over a source (the built-in synthetic desk by
// default) and writes trajectory.txt, mesh.ply, render.png, stats.json and stage_times.svg.

#include <cstdio>

#include <cstring>

#include "cli.hpp"
#include "run_args.hpp"
#include "sources.hpp"
#include "stop_signal.hpp"

int main(int argc, char** argv) {
  if (argc >= 2 && std::strcmp(argv[1], "--list") == 0) {
    return octofuse::examples::list_bag(argc == 3 ? argv[2] : std::string());
  }
  octofuse::examples::RunOptions options;
  options.out_dir = "octofuse-out";
  bool help = false;
  bool printed_config = false;
  const int parse_rc =
      octofuse::examples::parse_run_args(argc, argv, &options, &help, &printed_config);
  if (parse_rc != 0) return parse_rc;
  if (printed_config) return 0;
  if (help) {
    octofuse::examples::print_run_usage("octofuse-replay", "sim:desk");
    std::fputs(octofuse::cli::format_option(
                   "--list", "FILE", "print a bag's topics, types, counts and time span, and exit")
                   .c_str(),
               stdout);
    return 0;
  }
  // SIGINT/SIGTERM: finish the frame, write everything, exit 128 + the signal (cut short).
  options.stop = octofuse::examples::install_stop_handlers();
  octofuse::examples::RunSummary summary;
  const int rc = octofuse::examples::run_pipeline(options, &summary);
  if (rc != 0) return rc;
  octofuse::examples::print_run_summary(options, summary);
  if (!summary.failure.empty()) {
    std::fprintf(stderr, "error: %s\n", summary.failure.c_str());
    return 1;
  }
  if (const int signal_number = octofuse::examples::stop_signal_number()) {
    std::fprintf(stderr, "stopped by %s after %zu frames; outputs written\n",
                 octofuse::examples::stop_signal_name(signal_number), summary.frames.size());
    return 128 + signal_number;
  }
  return 0;
}
