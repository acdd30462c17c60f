// octofuse-live: the pipeline on a live camera (or a camera recording). Prints the frame rate and
// tracking state as it goes; on Ctrl-C or SIGTERM (or the end of a recording) it writes the same
// outputs as octofuse-replay, and the map with --save-map.

#include <cstdio>

#include "run_args.hpp"
#include "stop_signal.hpp"

int main(int argc, char** argv) {
  octofuse::examples::RunOptions options;
  options.source_spec = "openni2";
  options.out_dir = "octofuse-live-out";
  bool help = false;
  bool printed_config = false;
  const int parse_rc =
      octofuse::examples::parse_run_args(argc, argv, &options, &help, &printed_config);
  if (parse_rc != 0) return parse_rc;
  if (printed_config) return 0;
  if (help) {
    octofuse::examples::print_run_usage("octofuse-live", "openni2");
    std::printf(
        "\nCtrl-C or SIGTERM stops the run and writes the outputs (and the map, with "
        "--save-map).\n");
    return 0;
  }
  // Ctrl-C or SIGTERM is how a live run ends: finish the frame, write everything, exit 0 (a
  // second signal ends it at once).
  options.stop = octofuse::examples::install_stop_handlers();
  options.live_status = true;
  octofuse::examples::RunSummary summary;
  const int rc = octofuse::examples::run_pipeline(options, &summary);
  if (rc != 0) return rc;
  octofuse::examples::print_run_summary(options, summary);
  if (!summary.failure.empty()) {
    std::fprintf(stderr, "error: %s\n", summary.failure.c_str());
    return 1;
  }
  return 0;
}
