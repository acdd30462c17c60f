#pragma once
// Per-frame stage-time plot (stacked areas, like the paper's Fig. 8) written as a standalone SVG
// that any browser shows.

#include <string>
#include <vector>

namespace octofuse::plot {

struct StageSeries {
  std::string name;            // "track"
  std::string colour;          // "#1f77b4"
  std::vector<double> values;  // one value per frame (ms)
};

// Stacks the series in the order given. All series must have the same length. Returns false (and
// writes nothing) if the file cannot be written or the series are inconsistent.
bool write_stacked_svg(const std::string& path, const std::string& title,
                       const std::vector<StageSeries>& series);

}  // namespace octofuse::plot
