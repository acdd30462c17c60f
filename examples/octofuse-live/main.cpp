// octofuse-live: the pipeline on a live camera (or a camera recording). Prints the frame rate and
// tracking state as it goes; on Ctrl-C (or the end of a recording) it writes the same outputs as
// octofuse-replay.

#include <csignal>
#include <cstdio>

#include "run_args.hpp"

namespace {

std::atomic<bool> g_stop{false};

extern "C" void on_signal(int) {
  g_stop.store(true);
}

}  // namespace

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
    std::printf("\nCtrl-C stops the run and writes the outputs.\n");
    return 0;
  }
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  options.stop = &g_stop;
  options.live_status = true;
  octofuse::examples::RunSummary summary;
  const int rc = octofuse::examples::run_pipeline(options, &summary);
  if (rc != 0) return rc;
  octofuse::examples::print_run_summary(options, summary);
  return 0;
}
