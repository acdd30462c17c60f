// octofuse-replay: the main job. Runs the pipeline over a source (the built-in synthetic desk by
// default) and writes trajectory.txt, mesh.ply, render.png, stats.json and stage_times.svg.

#include "run_args.hpp"

int main(int argc, char** argv) {
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
    return 0;
  }
  octofuse::examples::RunSummary summary;
  const int rc = octofuse::examples::run_pipeline(options, &summary);
  if (rc != 0) return rc;
  octofuse::examples::print_run_summary(options, summary);
  return 0;
}
