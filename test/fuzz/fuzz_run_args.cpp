// The command line of octofuse-replay and octofuse-live: the input split at NUL bytes into
// arguments. parse_run_args either fills the options with values in their documented ranges or
// returns a non-zero exit code (after one "error:" line); it never crashes or reads past argv.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "run_args.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > 4096) return 0;
  // The "error:" lines go to stderr with the fuzzer's own output: silencing them would hide a
  // sanitizer report too.
  std::vector<std::string> args{"octofuse-replay"};
  std::string current;
  for (std::size_t i = 0; i < size; ++i) {
    if (data[i] == 0) {
      args.push_back(current);
      current.clear();
    } else {
      current.push_back(static_cast<char>(data[i]));
    }
  }
  if (!current.empty()) args.push_back(current);
  // argv as main() gets it: its own heap strings, so AddressSanitizer sees any overread.
  std::vector<std::vector<char>> storage;
  std::vector<char*> argv;
  for (const std::string& a : args) {
    storage.emplace_back(a.begin(), a.end());
    storage.back().push_back('\0');
  }
  for (std::vector<char>& s : storage) argv.push_back(s.data());
  argv.push_back(nullptr);

  octofuse::examples::RunOptions options;
  options.out_dir = "octofuse-out";  // as octofuse-replay's main() sets it
  bool help = false;
  const int rc = octofuse::examples::parse_run_args(static_cast<int>(args.size()), argv.data(),
                                                    &options, &help);
  if (rc != 0 || help) return 0;
  // Accepted: every value is in its documented range.
  if (options.out_dir.empty()) __builtin_trap();
  if (!(options.voxel_size_m >= 1e-4f && options.voxel_size_m <= 1.0f)) __builtin_trap();
  if (!(options.mu_m == 0.0f || (options.mu_m >= 1e-4f && options.mu_m <= 10.0f))) __builtin_trap();
  if (!(options.map_memory_mb >= 1.0f && options.map_memory_mb <= 1e6f)) __builtin_trap();
  if (options.threads < 1 || options.threads > 64) __builtin_trap();
  int icp = 0;
  for (int level = 0; level < 3; ++level) {
    const int it = options.budget.icp_iterations[level];
    if (it < 0 || it > 100) __builtin_trap();
    icp += it;
  }
  if (icp == 0) __builtin_trap();
  if (options.source.have_intrinsics &&
      !(std::isfinite(options.source.intrinsics[0]) && options.source.intrinsics[0] > 0.0 &&
        std::isfinite(options.source.intrinsics[1]) && options.source.intrinsics[1] > 0.0)) {
    __builtin_trap();
  }
  return 0;
}
